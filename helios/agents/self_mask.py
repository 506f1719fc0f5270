"""Which depth returns are the robot itself: the pixels whose point lies inside the body's box.

The hand camera sees Spot's legs and body when it looks down or sideways, and the map would turn
them into obstacles wherever the robot has stood (:meth:`Observer.without_self`). The test is a box
in the body frame: x and y within the footprint grown by a margin, z below a height above the body
origin (nothing below: the legs reach the floor).

Every frame asks this of ~77,000 returns, so the box test runs per pixel on the image grid: a
pixel's body-frame point is ``depth * ray + t`` with the ray rotated once per pixel row and column.
That rounds differently from back-projecting each return and rotating it with one matrix product
(the definition, :func:`own_pixels_exact`), by ~1e-14 m at these ranges. So the fast test decides
only returns more than :data:`DECIDE_MARGIN` from every face it tests; if any return comes that
close, the whole frame goes through the exact computation. The masks are the same bit for bit,
and the fast test costs a quarter of the exact one (3.4 -> 0.8 ms per 320 x 240 frame).
"""

from __future__ import annotations

import numpy as np

from robots.hal import CameraIntrinsics

DECIDE_MARGIN = 1e-9
"""m: the fast test decides a return only this far from a face of the box (rounding is < 1e-12 m
for returns within 1 km of the camera); closer, the frame takes the exact computation."""


def own_pixels_exact(depth: np.ndarray, intrinsics: CameraIntrinsics, T_body_cam: np.ndarray,
                     box: tuple[float, float, float, float], top: float) -> np.ndarray:
    """(H, W) bool: returns whose point, back-projected and moved into the body frame with one
    matrix product, lies inside ``box`` (x0 < x < x1, y0 < y < y1, margins included) below ``top``.
    The definition the fast test must reproduce."""
    x0, x1, y0, y1 = box
    own = np.zeros(depth.shape, dtype=bool)
    v, u = np.nonzero(depth > 0)
    if not len(v):
        return own
    pc = intrinsics.backproject(u, v, depth[v, u])
    pb = pc @ T_body_cam[:3, :3].T + T_body_cam[:3, 3]
    inside = (pb[:, 0] > x0) & (pb[:, 0] < x1) & (pb[:, 1] > y0) & (pb[:, 1] < y1) & (pb[:, 2] < top)
    own[v[inside], u[inside]] = True
    return own


def own_pixels(depth: np.ndarray, intrinsics: CameraIntrinsics, T_body_cam: np.ndarray,
               box: tuple[float, float, float, float], top: float) -> np.ndarray:
    """Same mask as :func:`own_pixels_exact`, computed per pixel on the image grid (module docstring)."""
    x0, x1, y0, y1 = box
    h, w = depth.shape
    R, t = T_body_cam[:3, :3], T_body_cam[:3, 3]
    ray_u = (np.arange(w, dtype=float) - intrinsics.cx) / intrinsics.fx     # optical x per metre of depth
    ray_v = (np.arange(h, dtype=float) - intrinsics.cy) / intrinsics.fy     # optical y per metre of depth
    d = depth.astype(np.float64)
    eps = DECIDE_MARGIN

    # x for every pixel (the cheapest face to rule a return out: most of a view lies ahead of the body).
    bx = d * (ray_u[None, :] * R[0, 0] + (ray_v[:, None] * R[0, 1] + R[0, 2])) + t[0]
    maybe = (d > 0) & (bx > x0 - eps) & (bx < x1 + eps)
    v, u = np.nonzero(maybe)
    own = np.zeros(depth.shape, dtype=bool)
    if not len(v):
        return own
    dv, ru, rv = d[v, u], ray_u[u], ray_v[v]
    px, py = dv * ru, dv * rv
    xs = bx[v, u]
    ys = px * R[1, 0] + py * R[1, 1] + dv * R[1, 2] + t[1]
    zs = px * R[2, 0] + py * R[2, 1] + dv * R[2, 2] + t[2]
    close = (np.abs(xs - x0) <= eps) | (np.abs(xs - x1) <= eps) | (np.abs(ys - y0) <= eps) | \
        (np.abs(ys - y1) <= eps) | (np.abs(zs - top) <= eps)
    if close.any():          # a return on a face: only the exact computation can say which side
        return own_pixels_exact(depth, intrinsics, T_body_cam, box, top)
    inside = (xs > x0) & (xs < x1) & (ys > y0) & (ys < y1) & (zs < top)
    own[v[inside], u[inside]] = True
    return own
