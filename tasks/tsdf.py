"""TSDF reconstruction of what an episode saw, and how much of the true receptacle surfaces it
covers: Open3D's tensor ``VoxelBlockGrid`` (Open3D 0.20's legacy ``ScalableTSDFVolume`` integrates
nothing — a regression test guards this), a coverage score against points sampled on the true
surfaces, and a mesh export.

Coverage of a surface = the fraction of points sampled on it every ``sample_spacing`` metres that
lie within ``tolerance`` (2 cm) of the reconstructed surface.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from helios.schema import ConfigValueError, require_range
from robots.hal import Observation


BYTES_PER_VOXEL = 20
"""tsdf, weight and an RGB colour, float32 each (:class:`TsdfIntegrator`'s attributes)."""
PREALLOCATION_LIMIT_BYTES = 4 * 2 ** 30
"""The most a TSDF may preallocate for its voxel blocks (``block_count`` x ``block_resolution``^3
voxels): 4 GiB, 25 times the default's 164 MB. block_count=10000000, inside its range, asked
Open3D for 820 GB and died on a "CPU malloc failed" traceback."""


@dataclass(frozen=True)
class TsdfConfig:
    voxel_size: float = 0.01          # m
    block_resolution: int = 16
    block_count: int = 2000
    """Initial capacity of the voxel-block hash map (blocks of block_resolution^3 voxels, 20 bytes
    each: 2000 blocks of 16^3 take 164 MB). Open3D grows it as blocks are activated, so this bounds
    only the first allocation: 20000 preallocated 1.6 GB even for a small scene (smoke-00000 needs
    ~2900 blocks at 1 cm; same coverage and triangles with either, 0.7 instead of 2.0 GB peak)."""
    depth_max: float = 4.0            # m, depth beyond this is not integrated
    trunc_voxels: float = 4.0         # truncation distance in voxels
    tolerance: float = 0.02           # m, a true surface point is covered within this distance
    sample_spacing: float = 0.02      # m between points sampled on true surfaces
    weight_threshold: float = 0.5     # voxels with weight above this are extracted (Open3D compares with ">": one frame counts)

    def __post_init__(self) -> None:
        require_range(self, "voxel_size", 0.001, 1.0)
        require_range(self, "block_resolution", 2, 64)
        require_range(self, "block_count", 1, 10_000_000)
        need = self.preallocated_bytes()
        if need > PREALLOCATION_LIMIT_BYTES:
            most = PREALLOCATION_LIMIT_BYTES // (self.block_resolution ** 3 * BYTES_PER_VOXEL)
            raise ConfigValueError(
                f"block_count={self.block_count} blocks of {self.block_resolution}^3 voxels would preallocate "
                f"{need / 2 ** 30:.1f} GiB ({BYTES_PER_VOXEL} bytes a voxel); at most "
                f"{PREALLOCATION_LIMIT_BYTES // 2 ** 30} GiB is allowed, block_count <= {most} at this "
                f"block_resolution (the map grows by itself as blocks are seen)")
        require_range(self, "depth_max", 0.0, 100.0, lo_open=True)
        require_range(self, "trunc_voxels", 0.0, 100.0, lo_open=True)
        require_range(self, "tolerance sample_spacing", 0.0, 1.0, lo_open=True)
        require_range(self, "weight_threshold", 0.0, 1e6)

    def preallocated_bytes(self) -> int:
        """What Open3D allocates up front for the voxel blocks (the hash map's own tables aside)."""
        return self.block_count * self.block_resolution ** 3 * BYTES_PER_VOXEL


class TsdfIntegrator:
    """Accumulates RGB-D observations into a voxel-block TSDF (CPU)."""

    def __init__(self, config: TsdfConfig = TsdfConfig()):
        import open3d as o3d
        import open3d.core as o3c

        self.o3d, self.o3c = o3d, o3c
        self.config = config
        self.device = o3c.Device("CPU:0")
        self.vbg = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "color"), attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
            attr_channels=((1), (1), (3)), voxel_size=config.voxel_size,
            block_resolution=config.block_resolution, block_count=config.block_count, device=self.device)
        self.frames = 0

    def integrate(self, obs: Observation) -> None:
        o3d, o3c = self.o3d, self.o3c
        if not np.any(obs.depth > 0):
            return
        K = o3c.Tensor(obs.intrinsics.K, o3c.float64)
        T_cam_world = o3c.Tensor(np.linalg.inv(obs.T_world_cam), o3c.float64)
        depth = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(obs.depth, dtype=np.float32)))
        color = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(obs.rgb, dtype=np.float32) / 255.0))
        kw = {"depth_scale": 1.0, "depth_max": self.config.depth_max, "trunc_voxel_multiplier": self.config.trunc_voxels}
        blocks = self.vbg.compute_unique_block_coordinates(depth, K, T_cam_world, **kw)
        self.vbg.integrate(blocks, depth, color, K, T_cam_world, **kw)
        self.frames += 1

    def points(self) -> np.ndarray:
        if self.frames == 0:
            return np.zeros((0, 3))
        cloud = self.vbg.extract_point_cloud(weight_threshold=self.config.weight_threshold)
        return cloud.point.positions.numpy().astype(float)

    def export_mesh(self, path: str | Path) -> int:
        """Write the reconstructed mesh (PLY/OBJ by suffix); returns its triangle count."""
        mesh = self.vbg.extract_triangle_mesh(weight_threshold=self.config.weight_threshold).to_legacy()
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        if not self.o3d.io.write_triangle_mesh(str(path), mesh):
            raise OSError(f"could not write mesh to {path}")
        return len(mesh.triangles)


def coverage(reconstructed: np.ndarray, surface_points: np.ndarray, tolerance: float) -> float:
    """Fraction of ``surface_points`` within ``tolerance`` of the reconstructed points."""
    from scipy.spatial import cKDTree

    if len(surface_points) == 0:
        raise ValueError("no surface points to score")
    if len(reconstructed) == 0:
        return 0.0
    dist, _ = cKDTree(reconstructed).query(surface_points, distance_upper_bound=tolerance)
    return float(np.mean(np.isfinite(dist)))


def rectangle_samples(centre, half, yaw: float, spacing: float, inset: float = 0.0) -> np.ndarray:
    """Points on a horizontal rectangle (centre x, y, z; half extents; heading), every ``spacing``."""
    hx, hy = half[0] - inset, half[1] - inset
    xs = np.arange(-hx, hx + 1e-9, spacing)
    ys = np.arange(-hy, hy + 1e-9, spacing)
    gx, gy = np.meshgrid(xs, ys)
    c, s = math.cos(yaw), math.sin(yaw)
    x = centre[0] + c * gx - s * gy
    y = centre[1] + s * gx + c * gy
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, centre[2])], axis=1)


def receptacle_surface_samples(scene, name: str, spacing: float, exclude_xy: Iterable = ()) -> np.ndarray:
    """Points on a receptacle's true top surfaces (its object-bearing surfaces, 1 cm in from the
    edges), leaving out points under objects resting there (the camera cannot see through them)."""
    rec = scene.receptacle(name)
    parts = []
    for surf, centre in zip(rec.model.surfaces, scene.surface_points(name)):
        parts.append(rectangle_samples(centre, surf.half, rec.yaw, spacing, inset=0.01))
    pts = np.concatenate(parts) if parts else np.zeros((0, 3))
    for x, y, r in exclude_xy:
        pts = pts[np.hypot(pts[:, 0] - x, pts[:, 1] - y) > r]
    return pts
