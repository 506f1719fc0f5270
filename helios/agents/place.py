"""The place skill: walk to where the arm reaches the goal receptacle's top, look at it, choose
where to let go (the paper's drop heuristic, or the improved place) and release there.

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

Where the release point comes from, in order: the receptacle's detection in the place view
(eroded, see ``PlaceConfig.mask_erosion_px``); else whatever the camera sees near the mapped top
height; else the map's estimate of the top itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from helios.agents.body import Body
from helios.agents.config import AgentConfig, PlaceConfig
from helios.agents.geometry import backproject
from helios.agents.observer import Observer
from helios.agents.skill import SkillOutcome
from helios.agents.target import Target
from robots.hal import RobotBackend
from robots.transforms import invert_transform


@dataclass(frozen=True)
class PlaceTarget:
    point: np.ndarray          # (3,) world point on the surface
    release_height: float      # m above ``point`` for the bottom of the object
    n_points: int              # surface points it was chosen from


def place(robot: RobotBackend, body: Body, observer: Observer, target: Target, config: AgentConfig) -> SkillOutcome:
    """One place attempt onto ``target`` (the goal receptacle); the arm is stowed afterwards."""
    cfg, reach = config.place, config.reach
    fp = np.asarray(target.footprint_xy, dtype=float)
    here = body.xy()
    nearest = fp[int(np.argmin(np.linalg.norm(fp - here, axis=1)))]
    inward = fp.mean(axis=0) - nearest
    n = float(np.linalg.norm(inward))
    spot = nearest + (inward / n * min(cfg.approach_inset, n) if n > 1e-6 else 0.0)
    surface = np.array([spot[0], spot[1], target.top])
    failed = body.approach(robot, surface + [0.0, 0.0, reach.place_lift], "place")
    if failed:
        return SkillOutcome(False, failed)
    body.face(robot, surface)
    if not body.gaze(robot, surface).success:
        return SkillOutcome(False, "cannot look at the place point from the place pose")
    obs = body.observe(robot)
    mask = observer.matching_mask(obs, target, observer.goal_class)
    chosen = None
    if mask is not None:
        inner = ndimage.binary_erosion(mask, iterations=cfg.mask_erosion_px) if cfg.mask_erosion_px else mask
        chosen = choose_place_point(backproject(obs, inner), obs.T_world_body, cfg)
    if chosen is None:   # not detected in this frame: what the camera sees near the mapped top
        pts = backproject(obs, stride=2)
        chosen = choose_place_point(pts[np.abs(pts[:, 2] - target.top) < 0.1], obs.T_world_body, cfg)
    if chosen is None:
        chosen = PlaceTarget(surface, cfg.drop_height if cfg.mode == "drop" else cfg.improved_height, 0)
        body.log.append("place: no detected surface in front; using the map's estimate")
    res = robot.place(chosen.point, release_height=chosen.release_height)
    body.log.append(f"place on {target.key} at {np.round(chosen.point, 2).tolist()}: {res.reason.value} {res.message}")
    body.stow(robot)
    return SkillOutcome(res.success, "" if res.success else f"place failed ({res.reason.value})", attempted=True)


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
