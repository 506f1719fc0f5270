"""The robot's body as the agent knows it: where it stands, where the arm points, and how it moves.

Every move goes through here: plan with FMM^2 on the agent's own occupancy map, walk the
waypoints, mark what the body swept as free and what it bumped into as an obstacle, look around
with the hand camera, gaze at a point, and check that the arm has room before it swings (Spot's
elbow sweeps ~0.34 m round the shoulder, and the map only knows what the camera has seen).
Nothing here decides *where* to go; the agent and the skills do.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import replace
from typing import Sequence

import numpy as np

from helios.agents import arm_room
from helios.agents.arm_room import look_pitch, pitch_ahead
from helios.agents.config import AgentConfig
from helios.agents.frontier_goals import unseen_bearing
from helios.agents.geometry import approach_poses, body_rectangle, turn_in_progress, turn_sweep
from helios.agents.observer import Observer
from helios.planning.fmm import FMMPlanner, PlannerConfig, PlanResult
from helios.planning.footprint import FootprintChecker
from helios.search.gaze_points import GazePoint
from robots.hal import CommandResult, Observation, Reason, RobotBackend, SE2Pose
from robots.transforms import wrap_angle

MAX_GAZE_YAW = math.radians(105)
"""The hand camera can be pointed this far to the side of the body heading."""
UNSEEN_SIDE_NO_TURN = math.radians(45)
"""Where a body that cannot turn looks towards an unseen side behind it: 45 degrees off its
heading, so the wider side view (60 degrees further) stays within ``MAX_GAZE_YAW``."""

HOP_EXTRA_MARGIN = 0.05
"""Metres added to the footprint's margin for a straight hop (``Body.hop``): planned paths keep
to the middle of free space (FMM^2), a hop only to its own sweep, so it asks for more room."""

TURN_BUMP_SWEEP = math.radians(10)
"""The part of an interrupted turn in place (rad) in which a bump is marked (``mark_turn_bump``)."""


class CheckerCache:
    """The body's footprint checkers on one occupancy grid, reused while ``OccupancyGrid.revision``
    stands: building one takes full-map passes (~2 ms on the 2000 x 2000 grid), and a global
    decision asks once per candidate (its gaze points) and again for every walk. Callers never
    modify a checker (``clear_under`` returns a new one), so a reused one answers as a new one
    would (``tests/test_exact_speedups.py``)."""

    def __init__(self) -> None:
        self._grid, self._revision, self._by_margin = None, -1, {}

    def get(self, occupancy, planner: PlannerConfig, extra_margin: float) -> FootprintChecker:
        """The checker of ``planner``'s footprint grown by ``extra_margin`` m; never-seen cells block
        when ``planner.unknown_is_obstacle``."""
        if self._grid is not occupancy or self._revision != occupancy.revision:
            self._grid, self._revision, self._by_margin = occupancy, occupancy.revision, {}
        if extra_margin not in self._by_margin:
            footprint = planner.footprint
            if extra_margin:
                footprint = replace(footprint, margin=footprint.margin + extra_margin)
            explored = occupancy.explored if planner.unknown_is_obstacle else None
            self._by_margin[extra_margin] = FootprintChecker.of_known_region(
                footprint, occupancy.geometry, occupancy.obstacle, occupancy.max_height, explored,
                occupancy.explored_bounds)
        return self._by_margin[extra_margin]


class Body:
    """Pose and arm state of one episode, and the motions built from HAL commands.

    ``log`` and ``timings`` are shared with the agent (one episode log; planning seconds)."""

    def __init__(self, config: AgentConfig, planner: FMMPlanner, observer: Observer, log: list[str],
                 timings: Counter):
        self.config = config
        self.planner = planner
        self.observer = observer
        self.log = log
        self.timings = timings
        self.pose: SE2Pose | None = None
        self.body_height = 0.5
        self.arm_stowed = False
        self.arm_direction: float | None = None     # world yaw the hand camera points along
        self.last_plan: PlanResult | None = None
        self.unstuck_from: list[np.ndarray] = []     # where unstick() has stepped away from
        self._checkers = CheckerCache()

    @property
    def map(self):
        return self.observer.map

    def xy(self) -> np.ndarray:
        return np.array([self.pose.x, self.pose.y])

    def observe(self, robot: RobotBackend) -> Observation:
        """A frame into the map (see :meth:`Observer.observe`); the body pose comes with it."""
        obs = self.observer.observe(robot)
        self.pose = obs.body_pose
        self.body_height = float(obs.T_world_body[2, 3])
        return obs

    def stow(self, robot: RobotBackend) -> None:
        robot.stow_arm()
        self.arm_stowed, self.arm_direction = True, None

    # ================================================================== walking
    def checker(self, extra_margin: float = 0.0) -> FootprintChecker:
        """Footprint checks on the current map (its footprint margin grown by ``extra_margin`` m),
        reused until the grids change (:class:`CheckerCache`)."""
        return self._checkers.get(self.map.occupancy, self.config.planner, extra_margin)

    def plan(self, goals, radius: float, yaws=None, horizon: float | None = None) -> PlanResult:
        occ = self.map.occupancy
        t0 = time.perf_counter()
        plan = self.planner.plan(self.map.geometry, occ.obstacle, occ.explored, self.pose, goals, radius, yaws,
                                 occ.max_height, horizon, occ.explored_bounds, footprints=self.checker())
        self.timings["planning"] += time.perf_counter() - t0
        self.timings["plans"] += 1
        self.last_plan = plan
        return plan

    def execute(self, robot: RobotBackend, plan: PlanResult) -> bool:
        """Walk a plan's waypoints (arm stowed first); on a stop, remember what was bumped."""
        return self._walk(robot, plan.waypoints)

    def _walk(self, robot: RobotBackend, waypoints: Sequence[SE2Pose]) -> bool:
        if not self.arm_stowed:
            self.stow(robot)
        start = self.xy()
        res = robot.navigate_to(waypoints[-1], via=waypoints[:-1])
        self.pose = res.final_pose if res.final_pose is not None else robot.observe().body_pose
        self._mark_swept(start, waypoints, res.success)
        if not res.success:
            self.log.append(f"walk stopped: {res.reason.value} {res.message}")
            if res.collided:
                self._mark_bump(waypoints)
        return bool(res.success)

    def hop(self, robot: RobotBackend, goal: SE2Pose, max_distance: float, radius: float) -> bool | None:
        """One straight move to a near pose, turning while walking (a single SE2 trajectory,
        checked with ``FootprintChecker.straight_move_free``). None when the goal is
        farther than ``max_distance`` or the sweep is not known to be free (the caller then
        plans); else whether the move completed. Within ``radius`` and ``rotate_min`` of the goal
        it is already there, as the planner would say."""
        here = self.pose
        dist = math.hypot(goal.x - here.x, goal.y - here.y)
        if max_distance <= 0 or dist > max_distance:
            return None
        turn = float(wrap_angle(goal.yaw - here.yaw))
        if dist <= radius and abs(turn) < self.config.planner.rotate_min:
            return True
        checker = self.checker(HOP_EXTRA_MARGIN).clear_under(here)
        if not checker.straight_move_free(here.x, here.y, here.yaw, goal.x, goal.y, turn):
            return None
        return self._walk(robot, [SE2Pose(goal.x, goal.y, float(wrap_angle(here.yaw + turn)))])

    def _mark_swept(self, start: np.ndarray, waypoints: Sequence[SE2Pose], completed: bool) -> None:
        """Where the body walked is free space, whether or not the camera ever saw the floor there."""
        pts = [start] + [np.array([w.x, w.y]) for w in waypoints]
        if not completed:   # stopped early: only up to where it stands now
            here = self.xy()
            k = int(np.argmin([np.linalg.norm(p - here) for p in pts]))
            pts = pts[:k] + [here]
        samples = [pts[0]]
        for a, b in zip(pts[:-1], pts[1:]):
            n = max(1, int(np.linalg.norm(b - a) / 0.15))
            samples += [a + (b - a) * t for t in np.linspace(1.0 / n, 1.0, n)]
        self.map.occupancy.mark_seen(np.array(samples), self.config.planner.footprint.body[3])

    def _mark_bump(self, waypoints: Sequence[SE2Pose]) -> None:
        """The walk ran into something the map does not show: put an obstacle just beyond the
        footprint in the direction the body was moving, so the next plan goes around it (a turn
        in place: see ``AgentConfig.turn_bumps``)."""
        turn = turn_in_progress(self.pose, waypoints) if self.config.turn_bumps == "sweep" else None
        if turn is not None:
            n, which = mark_turn_bump(self.map.occupancy, self.pose, self.config.planner.footprint, turn)
            self.log.append(f"bumped into something while turning: {n} {which} cells of its sweep marked occupied")
            return
        here = np.array([self.pose.x, self.pose.y])
        for wp in waypoints:
            step = np.array([wp.x, wp.y]) - here
            dist = float(np.linalg.norm(step))
            if dist > 0.02:
                d = step / dist
                body = self.config.planner.footprint.body
                c, s = math.cos(self.pose.yaw), math.sin(self.pose.yaw)
                local = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])   # direction in the body frame
                half = body[1] if local[0] > 0 else -body[0]
                side = body[3]
                extent = min(half / max(abs(local[0]), 1e-6), side / max(abs(local[1]), 1e-6))
                self.map.occupancy.mark_obstacle(here + d * (extent + 0.12), 0.12)
                self.log.append(f"bumped into something near ({here[0] + d[0] * extent:.2f}, {here[1] + d[1] * extent:.2f})")
                return

    def go(self, robot: RobotBackend, goals: np.ndarray, radius: float, yaws=None) -> tuple[bool, int]:
        """Plan-walk-look until within ``radius`` of one of ``goals`` (and facing its yaw)."""
        for _ in range(self.config.max_walk_chunks):
            plan = self.plan(goals, radius, yaws)
            if not plan.success and plan.reason == "blocked" and self.unstick(robot):
                plan = self.plan(goals, radius, yaws)
            if not plan.success:
                self.log.append(f"no path: {plan.reason}")
                return False, -1
            if not plan.waypoints:
                return True, plan.goal_index
            if not self.execute(robot, plan):
                return False, -1
            if plan.reaches_goal:
                return True, plan.goal_index
            self.look(robot, (0.0,))   # see what lies ahead (far and near) before the next stretch
        return False, -1

    def unstick(self, robot: RobotBackend) -> bool:
        """A plan is blocked at its first step: step straight, keeping the heading, to the nearest
        pose within ``unstick_distance`` where the body can turn all the way round on the map
        (see ``AgentConfig.unstick_distance``). Once per place; False if off, done here already,
        or there is no such pose."""
        limit = self.config.unstick_distance
        here = self.xy()
        if limit <= 0 or any(np.linalg.norm(here - p) < 0.2 for p in self.unstuck_from):
            return False
        self.unstuck_from.append(here)
        x, y, yaw = self.pose.x, self.pose.y, self.pose.yaw
        checker = self.checker().clear_under(self.pose)
        for dx, dy in _offsets_nearest_first(limit):
            nx, ny = x + dx, y + dy
            if checker.sweep_free(nx, ny, yaw, 2 * math.pi) and checker.segment_free(x, y, nx, ny, yaw):
                ok = self._step_to(robot, SE2Pose(nx, ny, yaw))
                self._mark_swept(here, [SE2Pose(nx, ny, yaw)], ok)
                self.log.append(f"blocked at the first step: stepped ({dx:+.1f}, {dy:+.1f}) m to turn freely")
                return ok
        return False

    def _step_to(self, robot: RobotBackend, pose: SE2Pose) -> bool:
        """One straight move to a near pose (arm stowed first); the pose is updated either way."""
        if not self.arm_stowed:
            self.stow(robot)
        res = robot.navigate_to(pose)
        self.pose = res.final_pose if res.final_pose is not None else robot.observe().body_pose
        return bool(res.success)

    def approach(self, robot: RobotBackend, point, what: str) -> str | None:
        """Walk to a free standing pose from which the arm reaches ``point`` (most comfortable
        first). None when there, else why not (``what`` names the action: "grasp", "place")."""
        poses = approach_poses(np.asarray(point, dtype=float), self.config.reach, self.checker())
        if not len(poses):
            return f"no free standing pose to {what} from"
        ok, _ = self.go(robot, poses[:, :2], self.config.gaze_goal_radius, poses[:, 2])
        return None if ok else f"could not reach a {what} pose"

    def face(self, robot: RobotBackend, point) -> None:
        """Turn on the spot towards ``point`` if it lies well to the side (a goal pose is reached
        within a radius, and its final turn may have been blocked)."""
        direction = math.atan2(point[1] - self.pose.y, point[0] - self.pose.x)
        if abs(wrap_angle(direction - self.pose.yaw)) > self.config.view.face_tolerance:
            self.go(robot, self.xy()[None], self.config.gaze_goal_radius, [direction])

    # ================================================================== looking
    def view_from(self, robot: RobotBackend, gp: GazePoint) -> bool:
        """Walk to a gaze point and take its view (False if it cannot be reached or looked from).
        A near one is reached in one straight step that turns as it walks (``gaze_hop``)."""
        ok = self.hop(robot, gp.pose, self.config.gaze_hop, self.config.gaze_goal_radius)
        if ok is None:
            ok, _ = self.go(robot, np.array([[gp.pose.x, gp.pose.y]]), self.config.gaze_goal_radius, gp.pose.yaw)
        if not ok:
            return False
        direction = math.atan2(gp.look_at[1] - self.pose.y, gp.look_at[0] - self.pose.x)
        if abs(wrap_angle(direction - self.pose.yaw)) > MAX_GAZE_YAW:
            self.log.append("gaze point: could not turn to face the object")
            return False
        if not self.room_to_look(robot, gp.look_at):
            self.log.append("gaze point: the arm has no room to look from here")
            return False
        if not self.gaze(robot, gp.look_at).success:
            return False
        self.observe(robot)
        return True

    def room_to_look(self, robot: RobotBackend, look_at) -> bool:
        """Before one look at ``look_at`` from here (``view_from``'s test on arrival): room for the
        arm at the look's pitch, after a ``make_room`` step if needed, and a clear sweep towards it."""
        direction = math.atan2(look_at[1] - self.pose.y, look_at[0] - self.pose.x)
        pitch = look_pitch(self.pose.x, self.pose.y, self.body_height, look_at)
        return self.make_room(robot, pitch) and self.arm_clear(direction, pitch)

    def look(self, robot: RobotBackend, yaws_deg: Sequence[float], facing: float | None = None,
             near_yaws_deg: Sequence[float] = (0.0,)) -> None:
        """Point the hand camera in several directions and observe each (plus the near floor)."""
        view = self.config.view
        far = pitch_ahead(self.body_height, view.look_distance, view.look_height)
        near = pitch_ahead(self.body_height, view.near_look_distance, 0.0)
        if not self.make_room(robot, far):     # the near-floor views are skipped where the arm cannot dip
            return
        base = self.pose.yaw if facing is None else facing
        for deg in sorted(yaws_deg, key=abs):     # front first: each view reveals walls for the next
            a = base + math.radians(deg)
            if abs(wrap_angle(a - self.pose.yaw)) > MAX_GAZE_YAW:
                continue
            if not self.arm_clear(a, far):
                continue
            point = [self.pose.x + view.look_distance * math.cos(a), self.pose.y + view.look_distance * math.sin(a),
                     view.look_height]
            res = self.gaze(robot, point)
            if res.success:
                self.observe(robot)
        for deg in sorted(near_yaws_deg, key=abs) if view.near_look_distance > 0 else ():
            a = base + math.radians(deg)      # the floor close by, which the far views miss
            if abs(wrap_angle(a - self.pose.yaw)) > MAX_GAZE_YAW or not self.arm_clear(a, near):
                continue
            res = self.gaze(robot, [self.pose.x + view.near_look_distance * math.cos(a),
                                    self.pose.y + view.near_look_distance * math.sin(a), 0.0])
            if res.success:
                self.observe(robot)

    def look_from_frontier(self, robot: RobotBackend, direction: float | None, parts) -> None:
        """Look round from here at a frontier whose parts (world points) are ``parts``: towards
        ``direction`` (None: straight ahead), or with ``AgentConfig.face_unseen`` towards the
        frontier's never-seen side, turning in place first when that lies more than 90 degrees
        off the heading and the map leaves room (the arm cannot look behind the body)."""
        if self.config.face_unseen:
            unseen = unseen_bearing(self.map.occupancy.explored, self.map.geometry, self.xy(), parts,
                                    self.config.frontier_reach + 1.0)
            if unseen is not None:
                off = float(wrap_angle(unseen - self.pose.yaw))
                if abs(off) <= math.pi / 2:
                    direction = unseen
                elif self.turn_to(robot, unseen):
                    direction = unseen
                    self.log.append(f"turned to face the unseen side of a frontier ({math.degrees(unseen):.0f} deg)")
                else:       # no room to turn: as far that way as the side views still reach
                    direction = self.pose.yaw + math.copysign(UNSEEN_SIDE_NO_TURN, off)
        self.look(robot, self.config.view.look_yaws_deg, direction)

    def turn_to(self, robot: RobotBackend, yaw: float) -> bool:
        """Turn in place to face world ``yaw`` (the planner may shuffle a little to make room);
        False, without moving, when the map leaves no room to turn."""
        plan = self.plan(self.xy()[None], 0.05, yaw)
        if not plan.success or plan.final_turn_blocked or not plan.waypoints:
            return False
        return self.execute(robot, plan)

    def start_scan(self, robot: RobotBackend) -> None:
        """Look around the start: front half with the arm, turn round, other half. The turn relies on the start
        clearance that episode generation guarantees (``PlannerConfig.start_clearance``); skipped if not free."""
        self.observe(robot)
        # the start clearance is free by construction: keep it as seen floor, or the strip beside
        # the start that no view covers can cut the start off from the rest once the robot leaves
        self.map.occupancy.mark_seen(self.xy()[None], self.config.planner.start_clearance)
        self.look_all_around(robot)
        if not self.config.view.start_turn_around:
            return
        if self.turn_to(robot, float(wrap_angle(self.pose.yaw + math.pi))):
            self.look_all_around(robot)
        else:
            self.log.append("start: could not turn round")

    def look_all_around(self, robot: RobotBackend) -> None:
        """The start's look pattern: wide far views plus the near floor on three sides."""
        view = self.config.view
        # with the near views off, their directions are not read (tasks.registry.ONLY_WITH refuses them)
        near_yaws_deg = view.start_near_yaws_deg if view.near_look_distance > 0 else ()
        self.look(robot, view.start_look_yaws_deg, near_yaws_deg=near_yaws_deg)

    def gaze(self, robot: RobotBackend, point) -> CommandResult:
        """Point the hand camera at a world point (the arm leaves its stowed/carry pose)."""
        res = robot.gaze_at(point)
        self.arm_stowed = False
        self.arm_direction = math.atan2(point[1] - self.pose.y, point[0] - self.pose.x)
        if not res.success:
            self.log.append(f"gaze failed: {res.reason.value} {res.message}")
            if res.reason is Reason.COLLISION:   # the arm met something the map lacks: remember it
                view = self.config.view
                reach = view.elbow_radius
                sx = self.pose.x + view.shoulder_ahead * math.cos(self.pose.yaw)
                sy = self.pose.y + view.shoulder_ahead * math.sin(self.pose.yaw)
                self.map.occupancy.mark_obstacle((sx + reach * math.cos(self.arm_direction),
                                                  sy + reach * math.sin(self.arm_direction)), 0.1, height=1.5)
        return res

    # ================================================================== arm room
    def elbow_clear(self, x: float, y: float, yaw: float, pitch: float | None = None) -> bool:
        """Moving the arm at all has room with the body at (x, y, yaw), for a look pitched
        ``pitch`` degrees down (:func:`helios.agents.arm_room.elbows_clear`)."""
        return bool(self._elbows_clear(np.array([x]), np.array([y]), yaw, pitch)[0])

    def _elbows_clear(self, xs: np.ndarray, ys: np.ndarray, yaw: float, pitch: float | None = None) -> np.ndarray:
        """``elbow_clear`` for several body positions at one heading."""
        return arm_room.elbows_clear(self.config.view, self.map.occupancy, self.map.geometry, xs, ys, yaw, pitch)

    def arm_clear(self, direction: float, pitch: float | None = None) -> bool:
        """The arm can point the camera in ``direction`` (world yaw): the elbow has room, and (the
        radius model) no tall obstacle lies on the arc the hand sweeps from where it points now."""
        if not self.elbow_clear(self.pose.x, self.pose.y, self.pose.yaw, pitch):
            return False
        now = self.pose.yaw if self.arm_direction is None else self.arm_direction
        return self._sweep_clear(self.pose.x, self.pose.y, self.pose.yaw, now, direction)

    def _sweep_clear(self, x: float, y: float, yaw: float, now: float, direction: float) -> bool:
        return arm_room.sweep_clear(self.config.view, self.map.occupancy, self.map.geometry, x, y, yaw, now, direction)

    def make_room(self, robot: RobotBackend, pitch: float | None = None) -> bool:
        """Before looking around: if a wall or a tall piece of furniture is too close for the arm,
        step straight away from it (at the current heading) to the nearest pose where the elbow
        has room. False if there is none within ``make_room_distance``."""
        yaw = self.pose.yaw
        room = self._room_at(self.pose.x, self.pose.y, yaw, pitch)
        if room is None:
            self.log.append("no room for the arm to look around here")
            return False
        nx, ny, dx, dy = room
        if dx == 0.0 and dy == 0.0:
            return True
        ok = self._step_to(robot, SE2Pose(nx, ny, yaw))
        self.log.append(f"made room for the arm: stepped ({dx:+.1f}, {dy:+.1f}) m")
        return ok and self.elbow_clear(self.pose.x, self.pose.y, self.pose.yaw, pitch)

    def _room_at(self, x: float, y: float, yaw: float,
                 pitch: float | None = None) -> tuple[float, float, float, float] | None:
        """Where ``make_room`` would look from, standing at (x, y, yaw): here if the elbow has room,
        else the nearest pose within ``make_room_distance`` (body-frame step dx, dy at the same
        heading) where it has and the straight step there is free; (x', y', dx, dy), None if none."""
        if self.elbow_clear(x, y, yaw, pitch):
            return x, y, 0.0, 0.0
        offsets = np.array(_offsets_nearest_first(self.config.view.make_room_distance))
        c, s = math.cos(yaw), math.sin(yaw)
        nx = x + offsets[:, 0] * c - offsets[:, 1] * s
        ny = y + offsets[:, 0] * s + offsets[:, 1] * c
        checker = self.checker().clear_under((x, y, yaw))
        for j in np.flatnonzero(self._elbows_clear(nx, ny, yaw, pitch)):
            if checker.segment_free(x, y, float(nx[j]), float(ny[j]), yaw):
                return float(nx[j]), float(ny[j]), float(offsets[j, 0]), float(offsets[j, 1])
        return None

    def can_look_from(self, poses, look_at) -> np.ndarray:
        """(N,) bool: a visit to each (x, y, yaw) pose could aim the camera at ``look_at`` by
        ``view_from``'s own tests on the current map: the elbow has room there, or ``make_room``
        finds a step to a pose where it has (nearest first, the straight step free); then the
        stowed arm's sweep towards ``look_at`` is clear (``arm_clear``). For gaze points
        (``GazeConfig.arm_room``): a point that fails would cost the walk there and take no view."""
        poses = np.atleast_2d(np.asarray(poses, dtype=float))
        out = np.zeros(len(poses), dtype=bool)
        for i, (x, y, yaw) in enumerate(poses):
            room = self._room_at(float(x), float(y), float(yaw),
                                 look_pitch(float(x), float(y), self.body_height, look_at))
            if room is not None:
                direction = math.atan2(look_at[1] - y, look_at[0] - x)     # as view_from: aimed on arrival
                out[i] = self._sweep_clear(room[0], room[1], float(yaw), float(yaw), direction)
        return out


