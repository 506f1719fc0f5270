"""Speed-ups that must not change a single result (issue "Twice as fast"): each fast path is
checked bit for bit against the straightforward computation it replaced."""

import math

import numpy as np
import pytest
import torch
from scipy import ndimage

from helios.config import RenderConfig
from helios.maps.grid import GridGeometry
from helios.maps.renderer import (Rendering, _kept, _kept_torch, _minus_run_start, _minus_run_start_torch,
                                  _select, _select_torch, _sorted_pairs, _sorted_segments, _sorting_permutation,
                                  empty_rendering, render_gaussians)
from helios.planning.fmm import FMMPlanner, _clearance, _descend, _far_enough_inside, _pool
from helios.planning.footprint import FootprintChecker, FootprintConfig
from robots.hal import CameraIntrinsics
from robots.transforms import invert_transform, look_at_camera

_RADIUS_BUCKETS = (1, 2, 3, 4, 5, 6, 8, 10, 12, 14, 16, 20, 24, 28, 32, 40, 48, 56, 64, 80, 96, 128)
_CHUNK_PAIRS = 2_000_000


def _empty(h, w, device):
    return empty_rendering(h, w, device)


def check_pose(T):
    return np.asarray(T, dtype=float)


def reference_render(means: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
                     intrinsics: CameraIntrinsics, T_world_cam: np.ndarray, cfg: RenderConfig,
                     pixel_mask: torch.Tensor | None = None) -> Rendering:
    """The renderer before the speed-up (torch.sort, float pixel grid, bounds tested per pair).
    Rasterise isotropic Gaussians (means (N, 3) world, scales (N,) std-dev in m, opacities (N,)).

    ``pixel_mask`` (H, W) bool restricts the output to those pixels (others get no pairs).
    """
    device = means.device
    H, W = intrinsics.height, intrinsics.width
    if means.shape[0] == 0:
        return _empty(H, W, device)
    T_cam_world = torch.as_tensor(invert_transform(check_pose(T_world_cam)), dtype=torch.float32, device=device)
    p = means @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy

    front = z > cfg.near
    zc = torch.where(front, z, torch.ones_like(z))
    u = fx * x / zc + cx
    v = fy * y / zc + cy
    # EWA screen covariance of an isotropic Gaussian; x/z, y/z clamped as in 3DGS for stability.
    lim_x = 1.3 * max(cx, W - cx) / fx
    lim_y = 1.3 * max(cy, H - cy) / fy
    tx = (x / zc).clamp(-lim_x, lim_x)
    ty = (y / zc).clamp(-lim_y, lim_y)
    s2 = (scales / zc) ** 2
    a = s2 * fx * fx * (1 + tx * tx) + cfg.blur_px2
    b = s2 * fx * fy * tx * ty
    c = s2 * fy * fy * (1 + ty * ty) + cfg.blur_px2
    det = (a * c - b * b).clamp_min(1e-12)
    conic_a, conic_b, conic_c = c / det, -b / det, a / det
    mid = 0.5 * (a + c)
    lam_max = mid + torch.sqrt((mid * mid - det).clamp_min(0.0))
    # alpha >= alpha_min  <=>  mahalanobis^2 <= 2 log(o / alpha_min)
    cutoff = 2.0 * torch.log((opacities / cfg.alpha_min).clamp_min(1.0))
    radius = torch.ceil(torch.sqrt(cutoff * lam_max)).clamp(1, cfg.max_radius_px)
    uc = torch.floor(u + 0.5)
    vc = torch.floor(v + 0.5)
    ok = (front & (cutoff > 0) & (uc + radius >= 0) & (uc - radius <= W - 1)
          & (vc + radius >= 0) & (vc - radius <= H - 1))
    if pixel_mask is not None:
        pm = pixel_mask.to(device=device, dtype=torch.bool)
        if not bool(pm.any()):
            return _empty(H, W, device)
        rows = torch.nonzero(pm.any(dim=1)).flatten()
        cols = torch.nonzero(pm.any(dim=0)).flatten()
        ok &= ((uc + radius >= cols[0]) & (uc - radius <= cols[-1])
               & (vc + radius >= rows[0]) & (vc - radius <= rows[-1]))
        pm_flat = pm.reshape(-1)
    idx = torch.nonzero(ok).flatten()
    if idx.numel() == 0:
        return _empty(H, W, device)

    # Global depth order of the visible Gaussians.
    order = torch.argsort(z[idx], stable=True)
    idx = idx[order]
    n_vis = idx.numel()
    rank = torch.arange(n_vis, device=device, dtype=torch.int64)
    r_vis = radius[idx]
    buckets = torch.as_tensor([r for r in _RADIUS_BUCKETS if r < cfg.max_radius_px] + [cfg.max_radius_px],
                              dtype=r_vis.dtype, device=device)
    bucket_of = torch.bucketize(r_vis, buckets)
    pair_g, pair_pix, pair_alpha, pair_rank = [], [], [], []
    candidates = 0
    for k in torch.unique(bucket_of).tolist():
        R = int(buckets[k])
        members = torch.nonzero(bucket_of == k).flatten()
        off = torch.arange(-R, R + 1, device=device, dtype=torch.float32)
        dy, dx = torch.meshgrid(off, off, indexing="ij")
        disc = dx * dx + dy * dy <= (R + 0.5) ** 2     # the footprint ellipse lies within radius R
        dx, dy = dx[disc].reshape(1, -1), dy[disc].reshape(1, -1)
        per = dx.shape[1]
        step = max(1, _CHUNK_PAIRS // per)
        for s in range(0, members.numel(), step):
            m = members[s:s + step]
            g = idx[m]
            pu = uc[g][:, None] + dx
            pv = vc[g][:, None] + dy
            du = pu - u[g][:, None]
            dv = pv - v[g][:, None]
            power = -0.5 * (conic_a[g][:, None] * du * du + 2.0 * conic_b[g][:, None] * du * dv
                            + conic_c[g][:, None] * dv * dv)
            alpha = (opacities[g][:, None] * torch.exp(power)).clamp_max(cfg.alpha_max)
            keep = (alpha >= cfg.alpha_min) & (pu >= 0) & (pu <= W - 1) & (pv >= 0) & (pv <= H - 1)
            pix = pv.to(torch.int64) * W + pu.to(torch.int64)
            if pixel_mask is not None:
                keep &= pm_flat[pix.clamp(0, H * W - 1)]
            candidates += keep.numel()
            rows_k, cols_k = torch.nonzero(keep, as_tuple=True)
            pair_g.append(g[rows_k])
            pair_rank.append(rank[m][rows_k])
            pair_pix.append(pix[rows_k, cols_k])
            pair_alpha.append(alpha[rows_k, cols_k])
    g_all = torch.cat(pair_g)
    if g_all.numel() == 0:
        return _empty(H, W, device)
    pix_all = torch.cat(pair_pix)
    rank_all = torch.cat(pair_rank)
    alpha_all = torch.cat(pair_alpha)

    # Sort by (pixel, depth rank) in one key, then composite each pixel's run front to back.
    key = pix_all * n_vis + rank_all
    key, perm = torch.sort(key)
    g_all, pix_all, alpha_all = g_all[perm], pix_all[perm], alpha_all[perm]
    log_one_minus = torch.log1p(-alpha_all.to(torch.float64))
    inclusive = torch.cumsum(log_one_minus, 0)
    exclusive = inclusive - log_one_minus
    starts = torch.ones_like(pix_all, dtype=torch.bool)
    starts[1:] = pix_all[1:] != pix_all[:-1]
    segment = torch.cumsum(starts.to(torch.int64), 0) - 1
    log_T = exclusive - exclusive[starts][segment]
    keep = log_T >= math.log(cfg.transmittance_min)
    weight = (alpha_all.to(torch.float64) * torch.exp(log_T))[keep].to(torch.float32)
    g_all, pix_all = g_all[keep], pix_all[keep]
    depth = z[g_all]

    sil = torch.zeros(H * W, dtype=torch.float32, device=device)
    sil.index_add_(0, pix_all, weight)
    acc = torch.zeros(H * W, dtype=torch.float32, device=device)
    acc.index_add_(0, pix_all, weight * depth)
    return Rendering(H, W, g_all, pix_all, weight, depth, sil.reshape(H, W), acc.reshape(H, W),
                     candidate_pairs=candidates)


# ----------------------------------------------------------------------------- renderer
def _random_scene(rng, n):
    means = np.stack([rng.uniform(-2.5, 2.5, n), rng.uniform(-1.5, 1.5, n), rng.uniform(-0.5, 6.0, n)], axis=1)
    scales = rng.uniform(0.005, 0.15, n)
    opacities = rng.uniform(0.05, 0.95, n)
    return (torch.tensor(means, dtype=torch.float32), torch.tensor(scales, dtype=torch.float32),
            torch.tensor(opacities, dtype=torch.float32))


def _same(a: Rendering, b: Rendering) -> bool:
    return all(torch.equal(getattr(a, f), getattr(b, f)) for f in
               ("gaussian_index", "pixel_index", "weight", "pair_depth", "silhouette", "accumulated_depth")) \
        and a.candidate_pairs == b.candidate_pairs


@pytest.mark.parametrize("seed", range(4))
def test_renderer_matches_the_previous_implementation_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    cam = CameraIntrinsics(160, 120, 130.0, 130.0, 79.5, 59.5)
    cfg = RenderConfig()
    means, scales, opacities = _random_scene(rng, 3000)
    pose = look_at_camera(np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), -1.0]), np.array([0.0, 0.0, 3.0]))
    fast = render_gaussians(means, scales, opacities, cam, pose, cfg)
    assert fast.weight.numel() > 10_000                     # a real scene, windows cut by the image edge
    assert _same(fast, reference_render(means, scales, opacities, cam, pose, cfg))
    mask = torch.zeros(120, 160, dtype=torch.bool)
    mask[30:70, 50:140] = True
    assert _same(render_gaussians(means, scales, opacities, cam, pose, cfg, mask),
                 reference_render(means, scales, opacities, cam, pose, cfg, mask))
    # without depth (view evidence): every other field as the full render's, bit for bit
    bare = render_gaussians(means, scales, opacities, cam, pose, cfg, depth=False)
    assert all(torch.equal(getattr(bare, f), getattr(fast, f)) for f in
               ("gaussian_index", "pixel_index", "weight", "silhouette")) and bare.candidate_pairs == fast.candidate_pairs
    assert bare.pair_depth.numel() == 0 and not bare.accumulated_depth.any()


