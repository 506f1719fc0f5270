"""Geometry of the 2D bird's-eye-view grids (occupancy and value maps share it).

Arrays are indexed ``[row, col]`` with ``row`` along world +y and ``col`` along world +x, so
``grid[row, col]`` covers x in [x0 + col * s, x0 + (col + 1) * s) and likewise for y.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from helios.config import OccupancyConfig


@dataclass(frozen=True)
class GridGeometry:
    cell_size: float
    size: int
    origin_x: float
    origin_y: float

    @staticmethod
    def from_config(cfg: OccupancyConfig) -> "GridGeometry":
        if cfg.origin_xy is None:
            half = cfg.grid_size * cfg.cell_size / 2.0
            return GridGeometry(cfg.cell_size, cfg.grid_size, -half, -half)
        return GridGeometry(cfg.cell_size, cfg.grid_size, float(cfg.origin_xy[0]), float(cfg.origin_xy[1]))

    @property
    def shape(self) -> tuple[int, int]:
        return (self.size, self.size)

    def world_to_cell(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rows, cols) of the cells containing world points ``xy`` (..., 2); may be outside."""
        xy = np.asarray(xy, dtype=float)
        return self.xy_to_cell(xy[..., 0], xy[..., 1])

    def xy_to_cell(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``world_to_cell`` for x and y in separate arrays: spares large callers (footprint
        checks of many poses) stacking them into one (..., 2) array first."""
        cols = np.floor((np.asarray(x, dtype=float) - self.origin_x) / self.cell_size).astype(np.int64)
        rows = np.floor((np.asarray(y, dtype=float) - self.origin_y) / self.cell_size).astype(np.int64)
        return rows, cols

    def cell_to_world(self, rows, cols) -> np.ndarray:
        """World (x, y) of cell centres, shape (..., 2)."""
        rows, cols = np.asarray(rows, dtype=float), np.asarray(cols, dtype=float)
        return np.stack([self.origin_x + (cols + 0.5) * self.cell_size,
                         self.origin_y + (rows + 0.5) * self.cell_size], axis=-1)

    def contains(self, rows, cols) -> np.ndarray:
        rows, cols = np.asarray(rows), np.asarray(cols)
        return (rows >= 0) & (rows < self.size) & (cols >= 0) & (cols < self.size)


def clip_index(cells, last: int):
    """Integer indices clamped to [0, last]: ``np.clip``'s answer without its per-call dtype
    checks (~10 us a call; a plan's footprint checks make thousands of calls)."""
    return np.minimum(np.maximum(cells, 0), last)
