"""Spot's plan-view footprint and collision checks of poses against the agent's occupancy map.

The body and legs collide with anything in the obstacle band and, when the caller passes the
unexplored cells, may not sweep those either (a stool that was never seen is still a stool); the
stowed arm (or an object carried in front) sits ~0.75 m up and only meets obstacles taller than
that, which the occupancy grid's per-cell maximum height tells apart. Cells under the robot's own
footprint count as free (see ``clear_under``): the hand camera cannot see under the body.
"""

from __future__ import annotations

import copy
import functools
import math
from dataclasses import dataclass

import numpy as np

from helios.maps.grid import GridGeometry, clip_index


@dataclass(frozen=True)
class FootprintConfig:
    body: tuple[float, float, float, float] = (-0.545, 0.43, -0.215, 0.215)
    """Body and legs, (x0, x1, y0, y1) in the body frame, m (Spot at its stand pose)."""
    arm: tuple[float, float, float, float] = (0.43, 0.62, -0.09, 0.09)
    """Stowed arm or carry pose in front of the body, m."""
    arm_clearance_height: float = 0.74
    """Obstacles at most this tall (m) pass under the stowed arm."""
    margin: float = 0.05
    """Safety margin added around both boxes, m."""

    def __post_init__(self) -> None:
        for box in (self.body, self.arm):
            if not (box[0] < box[1] and box[2] < box[3]):
                raise ValueError(f"footprint box {box} must be (x0 < x1, y0 < y1)")
        if self.margin < 0:
            raise ValueError("footprint margin must be >= 0")
        from helios.schema import require_range

        for box in (self.body, self.arm):
            if not all(abs(v) <= 3.0 for v in box):
                raise ValueError(f"footprint box {box} must lie within 3 m of the body centre")
        require_range(self, "arm_clearance_height", 0.0, 3.0)
        require_range(self, "margin", 0.0, 1.0)


