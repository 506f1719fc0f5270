"""2D bird's-eye-view occupancy grid from ground-projected depth (HELIOS's navigation layer).

Per cell we keep how many returns fell in the obstacle height band and whether any frame saw the
cell. Updates touch only the window the frame saw. Obstacles accumulate without decay, like VLFM;
a cell is an obstacle once ``obstacle_min_hits`` returns in the band have landed in it.
"""

from __future__ import annotations

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
        self.explored = np.zeros(shape, dtype=bool)
        self._bounds: tuple[int, int, int, int] | None = None  # explored bbox, half-open

    @property
    def free(self) -> np.ndarray:
        """Explored cells that are not obstacles."""
        return self.explored & ~self.obstacle

    @property
    def explored_bounds(self) -> tuple[int, int, int, int] | None:
        """(row0, row1, col0, col1) half-open bounding box of explored cells, None if none."""
        return self._bounds

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

    def memory_bytes(self) -> int:
        return self.obstacle_hits.nbytes + self.obstacle.nbytes + self.explored.nbytes