def test_run_start_subtraction_on_the_cpu_equals_the_torch_ops_bit_for_bit():
    rng = np.random.default_rng(3)
    runs = torch.as_tensor(np.sort(rng.integers(0, 2000, 50_000)))
    values = torch.cumsum(torch.as_tensor(np.log1p(-rng.uniform(0.0, 0.99, 50_000))), 0)
    fast, slow = _minus_run_start(values, runs), _minus_run_start_torch(values, runs)
    assert fast.dtype == torch.float64 and torch.equal(fast, slow)
    starts = torch.ones_like(runs, dtype=torch.bool)
    starts[1:] = runs[1:] != runs[:-1]
    assert bool((fast[starts] == 0).all()) and bool((fast[~starts] != 0).any())


def test_sorting_permutation_is_torch_sort_for_distinct_keys():
    key = torch.as_tensor(np.random.default_rng(0).permutation(5_000_000)[:300_000].astype(np.int64))
    assert torch.equal(_sorting_permutation(key), torch.sort(key).indices)
    huge = key + (1 << 40)                                  # too large to pack: torch.sort path
    assert torch.equal(_sorting_permutation(huge), torch.sort(huge).indices)


def test_packed_pair_sort_reads_back_what_the_key_sort_gathers():
    rng = np.random.default_rng(7)
    n_pixels, n_ranks = 160 * 120, 20_000
    # 250 000 distinct (pixel, rank) keys in random order (drawn, not a permutation of all 384 M:
    # that took 27 s and 3 GB)
    key = rng.permutation(np.unique(rng.integers(0, n_pixels * n_ranks, 260_000)))[:250_000].astype(np.int64)
    assert np.unique(key).size == key.size == 250_000
    pix, rank = torch.as_tensor(key // n_ranks), torch.as_tensor(key % n_ranks)
    sorted_pix, sorted_rank, perm = _sorted_pairs(pix, rank, n_pixels, n_ranks)
    order = torch.sort(pix * n_ranks + rank).indices
    assert torch.equal(perm, order)
    assert torch.equal(sorted_pix, pix[order]) and torch.equal(sorted_rank, rank[order])
    # too many bits to pack (a huge rank range): the key-sort fallback gives the same
    fallback = _sorted_pairs(pix, rank, n_pixels, 1 << 40)
    assert all(torch.equal(a, b) for a, b in zip(fallback, (sorted_pix, sorted_rank, perm)))


def _segments(rng, n_ranks: int, n_pixels: int):
    """Pairs in one segment per Gaussian (some empty), ranks a permutation, no (pixel, rank) twice."""
    counts = rng.integers(0, 40, n_ranks)
    counts[rng.random(n_ranks) < 0.2] = 0
    segment_rank = rng.permutation(n_ranks)
    pix = np.concatenate([rng.choice(n_pixels, c, replace=False) for c in counts])
    return torch.as_tensor(pix), torch.as_tensor(counts), torch.as_tensor(segment_rank)


def test_segment_sort_is_the_pair_sort():
    rng = np.random.default_rng(11)
    for n_pixels in (160 * 120, 1 << 16, 640 * 480):       # the last: too many pixels for 16 bits
        pix, counts, segment_rank = _segments(rng, 3_000, n_pixels)
        rank = torch.repeat_interleave(segment_rank, counts)
        fast = _sorted_segments(pix, counts, segment_rank, n_pixels)
        slow = _sorted_pairs(pix, rank, n_pixels, segment_rank.numel())
        assert all(a.dtype == b.dtype and torch.equal(a, b) for a, b in zip(fast, slow))
        key = fast[0] * segment_rank.numel() + fast[1]
        assert bool((key[1:] > key[:-1]).all())            # (pixel, rank) order, every pair once
        assert torch.equal(pix[fast[2]], fast[0]) and torch.equal(rank[fast[2]], fast[1])


def test_kept_pairs_and_selection_on_the_cpu_equal_the_torch_ops():
    rng = np.random.default_rng(8)
    alpha = torch.as_tensor(rng.random((700, 45), dtype=np.float32))
    keep = alpha >= 0.6
    keep[3] = False                                         # a row without pairs: a count of 0
    base_pix = torch.as_tensor(rng.integers(0, 19_200, 700))
    offset_pix = torch.as_tensor(rng.integers(-500, 500, 45))
    fast, slow = _kept(keep, base_pix, offset_pix, alpha), _kept_torch(keep, base_pix, offset_pix, alpha)
    assert torch.equal(fast[0], keep.sum(dim=1)) and int(fast[0][3]) == 0
    assert len(fast[1]) == int(keep.sum()) > 0
    assert all(a.dtype == b.dtype and torch.equal(a, b) for a, b in zip(fast, slow))
    mask = alpha.reshape(-1) >= 0.3
    arrays = (alpha.reshape(-1), torch.arange(mask.numel()), alpha.reshape(-1).to(torch.float64))
    fast, slow = _select(mask, *arrays), _select_torch(mask, *arrays)
    assert len(fast[1]) == int(mask.sum()) and all(a.dtype == b.dtype and torch.equal(a, b) for a, b in zip(fast, slow))
    everything = torch.ones_like(mask)                      # nothing cut: the arrays as they are, no gathers
    fast, slow = _select(everything, *arrays), _select_torch(everything, *arrays)
    assert all(a.dtype == b.dtype and torch.equal(a, b) for a, b in zip(fast, slow))


def test_is_valid_transform_gives_np_allcloses_answers():
    """The rigid-transform check with np.allclose written out (a third of the time, ~480 calls an
    episode): the same verdict on rotations, reflections, near-misses around both tolerances, NaN."""
    from robots.transforms import is_valid_transform

    def reference(T, tol=1e-6):
        T = np.asarray(T)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            return False
        R = T[:3, :3]
        return bool(np.allclose(R @ R.T, np.eye(3), atol=1e-4) and abs(np.linalg.det(R) - 1.0) < 1e-4
                    and np.allclose(T[3], [0, 0, 0, 1], atol=tol))

    rng = np.random.default_rng(3)
    cases = []
    for _ in range(400):
        q, _r = np.linalg.qr(rng.normal(size=(3, 3)))
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = q, rng.normal(size=3)
        cases.append(T)                                           # det +1 or -1 (a reflection)
        for scale in (1e-7, 3e-5, 5e-5, 1e-4, 1e-3):
            cases.append(T + np.pad(rng.normal(scale=scale, size=(3, 3)), ((0, 1), (0, 1))))
            bottom = T.copy()
            bottom[3, :3] = rng.normal(scale=scale, size=3)
            cases.append(bottom)
        cases.append(T.astype(np.float32))
    nan = np.eye(4)
    nan[0, 3] = np.nan
    cases += [nan, np.eye(3), np.eye(4)]
    verdicts = [is_valid_transform(T) for T in cases]
    assert verdicts == [reference(T) for T in cases]
    assert 0 < sum(verdicts) < len(verdicts)


def test_clip_index_is_np_clip_for_cell_indices():
    from helios.maps.grid import clip_index

    cells = np.random.default_rng(5).integers(-3000, 5000, size=(64, 37))
    for last in (0, 1, 1999):
        got = clip_index(cells, last)
        assert got.dtype == cells.dtype and np.array_equal(got, np.clip(cells, 0, last))


# ----------------------------------------------------------------------------- footprint
def _boxes_checker(rng, boxes: int) -> FootprintChecker:
    """A footprint checker on a 10 m map strewn with ``boxes`` small random obstacles."""
    geometry = GridGeometry(0.025, 400, -5.0, -5.0)
    obstacle = np.zeros(geometry.shape, dtype=bool)
    for _ in range(boxes):
        r, c = rng.integers(0, 390, size=2)
        obstacle[r:r + rng.integers(1, 12), c:c + rng.integers(1, 12)] = True
    return FootprintChecker(FootprintConfig(), geometry, obstacle)


@pytest.mark.parametrize("seed", range(3))
def test_footprint_tiles_give_the_exhaustive_answer(seed):
    rng = np.random.default_rng(seed)
    checker = _boxes_checker(rng, 60)
    for grid, pts in ((checker.obstacle, checker._body), (checker.tall, checker._arm)):
        # a walk across the map (one window), scattered poses, and poses hanging off the grid
        line = np.stack([np.linspace(-3, 3, 400), np.linspace(-2, 2.5, 400), rng.uniform(-np.pi, np.pi, 400)], axis=1)
        scattered = np.stack([rng.uniform(-6, 6, 300), rng.uniform(-6, 6, 300), rng.uniform(-np.pi, np.pi, 300)], axis=1)
        for poses in (line, scattered, line[:1]):
            fast = checker._hits(poses, pts, grid)
            assert np.array_equal(fast, checker._hits_exhaustive(poses, pts, grid))
        assert 0 < checker._hits(line, pts, grid).sum() < len(line)     # both answers occur


@pytest.mark.parametrize("seed", range(3))
def test_segments_free_is_segment_free_for_each_end(seed):
    """The planner's shuffle tests a batch of short straight moves from one pose at once."""
    rng = np.random.default_rng(seed)
    checker = _boxes_checker(rng, 80)
    answers = []
    for _ in range(40):
        x0, y0, yaw = rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-np.pi, np.pi)
        ends = np.stack([x0 + rng.uniform(-0.6, 0.6, 12), y0 + rng.uniform(-0.6, 0.6, 12)], axis=1)
        ends[0] = (x0, y0)                                     # a zero-length move too
        batch = checker.segments_free(x0, y0, ends, yaw)
        one_by_one = [checker.segment_free(x0, y0, x1, y1, yaw) for x1, y1 in ends]
        assert batch.tolist() == one_by_one
        answers += one_by_one
    assert 0 < sum(answers) < len(answers)                     # both answers occur
    assert checker.segments_free(0.0, 0.0, np.zeros((0, 2)), 0.0).shape == (0,)


