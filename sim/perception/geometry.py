"""Per-instance view geometry for the simulated detector, in plain Python floats (a handful of
instances per frame: numpy's per-call overhead would dominate), plus camera helpers.

For a visible body: its distance, the viewpoint bin (azimuth in the body's own frame, elevation,
distance), the foreshortening of its silhouette (grazing views of flat things are hard), and the
fraction of its expected silhouette that is visible (occlusion and truncation by the image edge).
Silhouettes are orthographic areas of the body's primitive parts (boxes exactly; cylinders and
spheres exactly), summed over parts and capped by the silhouette of their bounding box.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from robots.transforms import look_at_camera

# PyBullet geometry types (getCollisionShapeData)
_SPHERE, _BOX, _CYLINDER, _CAPSULE = 2, 3, 4, 7
_MASK64 = (1 << 64) - 1


# ------------------------------------------------------------------------------------ hashing
def mix(*keys: int) -> int:
    """A 64-bit hash of integers (splitmix64 rounds): stable across processes and platforms."""
    h = 0x9E3779B97F4A7C15
    for k in keys:
        h = ((h ^ (int(k) & _MASK64)) * 0xBF58476D1CE4E5B9) & _MASK64
        h ^= h >> 31
        h = (h * 0x94D049BB133111EB) & _MASK64
        h ^= h >> 29
    return h


def u01(*keys: int) -> float:
    """A uniform number in [0, 1) determined by ``keys``."""
    return (mix(*keys) >> 11) * (1.0 / (1 << 53))


def normal(*keys: int) -> float:
    """A standard normal number determined by ``keys`` (Box-Muller on two hashed uniforms)."""
    a = 1.0 - u01(*keys, 0x51)
    b = u01(*keys, 0x52)
    return math.sqrt(-2.0 * math.log(a)) * math.cos(2.0 * math.pi * b)


def logistic(x: float) -> float:
    if x >= 0:
        return 1.0 / (1.0 + math.exp(-x))
    e = math.exp(x)
    return e / (1.0 + e)


# ------------------------------------------------------------------------------------ shapes
@dataclass(frozen=True)
class PartShape:
    kind: str                                  # box | cylinder | sphere
    size: tuple[float, float, float]           # box half extents; cylinder (radius, half height, 0); sphere (r, 0, 0)
    centre: tuple[float, float, float]         # in the body frame
    axes: tuple[tuple[float, float, float], ...]   # rows: the part's x, y, z axes in the body frame


@dataclass(frozen=True)
class BodyShape:
    parts: tuple[PartShape, ...]
    centre: tuple[float, float, float]         # centre of the parts' bounding box, body frame
    half: tuple[float, float, float]           # half extents of that box
    max_silhouette: float                      # largest bounding-box silhouette over view directions (m^2)


def _quat_axes(q) -> tuple[tuple[float, float, float], ...]:
    x, y, z, w = q
    return ((1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w)),
            (2 * (x * y - z * w), 1 - 2 * (x * x + z * z), 2 * (y * z + x * w)),
            (2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y)))


def body_shape(collision_shape_data: Sequence[tuple]) -> BodyShape:
    """Parts of a body from PyBullet's ``getCollisionShapeData(body, -1)``."""
    parts = []
    lo = [math.inf] * 3
    hi = [-math.inf] * 3
    for entry in collision_shape_data:
        gtype, dims, pos, orn = entry[2], entry[3], entry[5], entry[6]
        axes = _quat_axes(orn)
        if gtype == _BOX:
            size = (dims[0] / 2, dims[1] / 2, dims[2] / 2)
            part = PartShape("box", size, tuple(pos), axes)
            ext = [sum(abs(axes[k][i]) * size[k] for k in range(3)) for i in range(3)]
        elif gtype in (_CYLINDER, _CAPSULE):
            r, hh = dims[1], dims[0] / 2
            part = PartShape("cylinder", (r, hh, 0.0), tuple(pos), axes)
            ext = [abs(axes[2][i]) * hh + r * math.sqrt(max(0.0, 1 - axes[2][i] ** 2)) for i in range(3)]
        elif gtype == _SPHERE:
            r = dims[0]
            part = PartShape("sphere", (r, 0.0, 0.0), tuple(pos), axes)
            ext = [r, r, r]
        else:   # meshes/planes do not occur in the catalogue; approximate by nothing
            continue
        parts.append(part)
        for i in range(3):
            lo[i] = min(lo[i], pos[i] - ext[i])
            hi[i] = max(hi[i], pos[i] + ext[i])
    if not parts:
        return BodyShape((), (0.0, 0.0, 0.0), (0.01, 0.01, 0.01), 4e-4)
    centre = tuple((a + b) / 2 for a, b in zip(lo, hi))
    half = tuple(max((b - a) / 2, 1e-3) for a, b in zip(lo, hi))
    hx, hy, hz = half
    max_sil = 4.0 * math.sqrt((hy * hz) ** 2 + (hx * hz) ** 2 + (hx * hy) ** 2)
    return BodyShape(tuple(parts), centre, half, max_sil)


