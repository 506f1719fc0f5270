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

from helios.schema import require, require_range
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

    def __post_init__(self) -> None:
        require_range(self, "width height", 16, 4096)    # pixels: below 16 nothing is recognisable
        require_range(self, "near", 0.001, 1.0)
        require_range(self, "far max_range", 0.0, 1000.0, lo_open=True)
        require(self.near < self.far, f"near ({self.near}) must be < far ({self.far})")


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


FLOOR_RGB = (150, 126, 100)   # light oak, distinct from the off-white walls


def camera_request(intr: CameraIntrinsics, T_world_cam: np.ndarray, config: CameraConfig,
                   floor_id: int | None = None) -> dict:
    """Everything a render needs, as plain data (sent as is to a render worker process)."""
    return {"width": intr.width, "height": intr.height, "viewMatrix": view_matrix(T_world_cam),
            "projectionMatrix": projection_matrix(intr, config.near, config.far), "renderer": config.renderer,
            "pinhole": (intr.fx, intr.fy, intr.cx, intr.cy), "T_world_cam": np.asarray(T_world_cam, dtype=float),
            "floor_id": floor_id}


def raw_render(client, pb, request: dict):
    """Call getCameraImage on any client; returns (rgba, zbuffer, segmentation) as numpy arrays."""
    renderer = pb.ER_TINY_RENDERER if request["renderer"] == "tiny" else pb.ER_BULLET_HARDWARE_OPENGL
    _, _, rgba, zbuf, seg = client.getCameraImage(
        request["width"], request["height"], viewMatrix=request["viewMatrix"],
        projectionMatrix=request["projectionMatrix"], renderer=renderer, shadow=0,
        flags=pb.ER_SEGMENTATION_MASK_OBJECT_AND_LINKINDEX)
    return rgba, zbuf, seg


def decode(rgba, zbuf, seg, request: dict, config: CameraConfig) -> RenderedFrame:
    """Raw renderer output to uint8 RGB, metric depth (0 = no return) and int32 segmentation.

    The floor (the plane z = 0) is not rasterised: TinyRenderer's cost grows with covered screen
    area and the floor covers most of most views. Pixels nothing was drawn on are intersected with
    the plane analytically instead (exact depth, the ground body's segmentation id, floor colour).
    """
    height, width = request["height"], request["width"]
    rgb = np.ascontiguousarray(np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[..., :3])
    zbuf = np.asarray(zbuf, dtype=np.float32).reshape(height, width)
    seg = np.array(seg, dtype=np.int32).reshape(height, width)
    near, far = np.float32(config.near), np.float32(config.far)
    depth = far * near / (far - (far - near) * zbuf)   # float32 throughout: 1 mm at 10 m is plenty
    depth[(zbuf >= np.float32(1.0 - 1e-6)) | (depth > config.max_range)] = 0.0
    if request.get("floor_id") is not None:
        _fill_floor(rgb, depth, seg, request, config)
    return RenderedFrame(rgb, depth, seg)


def _fill_floor(rgb: np.ndarray, depth: np.ndarray, seg: np.ndarray, request: dict, config: CameraConfig) -> None:
    v, u = np.nonzero(seg < 0)
    if v.size == 0:
        return
    fx, fy, cx, cy = request["pinhole"]
    T = request["T_world_cam"]
    # World-z component of each pixel's ray (optical z = 1); elementwise, no BLAS call on the hot path.
    dz = T[2, 0] * ((u - cx) / fx) + T[2, 1] * ((v - cy) / fy) + T[2, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -T[2, 3] / dz           # optical-axis depth of the hit, since each ray has unit optical z
    hit = (dz < 0) & (t >= config.near) & (t <= min(config.far, config.max_range))
    v, u, t = v[hit], u[hit], t[hit]
    depth[v, u] = t.astype(np.float32)
    seg[v, u] = request["floor_id"]
    rgb[v, u] = FLOOR_RGB


def render(world: World, intr: CameraIntrinsics, T_world_cam: np.ndarray, config: CameraConfig) -> RenderedFrame:
    """Render one RGB-D + segmentation frame from ``T_world_cam`` (optical frame -> world)."""
    request = camera_request(intr, T_world_cam, config, world.ground_id)
    rgba, zbuf, seg = raw_render(world.client, world.pb, request)
    return decode(rgba, zbuf, seg, request, config)