# ----------------------------------------------------------------------------- planner
def _random_obstacles(rng, shape, boxes):
    obstacle = np.zeros(shape, dtype=bool)
    for _ in range(boxes):
        r, c = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        obstacle[r:r + rng.integers(1, 30), c:c + rng.integers(1, 30)] = True
    return obstacle


@pytest.mark.parametrize("seed", range(6))
def test_clearance_and_seen_space_match_scipy(seed):
    rng = np.random.default_rng(seed)
    shape = tuple(rng.integers(20, 500, size=2))
    obstacle = _random_obstacles(rng, shape, int(rng.integers(1, 150)))
    assert np.array_equal(_clearance(obstacle, 0.05), ndimage.distance_transform_edt(~obstacle) * 0.05)
    for cell, radius in ((0.05, 0.3), (0.025, 0.3), (0.1, 0.33)):
        for mask in (~obstacle, np.ones(shape, dtype=bool)):        # all-seen: scipy's own convention
            assert np.array_equal(_far_enough_inside(mask, cell, radius),
                                  ndimage.distance_transform_edt(mask) * cell >= radius)
    assert np.array_equal(_clearance(np.zeros((30, 40), bool), 0.05),
                          ndimage.distance_transform_edt(np.ones((30, 40), bool)) * 0.05)