def _box_silhouette(h, v) -> float:
    return 4.0 * (abs(v[0]) * h[1] * h[2] + abs(v[1]) * h[0] * h[2] + abs(v[2]) * h[0] * h[1])


def silhouette(shape: BodyShape, v_body: Sequence[float]) -> tuple[float, float]:
    """(expected silhouette area in m^2, bounding-box silhouette area) seen along unit ``v_body``."""
    box = _box_silhouette(shape.half, v_body)
    total = 0.0
    for p in shape.parts:
        a = p.axes
        vl = (a[0][0] * v_body[0] + a[0][1] * v_body[1] + a[0][2] * v_body[2],
              a[1][0] * v_body[0] + a[1][1] * v_body[1] + a[1][2] * v_body[2],
              a[2][0] * v_body[0] + a[2][1] * v_body[1] + a[2][2] * v_body[2])
        if p.kind == "box":
            total += _box_silhouette(p.size, vl)
        elif p.kind == "cylinder":
            r, hh = p.size[0], p.size[1]
            c = min(1.0, abs(vl[2]))
            total += 4.0 * r * hh * math.sqrt(1.0 - c * c) + math.pi * r * r * c
        else:
            total += math.pi * p.size[0] ** 2
    return min(total, box), box


# ------------------------------------------------------------------------------------ view of a body
@dataclass(frozen=True)
class BodyView:
    distance: float          # m, camera centre to the body's bounding-box centre
    azimuth: float           # rad, direction of the camera around the body in the body's frame
    elevation: float         # rad, camera above the body centre's horizontal plane
    foreshortening: float    # silhouette of the bounding box / its largest silhouette, in (0, 1]
    expected_area: float     # m^2, silhouette the body would show unoccluded
    bin: tuple[int, int, int]   # (azimuth, elevation, distance) bin


def bin_index(value: float, edges: Sequence[float]) -> int:
    i = 0
    for e in edges:
        if value >= e:
            i += 1
    return i


def view_of(shape: BodyShape, T_world_body: np.ndarray, cam_pos: Sequence[float], azimuth_bins: int,
            elevation_edges_deg: Sequence[float], distance_edges: Sequence[float]) -> BodyView:
    R = T_world_body
    c = shape.centre
    # body-frame bounding-box centre in the world
    cx = R[0][0] * c[0] + R[0][1] * c[1] + R[0][2] * c[2] + R[0][3]
    cy = R[1][0] * c[0] + R[1][1] * c[1] + R[1][2] * c[2] + R[1][3]
    cz = R[2][0] * c[0] + R[2][1] * c[1] + R[2][2] * c[2] + R[2][3]
    dx, dy, dz = cam_pos[0] - cx, cam_pos[1] - cy, cam_pos[2] - cz
    d = math.sqrt(dx * dx + dy * dy + dz * dz) or 1e-6
    wx, wy, wz = dx / d, dy / d, dz / d
    # into the body frame (R^T v)
    v = (R[0][0] * wx + R[1][0] * wy + R[2][0] * wz,
         R[0][1] * wx + R[1][1] * wy + R[2][1] * wz,
         R[0][2] * wx + R[1][2] * wy + R[2][2] * wz)
    az = math.atan2(v[1], v[0])
    el = math.asin(max(-1.0, min(1.0, wz)))
    area, box = silhouette(shape, v)
    fore = min(1.0, box / shape.max_silhouette)
    az_bin = int((az + math.pi) / (2 * math.pi) * azimuth_bins) % azimuth_bins
    b = (az_bin, bin_index(math.degrees(el), elevation_edges_deg), bin_index(d, distance_edges))
    return BodyView(d, az, el, fore, area, b)


# ------------------------------------------------------------------------------------ cameras
def camera_around(target: Sequence[float], distance: float, azimuth: float, elevation: float) -> np.ndarray:
    """A camera ``distance`` m from ``target`` in world direction (azimuth, elevation), looking at it."""
    t = np.asarray(target, dtype=float)
    eye = t + distance * np.array([math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth),
                                   math.sin(elevation)])
    return look_at_camera(eye, t)
