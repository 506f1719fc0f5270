"""Vectorised pair-list rasteriser for isotropic 3D Gaussians (pure torch, CPU or CUDA).

gsplat's kernels need CUDA, and the map must run on a CPU-only robot laptop, so we rasterise as
a list of (Gaussian, pixel) pairs instead of tiles. Every step is a batched tensor op:

1. project Gaussian centres into the camera; EWA screen covariance ``s^2 J J^T + blur * I``;
2. depth-order Gaussians globally by centre depth (3DGS / SplaTAM convention);
3. emit candidate pairs per footprint-radius bucket as broadcast disc windows, keep
   ``alpha = min(alpha_max, o * exp(-d^T Sigma^-1 d / 2)) >= alpha_min``;
4. sort pairs by (pixel, depth rank) and composite front to back with a segmented cumulative sum
   of ``log(1 - alpha)`` (float64: the running sum spans millions of pairs);
5. ``kappa = alpha * T`` per pair: the paper's Eq. 1 weight. Images are ``index_add`` of
   ``kappa * feature`` over pixels; the Dirichlet update uses the pairs directly.

Pixel centres are at integer coordinates, matching ``CameraIntrinsics.backproject``. Restricting
rendering to a pixel mask is exact for the kept pixels (compositing is per pixel).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from helios.config import RenderConfig
from helios.maps.inputs import check_pose
from robots.hal import CameraIntrinsics
from robots.transforms import invert_transform

# Footprint radii are rounded up to these buckets: one broadcast window shape per bucket.
_RADIUS_BUCKETS = (1, 2, 3, 4, 5, 6, 8, 10, 12, 14, 16, 20, 24, 28, 32, 40, 48, 56, 64, 80, 96, 128)
# Upper bound on candidate pairs materialised at once (memory: ~40 B per candidate pair).
_CHUNK_PAIRS = 2_000_000
# Bits of the pair index packed under the sort key on the CPU (up to 16.7 M pairs per render).
_PACK_BITS = 24


@dataclass
class Rendering:
    """Per-pair compositing weights of one rendered view plus the images derived from them."""

    height: int
    width: int
    gaussian_index: torch.Tensor
    """(P,) int64 index into the rendered Gaussian arrays."""
    pixel_index: torch.Tensor
    """(P,) int64 flat pixel ``v * width + u``."""
    weight: torch.Tensor
    """(P,) float32 kappa = alpha * prod_{j in front} (1 - alpha_j)."""
    pair_depth: torch.Tensor
    """(P,) float32 camera depth of the pair's Gaussian centre."""
    silhouette: torch.Tensor
    """(H, W) float32 sum of kappa (accumulated opacity, <= 1)."""
    accumulated_depth: torch.Tensor
    """(H, W) float32 sum of kappa * z (SplaTAM's depth render; ~0 where nothing is mapped)."""
    candidate_pairs: int = 0
    """Candidate pairs examined (a cost measure for benchmarks)."""

    @property
    def device(self) -> torch.device:
        return self.silhouette.device

    def expected_depth(self, min_silhouette: float = 1e-3) -> torch.Tensor:
        """sum(kappa z) / sum(kappa) where the silhouette exceeds ``min_silhouette``, else 0."""
        s = self.silhouette
        return torch.where(s > min_silhouette, self.accumulated_depth / s.clamp_min(min_silhouette),
                           torch.zeros_like(s))

    def composite(self, features: torch.Tensor) -> torch.Tensor:
        """(H, W, F) image sum_n kappa_n * features[n] for per-Gaussian features (N, F)."""
        f = features if features.dim() == 2 else features[:, None]
        out = torch.zeros(self.height * self.width, f.shape[1], dtype=f.dtype, device=f.device)
        if self.weight.numel():
            out.index_add_(0, self.pixel_index, f.index_select(0, self.gaussian_index) * self.weight[:, None].to(f.dtype))
        return out.reshape(self.height, self.width, f.shape[1])

    def per_gaussian_sum(self, pixel_values: torch.Tensor | None, n_gaussians: int) -> torch.Tensor:
        """(N,) float64 sum over pixels of kappa * pixel_values[pixel] (all ones when None)."""
        w = self.weight.to(torch.float64)
        if pixel_values is not None:
            w = w * pixel_values.reshape(-1).index_select(0, self.pixel_index).to(torch.float64)
        out = torch.zeros(n_gaussians, dtype=torch.float64, device=w.device)
        if w.numel():
            out.index_add_(0, self.gaussian_index, w)
        return out

    def spliced(self, patch: "Rendering", region: torch.Tensor) -> "Rendering":
        """This rendering with the pixels in ``region`` taken from ``patch`` (a rendering of the
        same camera restricted to ``region``); exact because compositing is per pixel."""
        region_flat = region.reshape(-1)
        keep = torch.nonzero(~region_flat.index_select(0, self.pixel_index)).squeeze(1)   # not a bool mask: ~3x faster
        return Rendering(
            self.height, self.width,
            torch.cat([self.gaussian_index.index_select(0, keep), patch.gaussian_index]),
            torch.cat([self.pixel_index.index_select(0, keep), patch.pixel_index]),
            torch.cat([self.weight.index_select(0, keep), patch.weight]),
            torch.cat([self.pair_depth.index_select(0, keep), patch.pair_depth]),
            torch.where(region, patch.silhouette, self.silhouette),
            torch.where(region, patch.accumulated_depth, self.accumulated_depth),
            candidate_pairs=self.candidate_pairs + patch.candidate_pairs)

    def nbytes(self) -> int:
        """Bytes held by this rendering's tensors."""
        tensors = (self.gaussian_index, self.pixel_index, self.weight, self.pair_depth,
                   self.silhouette, self.accumulated_depth)
        return sum(t.numel() * t.element_size() for t in tensors)


