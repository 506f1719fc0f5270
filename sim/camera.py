"""Pinhole camera rendering in PyBullet: RGB, metric depth and instance segmentation with exact
intrinsics (any fx, fy, cx, cy — not only PyBullet's centred FOV model).

The OpenGL projection matrix is built from the intrinsics with OpenCV pixel conventions (pixel
centres at integer coordinates, u right, v down), so projecting a point with ``CameraIntrinsics``
and reading the rendered depth at that pixel agree. Depth comes back as metres along the optical
axis, 0 where nothing was hit (beyond ``max_range``), as Spot reports it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from robots.hal import CameraIntrinsics
from sim.world import World

# OpenGL camera frame = optical frame with y and z flipped (x right, y up, looking along -z).
_OPTICAL_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True)
class CameraConfig:
    width: int = 320                 # rendered resolution; intrinsics are scaled from the native 640x480
    height: int = 240
    near: float = 0.05               # m; keeps the near plane outside the gripper geometry
    far: float = 10.0                # m; OVMM's depth range
    max_range: float = 10.0          # m; depth beyond this reads 0 (no return)
    renderer: Literal["tiny", "egl"] = "tiny"   # EGL (Mesa/llvmpipe or GPU) pays off only at >= 640x480


@dataclass
class RenderedFrame:
    rgb: np.ndarray          # (H, W, 3) uint8
    depth: np.ndarray        # (H, W) float32 metres, 0 = no return
    segmentation: np.ndarray  # (H, W) int32 raw PyBullet ids: body + ((link + 1) << 24), -1 background

    @property
    def body_ids(self) -> np.ndarray:
        return decode_body_ids(self.segmentation)

    @property
    def link_indices(self) -> np.ndarray:
        return decode_link_indices(self.segmentation)


def decode_body_ids(seg: np.ndarray) -> np.ndarray:
    """Body unique id per pixel (-1 for background)."""
    seg = np.asarray(seg)
    out = seg & 0xFFFFFF
    out[seg < 0] = -1
    return out


def decode_link_indices(seg: np.ndarray) -> np.ndarray:
    """Link index per pixel (-1 = base link, and -1 for background)."""
    seg = np.asarray(seg)
    out = (seg >> 24) - 1
    out[seg < 0] = -1
    return out


def projection_matrix(intr: CameraIntrinsics, near: float, far: float) -> list[float]:
    """Column-major OpenGL projection for a pinhole camera (OpenCV pixel-centre convention)."""
    w, h = intr.width, intr.height
    P = np.array([
        [2.0 * intr.fx / w, 0.0, 1.0 - 2.0 * (intr.cx + 0.5) / w, 0.0],
        [0.0, 2.0 * intr.fy / h, 2.0 * (intr.cy + 0.5) / h - 1.0, 0.0],
        [0.0, 0.0, -(far + near) / (far - near), -2.0 * far * near / (far - near)],
        [0.0, 0.0, -1.0, 0.0],
    ])
    return P.T.reshape(-1).tolist()


def view_matrix(T_world_cam: np.ndarray) -> list[float]:
    """Column-major OpenGL view matrix (world -> GL camera) for an optical-frame camera pose."""
    T_cam_world = np.linalg.inv(T_world_cam)
    V = _OPTICAL_TO_GL @ T_cam_world
    return V.T.reshape(-1).tolist()


def linearize_depth(zbuf: np.ndarray, near: float, far: float) -> np.ndarray:
    """OpenGL z-buffer values in [0, 1] to metric depth along the optical axis."""
    zbuf = np.asarray(zbuf, dtype=np.float64)
    return far * near / (far - (far - near) * zbuf)


def render(world: World, intr: CameraIntrinsics, T_world_cam: np.ndarray, config: CameraConfig) -> RenderedFrame:
    """Render one RGB-D + segmentation frame from ``T_world_cam`` (optical frame -> world)."""
    pb = world.pb
    world.ensure_floor_visual()
    renderer = pb.ER_TINY_RENDERER if config.renderer == "tiny" else pb.ER_BULLET_HARDWARE_OPENGL
    _, _, rgba, zbuf, seg = world.client.getCameraImage(
        intr.width, intr.height,
        viewMatrix=view_matrix(T_world_cam),
        projectionMatrix=projection_matrix(intr, config.near, config.far),
        renderer=renderer, shadow=0,
        flags=pb.ER_SEGMENTATION_MASK_OBJECT_AND_LINKINDEX,
    )
    rgba = np.asarray(rgba, dtype=np.uint8).reshape(intr.height, intr.width, 4)
    zbuf = np.asarray(zbuf, dtype=np.float32).reshape(intr.height, intr.width)
    seg = np.asarray(seg, dtype=np.int32).reshape(intr.height, intr.width)
    depth = linearize_depth(zbuf, config.near, config.far)
    invalid = (zbuf >= 1.0 - 1e-7) | (depth > config.max_range) | ~np.isfinite(depth)
    depth[invalid] = 0.0
    return RenderedFrame(np.ascontiguousarray(rgba[..., :3]), depth.astype(np.float32), seg)