class FootprintChecker:
    """Collision tests of SE2 poses against an obstacle grid and its heights."""

    def __init__(self, config: FootprintConfig, geometry: GridGeometry, obstacle: np.ndarray,
                 max_height: np.ndarray | None = None, unknown: np.ndarray | None = None):
        self._shape(config, geometry)
        self.tall = obstacle if max_height is None else obstacle & (max_height > config.arm_clearance_height)
        # Body and legs may only sweep cells the camera has seen: something low (a stool's base,
        # a box) may hide in any unseen cell, and the hand camera never sees right under the body.
        self.obstacle = obstacle if unknown is None else obstacle | unknown
        self.blocks_unknown = unknown is not None

    def _shape(self, config: FootprintConfig, geometry: GridGeometry) -> None:
        self.config = config
        self.geometry = geometry
        step = geometry.cell_size / 2
        self._body, body_tiles = _footprint(tuple(config.body), config.margin, step, geometry.cell_size)
        self._arm, arm_tiles = _footprint(tuple(config.arm), config.margin, step, geometry.cell_size)
        self._tiles: list[tuple[np.ndarray, _Tiles]] = [(self._body, body_tiles), (self._arm, arm_tiles)]

    @classmethod
    def of_known_region(cls, config: FootprintConfig, geometry: GridGeometry, obstacle: np.ndarray,
                        max_height: np.ndarray, explored: np.ndarray | None,
                        bounds: tuple[int, int, int, int] | None) -> "FootprintChecker":
        """The checker ``FootprintChecker(config, geometry, obstacle, max_height, ~explored)`` (or
        ``unknown=None`` when ``explored`` is None), for grids with nothing explored and no obstacle
        outside ``bounds`` (row0, row1, col0, col1, half-open; None: nothing explored), as the
        occupancy grid's ``explored_bounds`` promises. The full-map passes then shrink to that
        window: a home is a tenth of the 50 m grid, and the agent builds a checker after every frame."""
        out = cls.__new__(cls)
        out._shape(config, geometry)
        r0, r1, c0, c1 = bounds if bounds is not None else (0, 0, 0, 0)
        window = (slice(r0, r1), slice(c0, c1))
        out.tall = np.zeros(geometry.shape, dtype=bool)
        out.tall[window] = obstacle[window] & (max_height[window] > config.arm_clearance_height)
        if explored is None:
            out.obstacle, out.blocks_unknown = obstacle, False
        else:
            out.obstacle, out.blocks_unknown = np.ones(geometry.shape, dtype=bool), True
            np.logical_or(obstacle[window], ~explored[window], out=out.obstacle[window])
        return out

    def clear_under(self, pose, grow: float = 0.05) -> "FootprintChecker":
        """A checker for moves *from* ``pose``: obstacle cells its footprint (grown by ``grow``)
        already overlaps are dropped. The robot stands there without touching anything, so such
        cells are map noise or margin, or were seen only after the robot got there (unseen cells
        count as free); kept, they would block every move away from them. ``grow`` stops cells
        right at the margin's edge from flickering in and out of the first few centimetres of a move."""
        x, y, yaw = (pose.x, pose.y, pose.yaw) if hasattr(pose, "yaw") else pose
        c, s = math.cos(yaw), math.sin(yaw)
        step = self.geometry.cell_size / 2
        pts = np.concatenate([_box_points(self.config.body, self.config.margin + grow, step),
                              _box_points(self.config.arm, self.config.margin + grow, step)])
        wx = x + c * pts[:, 0] - s * pts[:, 1]
        wy = y + s * pts[:, 0] + c * pts[:, 1]
        rows, cols = self.geometry.xy_to_cell(wx, wy)
        inside = self.geometry.contains(rows, cols)
        rows, cols = rows[inside], cols[inside]
        if not (self.obstacle[rows, cols].any()):
            return self
        obstacle = self.obstacle.copy()
        obstacle[rows, cols] = False
        tall = self.tall.copy() if self.tall is not self.obstacle else obstacle
        tall[rows, cols] = False
        return self._on(obstacle, tall)

    def seen_within(self, rows: slice, cols: slice, seen: np.ndarray, obstacle: np.ndarray) -> "FootprintChecker":
        """This checker with the cells ``seen`` marks (a mask over the window ``rows, cols``)
        counted as seen: there a cell blocks the body only where ``obstacle`` (the grid this
        checker was built from) has something. The same checker as one built with those cells
        taken out of ``unknown``, from one window instead of full-map passes: the planner makes
        one per plan (never-seen cells near the start count as seen) from the checker the body
        keeps while the grids stand."""
        window = self.obstacle[rows, cols]
        patched = np.where(seen, obstacle[rows, cols], window)
        if np.array_equal(patched, window):
            return self
        out = self.obstacle.copy()
        out[rows, cols] = patched
        return self._on(out, out if self.tall is self.obstacle else self.tall)

    def _on(self, obstacle: np.ndarray, tall: np.ndarray) -> "FootprintChecker":
        """This checker (footprint, tiles) on other grids: the derived checkers' one copy."""
        out = copy.copy(self)
        out.obstacle, out.tall = obstacle, tall
        return out

    @property
    def radius(self) -> float:
        """Radius of the circle swept by the footprint when turning in place."""
        return float(np.max(np.linalg.norm(np.concatenate([self._body, self._arm]), axis=1)))

    def _hits(self, poses: np.ndarray, pts: np.ndarray, grid: np.ndarray) -> np.ndarray:
        """(M,) bool: some point of ``pts`` (body frame) at each pose lands on a True cell of ``grid``.

        Exact, but most points are never transformed. The points are cut into tiles of about
        ``_TILE`` metres; every point of a tile lies within the tile's reach of its centre, so a
        tile whose bounding square of cells (one cell of slack for rounding) holds no True cell
        cannot hit anything. One integral image over the batch's cell window answers that for
        every (pose, tile) at once, and only tiles next to something take the point-by-point test
        (thousands of points per pose at half-cell spacing)."""
        hit = np.zeros(len(poses), dtype=bool)
        if not len(poses):
            return hit
        geo = self.geometry
        tiles = self._tiles_for(pts)
        c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
        cx = poses[:, 0:1] + c * tiles.centres[None, :, 0] - s * tiles.centres[None, :, 1]     # (M, T)
        cy = poses[:, 1:2] + s * tiles.centres[None, :, 0] + c * tiles.centres[None, :, 1]
        last = geo.size - 1
        r0, c0 = geo.xy_to_cell(cx - tiles.reach, cy - tiles.reach)
        r1, c1 = geo.xy_to_cell(cx + tiles.reach, cy + tiles.reach)
        r0, c0, r1, c1 = (clip_index(a, last) for a in (r0, c0, r1, c1))
        wr0, wr1, wc0, wc1 = int(r0.min()), int(r1.max()), int(c0.min()), int(c1.max())
        if (wr1 - wr0 + 1) * (wc1 - wc0 + 1) > len(poses) * len(pts):    # scattered poses: test them all
            return self._hits_exhaustive(poses, pts, grid)
        window = np.zeros((wr1 - wr0 + 2, wc1 - wc0 + 2), dtype=np.int32)
        np.cumsum(np.cumsum(grid[wr0:wr1 + 1, wc0:wc1 + 1], axis=0, dtype=np.int32), axis=1, out=window[1:, 1:])
        r0, r1, c0, c1 = r0 - wr0, r1 - wr0 + 1, c0 - wc0, c1 - wc0 + 1
        near = (window[r1, c1] - window[r0, c1] - window[r1, c0] + window[r0, c0]) > 0      # (M, T)
        for t in np.nonzero(near.any(axis=0))[0]:
            todo = near[:, t] & ~hit
            if todo.any():
                hit[todo] = self._hits_exhaustive(poses[todo], tiles.points[t], grid)
        return hit

    def _tiles_for(self, pts: np.ndarray) -> "_Tiles":
        """The tiles of one of this checker's point sets, cut once: a plan makes hundreds of tests."""
        for known, tiles in self._tiles:
            if known is pts:
                return tiles
        tiles = _tiles_of(pts, self.geometry.cell_size)
        self._tiles.append((pts, tiles))
        return tiles

    def _hits_exhaustive(self, poses: np.ndarray, pts: np.ndarray, grid: np.ndarray) -> np.ndarray:
        c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
        rows, cols = self.geometry.xy_to_cell(poses[:, 0:1] + c * pts[None, :, 0] - s * pts[None, :, 1],
                                              poses[:, 1:2] + s * pts[None, :, 0] + c * pts[None, :, 1])
        inside = self.geometry.contains(rows, cols)
        last = self.geometry.size - 1      # off-grid points look up an edge cell, then count as free
        return (grid[clip_index(rows, last), clip_index(cols, last)] & inside).any(axis=1)

    def poses_free(self, poses) -> np.ndarray:
        """(M,) bool: each (x, y, yaw) pose's footprint overlaps no obstacle."""
        poses = np.atleast_2d(np.asarray(poses, dtype=float))
        return ~(self._hits(poses, self._body, self.obstacle) | self._hits(poses, self._arm, self.tall))

    def segment_free(self, x0: float, y0: float, x1: float, y1: float, yaw: float, step: float | None = None) -> bool:
        """Every intermediate pose of a straight move at a fixed heading is free (sampled every
        half cell by default)."""
        return bool(np.all(self.poses_free(self._segment_poses(x0, y0, x1, y1, yaw, step))))

    def segments_free(self, x0: float, y0: float, ends: np.ndarray, yaw: float) -> np.ndarray:
        """(K,) bool: ``segment_free(x0, y0, *ends[k], yaw)`` for every end point at once. The same
        poses are tested (and each pose's answer does not depend on the batch), so the answers are
        the same; one batch instead of K calls, which the planner's shuffle (dozens of short steps
        from one pose, all tested when the robot is boxed in) spends most of a blocked plan on."""
        ends = np.asarray(ends, dtype=float).reshape(-1, 2)
        if not len(ends):
            return np.zeros(0, dtype=bool)
        batches = [self._segment_poses(x0, y0, float(x1), float(y1), yaw) for x1, y1 in ends]
        starts = np.cumsum([0] + [len(b) for b in batches[:-1]])
        return np.logical_and.reduceat(self.poses_free(np.concatenate(batches)), starts)

    def _segment_poses(self, x0: float, y0: float, x1: float, y1: float, yaw: float,
                       step: float | None = None) -> np.ndarray:
        """The poses a straight move is checked at: at least two, at most ``step`` apart (half a cell)."""
        step = self.geometry.cell_size / 2 if step is None else step
        n = max(2, int(math.ceil(math.hypot(x1 - x0, y1 - y0) / step)) + 1)
        t = np.linspace(0.0, 1.0, n)
        return np.stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0), np.full(n, yaw)], axis=1)

    def straight_move_free(self, x0: float, y0: float, yaw0: float, x1: float, y1: float, turn: float) -> bool:
        """Every pose of one move that walks straight from (x0, y0) to (x1, y1) while turning by
        the signed angle ``turn`` (x, y and yaw changing in proportion, as Spot's phase-
        synchronised SE2 trajectories do) is free, sampled so that neither the walk nor the turn
        moves a footprint point more than half a cell between two checked poses."""
        half = self.geometry.cell_size / 2
        n = 1 + max(2, int(math.ceil(math.hypot(x1 - x0, y1 - y0) / half)), int(math.ceil(abs(turn) / (half / self.radius))))
        t = np.linspace(0.0, 1.0, n)
        poses = np.stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0), yaw0 + t * turn], axis=1)
        return bool(self.poses_free(poses).all())

    def turn_free(self, x: float, y: float, yaw0: float, yaw1: float, step: float | None = None) -> bool:
        """Turning in place from yaw0 to yaw1 (the short way) sweeps only free space."""
        return self.sweep_free(x, y, yaw0, math.remainder(yaw1 - yaw0, 2 * math.pi), step)

    def sweep_free(self, x: float, y: float, yaw0: float, delta: float, step: float | None = None) -> bool:
        """Turning in place from yaw0 by the signed angle ``delta`` (either way round, up to a
        full turn) sweeps only free space: beside a cabinet the short way round can be blocked
        while the long way is free. By default headings are checked finely enough that the
        farthest footprint point moves half a cell."""
        if step is None:
            step = 0.5 * self.geometry.cell_size / self.radius
        n = max(2, int(abs(delta) / step) + 2)
        yaws = yaw0 + np.linspace(0.0, delta, n)
        return bool(np.all(self.poses_free(np.stack([np.full(n, x), np.full(n, y), yaws], axis=1))))