def test_pooling_matches_block_any():
    grid = np.random.default_rng(0).random((203, 117)) < 0.02
    for f in (1, 2, 3):
        h, w = 203 // f * f, 117 // f * f
        assert np.array_equal(_pool(grid, f), grid[:h, :w].reshape(h // f, f, w // f, f).any(axis=(1, 3)))


@pytest.mark.parametrize("seed", range(5))
def test_narrow_band_travel_time_gives_the_full_march_path(seed):
    rng = np.random.default_rng(seed)
    obstacle = _random_obstacles(rng, (300, 300), 120)
    clearance = ndimage.distance_transform_edt(~obstacle) * 0.05
    traversable = clearance >= 0.3
    free = np.argwhere(traversable)
    goal = np.zeros_like(traversable)
    g = free[rng.integers(len(free))]
    goal[g[0], g[1]] = True
    planner = FMMPlanner()
    full = planner._travel_time(traversable, goal, clearance)
    for s in free[rng.integers(len(free), size=8)]:
        start = (int(s[0]), int(s[1]))
        banded = planner._travel_time(traversable, goal, clearance, start)
        assert np.isfinite(banded[start]) == np.isfinite(full[start])
        if np.isfinite(full[start]):
            inside = np.isfinite(banded)
            assert np.array_equal(banded[inside], full[inside]) and banded[start] == full[start]
            assert _descend(banded, start) == _descend(full, start)


# ----------------------------------------------------------------------------- view evidence cache
def test_view_evidence_is_cached_unaliased_and_equal_to_a_fresh_render():
    from helios.config import HeliosConfig
    from helios.maps import ClassSet
    from helios.maps.gaussians import GaussianMap
    from sim.synthetic_boxes import pinhole

    cfg = HeliosConfig()
    gmap = GaussianMap(ClassSet.from_task(["cup", "table"]), cfg.gaussians, cfg.instances, cfg.scoring,
                       GridGeometry(0.025, 400, -5, -5))
    ys, zs = np.meshgrid(np.linspace(-0.05, 0.05, 5), np.linspace(0.95, 1.05, 5))
    gmap.add_gaussians(np.stack([np.full(25, 2.0), ys.ravel(), zs.ravel()], axis=1), 0.02, 0.5)
    cam, pose = pinhole(160, 120), look_at_camera([0.0, 0.0, 1.0], [2.0, 0.0, 1.0])
    idx = np.arange(25)
    calls = []
    render = gmap.render
    gmap.render = lambda *a, **k: calls.append(1) or render(*a, **k)
    first = gmap.view_evidence(idx, cam, pose)
    first += 100.0                                           # the caller's copy, not the cache's
    again = gmap.view_evidence(idx, cam, pose)
    assert len(calls) == 1
    working, _ = gmap.working_intrinsics(cam)
    r = render(working, pose, indices=idx)
    assert torch.equal(again, gmap.evidence_scale * r.per_gaussian_sum(r.silhouette, 25))
    gmap.view_evidence(idx[:10], cam, pose)                  # another index set is another entry
    gmap.view_evidence(idx, cam, look_at_camera([0.0, 0.1, 1.0], [2.0, 0.0, 1.0]))
    assert len(calls) == 3
    assert gmap._view_evidence_bytes == (25 + 10 + 25) * 8


def test_view_evidence_cache_stays_within_its_bytes(monkeypatch):
    import helios.maps.gaussians as gaussians
    from helios.config import HeliosConfig
    from helios.maps import ClassSet
    from helios.maps.gaussians import GaussianMap
    from sim.synthetic_boxes import pinhole

    monkeypatch.setattr(gaussians, "VIEW_EVIDENCE_CACHE_BYTES", 2 * 25 * 8)     # two entries
    cfg = HeliosConfig()
    gmap = GaussianMap(ClassSet.from_task(["cup"]), cfg.gaussians, cfg.instances, cfg.scoring,
                       GridGeometry(0.025, 400, -5, -5))
    gmap.add_gaussians(np.stack([np.full(25, 2.0), np.linspace(-0.1, 0.1, 25), np.full(25, 1.0)], axis=1), 0.02, 0.5)
    cam = pinhole(160, 120)
    poses = [look_at_camera([0.0, 0.05 * k, 1.0], [2.0, 0.0, 1.0]) for k in range(3)]
    first = [gmap.view_evidence(np.arange(25), cam, p) for p in poses]     # the third evicts the first
    assert len(gmap._view_evidence) == 2 and gmap._view_evidence_bytes == 2 * 25 * 8
    assert torch.equal(gmap.view_evidence(np.arange(25), cam, poses[0]), first[0])     # re-rendered, same


# ----------------------------------------------------------------------------- instances
def test_instance_footprints_are_the_unique_cells_in_row_major_order():
    from helios.config import HeliosConfig
    from helios.maps import ClassSet
    from helios.maps.instances import summarize_instances

    rng = np.random.default_rng(0)
    grid = GridGeometry(0.025, 400, -5, -5)
    classes = ClassSet.from_task(["cup", "table"])
    n = 3000
    means = np.stack([rng.uniform(-6, 6, n), rng.uniform(-6, 6, n), rng.uniform(0, 1, n)], axis=1)  # some off-grid
    ids = rng.integers(-1, 7, n)
    exp = rng.dirichlet(np.ones(len(classes)), n)
    out = summarize_instances(means, exp, exp * 0.1, exp.argmax(axis=1), ids, classes, HeliosConfig().scoring.alpha_cs,
                              grid)
    assert len(out) == 7
    means = means.astype(np.float32)                         # as the map holds them
    out = summarize_instances(means, exp, exp * 0.1, exp.argmax(axis=1), ids, classes, HeliosConfig().scoring.alpha_cs,
                              grid)
    labelled = np.nonzero(ids >= 0)[0]
    uniq, inv = np.unique(ids[labelled], return_inverse=True)
    S, centre, top = np.zeros((7, len(classes))), np.zeros((7, 3)), np.full(7, -np.inf)
    np.add.at(S, inv, exp[labelled])                         # the sequential sums the code used to do
    np.add.at(centre, inv, means[labelled])
    np.maximum.at(top, inv, means[labelled, 2])
    counts = np.bincount(inv).astype(np.float64)[:, None]
    for k, inst in enumerate(out):
        cells = np.stack(grid.world_to_cell(means[ids == inst.id, :2]), axis=1)
        expected = np.unique(cells, axis=0)
        assert np.array_equal(inst.footprint_xy, grid.cell_to_world(expected[:, 0], expected[:, 1]))
        assert list(inst.class_scores.values()) == (S[k] / counts[k]).tolist()
        assert np.array_equal(inst.centre, centre[k] / counts[k]) and inst.max_height == float(top[k])


# ----------------------------------------------------------------------------- simulator broad phase
def test_bodies_overlapping_is_the_per_body_aabb_test_after_objects_move():
    from robots.spot.sim_backend import SimBackendConfig
    from sim.world import GROUND
    from tasks.episodes import load_split
    from tasks.runner import build_episode_world

    world, _scene, spot = build_episode_world(load_split("smoke")[0], SimBackendConfig())
    try:
        def slow(lo, hi, skip):
            out = []
            for info in world.bodies.values():
                if info.body_id in skip or info.kind == GROUND:
                    continue
                blo, bhi = world.body_aabb(info.body_id)
                if not (any(bhi[i] < lo[i] for i in range(3)) or any(blo[i] > hi[i] for i in range(3))):
                    out.append(info.body_id)
            return out

        objects = [b.body_id for b in world.bodies.values() if b.kind == "object"]
        rng = np.random.default_rng(0)
        checked = 0
        for step in range(40):
            if step % 10 == 5:       # an object is put somewhere (carried, placed): its box must follow
                world.client.resetBasePositionAndOrientation(objects[step % len(objects)],
                                                             [*rng.uniform(-3, 3, 2), 0.5], [0, 0, 0, 1])
            if step % 10 == 7:       # ... and falls under physics
                world.step(60)
            centre = np.array([*rng.uniform(-4, 4, 2), rng.uniform(0, 1.5)])
            half = rng.uniform(0.2, 2.0, 3)
            skip = {spot.id, objects[0]} if step % 2 else {spot.id}
            lo, hi = list(centre - half), list(centre + half)
            assert world.bodies_overlapping(lo, hi, skip) == slow(lo, hi, skip)
            checked += bool(slow(lo, hi, skip))
        assert checked > 10
        # a box read while the object was in the air is not served after it fell
        world.client.resetBasePositionAndOrientation(objects[1], [0.0, 0.0, 1.5], [0, 0, 0, 1])
        assert objects[1] in world.bodies_overlapping([-0.05, -0.05, 1.45], [0.05, 0.05, 1.55], set())
        world.step(240)
        assert objects[1] not in world.bodies_overlapping([-0.05, -0.05, 1.45], [0.05, 0.05, 1.55], set())
    finally:
        world.close()


def test_touching_from_collider_boxes_finds_what_the_whole_robot_box_finds():
    """``SpotBody.touching`` bounds its broad phase by the links that have collision shapes only;
    every contact lies on one of them, so the hits are those of the box over all links."""
    from robots.hal import SE2Pose
    from robots.spot import model
    from robots.spot.sim_backend import SimBackendConfig
    from tasks.episodes import load_split
    from tasks.runner import build_episode_world

    world, _scene, spot = build_episode_world(load_split("smoke")[0], SimBackendConfig())
    try:
        c = world.client

        def slow(margin):
            lo, hi = world.body_aabb(spot.id)
            lo, hi = [v - margin - 0.01 for v in lo], [v + margin + 0.01 for v in hi]
            out = []
            for body_id in world.bodies_overlapping(lo, hi, {spot.id}):
                for pt in c.getClosestPoints(spot.id, body_id, distance=margin):
                    out.append((spot.link_name.get(pt[3], str(pt[3])), body_id))
            return out

        rng = np.random.default_rng(1)
        lo_b = np.array([model.ARM_LIMITS[n][0] for n in model.ARM_JOINTS])
        hi_b = np.array([model.ARM_LIMITS[n][1] for n in model.ARM_JOINTS])
        touched = 0
        for _ in range(150):
            spot.set_base_pose(SE2Pose(*rng.uniform(-4, 4, 2), float(rng.uniform(-math.pi, math.pi))))
            spot.set_arm_state(rng.uniform(lo_b, hi_b))
            for margin in (0.0, 0.05):
                fast = spot.touching(margin=margin)
                assert fast == slow(margin)
                touched += bool(fast)
        assert touched > 20, "the sampled poses should touch the home often"
    finally:
        world.close()


def test_gaze_point_own_footprint_growth_is_scipys_binary_dilation():
    """``_grown`` (OpenCV) marks the same cells as scipy's binary dilation by the same disc with a
    zero border: random masks, cells on every edge and corner, windows smaller than the disc."""
    from helios.search.gaze_points import _grown

    rng = np.random.default_rng(7)
    masks = [rng.random((h, w)) < p for h, w, p in ((40, 55, 0.02), (13, 9, 0.1), (3, 4, 0.5), (1, 1, 1.0), (64, 64, 0.0))]
    edges = np.zeros((20, 30), dtype=bool)
    edges[0, 0] = edges[-1, -1] = edges[0, -1] = edges[-1, 0] = edges[10, 0] = edges[0, 15] = True
    masks.append(edges)
    for k in (0, 1, 3, 6, 12):
        yy, xx = np.mgrid[-k:k + 1, -k:k + 1]
        disc = (yy ** 2 + xx ** 2) <= k * k
        for m in masks:
            want = ndimage.binary_dilation(m, structure=disc) if k else m
            got = _grown(m.astype(np.uint8), k).astype(bool)
            assert got.shape == m.shape and np.array_equal(got, want), (k, m.shape)


def test_the_body_reuses_its_footprint_checker_until_the_occupancy_grids_change():
    """``Body.checker`` hands back the same checker while ``OccupancyGrid.revision`` stands, and a
    new one after each kind of change (a depth frame, ``mark_seen``, ``mark_obstacle``), which
    answers as one built from scratch on the changed grids."""
    from collections import Counter
    from dataclasses import replace
    from types import SimpleNamespace

    from helios.agents.body import Body
    from helios.agents.config import AgentConfig
    from helios.config import OccupancyConfig
    from helios.maps.occupancy import OccupancyGrid

    occ = OccupancyGrid(OccupancyConfig(grid_size=240, origin_xy=(-3.0, -3.0)))
    body = Body(AgentConfig(), None, SimpleNamespace(map=SimpleNamespace(occupancy=occ, geometry=occ.geometry)),
                [], Counter())
    rng = np.random.default_rng(3)
    poses = np.column_stack([rng.uniform(-2.5, 2.5, 300), rng.uniform(-2.5, 2.5, 300), rng.uniform(-3, 3, 300)])

    def fresh(margin=0.0):
        fp = body.config.planner.footprint
        fp = replace(fp, margin=fp.margin + margin)
        unknown = ~occ.explored if body.config.planner.unknown_is_obstacle else None
        return FootprintChecker(fp, occ.geometry, occ.obstacle, occ.max_height, unknown)

    def same_as_fresh(margin=0.0):
        got, want = body.checker(margin), fresh(margin)
        return all(np.array_equal(getattr(got, a), getattr(want, a)) for a in ("obstacle", "tall")) and \
            got.blocks_unknown == want.blocks_unknown

    assert occ.explored_bounds is None and same_as_fresh()            # nothing seen yet: all unknown
    occ.mark_seen(np.array([[0.0, 0.0]]), 2.5)
    first = body.checker()
    assert body.checker() is first and body.checker(0.1) is not first and body.checker(0.1) is body.checker(0.1)
    intr = CameraIntrinsics(64, 48, 40.0, 40.0, 31.5, 23.5)
    depth = np.full((48, 64), 1.5, dtype=np.float32)
    T = look_at_camera(np.array([0.0, 0.0, 1.2]), np.array([1.0, 0.0, 0.3]))
    for change in (lambda: occ.mark_obstacle((0.8, 0.3), 0.2, height=1.0),
                   lambda: occ.integrate_depth(depth, intr, T),
                   lambda: occ.mark_seen(np.array([[-1.0, -1.0]]), 0.5)):
        before, revision = body.checker(), occ.revision
        change()
        assert occ.revision > revision
        now = body.checker()
        assert now is not before and body.checker() is now
        assert np.array_equal(now.poses_free(poses), fresh().poses_free(poses))
        assert np.array_equal(body.checker(0.1).poses_free(poses), fresh(0.1).poses_free(poses))
        assert same_as_fresh() and same_as_fresh(0.1)     # built on the explored window only, the same grids
        r0, r1, c0, c1 = occ.explored_bounds
        outside = np.ones(occ.obstacle.shape, dtype=bool)
        outside[r0:r1, c0:c1] = False
        assert not (occ.obstacle & outside).any() and not (occ.explored & outside).any()
    assert not body.checker().poses_free(np.array([[0.8, 0.3, 0.0]]))[0]       # the marked obstacle


def _plan_fields(plan):
    return (plan.success, plan.reason, plan.path.tolist(), repr(plan.actions),
            [(w.x, w.y, w.yaw) for w in plan.waypoints], plan.reaches_goal, plan.length, plan.goal_index,
            plan.final_turn_blocked, plan.blocked_ahead)


def test_a_plan_from_the_bodys_checker_is_the_plan_from_a_fresh_one():
    """``FMMPlanner.plan(..., footprints=)`` derives the plan's footprint checker from one built on
    the same grids (never-seen cells near the start counted as seen with ``seen_within``) instead
    of rebuilding it: the same poses answer the same, and the plans are identical, on the map of a
    recorded val episode (the shuffle loop) from many starts and goals, near unseen cells included."""
    from pathlib import Path

    from helios.planning.fmm import PlannerConfig
    from robots.hal import SE2Pose

    d = np.load(Path(__file__).parent / "data" / "planner_shuffle_loop.npz")
    geo = GridGeometry(float(d["cell"]), int(d["size"]), float(d["origin"][0]), float(d["origin"][1]))
    obstacle, explored, max_height = d["obstacle"], d["explored"], d["max_height"]
    cfg = PlannerConfig()
    planner = FMMPlanner(cfg)
    base = FootprintChecker(cfg.footprint, geo, obstacle, max_height, ~explored)
    rng = np.random.default_rng(7)
    seen = np.argwhere(explored)
    starts = [SE2Pose(*d["start"])] + [SE2Pose(*geo.cell_to_world(*seen[i]), float(rng.uniform(-np.pi, np.pi)))
                                       for i in rng.integers(len(seen), size=24)]
    base_before = base.obstacle.copy()
    probe = np.column_stack([rng.normal(0, 0.8, 400), rng.normal(0, 0.8, 400), rng.uniform(-3, 3, 400)])
    patched = 0
    for i, start in enumerate(starts):
        reference = planner._checker(geo, obstacle, explored, max_height, start, None)
        derived = planner._checker(geo, obstacle, explored, max_height, start, base)
        patched += derived is not base
        assert np.array_equal(derived.obstacle, reference.obstacle) and np.array_equal(derived.tall, reference.tall)
        poses = probe + [start.x, start.y, 0.0]
        assert np.array_equal(derived.poses_free(poses), reference.poses_free(poses))
        goals = d["goals"] if i == 0 else geo.cell_to_world(*seen[rng.integers(len(seen), size=3)].T)
        fresh = planner.plan(geo, obstacle, explored, start, goals, 0.8, max_height=max_height)
        reused = planner.plan(geo, obstacle, explored, start, goals, 0.8, max_height=max_height, footprints=base)
        assert _plan_fields(reused) == _plan_fields(fresh)
    assert patched > 5                                   # unseen cells near the start did occur
    assert np.array_equal(base.obstacle, base_before)    # the body's checker itself is never changed
    # a checker for another footprint, or one blind to unknown cells, is not used
    other = FootprintChecker(FootprintConfig(margin=0.2), geo, obstacle, max_height, ~explored)
    assert planner._checker(geo, obstacle, explored, max_height, starts[0], other).config == cfg.footprint
    blind = FootprintChecker(cfg.footprint, geo, obstacle, max_height)
    assert planner._checker(geo, obstacle, explored, max_height, starts[0], blind).blocks_unknown


def _box_mesh_loop(half_extents, max_cell: float = 0.25):
    """The per-vertex loop ``sim.assets.box_mesh`` replaced (the oracle)."""
    h = np.asarray(half_extents, dtype=float)
    verts, idx, normals, uvs = [], [], [], []
    for axis in range(3):
        u_ax, v_ax = [a for a in range(3) if a != axis]
        nu = max(1, int(math.ceil(2 * h[u_ax] / max_cell)))
        nv = max(1, int(math.ceil(2 * h[v_ax] / max_cell)))
        for sign in (1.0, -1.0):
            base = len(verts)
            n = [0.0, 0.0, 0.0]
            n[axis] = sign
            for i in range(nu + 1):
                for j in range(nv + 1):
                    p = np.zeros(3)
                    p[axis] = sign * h[axis]
                    p[u_ax] = -h[u_ax] + 2 * h[u_ax] * i / nu
                    p[v_ax] = -h[v_ax] + 2 * h[v_ax] * j / nv
                    verts.append(p.tolist())
                    normals.append(n)
                    uvs.append([p[u_ax] + h[u_ax], p[v_ax] + h[v_ax]])
            flip = (sign < 0) != (axis == 1)
            for i in range(nu):
                for j in range(nv):
                    a, b = base + i * (nv + 1) + j, base + (i + 1) * (nv + 1) + j
                    quad = [a, b, b + 1, a, b + 1, a + 1]
                    idx += [quad[0], quad[2], quad[1], quad[3], quad[5], quad[4]] if flip else quad
    return verts, idx, normals, uvs


def _bits(values) -> list:
    """Floats as their exact bit patterns (so -0.0 and 0.0 differ), ints as they are."""
    return [v if isinstance(v, int) else float(v).hex() for v in np.ravel(np.asarray(values, dtype=object))]


@pytest.mark.parametrize("seed", [0, 1])
def test_box_mesh_equals_the_per_vertex_loop_bit_for_bit(seed):
    from sim.assets import box_mesh

    rng = np.random.default_rng(seed)
    for _ in range(60):
        h = tuple(float(x) for x in rng.uniform(0.005, 3.0, 3))
        max_cell = float(rng.choice([0.1, 0.25, 0.5, 1e9]))
        new, old = box_mesh(h, max_cell), _box_mesh_loop(h, max_cell)
        for a, b in zip(new, old):
            assert _bits(a) == _bits(b)


def test_a_layout_comes_back_equal_and_unshared():
    """The per-worker layout cache hands out copies: a caller's change never reaches the next one."""
    from sim.scenes.layout import generate_layout

    a = generate_layout(1835504127)
    b = generate_layout(1835504127)
    assert a == b and a is not b and a.receptacles[0] is not b.receptacles[0]
    a.receptacles.pop()
    a.objects[0].x += 1.0
    assert generate_layout(1835504127) == b


# ------------------------------------------------------------------ the robot's own pixels
def _own_case(rng):
    """A hand-camera frame looking down beside the body: most returns lie in the body's box or near it."""
    intr = CameraIntrinsics(320, 240, 226.0, 226.0, 159.5, 119.5)
    eye = np.array([rng.uniform(0.2, 0.6), rng.uniform(-0.4, 0.4), rng.uniform(0.3, 0.7)])
    target = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.6, 0.6), rng.uniform(-0.6, -0.2)])
    T_body_cam = look_at_camera(eye, target)
    depth = rng.uniform(0.05, 2.5, size=(240, 320)).astype(np.float32)
    depth[rng.random((240, 320)) < 0.1] = 0.0        # no return
    return depth, intr, T_body_cam


