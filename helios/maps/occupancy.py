"""2D bird's-eye-view occupancy grid from ground-projected depth (HELIOS's navigation layer).

Per cell we keep how many returns fell in the obstacle height band and whether any frame saw the
cell. Updates touch only the window the frame saw. Obstacles accumulate without decay, like VLFM;
a cell is an obstacle once ``obstacle_min_hits`` returns in the band have landed in it.
"""

from __future__ import annotations

import cv2
import numpy as np

from helios.config import OccupancyConfig
from helios.maps.grid import GridGeometry
from helios.maps.ground_view import GroundView, project_to_ground
from robots.hal import CameraIntrinsics


class OccupancyGrid:
    """Obstacle / explored / free cells on a ``grid_size`` x ``grid_size`` grid.

    ``obstacle`` and ``explored`` are numpy bool arrays indexed ``[row (y), col (x)]``; see
    :class:`helios.maps.grid.GridGeometry` for the world <-> cell conversion.
    """

    def __init__(self, cfg: OccupancyConfig):
        self.cfg = cfg
        self.geometry = GridGeometry.from_config(cfg)
        shape = self.geometry.shape
        self.obstacle_hits = np.zeros(shape, dtype=np.int32)
        self.obstacle = np.zeros(shape, dtype=bool)
        # Highest return in the obstacle band per cell (m; 0 where none): line-of-sight tests and
        # the planner's "does the stowed arm clear it" check need heights, not just occupancy.
        self.max_height = np.zeros(shape, dtype=np.float32)
        self.explored = np.zeros(shape, dtype=bool)
        self._bounds: tuple[int, int, int, int] | None = None  # explored bbox, half-open
        self.revision = 0
        """Counts the changes to the grids (every ``integrate``, ``mark_seen``, ``mark_obstacle``):
        what is derived from them stays valid while it is unchanged (the agent's footprint
        checker, rebuilt from the full grids, is reused on that basis)."""

    @property
    def free(self) -> np.ndarray:
        """Explored cells that are not obstacles."""
        return self.explored & ~self.obstacle

    @property
    def explored_bounds(self) -> tuple[int, int, int, int] | None:
        """(row0, row1, col0, col1) half-open bounding box of explored cells, None if none. Every
        obstacle cell lies inside it too: a cell becomes an obstacle only where a return landed
        (which counts as seen) or in a disc ``mark_obstacle`` declares seen.
        ``FootprintChecker.of_known_region`` relies on that."""
        return self._bounds

    def explored_cells(self) -> int:
        """How many cells have been seen (counted inside ``explored_bounds``)."""
        b = self._bounds
        return 0 if b is None else int(np.count_nonzero(self.explored[b[0]:b[1], b[2]:b[3]]))

    def integrate_depth(self, depth: np.ndarray, intrinsics: CameraIntrinsics,
                        T_world_cam: np.ndarray) -> GroundView:
        """Project one depth frame and add it; returns the view for the value maps."""
        view = project_to_ground(depth, intrinsics, T_world_cam, self.geometry, self.cfg)
        self.integrate(view)
        return view

    def integrate(self, view: GroundView) -> None:
        """Add one ground-projected frame: obstacle hits in the height band, seen cells explored."""
        if view.is_empty:
            return
        self.revision += 1
        r0, r1, c0, c1 = view.window
        geo, cfg = self.geometry, self.cfg
        z = view.points[:, 2]
        band = (z >= cfg.obstacle_min_height) & (z <= cfg.obstacle_max_height)
        rows, cols = geo.world_to_cell(view.points[:, :2])
        inside = (rows >= r0) & (rows < r1) & (cols >= c0) & (cols < c1)
        h, w = r1 - r0, c1 - c0
        flat = (rows[inside] - r0) * w + (cols[inside] - c0)
        hits = np.bincount(flat[band[inside]], minlength=h * w).reshape(h, w)
        landed = np.bincount(flat, minlength=h * w).reshape(h, w) > 0

        self.obstacle_hits[r0:r1, c0:c1] += hits.astype(np.int32)
        in_band = inside & band
        top = np.zeros(h * w, dtype=np.float32)
        np.maximum.at(top, flat[band[inside]], z[in_band].astype(np.float32))
        self.max_height[r0:r1, c0:c1] = np.maximum(self.max_height[r0:r1, c0:c1], top.reshape(h, w))
        self.obstacle[r0:r1, c0:c1] = self.obstacle_hits[r0:r1, c0:c1] >= cfg.obstacle_min_hits
        seen = view.visible | landed
        self.explored[r0:r1, c0:c1] |= seen
        if seen.any():
            rs, cs = np.nonzero(seen.any(axis=1))[0], np.nonzero(seen.any(axis=0))[0]
            box = (r0 + int(rs[0]), r0 + int(rs[-1]) + 1, c0 + int(cs[0]), c0 + int(cs[-1]) + 1)
            if self._bounds is None:
                self._bounds = box
            else:
                b = self._bounds
                self._bounds = (min(b[0], box[0]), max(b[1], box[1]), min(b[2], box[2]), max(b[3], box[3]))

    def mark_seen(self, xy, radius: float) -> None:
        """Declare discs of cells around points (N, 2) explored, e.g. where the robot's body has
        been: the hand camera never sees right under it, but nothing can stand where it stood."""
        self.revision += 1
        geo = self.geometry
        pts = np.asarray(xy, dtype=float).reshape(-1, 2)
        k = int(np.ceil(radius / geo.cell_size))
        yy, xx = np.mgrid[-k:k + 1, -k:k + 1]
        disc = yy ** 2 + xx ** 2 <= k * k
        for r, c in zip(*geo.world_to_cell(pts)):
            r0, c0 = int(r) - k, int(c) - k
            if r0 < 0 or c0 < 0 or r0 + 2 * k + 1 > geo.size or c0 + 2 * k + 1 > geo.size:
                continue
            self.explored[r0:r0 + 2 * k + 1, c0:c0 + 2 * k + 1] |= disc
            box = (r0, r0 + 2 * k + 1, c0, c0 + 2 * k + 1)
            b = self._bounds or box
            self._bounds = (min(b[0], box[0]), max(b[1], box[1]), min(b[2], box[2]), max(b[3], box[3]))

    def mark_obstacle(self, xy, radius: float, height: float = 1.0) -> None:
        """Declare a disc of cells occupied (e.g. where the robot bumped into something it never
        saw); it counts as seen and as an obstacle ``height`` metres tall from now on."""
        self.revision += 1
        geo = self.geometry
        r, c = geo.world_to_cell(np.asarray(xy, dtype=float)[:2])
        k = int(np.ceil(radius / geo.cell_size))
        r0, r1 = max(int(r) - k, 0), min(int(r) + k + 1, geo.size)
        c0, c1 = max(int(c) - k, 0), min(int(c) + k + 1, geo.size)
        if r1 <= r0 or c1 <= c0:
            return
        rr, cc = np.ogrid[r0:r1, c0:c1]
        self._occupy(r0, r1, c0, c1, (rr - r) ** 2 + (cc - c) ** 2 <= k * k, height)

    def mark_polygons(self, polygons, keep_out=None, unseen_only: bool = True, height: float = 1.0) -> int:
        """Declare the cells inside any of ``polygons`` ((K, P, 2) world x, y) occupied, except those
        inside ``keep_out`` ((P, 2), e.g. where the body stands) and, with ``unseen_only``, those a
        frame has seen; returns how many cells were marked. A turn that bumped into something hit
        it inside the sweep of the body, and unless the map is wrong about seen floor, in the part
        of the sweep nobody saw (:meth:`helios.agents.body.Body` after a collision)."""
        geo = self.geometry
        polys = np.asarray(polygons, dtype=float).reshape(-1, np.shape(polygons)[-2], 2)
        rows, cols = geo.world_to_cell(polys.reshape(-1, 2))
        r0, r1 = max(int(rows.min()) - 1, 0), min(int(rows.max()) + 2, geo.size)
        c0, c1 = max(int(cols.min()) - 1, 0), min(int(cols.max()) + 2, geo.size)
        if r1 <= r0 or c1 <= c0:
            return 0

        def raster(poly_list) -> np.ndarray:
            mask = np.zeros((r1 - r0, c1 - c0), dtype=np.uint8)
            for p in poly_list:   # one at a time: one fillPoly call over overlapping polygons leaves holes
                # OpenCV's pixel i has its centre at i; cell c spans [c, c + 1) cells from the origin
                q = (np.asarray(p) - (geo.origin_x, geo.origin_y)) / geo.cell_size - (c0 + 0.5, r0 + 0.5)
                cv2.fillPoly(mask, [np.round(q * 16).astype(np.int32)], 1, shift=4)
            return mask.astype(bool)

        mark = raster(polys)
        if keep_out is not None:
            mark &= ~raster([np.asarray(keep_out, dtype=float)])
        if unseen_only:
            mark &= ~self.explored[r0:r1, c0:c1]
        n = int(mark.sum())
        if n:
            self.revision += 1
            self._occupy(r0, r1, c0, c1, mark, height)
        return n

    def _occupy(self, r0: int, r1: int, c0: int, c1: int, mask: np.ndarray, height: float) -> None:
        """Cells of ``mask`` (the window rows r0:r1, cols c0:c1) become seen obstacles at least
        ``height`` tall, with enough hits to stay so; the explored bounds grow to the window."""
        self.obstacle_hits[r0:r1, c0:c1][mask] += self.cfg.obstacle_min_hits
        self.obstacle[r0:r1, c0:c1] |= mask
        self.explored[r0:r1, c0:c1] |= mask
        self.max_height[r0:r1, c0:c1][mask] = np.maximum(self.max_height[r0:r1, c0:c1][mask], height)
        box = (r0, r1, c0, c1)
        b = self._bounds or box
        self._bounds = (min(b[0], box[0]), max(b[1], box[1]), min(b[2], box[2]), max(b[3], box[3]))

    def memory_bytes(self) -> int:
        return self.obstacle_hits.nbytes + self.obstacle.nbytes + self.explored.nbytes + self.max_height.nbytes
