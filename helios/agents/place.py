"""Where to let go of the object: the paper's drop heuristic and the improved place.

The paper (Sec. Results): "dropping the object above the highest detected point in a region in
front of the agent"; it names place as a major failure cause (objects roll off because nothing
adjusts the release). ``improved`` keeps the same detected surface but

- takes the highest *horizontal level* holding a good share of the detected points (a dense
  peak of heights), not the single highest point, which may be another object standing on the
  receptacle or mask bleed onto the wall behind it,
- releases above that surface's most interior point (largest distance to its edge and to
  anything standing on it, on a ``surface_cell`` grid), so a rolling or tipping object has room, and
- lowers the object to ``improved_height`` above the surface instead of ``drop_height``.

The grasp's roll is kept (the HAL's ``place`` turns the hand only about the vertical), so a
side-grasped object arrives upright.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from helios.agents.config import PlaceConfig
from robots.transforms import invert_transform


@dataclass(frozen=True)
class PlaceTarget:
    point: np.ndarray          # (3,) world point on the surface
    release_height: float      # m above ``point`` for the bottom of the object
    n_points: int              # surface points it was chosen from


def region_points(points_world: np.ndarray, T_world_body: np.ndarray, cfg: PlaceConfig) -> np.ndarray:
    """The points (N, 3) inside the body-frame region in front of the robot."""
    pts = np.asarray(points_world, dtype=float).reshape(-1, 3)
    if not len(pts):
        return pts
    T = invert_transform(T_world_body)
    pb = pts @ T[:3, :3].T + T[:3, 3]
    x0, x1, y0, y1 = cfg.region
    keep = (pb[:, 0] >= x0) & (pb[:, 0] <= x1) & (pb[:, 1] >= y0) & (pb[:, 1] <= y1)
    return pts[keep]


def choose_place_point(points_world: np.ndarray, T_world_body: np.ndarray, cfg: PlaceConfig) -> PlaceTarget | None:
    """Release point from detected surface points (world), or None if too few lie in the region."""
    pts = region_points(points_world, T_world_body, cfg)
    if len(pts) < 5:
        return None
    z = pts[:, 2]
    if cfg.mode == "drop":
        top = float(np.percentile(z, 99))       # robust to a stray high point
        p = pts[int(np.argmin(np.abs(z - top)))]
        return PlaceTarget(np.array([p[0], p[1], top]), cfg.drop_height, len(pts))
    level = support_level(z, cfg.top_band)
    surface = pts[np.abs(z - level) <= cfg.top_band]
    above = pts[z > level + cfg.top_band]        # things standing on the surface
    lo = surface[:, :2].min(axis=0) - cfg.surface_cell
    def cells(xy):
        return np.floor((xy - lo) / cfg.surface_cell).astype(int)
    c = cells(surface[:, :2])
    shape = c.max(axis=0) + 2
    grid = np.zeros((shape[0], shape[1]), dtype=bool)
    grid[c[:, 0], c[:, 1]] = True
    grid = ndimage.binary_closing(grid, iterations=1) | grid        # fill gaps between samples
    if len(above):
        a = cells(above[:, :2])
        keep = (a[:, 0] >= 0) & (a[:, 1] >= 0) & (a[:, 0] < shape[0]) & (a[:, 1] < shape[1])
        grid[a[keep, 0], a[keep, 1]] = False                          # never on top of another object
    inside = ndimage.distance_transform_edt(grid) * cfg.surface_cell
    best = np.unravel_index(int(np.argmax(inside)), inside.shape)
    xy_best = lo + (np.array(best) + 0.5) * cfg.surface_cell
    return PlaceTarget(np.array([xy_best[0], xy_best[1], level]), cfg.improved_height, len(surface))


def support_level(z: np.ndarray, band: float) -> float:
    """Height of the highest horizontal level holding a good share of the points: a flat top
    shows as a dense peak of heights, a wall or an object's side as a thin spread."""
    z = np.asarray(z, dtype=float)
    bins = np.arange(z.min() - band, z.max() + 2 * band, band)
    counts, edges = np.histogram(z, bins=bins)
    dense = np.nonzero(counts >= 0.25 * counts.max())[0]
    k = int(dense[-1])
    members = z[(z >= edges[k]) & (z <= edges[k + 1])]
    return float(np.median(members))
