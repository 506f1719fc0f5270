"""The scripted demo agent: one pick-and-place in the demo layout (two tables and a mug), through
HAL calls only (``navigate_to``, ``gaze_at``, ``observe``, ``grasp``, ``stow_arm``, ``place``).

Walk to the pick table, look at the mug with the hand camera, grasp it by pixel, carry it, release
it 10 cm above the place table (20 cm inside its near edge), stow. It is allowed one shortcut an
agent never gets: it is told the layout instead of perceiving it. What it is told comes in one of
two forms, both :class:`Hints`:

* :class:`DemoHints` (``tools spot``: a real robot or the fake): the tables and where the mug
  should be, measured from the robot's start pose (``from_layout``) or the fake's ground truth
  (``from_facts``); the robot's position comes from ``observe``, the mug's pixel from projecting
  its expected position into the image.
* :class:`GroundTruthHints` (``tools demo``, in the simulator): the tables' true poses, the robot's
  true pose and the mug's pixels in the ground-truth segmentation.

The ``scripted-demo`` entry of ``tasks.registry`` builds it for ``tools spot``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from robots.hal import RobotFault, SE2Pose

BODY_FRONT = 0.45   # m from Spot's body centre to its front (body box + hips)


# ============================================================================ what the script is told
class Table(Protocol):
    """A table top the script walks to."""

    name: str

    @property
    def centre(self): ...                                  # odom frame, m (x, y)

    @property
    def top_height(self) -> float: ...                     # m

    def extent_along(self, d: np.ndarray) -> float: ...     # half-width of the top along unit direction d


class Hints(Protocol):
    """What the scripted demo knows in advance, and how it finds the robot and the mug."""

    pick_table: Table
    place_table: Table
    not_found: str                                         # why the mug is missing from an image

    @property
    def mug_position(self): ...                            # (x, y, z), m

    def robot_xy(self, robot) -> np.ndarray: ...           # where the robot stands now

    def mug_pixel(self, robot, obs, look: np.ndarray) -> tuple[int, int] | None: ...


@dataclass(frozen=True)
class TableHint:
    """A table the scripted demo is told about (an agent would perceive it)."""

    name: str
    centre: tuple[float, float]          # odom frame, m
    yaw: float                           # rad
    half_extents: tuple[float, float]    # top, along its own x and y, m
    top_height: float                    # m

    def extent_along(self, d: np.ndarray) -> float:
        """Half-width of the top along unit direction ``d`` (support function of its rectangle)."""
        u = np.array([math.cos(self.yaw), math.sin(self.yaw)])
        v = np.array([-math.sin(self.yaw), math.cos(self.yaw)])
        return abs(float(d @ u)) * self.half_extents[0] + abs(float(d @ v)) * self.half_extents[1]


@dataclass(frozen=True)
class DemoHints:
    """What the scripted demo knows in advance: the two tables and where the mug should be."""

    pick_table: TableHint
    place_table: TableHint
    mug_position: tuple[float, float, float]
    not_found = "mug not in view"

    @staticmethod
    def from_facts(facts: dict) -> "DemoHints":
        """From the fake's (or the simulator's) ground truth (``launch.scene_facts``)."""
        def table(f):
            return TableHint(f["name"], tuple(map(float, f["centre"])), float(f["yaw"]),
                             tuple(map(float, f["half_extents"])), float(f["top_height"]))
        return DemoHints(table(facts["pick_table"]), table(facts["place_table"]),
                         tuple(float(v) for v in facts["mug_position"]))

    @staticmethod
    def from_layout(start: SE2Pose) -> "DemoHints":
        """The demo layout (``sim.scenes.demo.DemoLayout``) measured from the robot's start pose:
        what a real robot needs when the room is set up like the demo scene."""
        from sim.scenes.demo import DemoLayout

        lay = DemoLayout()

        def at(x: float, y: float) -> tuple[float, float]:
            p = start.compose(SE2Pose(x, y, 0.0))
            return (p.x, p.y)

        pick = TableHint("table_pick", at(*lay.pick_table_xy), start.yaw, (0.4, 0.4), lay.table_height)
        place = TableHint("table_place", at(*lay.place_table_xy), start.yaw + 0.3, (0.5, 0.35), lay.table_height)
        mx, my = at(lay.pick_table_xy[0] - 0.22, lay.pick_table_xy[1])
        return DemoHints(pick, place, (mx, my, lay.table_height))   # the mug stands on the table

    def robot_xy(self, robot) -> np.ndarray:
        here = robot.observe().body_pose
        return np.array([here.x, here.y])

    def mug_pixel(self, robot, obs, look: np.ndarray) -> tuple[int, int] | None:
        return _pixel_of(obs, look)


class WorldTable:
    """A table of the simulated world, read from the world whenever asked (ground truth)."""

    def __init__(self, world, name: str):
        self._world = world
        self.name = name

    @property
    def centre(self) -> np.ndarray:
        return self._world.position(self._world.body(self.name).body_id)[:2]

    @property
    def top_height(self) -> float:
        return self._world.body(self.name).extra["top_height"]

    def extent_along(self, d: np.ndarray) -> float:
        """Half-width of the top along unit direction ``d`` (support function of its rectangle)."""
        info = self._world.body(self.name)
        hx, hy = info.extra["top_half_extents"]
        T = self._world.pose(info.body_id)
        u, v = T[:2, 0], T[:2, 1]
        return abs(float(d @ u)) * hx + abs(float(d @ v)) * hy


class GroundTruthHints:
    """The simulator's ground truth of the demo scene (``sim.scenes.demo.build_demo_scene``): the
    robot's true pose (no ``observe``) and the mug's pixels in the segmentation, not a detector.
    ``say`` gets the mug's pixel count."""

    not_found = "mug not visible"

    def __init__(self, world, scene: dict, backend, say: Callable[[str], None] = print):
        self.pick_table = WorldTable(world, scene["pick_table"])
        self.place_table = WorldTable(world, scene["place_table"])
        self.mug = scene["mug"]
        self.mug_position = world.position(self.mug)
        self._backend = backend
        self._say = say

    def robot_xy(self, robot) -> np.ndarray:
        return np.array(self._backend.spot.base_pose().as_tuple()[:2])

    def mug_pixel(self, robot, obs, look: np.ndarray) -> tuple[int, int] | None:
        from sim.camera import decode_body_ids

        ids = decode_body_ids(self._backend.segmentation_for(obs))
        vs, us = np.nonzero(ids == self.mug)
        if len(us) == 0:
            return None
        pixel = (int(np.median(us)), int(np.median(vs)))
        self._say(f"[demo]    mug covers {len(us)} pixels; grasping at pixel {pixel}")
        return pixel


