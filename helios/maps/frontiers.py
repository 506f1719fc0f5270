"""Frontiers: where explored free space meets unexplored space, one centre point per boundary.

A frontier cell is a free cell with an unexplored 4-neighbour (4-connectivity so an unbroken
diagonal wall never leaks) and at least ``obstacle_clearance`` from any obstacle (which removes
the thin slivers the polar visibility test sees behind oblique surfaces). Frontier cells are
grouped 8-connected; groups shorter than
``min_size`` are dropped; each group's centre is its member cell closest to the group's
centroid, so curved boundaries still get a centre *on* the boundary. Unexplored pockets smaller
than ``fill_holes_area`` inside explored space count as explored first (VLFM), so sensor holes do
not create frontiers. Only the explored bounding box is processed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from helios.config import FrontierConfig
from helios.maps.occupancy import OccupancyGrid

_CROSS = ndimage.generate_binary_structure(2, 1)
_SQUARE = ndimage.generate_binary_structure(2, 2)
_CROSS.flags.writeable = False
_SQUARE.flags.writeable = False


@dataclass(frozen=True)
class Frontier:
    """One frontier: centre in world metres, size, member cells, and value-map values."""

    x: float
    y: float
    size: float
    """Length in metres (member cells x cell size)."""
    cells: np.ndarray = field(repr=False)
    """(K, 2) int (row, col) of the member cells."""
    values: dict[str, float] = field(default_factory=dict)
    """Value-map value per layer near the centre (see ValueMap.value_near)."""

    @property
    def xy(self) -> np.ndarray:
        return np.array([self.x, self.y])


def frontier_mask(occupancy: OccupancyGrid, cfg: FrontierConfig) -> tuple[np.ndarray, tuple[int, int]]:
    """Bool frontier-cell mask of the explored bounding box (plus a 1-cell rim) and its offset."""
    bounds = occupancy.explored_bounds
    if bounds is None:
        return np.zeros((0, 0), dtype=bool), (0, 0)
    size = occupancy.geometry.size
    r0, r1, c0, c1 = max(bounds[0] - 1, 0), min(bounds[1] + 1, size), max(bounds[2] - 1, 0), min(bounds[3] + 1, size)
    explored = occupancy.explored[r0:r1, c0:c1].copy()
    obstacle = occupancy.obstacle[r0:r1, c0:c1]

    max_hole = cfg.fill_holes_area / occupancy.geometry.cell_size ** 2
    if max_hole >= 1:
        holes, n = ndimage.label(~explored, structure=_CROSS)
        if n:
            sizes = np.bincount(holes.ravel(), minlength=n + 1)
            border = np.unique(np.concatenate([holes[0], holes[-1], holes[:, 0], holes[:, -1]]))
            small = sizes <= max_hole
            small[0] = False
            small[border] = False
            explored |= small[holes]

    free = explored & ~obstacle
    clearance = int(np.ceil(cfg.obstacle_clearance / occupancy.geometry.cell_size - 1e-9))
    if clearance > 0:
        free &= ~ndimage.binary_dilation(obstacle, structure=_SQUARE, iterations=clearance)
    touches_unexplored = ndimage.binary_dilation(~explored, structure=_CROSS)
    return free & touches_unexplored, (r0, c0)


def find_frontiers(occupancy: OccupancyGrid, cfg: FrontierConfig) -> list[Frontier]:
    """Frontiers of the occupancy grid, longest first."""
    mask, (r0, c0) = frontier_mask(occupancy, cfg)
    if not mask.any():
        return []
    labels, n = ndimage.label(mask, structure=_SQUARE)
    rows, cols = np.nonzero(labels)
    lab = labels[rows, cols]
    counts = np.bincount(lab, minlength=n + 1)
    cell = occupancy.geometry.cell_size
    keep = counts * cell >= cfg.min_size - 1e-9
    keep[0] = False
    sel = keep[lab]
    rows, cols, lab = rows[sel], cols[sel], lab[sel]
    if lab.size == 0:
        return []
    mean_r = np.bincount(lab, weights=rows, minlength=n + 1) / np.maximum(counts, 1)
    mean_c = np.bincount(lab, weights=cols, minlength=n + 1) / np.maximum(counts, 1)
    dist = (rows - mean_r[lab]) ** 2 + (cols - mean_c[lab]) ** 2
    order = np.lexsort((dist, lab))                 # by label, then distance to the centroid
    lab_sorted = lab[order]
    firsts = order[np.r_[True, lab_sorted[1:] != lab_sorted[:-1]]]

    frontiers = []
    for i in firsts:
        k = lab[i]
        members = np.stack([rows[lab == k] + r0, cols[lab == k] + c0], axis=1)
        x, y = occupancy.geometry.cell_to_world(rows[i] + r0, cols[i] + c0)
        frontiers.append(Frontier(x=float(x), y=float(y), size=float(counts[k] * cell), cells=members))
    frontiers.sort(key=lambda f: -f.size)
    return frontiers
