"""The Gaussian layer on CUDA gives what it gives on the CPU (marked ``gpu``: skipped, with the
reason, on machines without a CUDA device; `python -m pytest -m gpu` runs it where there is one)."""

import numpy as np
import pytest
import torch

from helios.config import HeliosConfig, RenderConfig
from helios.maps.renderer import render_gaussians
from helios.schema import with_overrides
from robots.hal import CameraIntrinsics
from robots.transforms import look_at_camera

pytestmark = pytest.mark.gpu


def test_rendering_on_cuda_matches_the_cpu():
    rng = np.random.default_rng(0)
    n = 4000
    means = torch.tensor(np.stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(1, 6, n)], axis=1),
                         dtype=torch.float32)
    scales = torch.tensor(rng.uniform(0.01, 0.1, n), dtype=torch.float32)
    opacities = torch.tensor(rng.uniform(0.1, 0.9, n), dtype=torch.float32)
    cam = CameraIntrinsics(160, 120, 130.0, 130.0, 79.5, 59.5)
    pose = look_at_camera(np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, 3.0]))
    cpu = render_gaussians(means, scales, opacities, cam, pose, RenderConfig())
    cuda = render_gaussians(means.cuda(), scales.cuda(), opacities.cuda(), cam, pose, RenderConfig())
    assert cuda.device.type == "cuda" and cpu.weight.numel() > 10_000
    np.testing.assert_allclose(cuda.silhouette.cpu().numpy(), cpu.silhouette.numpy(), atol=1e-4)
    np.testing.assert_allclose(cuda.accumulated_depth.cpu().numpy(), cpu.accumulated_depth.numpy(), rtol=1e-4, atol=1e-3)


def test_a_map_update_on_cuda_matches_the_cpu():
    from tools.bench_maps import synthetic_frames
    from helios.maps.hierarchical import HierarchicalMap

    frames = list(synthetic_frames(6, seed=0))
    maps = {}
    for device in ("cpu", "cuda"):
        hmap = HierarchicalMap(with_overrides(HeliosConfig(), [f"device={device}"]), ("cup", "table", "counter"),
                               ("table", "counter"))
        for obs, detections, scores in frames:
            hmap.update(obs, detections, scores)
        maps[device] = hmap
    cpu, cuda = maps["cpu"].objects, maps["cuda"].objects
    assert cuda.device.type == "cuda" and len(cpu) > 100
    assert len(cuda) == len(cpu)
    np.testing.assert_allclose(cuda.concentrations.cpu().numpy(), cpu.concentrations.numpy(), rtol=1e-3, atol=1e-3)