# ============================================================================ the script
@dataclass
class AgentStep:
    name: str
    ok: bool
    detail: str
    seconds: float


@dataclass
class AgentOutcome:
    success: bool                      # every step succeeded (the agent's own view)
    steps: list[AgentStep] = field(default_factory=list)
    fault: str | None = None           # a robot fault that ended the run, if any
    place_target: tuple[float, float, float] | None = None


def approach_pose(table: Table, target_xy: np.ndarray, robot_xy: np.ndarray, clearance: float) -> SE2Pose:
    """A pose facing ``target_xy`` from the robot's side, ``clearance`` in front of the table edge,
    shifted sideways so the target lies on the robot's forward axis."""
    centre = np.asarray(table.centre, dtype=float)
    d = target_xy - robot_xy
    d = d / np.linalg.norm(d)
    p = centre - d * (table.extent_along(d) + BODY_FRONT + clearance)
    perp = np.array([-d[1], d[0]])
    p = p + perp * float((target_xy - centre) @ perp)
    return SE2Pose(p[0], p[1], math.atan2(d[1], d[0]))


def _pixel_of(obs, point) -> tuple[int, int] | None:
    p_cam = np.linalg.inv(obs.T_world_cam) @ np.append(np.asarray(point, dtype=float), 1.0)
    if p_cam[2] <= 0:
        return None
    (u, v), _ = obs.intrinsics.project(p_cam[:3])
    u, v = int(round(float(u))), int(round(float(v)))
    if 0 <= u < obs.intrinsics.width and 0 <= v < obs.intrinsics.height:
        return u, v
    return None