def test_own_pixels_on_the_image_grid_are_the_back_projected_box_test(monkeypatch):
    from helios.agents import self_mask

    box, top = (-0.53, 0.53, -0.33, 0.33), 0.25
    rng = np.random.default_rng(3)
    owned = 0
    for _ in range(20):
        depth, intr, T = _own_case(rng)
        exact = self_mask.own_pixels_exact(depth, intr, T, box, top)
        assert np.array_equal(self_mask.own_pixels(depth, intr, T, box, top), exact)
        owned += int(exact.sum())
    assert owned > 1000                                   # the cases do reach into the box
    # A return exactly on a face: the fast test cannot decide it and hands the frame over.
    depth, intr, T = _own_case(rng)
    v, u = 120, 160
    depth[v, u] = 1.0
    point = T[:3, :3] @ intr.backproject(u, v, float(depth[v, u])) + T[:3, 3]
    x, y, z = (float(c) for c in point)
    face_box, face_top = (x, x + 1.0, y - 1.0, y + 1.0), z + 1.0
    calls = []
    real = self_mask.own_pixels_exact
    monkeypatch.setattr(self_mask, "own_pixels_exact", lambda *a: calls.append(1) or real(*a))
    fast = self_mask.own_pixels(depth, intr, T, face_box, face_top)
    assert calls and np.array_equal(fast, real(depth, intr, T, face_box, face_top))


