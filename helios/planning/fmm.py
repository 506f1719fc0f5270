"""Fast-marching-squared path planning on the agent's occupancy map, and its conversion into
Spot-sized continuous actions (HELIOS appendix "Path Planner", after home-robot's FMM planner).

- The travel-time field comes from scikit-fmm with speed proportional to the distance to the
  nearest obstacle (saturating at ``speed_saturation``): paths keep to the middle of free space.
- It is computed only over the known part of the map (a crop around the explored region, the
  start and the goal) and on a grid coarsened to ``plan_cell_size`` (the 2.5 cm map max-pooled),
  which keeps a replan well under 100 ms; forward moves are still checked at 2.5 cm.
- The path becomes continuous actions: rotate in place by 5-30 degree steps, then move forward
  0.1-1.0 m; every intermediate position of a forward move, and every heading of a turn, is
  checked against Spot's footprint (:mod:`helios.planning.footprint`). Where a turn in place
  would sweep Spot's corners into something, a short straight step forward, back or sideways
  (at most ``shuffle_max``; Spot is holonomic) first makes room: an addition to the paper's
  action set, which has no answer for a robot standing with its back near a wall.
- A goal inside an obstacle, an unreachable goal or a boxed-in start gives a result with a reason,
  never an exception or a hang.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from helios.maps.grid import GridGeometry, clip_index
from helios.planning.footprint import FootprintChecker, FootprintConfig
from robots.hal import SE2Pose
from robots.transforms import wrap_angle

SHUFFLE_BATCH = 8
"""A shuffle tests the straight moves of this many candidate steps per batch: a boxed-in robot
tries all of them (5 batches instead of 40 calls), a free one usually takes the first."""


@dataclass(frozen=True)
class PlannerConfig:
    plan_cell_size: float = 0.05
    """FMM grid cell (m): the occupancy map max-pooled to this size (must be a multiple of it)."""
    robot_radius: float = 0.30
    """Corridor half width (m): path cells keep this clearance (Spot's half width + margin)."""
    speed_saturation: float = 1.0
    """Clearance (m) at which the fast-marching speed saturates (FM^2: speed ~ clearance)."""
    min_speed: float = 0.05
    crop_margin: float = 1.0
    """Metres of map kept around the explored region, the start and the goal."""
    start_clearance: float = 0.7
    """Radius (m) around the robot treated as seen: the hand camera cannot see under or beside
    the body. 0.7 m covers the circle Spot's corners sweep when it turns in place."""
    forward_min: float = 0.1
    forward_max: float = 1.0
    rotate_min: float = math.radians(5)
    rotate_max: float = math.radians(30)
    shuffle_max: float = 0.5
    """When a turn in place is blocked, straight steps forward, back or sideways up to this (m)
    are tried to find room for it (Spot walks in any direction)."""
    horizon: float = 3.0
    """Metres of path turned into actions per plan (the agent replans after executing them)."""
    turn_while_walking: float = 0.0
    """Largest change of heading (rad) taken while walking the next straight move instead of
    turning in place first, when the footprint's sweep of that combined move is free
    (``FootprintChecker.straight_move_free``; Spot's SE2 trajectories change x, y and yaw
    together; the action list still reads rotate, forward). 0 (default): the paper's planner,
    rotate then forward, one stop per action. Why one might: on 8 train episodes the robot spent
    67 % of its time walking or turning, more of it turning in place (713 rad, 1346 s) than
    walking (381 m in 858 straight moves, 1207 s). Measured with 0.8 on the first 100 train
    episodes: 415 s of robot time per episode against 425, FindObj 55 against 55 (+3 -3), SR 12
    against 13, timeouts 26 against 25 (README, "Where the robot's time goes"), so it stays off."""
    step_without_turning: bool = False
    """True: where the next move needs a turn that is blocked (no shuffle, no long way round),
    walk straight towards the path keeping the heading, backwards or sideways (Spot is holonomic),
    until a turn is free. False (default, the paper's rotate-then-forward planner): the plan is
    ``blocked``. Why one might: a robot that walked forward into a niche cannot turn round to
    leave it, every plan is then blocked at its first move and the agent gives up in zero robot
    time; in 4 probed train wedges a 0.1 m step without turning was free in every one (README,
    "Where the misses are"). Measured on 200 train episodes: "not found" 15 against 38, FindObj
    59.5 against 55.5, but timeouts 86 against 61 and SR 12.5 against 11.5, so it stays off."""
    max_plan_cells: int = 400_000
    """Largest FMM grid (coarse cells). When the known region (plus start, goal and margin) would
    need more, the plan cell grows by whole multiples until it fits: a fully explored 50 m grid
    plans at 10 cm, homes up to ~30 m across stay at ``plan_cell_size``. Forward moves and turns
    are still footprint-checked on the 2.5 cm map. 0 = never coarsen (replans of a whole 50 m grid
    then take ~300 ms)."""
    unknown_is_obstacle: bool = True
    """Footprint checks treat never-seen cells (beyond ``start_clearance``) as occupied for the
    body, not for the raised arm; paths keep ``robot_radius`` inside seen space either way."""
    blocked_without_progress: bool = False
    """True: a plan whose actions stop at a block (``blocked_ahead``) without getting any nearer
    the goal (the travel time where they end is not below the start's) fails as ``blocked``, as a
    plan blocked at its first move does. Why one might: a forward step, a shuffle back and a turn
    can end where they began, and an agent that walks such a plan replans the same one over and
    over (train-00022 did so 113 times, 454 s, until the time limit; the target's room lay past
    that frontier). Measured on the first 100 train episodes (README, "rooms never entered"): 62
    records change, FindObj 57 against 55 (+3 -1), Pick 40 against 38, SR 11 against 13 (+1 -3),
    timeouts 28 against 25; the loops end, but an agent out of options then gives up early
    instead, so it stays off (False: such plans succeed with ``reaches_goal`` False)."""
    footprint: FootprintConfig = field(default_factory=FootprintConfig)

    def __post_init__(self) -> None:
        if not (0 < self.forward_min <= self.forward_max and 0 < self.rotate_min <= self.rotate_max):
            raise ValueError("need 0 < forward_min <= forward_max and 0 < rotate_min <= rotate_max")
        if self.plan_cell_size <= 0 or self.robot_radius <= 0 or self.horizon <= 0:
            raise ValueError("plan_cell_size, robot_radius and horizon must be > 0")
        from helios.schema import require_range

        require_range(self, "plan_cell_size", 0.005, 1.0)
        require_range(self, "robot_radius speed_saturation min_speed", 0.0, 10.0, lo_open=True)
        require_range(self, "crop_margin start_clearance shuffle_max", 0.0, 20.0)
        require_range(self, "forward_min forward_max", 0.0, 10.0, lo_open=True)
        require_range(self, "rotate_min rotate_max", 0.0, math.pi, lo_open=True)
        require_range(self, "horizon", 0.0, 100.0, lo_open=True)
        require_range(self, "turn_while_walking", 0.0, math.pi)
        require_range(self, "max_plan_cells", 0, 100_000_000)
        if 0 < self.max_plan_cells < 100:
            raise ValueError(f"max_plan_cells must be 0 (no limit) or >= 100, got {self.max_plan_cells}")


@dataclass(frozen=True)
class Action:
    kind: str        # "rotate" (rad, signed), "forward"/"backward" (m), "strafe" (m, left +)
    amount: float


@dataclass
class PlanResult:
    success: bool
    reason: str                       # ok | goal_in_obstacle | unreachable | start_blocked | blocked
    path: np.ndarray                  # (N, 2) world metres, start to goal
    actions: list[Action] = field(default_factory=list)
    waypoints: list[SE2Pose] = field(default_factory=list)
    reaches_goal: bool = False        # the actions end at the goal (not cut by the horizon or a block)
    length: float = 0.0               # path length, m
    goal_index: int = 0               # which of several goals the path ends at
    final_turn_blocked: bool = False  # reached the goal but turning to goal_yaw there is not free
    blocked_ahead: bool = False       # the actions stop short because the footprint is blocked further on

    @property
    def empty(self) -> bool:
        return not self.waypoints


class FMMPlanner:
    """Plans on an occupancy grid (obstacle, explored, max_height arrays and their geometry)."""

    def __init__(self, config: PlannerConfig = PlannerConfig()):
        self.config = config

    def plan(self, geometry: GridGeometry, obstacle: np.ndarray, explored: np.ndarray, start: SE2Pose,
             goal_xy, goal_radius: float = 0.3, goal_yaw=None, max_height: np.ndarray | None = None,
             horizon: float | None = None, explored_bounds: tuple[int, int, int, int] | None = None,
             footprints: FootprintChecker | None = None) -> PlanResult:
        """Plan from ``start`` to within ``goal_radius`` of ``goal_xy``: one point (2,) or several
        (K, 2), any of which will do (``goal_index`` says which one the path ends at); ``goal_yaw``
        (a float, or one per goal) adds a final turn. ``horizon`` overrides the config's;
        ``explored_bounds`` (row0, row1, col0, col1), when the caller tracks it, saves a full-grid scan;
        ``footprints``, a checker the caller built on these very grids (``obstacle``, ``max_height``
        and, when ``unknown_is_obstacle``, ``~explored``) with this planner's footprint, saves
        rebuilding one (full-map passes) for every plan."""
        cfg = self.config
        goals = np.asarray(goal_xy, dtype=float)
        goals = goals.reshape(1, -1)[:, :2] if goals.ndim == 1 else goals[:, :2]
        if not len(goals) or not np.all(np.isfinite(goals)) or not math.isfinite(goal_radius) or goal_radius < 0:
            raise ValueError(f"goals must be finite with a radius >= 0, got {goals.tolist()} r={goal_radius}")
        yaws = None if goal_yaw is None else np.broadcast_to(np.asarray(goal_yaw, dtype=float), (len(goals),))
        f = max(1, int(round(cfg.plan_cell_size / geometry.cell_size)))
        window = self._window(geometry, explored, start, goals, f, explored_bounds)
        if window is None:
            return PlanResult(False, "unreachable", np.zeros((0, 2)))
        cells = (window[1] - window[0]) * (window[3] - window[2]) / f ** 2
        if cfg.max_plan_cells and cells > cfg.max_plan_cells:      # a huge known region: coarser FMM cells
            f *= int(math.ceil(math.sqrt(cells / cfg.max_plan_cells)))
            window = self._window(geometry, explored, start, goals, f, explored_bounds)
        r0, r1, c0, c1 = window
        coarse_obs = _pool(obstacle[r0:r1, c0:c1], f)
        coarse_exp = _pool(explored[r0:r1, c0:c1], f)
        cell = geometry.cell_size * f
        origin = np.array([geometry.origin_x + c0 * geometry.cell_size, geometry.origin_y + r0 * geometry.cell_size])

        def to_cell(xy):
            """(row, col) of the coarse cell holding a point, clipped to the window; arrays for (N, 2)."""
            c = np.floor((np.asarray(xy) - origin) / cell).astype(int)
            rows, cols = clip_index(c[..., 1], coarse_obs.shape[0] - 1), clip_index(c[..., 0], coarse_obs.shape[1] - 1)
            return (int(rows), int(cols)) if c.ndim == 1 else (rows, cols)

        def to_world(rc):
            rc = np.asarray(rc, dtype=float)
            return origin + (rc[..., ::-1] + 0.5) * cell

        rs, cs = np.ogrid[:coarse_obs.shape[0], :coarse_obs.shape[1]]
        sr, sc = to_cell((start.x, start.y))
        near_start = (rs - sr) ** 2 + (cs - sc) ** 2 <= (cfg.start_clearance / cell) ** 2
        coarse_exp = coarse_exp | near_start
        clearance = _clearance(coarse_obs, cell)
        # the whole body width must lie in seen space, not just the centre line
        traversable = _far_enough_inside(coarse_exp, cell, cfg.robot_radius) & (clearance >= cfg.robot_radius)
        goal_region = np.zeros(traversable.shape, dtype=bool)
        in_obstacle = 0
        ys, xs = origin[1] + (rs + 0.5) * cell, origin[0] + (cs + 0.5) * cell     # cell centres, m
        for g in goals:
            gr, gc = to_cell(g)
            in_obstacle += bool(coarse_obs[gr, gc])
            if coarse_obs[gr, gc] and goal_radius < cell:
                continue
            disc = (ys - g[1]) ** 2 + (xs - g[0]) ** 2 <= goal_radius ** 2
            disc[gr, gc] = True      # the goal's own cell, whatever the radius
            goal_region |= disc
        goal_region &= traversable
        if not goal_region.any():
            reason = "goal_in_obstacle" if in_obstacle == len(goals) else "unreachable"
            return PlanResult(False, reason, np.zeros((0, 2)))
        start_cell = self._nearest(traversable, sr, sc, int(math.ceil(0.5 / cell)))
        if start_cell is None:
            return PlanResult(False, "start_blocked", np.zeros((0, 2)))
        times = self._travel_time(traversable, goal_region, clearance, start_cell)
        if not np.isfinite(times[start_cell]):
            return PlanResult(False, "unreachable", np.zeros((0, 2)))
        cells = _descend(times, start_cell)
        path = np.concatenate([[[start.x, start.y]], to_world(np.array(cells))[1:]]) if len(cells) > 1 \
            else np.array([[start.x, start.y]])
        goal_index = int(np.argmin(np.linalg.norm(goals - path[-1], axis=1)))
        goal = goals[goal_index]
        if np.linalg.norm(path[-1] - goal) > 1e-6 and np.linalg.norm(goal - path[-1]) <= cell and \
                traversable[to_cell(goal)]:
            path = np.concatenate([path, goal[None]])      # finish exactly on the goal when it is free
        length = float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1))) if len(path) > 1 else 0.0
        checker = self._checker(geometry, obstacle, explored, max_height, start, footprints).clear_under(start)
        final_yaw = None if yaws is None else float(yaws[goal_index])
        horizon = cfg.horizon if horizon is None else horizon
        actions, waypoints, complete, blocked, turn_blocked = self._actions(path, start, final_yaw, checker,
                                                                            (traversable, to_cell), horizon)
        if blocked and waypoints and cfg.blocked_without_progress:
            end_r, end_c = to_cell((waypoints[-1].x, waypoints[-1].y))
            if not times[end_r, end_c] < times[start_cell]:
                waypoints = []           # no nearer the goal: blocked, as at the first move
        if not waypoints:
            if blocked:
                return PlanResult(False, "blocked", path, length=length, goal_index=goal_index)
            # already there (and facing the right way, unless turning there is blocked)
            return PlanResult(True, "ok", path, [], [], True, length, goal_index, turn_blocked)
        return PlanResult(True, "ok", path, actions, waypoints, complete, length, goal_index, turn_blocked, blocked)

    # ------------------------------------------------------------------ pieces
    def _checker(self, geometry: GridGeometry, obstacle: np.ndarray, explored: np.ndarray,
                 max_height: np.ndarray | None, start: SE2Pose, given: FootprintChecker | None) -> FootprintChecker:
        """Footprint checks for this plan: never-seen cells block the body (``unknown_is_obstacle``)
        except within ``start_clearance`` of the start, which the camera cannot see around the body.
        Built from ``given`` (the caller's checker on these grids) when it fits, else from scratch."""
        cfg = self.config
        fits = given is not None and given.config == cfg.footprint and given.blocks_unknown == cfg.unknown_is_obstacle
        if not cfg.unknown_is_obstacle:
            return given if fits else FootprintChecker(cfg.footprint, geometry, obstacle, max_height)
        k = int(math.ceil(cfg.start_clearance / geometry.cell_size))
        sr0, sc0 = (int(v) for v in geometry.world_to_cell(np.array([start.x, start.y])))
        a0, a1, b0, b1 = max(sr0 - k, 0), min(sr0 + k + 1, geometry.size), max(sc0 - k, 0), min(sc0 + k + 1, geometry.size)
        rr, cc = np.ogrid[a0:a1, b0:b1]
        near = (rr - sr0) ** 2 + (cc - sc0) ** 2 <= k * k
        if fits:
            return given.seen_within(slice(a0, a1), slice(b0, b1), near, obstacle)
        unknown = ~explored
        unknown[a0:a1, b0:b1] &= ~near
        return FootprintChecker(cfg.footprint, geometry, obstacle, max_height, unknown)

    def _window(self, geometry: GridGeometry, explored: np.ndarray, start: SE2Pose, goals: np.ndarray, f: int,
                bounds=None):
        if bounds is not None:
            rows, cols = np.array([bounds[0], bounds[1] - 1]), np.array([bounds[2], bounds[3] - 1])
        else:
            rows, cols = np.nonzero(explored.any(axis=1))[0], np.nonzero(explored.any(axis=0))[0]
        pts_r, pts_c = geometry.world_to_cell(np.concatenate([[[start.x, start.y]], goals]))
        r_lo, r_hi = int(pts_r.min()), int(pts_r.max())
        c_lo, c_hi = int(pts_c.min()), int(pts_c.max())
        if len(rows):
            r_lo, r_hi = min(r_lo, int(rows[0])), max(r_hi, int(rows[-1]))
            c_lo, c_hi = min(c_lo, int(cols[0])), max(c_hi, int(cols[-1]))
        m = int(math.ceil(self.config.crop_margin / geometry.cell_size))
        r0, r1 = max(0, r_lo - m), min(geometry.size, r_hi + m + 1)
        c0, c1 = max(0, c_lo - m), min(geometry.size, c_hi + m + 1)
        if r1 <= r0 or c1 <= c0:
            return None
        # align to whole coarse cells
        r1 = r0 + ((r1 - r0) // f) * f or r0 + f
        c1 = c0 + ((c1 - c0) // f) * f or c0 + f
        return r0, min(r1, geometry.size), c0, min(c1, geometry.size)

    @staticmethod
    def _nearest(mask: np.ndarray, r: int, c: int, k: int):
        if mask[r, c]:
            return (r, c)
        sub = mask[max(r - k, 0):r + k + 1, max(c - k, 0):c + k + 1]
        rr, cc = np.nonzero(sub)
        if not len(rr):
            return None
        i = int(np.argmin((rr + max(r - k, 0) - r) ** 2 + (cc + max(c - k, 0) - c) ** 2))
        return (int(rr[i] + max(r - k, 0)), int(cc[i] + max(c - k, 0)))

    def _travel_time(self, traversable: np.ndarray, goal_region: np.ndarray, clearance: np.ndarray,
                     start: tuple[int, int] | None = None) -> np.ndarray:
        """Travel time to the goal region (coarse cells; inf where unreachable).

        With ``start`` given, the march stops once it is past the start: scikit-fmm's narrow band
        accepts cells in order of travel time, so every cell it returns carries exactly the value
        of the full solution, and the descent from the start only looks at smaller values (cells
        beyond the band read inf, which the descent treats like any larger value). The band
        starts at 2.5x the straight-line distance (speed is at most 1) and triples until the
        start is inside it; on a home map this marches a fraction of the grid."""
        import skfmm

        cfg = self.config
        phi = np.where(goal_region, -1.0, 1.0)
        speed = np.clip(clearance / cfg.speed_saturation, cfg.min_speed, 1.0)
        masked = np.ma.MaskedArray(phi, ~traversable)
        bands = [0.0]
        if start is not None:
            gr, gc = np.nonzero(goal_region)
            straight = float(np.sqrt(((gr - start[0]) ** 2 + (gc - start[1]) ** 2).min()))
            band = 2.5 * straight + 20.0
            bands = []
            while band < traversable.size:      # no travel time exceeds the cell count / min speed
                bands.append(band)               # ... times 1/min_speed; the last try is the full march
                band *= 3.0
            bands.append(0.0)
        for band in bands:
            try:
                t = skfmm.travel_time(masked, speed, dx=1.0, narrow=band)
            except ValueError:  # no zero contour inside the unmasked region
                return np.full(traversable.shape, np.inf)
            out = np.ma.filled(t.astype(float), np.inf)
            out[goal_region] = 0.0
            if start is None or band == 0.0 or np.isfinite(out[start]):
                return out
        return out

    def _actions(self, path: np.ndarray, start: SE2Pose, goal_yaw, checker: FootprintChecker, corridor,
                 horizon: float):
        """Rotate-then-forward actions along ``path`` up to the horizon (every move checked)."""
        cfg = self.config
        actions: list[Action] = []
        waypoints: list[SE2Pose] = []
        x, y, yaw = start.x, start.y, start.yaw
        travelled, i = 0.0, 0
        blocked = False
        while i < len(path) - 1 and travelled < horizon:
            j = self._next_point(path, i, x, y, checker, corridor)
            tx, ty = path[j]
            dist = math.hypot(tx - x, ty - y)
            if dist < 1e-6:
                i = j
                continue
            heading = math.atan2(ty - y, tx - x)
            turn = float(wrap_angle(heading - yaw))
            move = min(dist, cfg.forward_max)
            ex, ey = x + move * math.cos(heading), y + move * math.sin(heading)
            if cfg.rotate_min <= abs(turn) <= cfg.turn_while_walking and \
                    checker.straight_move_free(x, y, yaw, ex, ey, turn):      # see PlannerConfig.turn_while_walking
                actions.extend([Action("rotate", turn), Action("forward", move)])
                x, y, yaw = ex, ey, heading
                waypoints.append(SE2Pose(x, y, yaw))
                travelled += move
                if move == dist:
                    i = j
                continue
            if abs(turn) >= cfg.rotate_min:
                long_way = False
                if not checker.turn_free(x, y, yaw, heading):
                    shifted = self._shuffle(checker, x, y, yaw, (tx, ty), actions, waypoints)
                    if shifted is not None:
                        x, y = shifted
                        heading = math.atan2(ty - y, tx - x)
                        turn = float(wrap_angle(heading - yaw))
                        dist = math.hypot(tx - x, ty - y)
                    elif (other := _long_way(checker, x, y, yaw, turn)) is not None:
                        turn, long_way = other, True
                    elif cfg.step_without_turning and \
                            (step := self._sidestep(checker, x, y, yaw, tx, ty, min(dist, cfg.forward_max),
                                                    actions, waypoints)) > 0.0:
                        x, y = waypoints[-1].x, waypoints[-1].y
                        travelled += step
                        if step < min(dist, cfg.forward_max) - 1e-6:
                            blocked = True       # stopped short, as a forward move would
                            break
                        if step >= dist - 1e-9:
                            i = j
                        continue
                    else:
                        blocked = True
                        break
                yaw = self._emit_turn(actions, waypoints, x, y, yaw, turn, long_way)
            else:
                heading = yaw   # within 5 degrees: walk on at the current heading
            move = min(dist, cfg.forward_max)       # a shuffle may have put the point farther away
            step = self._free_distance(checker, x, y, heading, move)
            last = j == len(path) - 1 and move == dist
            if step < (min(cfg.forward_min, move) if last else cfg.forward_min):
                blocked = True
                break
            x, y = x + step * math.cos(heading), y + step * math.sin(heading)
            actions.append(Action("forward", step))
            waypoints.append(SE2Pose(x, y, yaw))
            travelled += step
            if step < move - 1e-6:       # stopped short: the footprint is blocked further on
                blocked = True
                break
            if move == dist:
                i = j
        complete = not blocked and i >= len(path) - 1
        turn_blocked = False
        if complete and goal_yaw is not None:
            turn = float(wrap_angle(goal_yaw - yaw))
            if abs(turn) >= cfg.rotate_min:
                if checker.turn_free(x, y, yaw, goal_yaw):
                    self._emit_turn(actions, waypoints, x, y, yaw, turn)
                elif (other := _long_way(checker, x, y, yaw, turn)) is not None:
                    self._emit_turn(actions, waypoints, x, y, yaw, other, stepwise=True)
                else:
                    turn_blocked = True    # at the goal, but cannot face the requested way
        return actions, waypoints, complete, blocked, turn_blocked

    def _next_point(self, path: np.ndarray, i: int, x: float, y: float, checker: FootprintChecker, corridor) -> int:
        """Index of the path point the next straight move aims at: the farthest within
        ``forward_max`` whose straight line stays in the planning corridor; if that is closer
        than ``forward_min`` (a corridor corner cut), the farthest one the footprint can reach."""
        cfg = self.config
        traversable, to_cell = corridor
        best = None
        reach = i + 1
        for k in range(i + 1, len(path)):
            if math.hypot(path[k, 0] - x, path[k, 1] - y) > cfg.forward_max:
                break
            reach = k
            if _line_in(traversable, to_cell, (x, y), path[k]):
                best = k
        short = best is None or math.hypot(path[best, 0] - x, path[best, 1] - y) < cfg.forward_min
        if short and reach > (best or i):
            for k in range(reach, (best or i), -1):
                heading = math.atan2(path[k, 1] - y, path[k, 0] - x)
                if checker.segment_free(x, y, path[k, 0], path[k, 1], heading, step=checker.geometry.cell_size / 2):
                    return k
        return best if best is not None else i + 1

    def _shuffle(self, checker: FootprintChecker, x, y, yaw, toward, actions, waypoints):
        """When turning in place would sweep into something (Spot's rear corners reach 0.65 m),
        step straight forward, back or sideways at the current heading (Spot is holonomic) to the
        nearest spot where the turn towards ``toward`` is free; the step is emitted as an action
        (``forward``/``backward`` in m, ``strafe`` signed, left positive). None if there is none."""
        cfg = self.config
        c, s = math.cos(yaw), math.sin(yaw)
        steps = np.arange(0.05, cfg.shuffle_max + 1e-9, 0.05)
        options = [(d, 0.0) for d in steps] + [(-d, 0.0) for d in steps] + \
                  [(0.0, d) for d in steps] + [(0.0, -d) for d in steps]
        options.sort(key=lambda o: abs(o[0]) + abs(o[1]))
        ends = [(x + fx * c - fy * s, y + fx * s + fy * c) for fx, fy in options]
        step_free: list[bool] = []
        for i, ((fx, fy), (nx, ny)) in enumerate(zip(options, ends)):
            if i == len(step_free):     # the straight moves of the next few steps in one batch
                step_free += list(checker.segments_free(x, y, np.array(ends[i:i + SHUFFLE_BATCH]), yaw))
            heading = math.atan2(toward[1] - ny, toward[0] - nx)
            if step_free[i] and checker.turn_free(nx, ny, yaw, heading):
                if fy == 0.0:
                    actions.append(Action("forward" if fx > 0 else "backward", abs(float(fx))))
                else:
                    actions.append(Action("strafe", float(fy)))
                waypoints.append(SE2Pose(nx, ny, yaw))
                return nx, ny
        return None

    def _sidestep(self, checker: FootprintChecker, x, y, yaw, tx, ty, dist, actions, waypoints) -> float:
        """``step_without_turning``: walk straight towards (tx, ty) keeping the heading (Spot walks
        backwards and sideways too), as far as the footprint stays free, up to ``dist``; emitted as
        its forward/backward and strafe parts (one straight move, one waypoint). Returns the
        distance (0: not even ``forward_min`` is free, nothing emitted)."""
        direction = math.atan2(ty - y, tx - x)
        step = self._free_distance(checker, x, y, direction, dist, yaw)
        if step < self.config.forward_min - 1e-9:
            return 0.0
        rel = direction - yaw
        along, side = step * math.cos(rel), step * math.sin(rel)
        if abs(along) > 1e-9:
            actions.append(Action("forward" if along > 0 else "backward", abs(along)))
        if abs(side) > 1e-9:
            actions.append(Action("strafe", side))
        waypoints.append(SE2Pose(x + step * math.cos(direction), y + step * math.sin(direction), yaw))
        return step

    def _emit_turn(self, actions, waypoints, x, y, yaw, turn, stepwise: bool = False) -> float:
        """Rotate actions of at most ``rotate_max`` and a waypoint at the end. A robot turns the
        short way to a waypoint's heading, so a turn the long way round (``stepwise``, when the
        short way is blocked) gets a waypoint after every action."""
        cfg = self.config
        n = max(1, int(math.ceil(abs(turn) / cfg.rotate_max)))
        for k in range(1, n + 1):
            actions.append(Action("rotate", turn / n))
            if stepwise and k < n:
                waypoints.append(SE2Pose(x, y, float(wrap_angle(yaw + turn * k / n))))
        yaw = float(wrap_angle(yaw + turn))
        waypoints.append(SE2Pose(x, y, yaw))
        return yaw

    @staticmethod
    def _free_distance(checker: FootprintChecker, x, y, heading, dist, yaw: float | None = None) -> float:
        """Longest prefix of the straight move along ``heading`` (to at most ``dist``) whose
        footprint stays free, the body facing ``yaw`` (None: the way it walks), sampled every half
        cell so no cell can slip between two checked poses."""
        n = max(2, int(math.ceil(dist / (checker.geometry.cell_size / 2))) + 1)
        t = np.linspace(0.0, dist, n)
        poses = np.stack([x + t * math.cos(heading), y + t * math.sin(heading),
                          np.full(n, heading if yaw is None else yaw)], axis=1)
        free = checker.poses_free(poses)
        if free.all():
            return dist
        first_bad = int(np.argmin(free))
        return float(t[first_bad - 1]) if first_bad > 0 else 0.0


def _long_way(checker: FootprintChecker, x: float, y: float, yaw: float, turn: float) -> float | None:
    """The same change of heading turning the other way round, if that sweep is free; else None."""
    other = turn - math.copysign(2 * math.pi, turn)
    return other if checker.sweep_free(x, y, yaw, other) else None


def _pool(grid: np.ndarray, f: int) -> np.ndarray:
    """Max-pool a bool grid by ``f`` (any cell set in a block sets the coarse cell)."""
    if f == 1:
        return grid.copy()
    h, w = grid.shape[0] // f * f, grid.shape[1] // f * f
    out = grid[0:h:f, 0:w:f].copy()          # f * f strided ORs: several times faster than
    for i in range(f):                       # reshape(...).any(axis=(1, 3)) on a 2000 x 2000 map
        for j in range(f):
            if i or j:
                out |= grid[i:h:f, j:w:f]
    return out


def _clearance(obstacle: np.ndarray, cell: float) -> np.ndarray:
    """``distance_transform_edt(~obstacle) * cell``, bit for bit, about 3x faster: OpenCV's exact
    (Felzenszwalb) Euclidean transform gives float32 distances whose squares round back to the
    integer squared distances, which then take scipy's float64 sqrt. Used while those squares
    stay below 2^21 (float32 keeps them within 0.25 of the integer); scipy otherwise, and for a
    map without obstacles (scipy's answer for that case is its own)."""
    import cv2

    h, w = obstacle.shape
    if h * h + w * w >= 1 << 21 or not obstacle.any():
        return ndimage.distance_transform_edt(~obstacle) * cell
    d = cv2.distanceTransform((~obstacle).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return np.sqrt(np.rint(d.astype(np.float64) ** 2)) * cell


def _far_enough_inside(mask: np.ndarray, cell: float, radius: float) -> np.ndarray:
    """``distance_transform_edt(mask) * cell >= radius``, the same booleans at a fraction of the
    cost: a cell passes when no False cell lies at an offset whose distance (computed with the
    same float operations) falls short of ``radius``, i.e. an erosion with that disc. A mask with
    no False cell at all gets scipy's answer for it (distances to a virtual cell above row 0)."""
    import cv2

    if mask.all():
        rows, cols = np.indices(mask.shape)
        return np.sqrt(((rows + 1) ** 2 + cols ** 2).astype(float)) * cell >= radius
    k = int(math.ceil(radius / cell)) + 1
    off = np.arange(-k, k + 1)
    near = np.sqrt((off[:, None] ** 2 + off[None, :] ** 2).astype(float)) * cell < radius
    return cv2.erode(mask.astype(np.uint8), near.astype(np.uint8), borderType=cv2.BORDER_CONSTANT,
                     borderValue=1).astype(bool)


def _descend(times: np.ndarray, start: tuple[int, int]) -> list[tuple[int, int]]:
    """Steepest descent on the travel-time field from ``start`` to its zero set."""
    path = [start]
    r, c = start
    h, w = times.shape
    for _ in range(h * w):
        if times[r, c] <= 0:
            break
        r0, c0 = max(r - 1, 0), max(c - 1, 0)
        window = times[r0:r + 2, c0:c + 2]
        dr, dc = np.unravel_index(int(np.argmin(window)), window.shape)
        nr, nc = r0 + dr, c0 + dc
        if times[nr, nc] >= times[r, c]:
            break
        r, c = nr, nc
        path.append((r, c))
    return path


def _line_in(mask: np.ndarray, to_cell, a, b) -> bool:
    """Every point of the segment a-b, sampled every 2.5 cm, lies in ``mask`` (``to_cell`` takes
    one point or an (N, 2) array)."""
    n = max(2, int(math.dist(a, b) / 0.025) + 1)
    t = np.linspace(0.0, 1.0, n)
    rows, cols = to_cell(np.stack([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])], axis=1))
    return bool(mask[rows, cols].all())