class ScriptedDemo:
    """The scripted pick-and-place. ``run(robot)`` drives the robot through the HAL once and returns
    the :class:`AgentOutcome`. Each step is printed through ``say`` as ``[tag] n. name  ok|FAILED
    detail  [seconds]`` (``decimals`` digits) and handed to ``on_step``; a robot fault ends the run
    and is reported in the outcome."""

    name = "scripted-demo"

    def __init__(self, hints: Hints, say: Callable[[str], None] = print, tag: str = "spot", decimals: int = 2,
                 on_step: Callable[[AgentStep], None] | None = None):
        self.hints = hints
        self._say = say
        self._tag = tag
        self._decimals = decimals
        self._on_step = on_step

    def run(self, robot) -> AgentOutcome:
        hints, say = self.hints, self._say
        out = AgentOutcome(success=False)

        def step(name: str, result) -> bool:
            ok = bool(result)
            detail = result.message or result.reason.value
            out.steps.append(AgentStep(name, ok, detail, float(result.duration)))
            say(f"[{self._tag}] {len(out.steps)}. {name:<34} {'ok' if ok else 'FAILED':<6} {detail}  "
                f"[{result.duration:.{self._decimals}f} s]")
            if self._on_step is not None:
                self._on_step(out.steps[-1])
            return ok

        mug = np.asarray(hints.mug_position, dtype=float)
        try:
            robot_xy = hints.robot_xy(robot)
            if not step("walk to the pick table", robot.navigate_to(
                    approach_pose(hints.pick_table, mug[:2], robot_xy, 0.30))):
                return out
            look = mug + np.array([0.0, 0.0, 0.05])
            if not step("look at the mug with the hand camera", robot.gaze_at(look)):
                return out
            obs = robot.observe()
            pixel = hints.mug_pixel(robot, obs, look)
            if pixel is None:
                out.steps.append(AgentStep("find the mug in the image", False, hints.not_found, 0.0))
                return out
            if not step(f"grasp at pixel {pixel}", robot.grasp(obs, pixel)):
                return out
            if not step("carry pose", robot.stow_arm()):
                return out
            robot_xy = hints.robot_xy(robot)
            centre = np.asarray(hints.place_table.centre, dtype=float)
            d = (centre - robot_xy) / np.linalg.norm(centre - robot_xy)
            # release 20 cm inside the near edge of the table top, as the paper's place heuristic does
            place_xy = centre - d * hints.place_table.extent_along(d) + d * 0.20
            if not step("walk to the place table", robot.navigate_to(
                    approach_pose(hints.place_table, place_xy, robot_xy, 0.20))):
                return out
            target = (float(place_xy[0]), float(place_xy[1]), hints.place_table.top_height)
            out.place_target = target
            if not step("release 10 cm above the table", robot.place(target, release_height=0.10)):
                return out
            step("stow the arm", robot.stow_arm())
            out.success = all(s.ok for s in out.steps)
        except RobotFault as exc:
            out.fault = f"{type(exc).__name__}: {exc}"
            say(f"[{self._tag}] robot fault: {out.fault}")
        return out


def physical_outcome(world, scene: dict, place_target=None) -> dict:
    """Ground truth after a run in the simulator: where the mug came to rest (sim/fake only)."""
    from sim.grasping import support_body

    mug = scene["mug"]
    world.settle([b.body_id for b in world.bodies_of_kind("object")], max_time=3.0)
    final = world.position(mug)
    support = support_body(world, mug)
    resting_on = world.bodies[support].name if support is not None else None
    settled = world.is_at_rest(mug)
    out = {"resting_on": resting_on, "settled": bool(settled), "final_position": [float(v) for v in final],
           "success": bool(resting_on == scene["place_table"] and settled)}
    if place_target is not None:
        out["offset_from_target"] = float(np.linalg.norm(final[:2] - np.asarray(place_target[:2])))
    return out