def test_ground_projection_points_and_window_are_the_selected_rows_and_column_extremes():
    from helios.config import OccupancyConfig
    from helios.maps.ground_view import project_to_ground

    cfg = OccupancyConfig(max_depth=3.0)
    geometry = GridGeometry.from_config(cfg)
    intr = CameraIntrinsics(320, 240, 226.0, 226.0, 159.5, 119.5)
    rng = np.random.default_rng(5)
    T = look_at_camera(np.array([1.0, 2.0, 0.8]), np.array([3.0, 3.5, 0.2]))
    depth = rng.uniform(0.1, 6.0, size=(240, 320)).astype(np.float32)     # some returns beyond max_depth
    view = project_to_ground(depth, intr, T, geometry, cfg)
    s = cfg.depth_stride
    d = depth[::s, ::s]
    vv, uu = np.mgrid[0:240:s, 0:320:s]
    valid = d >= cfg.min_depth
    d, uu, vv = d[valid].astype(np.float64), uu[valid], vv[valid]
    rays = np.stack([(uu - intr.cx) / intr.fx, (vv - intr.cy) / intr.fy, np.ones_like(d)], axis=-1)
    dirs = rays @ T[:3, :3].T
    near = d <= cfg.max_depth
    assert 0 < near.sum() < near.size
    assert np.array_equal(view.points, T[:3, 3] + dirs[near] * d[near, None])
    vis = T[:2, 3] + dirs[:, :2] * np.minimum(d, cfg.max_depth)[:, None]
    lo = np.minimum(vis.min(axis=0), T[:2, 3])
    hi = np.maximum(vis.max(axis=0), T[:2, 3])
    (r0, c0), (r1, c1) = [np.asarray(geometry.world_to_cell(p)).ravel() for p in (lo, hi)]
    assert view.window == (int(r0), int(r1) + 1, int(c0), int(c1) + 1)
