"""Gaze points for local search (paper Sec. "Local search").

Poses on a contour around an instance's ground projection, from which the robot looks at the
instance's ground-plane centre and highest point. Points are dropped when

- the robot standing there (its footprint, see :mod:`helios.planning.footprint`) overlaps an
  occupied cell, or
- an occupied cell taller than the instance's highest point (plus ``los_margin``) lies on the
  straight line between the point and the instance: it would hide the instance.

The contour is the instance's footprint grown by ``standoff`` metres (its support function in
each direction plus the standoff), sampled every ``spacing`` metres of arc. The first ring is
where local search looks from; the outer rings are a fallback (``outer_rings = "fallback"``): an
outer point is kept only if the inner point of its direction (the nearest inner direction) is
blocked, and no nearer ring has a free point there. ``outer_rings = "always"`` keeps every free
point of every ring (our earlier reading, 8-12+ gaze points per candidate, nearly twice the
gaze point visits per episode). Cells of the instance's own footprint (grown by
``own_margin``) never block its line of sight: a table's top does not hide the table.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Literal

import cv2
import numpy as np

from helios.maps.grid import GridGeometry
from helios.planning.footprint import FootprintChecker
from helios.schema import require, require_range
from robots.hal import SE2Pose


@dataclass(frozen=True)
class GazeConfig:
    standoffs: tuple[float, ...] = (0.9, 1.3)
    """Distances (m) from the instance's footprint edge to the robot's body centre, one ring each.
    0.9 m leaves the body front (0.43 m + margin) clear of a table edge with the hand camera
    about 0.4 m from it; 1.3 m is the fallback ring."""
    outer_rings: Literal["fallback", "always"] = "fallback"
    """``fallback``: outer-ring points only where the inner ones are blocked (the docstring's
    reading of the paper's one contour); ``always``: every ring in full."""
    spacing: float = 0.6
    """Arc length (m) between neighbouring gaze points on a ring."""
    min_points: int = 8
    """At least this many directions per ring, however small the instance."""
    los_margin: float = 0.0
    """An occupied cell blocks the view when its height exceeds the instance's top by this (m)."""
    own_margin: float = 0.15
    """The instance's own footprint grown by this (m) is ignored by the line-of-sight test."""
    min_look_height: float = 0.05
    """Lower bound (m) of the look-at point's height (objects on the floor)."""
    arm_room: bool = False
    """True: a point from which the arm could not aim the camera (no room for the elbow there or
    a short step away, or a tall obstacle on the hand's sweep; the agent's own test, passed in as
    ``can_look``) counts as blocked, so the outer ring stands in for it. False (default, the
    paper's contour): only the body's footprint and the line of sight decide; the visit then
    finds out, after the walk. Why one might: in 30 train timeouts, 219 of 702 local-search steps
    took no view, 64 of them for want of arm room after ~10 s of walking each (README, "Gaze
    point visits that take no view")."""

    def __post_init__(self) -> None:
        require(bool(self.standoffs) and all(0 < s <= 5.0 for s in self.standoffs),
                "standoffs must be distances in (0, 5] m")
        require(0 < self.spacing <= 5.0 and 3 <= self.min_points <= 360, "need 0 < spacing <= 5 m and 3 <= min_points <= 360")
        require(self.outer_rings in ("fallback", "always"), f"outer_rings must be 'fallback' or 'always', got {self.outer_rings!r}")
        require_range(self, "los_margin", -1.0, 2.0)
        require_range(self, "own_margin", 0.0, 2.0)
        require_range(self, "min_look_height", 0.0, 3.0)


@dataclass(frozen=True)
class GazePoint:
    pose: SE2Pose               # where the body stands, facing the instance's centre
    look_at: np.ndarray         # (3,) world point the hand camera is aimed at


def contour_points(footprint_xy: np.ndarray, standoff: float, spacing: float, min_points: int) -> np.ndarray:
    """(M, 2) points at ``standoff`` beyond the support of ``footprint_xy`` in M directions."""
    pts = np.asarray(footprint_xy, dtype=float).reshape(-1, 2)
    centre = pts.mean(axis=0)
    extent = float(np.max(np.linalg.norm(pts - centre, axis=1))) if len(pts) else 0.0
    n = max(min_points, int(math.ceil(2 * math.pi * (extent + standoff) / spacing)))
    ang = 2 * math.pi * np.arange(n) / n
    dirs = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    support = np.max((pts - centre) @ dirs.T, axis=0)          # (n,) half-width in each direction
    return centre + (np.maximum(support, 0.0) + standoff)[:, None] * dirs


def gaze_points(footprint_xy: np.ndarray, top_z: float, geometry: GridGeometry, obstacle: np.ndarray,
                max_height: np.ndarray, checker: FootprintChecker, config: GazeConfig = GazeConfig(),
                centre_xy=None, can_look: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
                ) -> list[GazePoint]:
    """Free gaze points with a clear line of sight to the instance (ring by ring, nearest ring first).
    With ``config.arm_room``, ``can_look(poses, look_at)`` ((N, 3) poses, the look-at point; (N,)
    bool) must also pass, or the point counts as blocked (required then)."""
    require(not config.arm_room or can_look is not None, "GazeConfig.arm_room needs a can_look test")
    pts = np.asarray(footprint_xy, dtype=float).reshape(-1, 2)
    if not len(pts):
        return []
    centre = pts.mean(axis=0) if centre_xy is None else np.asarray(centre_xy, dtype=float)[:2]
    look = np.array([centre[0], centre[1], max(float(top_z), config.min_look_height)])
    rings = [contour_points(pts, s, config.spacing, config.min_points) for s in config.standoffs]
    window = _Window(geometry, np.concatenate([pts, *rings]), obstacle.shape)
    if window.r1 <= window.r0 or window.c1 <= window.c0:
        return []              # the instance and its rings lie off the map grid (OpenCV failed on the empty window)
    own = np.zeros((window.r1 - window.r0, window.c1 - window.c0), dtype=np.uint8)
    r, c = window.local_cells(pts)
    own[r, c] = 1
    own = _grown(own, int(math.ceil(config.own_margin / geometry.cell_size))).astype(bool)
    blocking = window.crop(obstacle) & (window.crop(max_height) > float(top_z) + config.los_margin) & ~own
    # directions round the footprint's mean (the contour's own centre), to match outer points to
    # the inner point they stand in for
    middle = pts.mean(axis=0)
    inner_dirs = np.arctan2(rings[0][:, 1] - middle[1], rings[0][:, 0] - middle[0])
    covered = np.zeros(len(inner_dirs), dtype=bool)       # directions with a free point on a nearer ring
    out: list[GazePoint] = []
    for j, ring in enumerate(rings):
        dirs = np.arctan2(ring[:, 1] - middle[1], ring[:, 0] - middle[0])
        gap = np.abs(np.angle(np.exp(1j * (dirs[:, None] - inner_dirs[None, :]))))
        sector = np.argmin(gap, axis=1)
        wanted = np.ones(len(ring), dtype=bool) if j == 0 or config.outer_rings == "always" else ~covered[sector]
        yaw = np.arctan2(centre[1] - ring[:, 1], centre[0] - ring[:, 0])
        poses = np.column_stack([ring, yaw])
        free = checker.poses_free(poses)
        keep = [k for k, p in enumerate(poses) if wanted[k] and free[k] and window.line_clear(p[:2], centre, blocking)]
        if config.arm_room and keep:
            keep = [k for k, ok in zip(keep, can_look(poses[keep], look)) if ok]
        found = np.zeros(len(ring), dtype=bool)
        for k in keep:
            p = poses[k]
            found[k] = True
            out.append(GazePoint(SE2Pose(float(p[0]), float(p[1]), float(p[2])), look.copy()))
        covered[sector[found]] = True
    return out


def _grown(mask: np.ndarray, k: int) -> np.ndarray:
    """A uint8 0/1 mask dilated by the disc of radius ``k`` cells, nothing outside its edges.

    The same cells as ``scipy.ndimage.binary_dilation`` with that (symmetric) disc and its
    default zero border (``tests/test_exact_speedups.py``), through OpenCV: gaze points are
    recomputed for every candidate at every global decision, and the dilation was a third of it."""
    if k <= 0:
        return mask
    yy, xx = np.mgrid[-k:k + 1, -k:k + 1]
    disc = ((yy ** 2 + xx ** 2) <= k * k).astype(np.uint8)
    return cv2.dilate(mask, disc, borderType=cv2.BORDER_CONSTANT, borderValue=0)


def line_of_sight(a, b, geometry: GridGeometry, blocking: np.ndarray) -> bool:
    """No blocking cell (a full-map bool grid) on the straight segment a -> b."""
    window = _Window(geometry, np.array([a[:2], b[:2]], dtype=float), blocking.shape)
    return window.line_clear(a, b, window.crop(blocking))


class _Window:
    """A rectangle of the grid around some world points, so work stays local to the instance."""

    def __init__(self, geometry: GridGeometry, xy: np.ndarray, shape, pad: int = 2):
        rows, cols = geometry.world_to_cell(xy)
        self.geometry = geometry
        self.r0 = int(np.clip(rows.min() - pad, 0, shape[0]))
        self.r1 = int(np.clip(rows.max() + pad + 1, 0, shape[0]))
        self.c0 = int(np.clip(cols.min() - pad, 0, shape[1]))
        self.c1 = int(np.clip(cols.max() + pad + 1, 0, shape[1]))

    def crop(self, grid: np.ndarray) -> np.ndarray:
        return grid[self.r0:self.r1, self.c0:self.c1]

    def local_cells(self, xy) -> tuple[np.ndarray, np.ndarray]:
        rows, cols = self.geometry.world_to_cell(np.asarray(xy, dtype=float))
        rows, cols = rows - self.r0, cols - self.c0
        keep = (rows >= 0) & (rows < self.r1 - self.r0) & (cols >= 0) & (cols < self.c1 - self.c0)
        return rows[keep], cols[keep]

    def line_clear(self, a, b, local_blocking: np.ndarray) -> bool:
        a, b = np.asarray(a, dtype=float)[:2], np.asarray(b, dtype=float)[:2]
        n = max(2, int(math.dist(a, b) / (0.5 * self.geometry.cell_size)) + 1)
        t = np.linspace(0.0, 1.0, n)[:, None]
        rows, cols = self.local_cells(a + t * (b - a))
        return not bool(local_blocking[rows, cols].any())


def visiting_order(views: list[GazePoint], start_xy) -> list[GazePoint]:
    """The order a local search visits its gaze points in: the nearest to ``start_xy`` first,
    then each time the nearest to the last one (the paper: "starting from the closest")."""
    views, order, here = list(views), [], np.asarray(start_xy, dtype=float)
    while views:
        i = int(np.argmin([math.hypot(g.pose.x - here[0], g.pose.y - here[1]) for g in views]))
        order.append(views.pop(i))
        here = np.array([order[-1].pose.x, order[-1].pose.y])
    return order
