"""The pair-list Gaussian rasteriser against hand-computed weights and a naive per-pixel loop."""

import math

import numpy as np
import pytest
import torch

from helios.config import RenderConfig
from helios.maps.renderer import render_gaussians
from robots.hal import CameraIntrinsics
from robots.transforms import look_at_camera as look_at

CAM = CameraIntrinsics(40, 30, 30.0, 30.0, 19.5, 14.5)
CFG = RenderConfig()
IDENTITY = np.eye(4)   # camera at the origin, optical axis along world +z


def tensors(means, scales, opacities):
    return (torch.tensor(means, dtype=torch.float32), torch.tensor(scales, dtype=torch.float32),
            torch.tensor(opacities, dtype=torch.float32))


def naive_render(means, scales, opacities, cam, cfg):
    """Per-pixel loop: EWA splat, global centre-depth order, front-to-back compositing."""
    H, W = cam.height, cam.width
    sil, acc = np.zeros((H, W)), np.zeros((H, W))
    order = np.argsort(means[:, 2], kind="stable")
    for v in range(H):
        for u in range(W):
            T = 1.0
            for n in order:
                x, y, z = means[n]
                if z <= cfg.near:
                    continue
                J = np.array([[cam.fx / z, 0, -cam.fx * x / z ** 2], [0, cam.fy / z, -cam.fy * y / z ** 2]])
                cov = scales[n] ** 2 * J @ J.T + cfg.blur_px2 * np.eye(2)
                d = np.array([u - (cam.fx * x / z + cam.cx), v - (cam.fy * y / z + cam.cy)])
                alpha = min(cfg.alpha_max, opacities[n] * math.exp(-0.5 * d @ np.linalg.solve(cov, d)))
                if alpha < cfg.alpha_min or T < cfg.transmittance_min:
                    continue
                sil[v, u] += alpha * T
                acc[v, u] += alpha * T * z
                T *= 1 - alpha
    return sil, acc


def test_one_gaussian_in_front_of_another_composites_front_to_back():
    # listed back first: the renderer must order by depth itself
    means, scales, opac = tensors([[0.0, 0.0, 3.0], [0.0, 0.0, 2.0]], [0.05, 0.05], [0.8, 0.6])
    r = render_gaussians(means, scales, opac, CAM, IDENTITY, CFG)
    centre = 14 * CAM.width + 20   # pixel (u=20, v=14) is 0.5 px from the principal point
    at = r.pixel_index == centre
    w = dict(zip(r.gaussian_index[at].tolist(), r.weight[at].tolist()))
    # alpha of each at that pixel from its own footprint
    def alpha(n, z):
        s2 = (0.05 * 30.0 / z) ** 2 + CFG.blur_px2
        return float(opac[n]) * math.exp(-0.5 * (0.5 ** 2 + 0.5 ** 2) / s2)
    a_front, a_back = alpha(1, 2.0), alpha(0, 3.0)
    assert w[1] == pytest.approx(a_front, rel=1e-5)
    assert w[0] == pytest.approx(a_back * (1 - a_front), rel=1e-5)
    assert float(r.silhouette.reshape(-1)[centre]) == pytest.approx(w[0] + w[1], rel=1e-6)
    assert float(r.silhouette.max()) <= 1.0
    # silhouette is exactly the per-pixel sum of the pair weights everywhere
    sums = torch.zeros(CAM.height * CAM.width).index_add_(0, r.pixel_index, r.weight)
    torch.testing.assert_close(sums.reshape(CAM.height, CAM.width), r.silhouette)


def test_matches_naive_per_pixel_reference_on_a_random_scene():
    rng = np.random.default_rng(3)
    n = 25
    means = np.stack([rng.uniform(-0.8, 0.8, n), rng.uniform(-0.6, 0.6, n), rng.uniform(1.0, 4.0, n)], axis=1)
    scales, opac = rng.uniform(0.01, 0.08, n), rng.uniform(0.2, 0.95, n)
    r = render_gaussians(*tensors(means, scales, opac), CAM, IDENTITY, CFG)
    sil, acc = naive_render(means, scales, opac, CAM, CFG)
    np.testing.assert_allclose(r.silhouette.numpy(), sil, atol=2e-5)
    np.testing.assert_allclose(r.accumulated_depth.numpy(), acc, atol=1e-4)
    assert float(r.silhouette.max()) <= 1.0 + 1e-6


def test_expected_depth_and_feature_composite():
    means, scales, opac = tensors([[0.0, 0.0, 2.0]], [0.1], [0.9])
    r = render_gaussians(means, scales, opac, CAM, IDENTITY, CFG)
    ed = r.expected_depth(1e-3)
    covered = r.silhouette > 1e-3
    torch.testing.assert_close(ed[covered], torch.full_like(ed[covered], 2.0))
    assert float(ed[~covered].abs().max()) == 0.0
    colour = r.composite(torch.tensor([[0.2, 0.4, 1.0]]))
    torch.testing.assert_close(colour[..., 2], r.silhouette)
    torch.testing.assert_close(colour[..., 0], 0.2 * r.silhouette)


def test_pixel_mask_is_exact_on_kept_pixels_and_empty_elsewhere():
    rng = np.random.default_rng(5)
    means = np.stack([rng.uniform(-0.5, 0.5, 12), rng.uniform(-0.4, 0.4, 12), rng.uniform(1.0, 3.0, 12)], axis=1)
    args = tensors(means, rng.uniform(0.02, 0.06, 12), rng.uniform(0.3, 0.9, 12))
    full = render_gaussians(*args, CAM, IDENTITY, CFG)
    mask = torch.zeros(CAM.height, CAM.width, dtype=torch.bool)
    mask[5:20, 10:30] = True
    part = render_gaussians(*args, CAM, IDENTITY, CFG, pixel_mask=mask)
    torch.testing.assert_close(part.silhouette[mask], full.silhouette[mask])
    assert float(part.silhouette[~mask].abs().max()) == 0.0


def test_gaussians_behind_or_beside_the_camera_are_culled_and_empty_input_is_fine():
    means, scales, opac = tensors([[0.0, 0.0, -2.0], [50.0, 0.0, 2.0]], [0.1, 0.1], [0.9, 0.9])
    r = render_gaussians(means, scales, opac, CAM, IDENTITY, CFG)
    assert r.weight.numel() == 0 and float(r.silhouette.sum()) == 0.0
    empty = render_gaussians(torch.zeros(0, 3), torch.zeros(0), torch.zeros(0), CAM, IDENTITY, CFG)
    assert empty.silhouette.shape == (CAM.height, CAM.width) and empty.weight.numel() == 0


def test_world_pose_is_applied():
    T = look_at([1.0, 2.0, 1.0], [1.0, 5.0, 1.0])          # looking along world +y
    means, scales, opac = tensors([[1.0, 4.0, 1.0]], [0.05], [0.9])
    r = render_gaussians(means, scales, opac, CAM, T, CFG)
    v, u = divmod(int(r.pixel_index[r.weight.argmax()]), CAM.width)
    assert (u, v) in {(19, 14), (20, 14), (19, 15), (20, 15)}
    assert float(r.pair_depth[0]) == pytest.approx(2.0, abs=1e-5)
