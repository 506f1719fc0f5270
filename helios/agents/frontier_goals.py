"""Where exploration may go: the frontiers on offer with the parts of each still worth walking
to, and the places worth a second look once no frontier is left.

Kept apart from the decision (:mod:`helios.agents.helios_agent`) because both are bookkeeping
over the map and the agent's memory of places reached or found unreachable, not choices.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from helios.agents.config import AgentConfig
from helios.agents.geometry import away_from
from helios.search.objective import FrontierOption

MAX_PARTS = 16
"""Cells sampled along a frontier as walking goals besides its centre."""


@dataclass
class StallWatch:
    """Counts the exploration steps in a row towards one frontier that get nowhere: each ends
    within ``AgentConfig.stall_radius`` of where the first of them ended, and together they see
    less than ``stall_new_area`` of new floor (see ``AgentConfig.stall_steps``). A step towards
    another frontier (centre farther than ``frontier_blacklist_radius``), one that ends elsewhere
    or one that brings the new floor since the first to ``stall_new_area`` starts the count again
    from that step."""

    config: AgentConfig
    _first: tuple[np.ndarray, np.ndarray, int] | None = None   # frontier, where it ended, explored cells
    _count: int = 0

    def stalled(self, frontier_xy, here, occupancy) -> int:
        """Note a step towards ``frontier_xy`` that ended at ``here``; the number of steps after
        the first that got nowhere when that reaches ``stall_steps`` (the watch then starts
        afresh), else 0."""
        cfg = self.config
        xy, here = np.asarray(frontier_xy, dtype=float)[:2], np.asarray(here, dtype=float)[:2]
        seen = occupancy.explored_cells()
        first = self._first
        if first is None or np.linalg.norm(first[0] - xy) > cfg.frontier_blacklist_radius \
                or np.linalg.norm(first[1] - here) > cfg.stall_radius \
                or (seen - first[2]) * occupancy.geometry.cell_size ** 2 >= cfg.stall_new_area:
            self._first, self._count = (xy, here, seen), 0
            return 0
        self._count += 1
        if self._count < cfg.stall_steps:
            return 0
        count, self._first, self._count = self._count, None, 0
        return count


def frontier_options(frontiers, layer: str, geometry, reached: Sequence[np.ndarray],
                     unreachable: Sequence[np.ndarray], config: AgentConfig
                     ) -> tuple[list[FrontierOption], dict[int, np.ndarray]]:
    """The frontiers still on offer for ``layer`` and, per option key, its goal points (centre
    first, then up to ``MAX_PARTS`` of its cells). A frontier whose centre lies within
    ``frontier_blacklist_radius`` of a place reached or found unreachable is out; with
    ``frontier_parts`` its goal points are only the parts not reached yet, and a frontier with
    none left is out too (see ``AgentConfig.frontier_parts``)."""
    out: list[FrontierOption] = []
    goals: dict[int, np.ndarray] = {}
    radius = config.frontier_blacklist_radius
    for f in frontiers:
        centre = np.asarray(f.xy, dtype=float)[None]
        if not away_from(centre, [*unreachable, *reached], radius)[0]:
            continue
        cells = f.cells[:: max(1, len(f.cells) // MAX_PARTS)]
        points = np.concatenate([centre, geometry.cell_to_world(cells[:, 0], cells[:, 1])])
        if config.frontier_parts:
            points = points[away_from(points, reached, radius)]
            if not len(points):
                continue
        goals[len(out)] = points
        out.append(FrontierOption(f.xy, float(f.values.get(layer, 0.0)), key=len(out)))
    return out, goals


def revisit_goals(occupancy, geometry, value_layer: np.ndarray, avoid: Sequence[np.ndarray],
                  config: AgentConfig) -> np.ndarray:
    """(K, 2) seen free places on a 0.5 m lattice, best value first (at most
    ``revisit_candidates``), each at least ``revisit_spacing`` from every point in ``avoid``
    (places revisited already and the robot)."""
    b = occupancy.explored_bounds
    step = max(1, int(round(0.5 / geometry.cell_size)))
    rows, cols = np.mgrid[b[0]:b[1]:step, b[2]:b[3]:step]
    rows, cols = rows.ravel(), cols.ravel()
    free = occupancy.explored[rows, cols] & ~occupancy.obstacle[rows, cols]
    rows, cols = rows[free], cols[free]
    if not len(rows):
        return np.zeros((0, 2))
    xy = geometry.cell_to_world(rows, cols)
    value = value_layer[rows, cols]
    far = np.ones(len(xy), dtype=bool)
    for p in avoid:
        far &= np.linalg.norm(xy - p, axis=1) > config.revisit_spacing
    order = np.argsort(-value[far], kind="stable")[: config.revisit_candidates]
    return xy[far][order]


def unseen_bearing(explored: np.ndarray, geometry, xy, parts: np.ndarray, radius: float) -> float | None:
    """World yaw from ``xy`` towards the never-seen side of a frontier: the circular mean of the
    bearings to the unexplored 4-neighbours of its ``parts`` (world points on the frontier)
    within ``radius`` (m) of ``xy``, or of all of them when none is that close. None when no
    part has an unexplored neighbour (the frontier has been seen since) or they balance out.

    Why not the frontier's centre: the robot often arrives standing on the frontier, where the
    bearing to the centre says nothing, and the unseen cells lie beside or behind it. Only cells
    next to a frontier part count, so the far side of a wall (unexplored too) does not pull.
    """
    xy = np.asarray(xy, dtype=float).reshape(2)
    parts = np.asarray(parts, dtype=float).reshape(-1, 2)
    if not len(parts):
        return None
    rows, cols = geometry.world_to_cell(parts)
    steps = np.array([(1, 0), (-1, 0), (0, 1), (0, -1)])
    nr = np.clip(rows[:, None] + steps[:, 0], 0, explored.shape[0] - 1).ravel()
    nc = np.clip(cols[:, None] + steps[:, 1], 0, explored.shape[1] - 1).ravel()
    unseen = ~explored[nr, nc]
    if not unseen.any():
        return None
    d = geometry.cell_to_world(nr[unseen], nc[unseen]).reshape(-1, 2) - xy
    dist = np.hypot(d[:, 0], d[:, 1])
    keep = dist > 1e-9                      # a cell under the robot has no bearing
    if (dist <= radius).any():
        keep &= dist <= radius
    if not keep.any():
        return None
    mean = (d[keep] / dist[keep][:, None]).sum(axis=0)
    if np.hypot(mean[0], mean[1]) < 1e-6 * keep.sum():
        return None
    return float(np.arctan2(mean[1], mean[0]))