_TILE = 0.15
"""Edge (m) of the tiles footprint points are grouped into for the quick test in ``_hits``."""


@dataclass(frozen=True)
class _Tiles:
    centres: np.ndarray     # (T, 2) body frame, m
    reach: np.ndarray       # (T,) m: every point of the tile is closer than this to its centre (+ a cell)
    points: list            # T arrays (n_t, 2)


def _tiles_of(pts: np.ndarray, cell_size: float) -> _Tiles:
    """``pts`` grouped into square tiles of about ``_TILE`` m."""
    cell = np.floor((pts - pts.min(axis=0)) / _TILE).astype(np.int64)
    labels = cell[:, 0] * (int(cell[:, 1].max()) + 1) + cell[:, 1]
    groups = [pts[labels == k] for k in np.unique(labels)]
    centres = np.array([0.5 * (g.min(axis=0) + g.max(axis=0)) for g in groups])
    reach = np.array([np.sqrt(((g - c) ** 2).sum(axis=1).max()) for g, c in zip(groups, centres)]) + cell_size
    return _Tiles(centres, reach, groups)


@functools.lru_cache(maxsize=32)
def _footprint(box: tuple, margin: float, step: float, cell_size: float) -> tuple[np.ndarray, _Tiles]:
    """A footprint box's points and their tiles (read-only), made once per geometry: every plan
    builds a checker, and cutting the tiles cost ~1.5 ms a checker."""
    pts = _box_points(box, margin, step)
    pts.flags.writeable = False
    return pts, _tiles_of(pts, cell_size)


def _box_points(box, margin: float, step: float) -> np.ndarray:
    """Grid of points covering the box grown by ``margin``, edges included, at most ``step`` apart."""
    x0, x1, y0, y1 = box[0] - margin, box[1] + margin, box[2] - margin, box[3] + margin
    xs = np.linspace(x0, x1, int(math.ceil((x1 - x0) / step)) + 1)
    ys = np.linspace(y0, y1, int(math.ceil((y1 - y0) / step)) + 1)
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx.ravel(), gy.ravel()], axis=1)