def _offsets_nearest_first(limit: float) -> list[tuple[float, float]]:
    """(dx, dy) steps on a 0.1 m lattice within ``limit`` (m), origin excluded, nearest first."""
    steps = np.arange(-limit, limit + 1e-9, 0.1)
    offsets = [(dx, dy) for dx in steps for dy in steps if 0 < math.hypot(dx, dy) <= limit + 1e-9]
    return sorted(offsets, key=lambda o: math.hypot(*o))


def mark_turn_bump(occupancy, pose: SE2Pose, footprint, turn: float) -> tuple[int, str]:
    """A turn in place stopped at ``pose`` on a collision, ``turn`` rad short of its heading: the
    thing it hit lies in what the body (with the footprint's margin) would sweep over the next
    ``TURN_BUMP_SWEEP``. Mark the never-seen cells there occupied, or, when the map had seen all
    of them (something it missed), the whole of that sweep outside the body; returns the count
    and which ("unseen" or "seen")."""
    sweep = turn_sweep(pose, footprint.body, math.copysign(min(abs(turn), TURN_BUMP_SWEEP), turn), footprint.margin)
    here = body_rectangle(pose, footprint.body, footprint.margin)
    n = occupancy.mark_polygons(sweep, keep_out=here)
    return (n, "unseen") if n else (occupancy.mark_polygons(sweep, keep_out=here, unseen_only=False), "seen")