def _sorting_permutation(key: torch.Tensor) -> torch.Tensor:
    """The permutation sorting ``key`` (int64, all distinct, so any sort gives the same one).

    On the CPU the pair index is packed into the low bits of the key and the packed values are
    sorted with numpy's SIMD sort: about 5x faster than ``torch.sort`` returning indices."""
    n = key.numel()
    if key.device.type == "cpu" and n < (1 << _PACK_BITS) and int(key.max()) < (1 << (62 - _PACK_BITS)):
        packed = key.numpy() << _PACK_BITS         # in place from here on: no more memory than torch.sort
        packed |= np.arange(n, dtype=np.int64)
        packed.sort()
        packed &= (1 << _PACK_BITS) - 1
        return torch.from_numpy(packed)
    return torch.sort(key).indices


def _sorted_pairs(pix: torch.Tensor, rank: torch.Tensor, n_pixels: int, n_ranks: int
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Pairs sorted by (pixel, depth rank): the sorted pixels, the sorted ranks and the sorting
    permutation (for the pairs' other arrays). Keys are distinct, so the order is unique.

    On the CPU, pixel, rank and pair index are packed into one int64 and sorted with numpy: the
    sorted pixels and ranks are then read back from the packed bits instead of gathered through
    the permutation (two random gathers over every pair saved)."""
    n = pix.numel()
    rank_bits = max(1, (n_ranks - 1).bit_length())
    pix_bits = max(1, (n_pixels - 1).bit_length())
    if pix.device.type == "cpu" and n < (1 << _PACK_BITS) and pix_bits + rank_bits + _PACK_BITS <= 62:
        packed = pix.numpy() << (rank_bits + _PACK_BITS)
        packed |= rank.numpy() << _PACK_BITS
        packed |= np.arange(n, dtype=np.int64)
        packed.sort()
        perm = packed & ((1 << _PACK_BITS) - 1)
        sorted_rank = (packed >> _PACK_BITS) & ((1 << rank_bits) - 1)
        packed >>= rank_bits + _PACK_BITS
        return torch.from_numpy(packed), torch.from_numpy(sorted_rank), torch.from_numpy(perm)
    perm = _sorting_permutation(pix * n_ranks + rank)
    return pix.index_select(0, perm), rank.index_select(0, perm), perm


def _sorted_segments(pix: torch.Tensor, counts: torch.Tensor, segment_rank: torch.Tensor, n_pixels: int
                     ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`_sorted_pairs` for pairs that come in segments, one per Gaussian: segment ``s`` is
    ``counts[s]`` consecutive pairs of depth rank ``segment_rank[s]`` (a permutation of the ranks
    ``0 .. len(counts) - 1``).

    On the CPU with at most 65 536 pixels, linear passes replace the comparison sort, which was
    half of a render: the segments are laid out in rank order (a repeat and an add), then a stable
    sort on the 16-bit pixel (numpy's radix sort) groups the pairs by pixel with their ranks still
    ascending: the same unique (pixel, rank) order. Pixel, rank and pair index travel packed in
    one int64, so the permutation costs one random gather (elsewhere: the packed key sort)."""
    n_ranks = segment_rank.numel()
    rank_bits = max(1, (n_ranks - 1).bit_length())
    if (pix.device.type != "cpu" or n_pixels > (1 << 16) or pix.numel() >= (1 << _PACK_BITS)
            or 16 + rank_bits + _PACK_BITS > 62):
        return _sorted_pairs(pix, torch.repeat_interleave(segment_rank, counts), n_pixels, n_ranks)
    c = counts.numpy()
    segment_of_rank = np.empty(n_ranks, dtype=np.int64)
    segment_of_rank[segment_rank.numpy()] = np.arange(n_ranks, dtype=np.int64)
    count_r = c[segment_of_rank]
    start_r = (np.cumsum(c) - c)[segment_of_rank]             # where each rank's segment starts
    in_rank_order = np.repeat(start_r - (np.cumsum(count_r) - count_r), count_r)
    in_rank_order += np.arange(in_rank_order.size, dtype=np.int64)
    pix_r = pix.numpy()[in_rank_order]
    by_pixel = np.argsort(pix_r.astype(np.uint16), kind="stable")
    # One random gather instead of three: pixel, rank and pair index packed as in _sorted_pairs.
    packed = np.repeat(np.arange(n_ranks, dtype=np.int64) << _PACK_BITS, count_r)
    packed |= in_rank_order
    pix_r <<= rank_bits + _PACK_BITS
    packed |= pix_r
    packed = packed[by_pixel]
    perm = packed & ((1 << _PACK_BITS) - 1)
    rank = (packed >> _PACK_BITS) & ((1 << rank_bits) - 1)
    packed >>= rank_bits + _PACK_BITS
    return torch.from_numpy(packed), torch.from_numpy(rank), torch.from_numpy(perm)


_WINDOWS: dict = {}


def _window(R: int, W: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Integer offsets (dx, dy as (1, n) float32) of the disc of radius R + 1/2 and their flat
    pixel offsets for image width W (cached: the same few radii come back every render)."""
    key = (R, W, str(device))
    hit = _WINDOWS.get(key)
    if hit is None:
        off = torch.arange(-R, R + 1, device=device, dtype=torch.float32)
        dy, dx = torch.meshgrid(off, off, indexing="ij")
        disc = dx * dx + dy * dy <= (R + 0.5) ** 2     # the footprint ellipse lies within radius R
        dx, dy = dx[disc].reshape(1, -1), dy[disc].reshape(1, -1)
        offset_pix = (dy.to(torch.int64) * W + dx.to(torch.int64)).flatten()
        hit = _WINDOWS[key] = (dx, dy, offset_pix)
    return hit


def _minus_run_start(values: torch.Tensor, runs: torch.Tensor) -> torch.Tensor:
    """``values`` minus the value at the start of its run of equal ``runs`` entries (float64).

    The same subtraction of the same operands either way; on the CPU numpy gathers each run's
    first value by repeating it over the run, ~3x faster than torch's boolean-mask gather."""
    if values.device.type == "cpu":
        v, r = values.numpy(), runs.numpy()
        starts = np.empty(r.size, dtype=bool)
        starts[0] = True
        np.not_equal(r[1:], r[:-1], out=starts[1:])
        first = np.flatnonzero(starts)
        counts = np.diff(first, append=r.size)
        return torch.from_numpy(v - np.repeat(v[first], counts))
    return _minus_run_start_torch(values, runs)


def _minus_run_start_torch(values: torch.Tensor, runs: torch.Tensor) -> torch.Tensor:
    """:func:`_minus_run_start` in torch ops (any device)."""
    starts = torch.ones_like(runs, dtype=torch.bool)
    starts[1:] = runs[1:] != runs[:-1]
    segment = torch.cumsum(starts.to(torch.int64), 0) - 1
    return values - values[starts][segment]


def _kept(keep: torch.Tensor, base_pix: torch.Tensor, offset_pix: torch.Tensor, alpha: torch.Tensor
          ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The pairs of a chunk's true ``keep[i, j]`` (row-major, so each row's pairs are one segment):
    the pair count of each row ``i``, the pixel ``base_pix[i] + offset_pix[j]`` and ``alpha[i, j]``.
    On the CPU through numpy, a third of the time of ``torch.nonzero`` and the gathers."""
    if keep.device.type == "cpu":
        k = keep.numpy()
        flat = np.flatnonzero(k)
        counts = np.count_nonzero(k, axis=1)
        pix = np.add(base_pix.numpy()[:, None], offset_pix.numpy()).reshape(-1)[flat]
        return (torch.from_numpy(counts.astype(np.int64, copy=False)), torch.from_numpy(pix),
                torch.from_numpy(alpha.numpy().reshape(-1)[flat]))
    return _kept_torch(keep, base_pix, offset_pix, alpha)


def _kept_torch(keep: torch.Tensor, base_pix: torch.Tensor, offset_pix: torch.Tensor, alpha: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`_kept` in torch ops (any device)."""
    i, j = torch.nonzero(keep, as_tuple=True)
    return (torch.bincount(i, minlength=keep.shape[0]), base_pix.index_select(0, i) + offset_pix.index_select(0, j),
            alpha.view(-1).index_select(0, i * keep.shape[1] + j))


def _select(mask: torch.Tensor, *arrays: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """Each of ``arrays`` (1-D, the length of ``mask``) where ``mask`` is true: one scan, then
    gathers (numpy's on the CPU, ~3x faster than ``torch.nonzero`` and ``index_select``)."""
    if mask.device.type == "cpu":
        kept = np.flatnonzero(mask.numpy())
        if kept.size == mask.numel():       # nothing cut (about half of the renders): no gathers
            return arrays
        return tuple(torch.from_numpy(a.numpy()[kept]) for a in arrays)
    return _select_torch(mask, *arrays)


def _select_torch(mask: torch.Tensor, *arrays: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """:func:`_select` in torch ops (any device)."""
    kept = torch.nonzero(mask).flatten()
    return tuple(a.index_select(0, kept) for a in arrays)


def empty_rendering(height: int, width: int, device: torch.device) -> Rendering:
    zi = torch.zeros(0, dtype=torch.int64, device=device)
    zf = torch.zeros(0, dtype=torch.float32, device=device)
    img = torch.zeros(height, width, dtype=torch.float32, device=device)
    return Rendering(height, width, zi, zi.clone(), zf, zf.clone(), img, img.clone())


def render_gaussians(means: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
                     intrinsics: CameraIntrinsics, T_world_cam: np.ndarray, cfg: RenderConfig,
                     pixel_mask: torch.Tensor | None = None, depth: bool = True) -> Rendering:
    """Rasterise isotropic Gaussians (means (N, 3) world, scales (N,) std-dev in m, opacities (N,)).

    ``pixel_mask`` (H, W) bool restricts the output to those pixels (others get no pairs).
    """
    device = means.device
    H, W = intrinsics.height, intrinsics.width
    if means.shape[0] == 0:
        return empty_rendering(H, W, device)
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
            return empty_rendering(H, W, device)
        rows = torch.nonzero(pm.any(dim=1)).flatten()
        cols = torch.nonzero(pm.any(dim=0)).flatten()
        ok &= ((uc + radius >= cols[0]) & (uc - radius <= cols[-1])
               & (vc + radius >= rows[0]) & (vc - radius <= rows[-1]))
        pm_flat = pm.reshape(-1)
    idx = torch.nonzero(ok).flatten()
    if idx.numel() == 0:
        return empty_rendering(H, W, device)

    # Global depth order of the visible Gaussians; their per-Gaussian terms gathered once in that
    # order (``index_select``: advanced indexing costs ~20 us more per call, and the loop below
    # makes dozens of calls per bucket).
    order = torch.argsort(z[idx], stable=True)
    idx = idx[order]
    buckets = [r for r in _RADIUS_BUCKETS if r < cfg.max_radius_px] + [cfg.max_radius_px]
    bucket_of = torch.bucketize(radius.index_select(0, idx),
                                torch.as_tensor(buckets, dtype=radius.dtype, device=device))
    # Per-Gaussian terms of the pair test. With the window centre (uc, vc) and integer offsets,
    # du = (uc - u) + dx rounds the same exact value as (uc + dx) - u (both operands of uc - u
    # are within a factor of two, so it is exact), and pixels are integers: no float pixel grid.
    ru, rv = (uc - u).index_select(0, idx), (vc - v).index_select(0, idx)
    ca, cb2, cc = conic_a.index_select(0, idx), (2.0 * conic_b).index_select(0, idx), conic_c.index_select(0, idx)
    op = opacities.index_select(0, idx)
    ucv, vcv = uc.index_select(0, idx), vc.index_select(0, idx)
    base_pix = vcv.to(torch.int64) * W + ucv.to(torch.int64)
    # Windows wholly inside the image need no bounds test (the bucket radius R >= radius). Group
    # the Gaussians by (bucket, cut by the image edge), depth order kept within a group by one
    # stable sort, and gather their terms once in that order: each chunk below is then a slice.
    bucket_r = torch.as_tensor(buckets, dtype=ucv.dtype, device=device).index_select(0, bucket_of)
    cut = ~((ucv - bucket_r >= 0) & (ucv + bucket_r <= W - 1) & (vcv - bucket_r >= 0) & (vcv + bucket_r <= H - 1))
    group_of = bucket_of * 2 + cut
    by_group = torch.argsort(group_of, stable=True)
    ks, counts = torch.unique_consecutive(group_of.index_select(0, by_group), return_counts=True)
    ru, rv, ca, cb2, cc, op, ucv, vcv, base_pix = (t.index_select(0, by_group) for t in
                                                    (ru, rv, ca, cb2, cc, op, ucv, vcv, base_pix))
    pair_pix, pair_alpha, pair_counts = [], [], []
    candidates = 0
    first = 0
    for k, count in zip(ks.tolist(), counts.tolist()):
        R, bounded = buckets[k // 2], bool(k % 2)
        dx, dy, offset_pix = _window(R, W, device)
        per = dx.shape[1]
        step = max(1, _CHUNK_PAIRS // per)
        for s in range(first, first + count, step):
            g = slice(s, min(s + step, first + count))
            du = ru[g, None] + dx
            dv = rv[g, None] + dy
            power = (ca[g, None] * du).mul_(du)
            power.add_((cb2[g, None] * du).mul_(dv))
            power.add_((cc[g, None] * dv).mul_(dv))
            alpha = power.mul_(-0.5).exp_().mul_(op[g, None]).clamp_max_(cfg.alpha_max)
            keep = alpha >= cfg.alpha_min
            if bounded:
                ucg, vcg = ucv[g, None], vcv[g, None]
                keep &= (dx >= -ucg) & (dx <= (W - 1) - ucg) & (dy >= -vcg) & (dy <= (H - 1) - vcg)
            if pixel_mask is not None:
                pix = base_pix[g, None] + offset_pix
                keep &= pm_flat[pix.clamp(0, H * W - 1)]
            candidates += keep.numel()
            counts_k, pix_k, alpha_k = _kept(keep, base_pix[g], offset_pix, alpha)
            pair_counts.append(counts_k)
            pair_pix.append(pix_k)
            pair_alpha.append(alpha_k)
        first += count
    pix_all = torch.cat(pair_pix)
    if pix_all.numel() == 0:
        return empty_rendering(H, W, device)

    # Sort by (pixel, depth rank), then composite each pixel's run front to back. The chunks
    # cover the groups' Gaussians in order, so the pairs are one segment per Gaussian, of rank
    # ``by_group[q]`` for the q-th.
    pix_all, rank_all, perm = _sorted_segments(pix_all, torch.cat(pair_counts), by_group, H * W)
    alpha_all = torch.cat(pair_alpha).index_select(0, perm)
    log_one_minus = torch.log1p(-alpha_all.to(torch.float64))
    inclusive = torch.cumsum(log_one_minus, 0)
    exclusive = inclusive - log_one_minus
    log_T = _minus_run_start(exclusive, pix_all)
    # Ranks, not Gaussian indices, through the cut: the index gather then skips the dropped pairs.
    rank_all, pix_all, log_T, alpha_all = _select(log_T >= math.log(cfg.transmittance_min), rank_all, pix_all, log_T,
                                                  alpha_all)
    g_all = idx.index_select(0, rank_all)
    weight = (alpha_all.to(torch.float64) * torch.exp(log_T)).to(torch.float32)
    sil = torch.zeros(H * W, dtype=torch.float32, device=device)
    sil.index_add_(0, pix_all, weight)
    acc = torch.zeros(H * W, dtype=torch.float32, device=device)
    if depth:
        pair_depth = z.index_select(0, g_all)
        acc.index_add_(0, pix_all, weight * pair_depth)
    else:                                   # (view evidence reads neither)
        pair_depth = torch.zeros(0, dtype=torch.float32, device=device)
    return Rendering(H, W, g_all, pix_all, weight, pair_depth, sil.reshape(H, W), acc.reshape(H, W),
                     candidate_pairs=candidates)
