"""The PyBullet implementation of the HAL: a simulated Spot that walks (kinematically, along ruckig
trajectories, stopping on contact), looks through its hand camera and grasps and drops objects
with real physics.

It exposes exactly the ``robots.hal.RobotBackend`` contract. Simulation-only facilities (the
world, collision events, ground-truth segmentation for the simulated detector, a frame stream for
recordings) are separate attributes that agents never receive.

:class:`SimSpotBackend` is one class in three modules: this one holds its construction and state,
observation and frames, the base walk, what every motion shares (contact bookkeeping and guards,
the held object's kinematic ride and slip check), time (physics steps, kinematic advances, the
pacer, the frame stream) and the small HAL commands; the arm's motion is the mixin
:class:`robots.spot.sim_arm.SimArm`, the grasp, place and claw physics the mixin
:class:`robots.spot.sim_manipulation.SimManipulation`. Callers import everything from here.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass
from typing import Callable, Literal, Sequence

import numpy as np

from helios.schema import ConfigValueError, require_range
from robots.hal import (
    as_se2,
    BackendClosedError,
    CameraIntrinsics,
    CommandResult,
    NavigateResult,
    Observation,
    Reason,
    SE2Pose,
)
from robots.spot import model
from robots.spot.motion import MotionConfig, plan_base
from robots.spot.sim_arm import SimArm
from robots.spot.sim_manipulation import _Held, SimManipulation
from robots.transforms import invert_transform, transform_to_pose
from sim import camera as sim_camera
from sim import grasping
from sim.camera import CameraConfig
from sim.grasping import GraspConfig
from sim.render_worker import RenderWorker, moving_state
from sim.spot import ContactGuard, SpotBody
from sim.world import OBJECT, World, WorldConfig


@dataclass(frozen=True)
class SimBackendConfig:
    world: WorldConfig = WorldConfig()
    camera: CameraConfig = CameraConfig()
    motion: MotionConfig = MotionConfig()
    grasp: GraspConfig = GraspConfig()
    stream_hz: float = 2.0                 # hand-camera frames per simulated second handed to listeners
    # "process": streamed frames render in a worker process, overlapping physics (needs a spare
    # core); "inline": render in this process (use when several simulations share the cores).
    stream_renderer: Literal["process", "inline"] = "process"
    # Body frame, m: high and close to the body, so the hand stays above furniture and inside the
    # footprint the base was checked with while it turns the camera.
    gaze_hand_position: tuple[float, float, float] = (0.45, 0.0, 0.50)
    carry_hand_position: tuple[float, float, float] = (0.55, 0.0, 0.50)  # body frame, m (object held in front)
    arm_tolerance: float = 0.03            # rad, per joint, for an arm move to count as arrived ...
    hand_tolerance: float = 0.015          # ... or m of hand position error (a loaded arm sags a little)
    arm_settle_time: float = 0.6           # s allowed after a trajectory ends to reach the tolerance
    contact_check_every: int = 4           # physics steps between arm contact checks
    # Free-space arm moves (nothing held, no intended gripper contact) replay the ruckig trajectory
    # kinematically with collision checks at every control sample, and hand over to physics the
    # moment the arm touches a movable object. Grasping and placing always run physics.
    kinematic_free_arm: bool = True
    # Carrying: base and arm moves with an object in the claw (outside grasping and placing) move
    # the object rigidly with the wrist, pose by pose, while neither it nor the robot touches
    # anything, and hand over to physics (the finite-force grasp constraint, slips, jams) the moment
    # the held object touches the scene. false: every carrying move steps physics at 240 Hz, which
    # was ~40 % of a carrying episode's wall time (see README, "The simulated Spot").
    kinematic_carry: bool = True
    # Kinematic base walks and free-space arm moves (nothing held, nothing else moving) query
    # contacts only where they are possible: one clearance query looking this far (m) vouches for
    # the poses from which the robot cannot reach anything (sim.spot.ContactGuard); the contacts
    # found are the same. 0: a contact query at every pose.
    clearance_horizon: float = 0.5

    def __post_init__(self) -> None:
        require_range(self, "stream_hz", 0.0, 1000.0)     # 0 = no frame stream
        for name in ("gaze_hand_position", "carry_hand_position"):
            v = getattr(self, name)
            if not all(isinstance(c, (int, float)) and math.isfinite(c) and abs(c) <= 2.0 for c in v):
                raise ConfigValueError(f"{name} must be 3 numbers within 2 m of the body, got {v}")
        require_range(self, "arm_tolerance hand_tolerance", 0.0, 1.0, lo_open=True)
        require_range(self, "arm_settle_time", 0.0, 60.0)
        require_range(self, "contact_check_every", 1, 10000)
        require_range(self, "clearance_horizon", 0.0, 5.0)


class MotionInterrupted(Exception):
    """Raised by a :attr:`SimSpotBackend.pacer` to end the motion in progress where it is (the fake
    Spot's e-stop, stop command, lost lease or power cut). The robot stays where it stopped."""


@dataclass(frozen=True)
class CollisionEvent:
    """The robot started touching part of the scene (one event per contact onset)."""

    time: float
    robot_link: str
    body: str
    phase: str


class _KinematicCarry:
    """Moves a held object rigidly with the wrist during one kinematic move.

    The object keeps the pose relative to the wrist it had when the move began (where the grasp
    constraint and gravity left it), so handing back to physics resumes from that balance.
    Why not physics: the base and the arm are placed pose by pose every control step (50 ms), so
    a physically tracked object is yanked after each jump by the constraint at its force limit;
    rigid carriage is closer to a real Spot's smooth carry and skips ~12 solver steps per pose.
    What it leaves out: inertial slip under the base's acceleration (1 m/s^2 against a 60 N
    hold); contact with the scene hands the object back to physics, where jams and slips happen
    as before.
    """

    def __init__(self, world: World, spot: SpotBody, body_id: int):
        self.world = world
        self.spot = spot
        self.body_id = body_id
        self.T_wrist_obj = invert_transform(spot.link_pose("arm0.link_wr1")) @ world.pose(body_id)

    def follow(self) -> None:
        """Put the object where the wrist now holds it, at rest."""
        T = self.spot.link_pose("arm0.link_wr1") @ self.T_wrist_obj
        pos, quat = transform_to_pose(T)
        c = self.world.client
        c.resetBasePositionAndOrientation(self.body_id, pos.tolist(), quat.tolist())
        c.resetBaseVelocity(self.body_id, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])

    def touching(self) -> bool:
        """Whether the object touches anything but the robot (closest-point queries, no step)."""
        lo, hi = self.world.body_aabb(self.body_id)
        lo = [v - 0.01 for v in lo]
        hi = [v + 0.01 for v in hi]
        c = self.world.client
        others = [self.world.ground_id, *self.world.bodies_overlapping(lo, hi, (self.body_id, self.spot.id))]
        return any(c.getClosestPoints(self.body_id, other, distance=0.0) for other in others)


class SimSpotBackend(SimArm, SimManipulation):
    """Spot in a PyBullet :class:`World` behind the :class:`robots.hal.RobotBackend` contract."""

    def __init__(self, world: World, spot: SpotBody, config: SimBackendConfig = SimBackendConfig(),
                 owns_world: bool = True):
        self.world = world
        self.spot = spot
        self.config = config
        self._owns_world = owns_world
        native = model.HAND_CAMERA
        self.intrinsics = CameraIntrinsics(native.width, native.height, native.fx, native.fy, native.cx,
                                           native.cy).scaled(config.camera.width, config.camera.height)
        self.collision_events: list[CollisionEvent] = []
        # Sim-only record of the last release (object body, its world position when the claw opened),
        # for the metrics judge.
        self.last_release: tuple[int, np.ndarray] | None = None
        self.last_grasp_hand_pose: np.ndarray | None = None   # T_world_hand when the jaws started closing
        self._active_contacts: set[int] = set()
        self._held: _Held | None = None
        self._frame_id = 0
        self._segmentations: OrderedDict[int, np.ndarray] = OrderedDict()
        self._recent: OrderedDict[int, Observation] = OrderedDict()
        self._listeners: list[Callable[[Observation], None]] = []
        self._next_stream = world.time
        self._render_worker: RenderWorker | None = None
        self._step_remainder = 0.0
        self._closed = False
        # pacer(dt): called after every dt of simulated motion (a physics step or a kinematic
        # control step). The fake Spot sets it to run motions in (scaled) wall-clock time and to
        # end them (MotionInterrupted) when the robot is stopped; None = as fast as possible.
        self.pacer: Callable[[float], None] | None = None

    # ================================================================== observation
    def observe(self) -> Observation:
        self._check_open()
        T_world_cam = self.spot.T_world_camera()
        frame = sim_camera.render(self.world, self.intrinsics, T_world_cam, self.config.camera)
        return self._make_observation(self._capture_state(T_world_cam), frame)

    def _capture_state(self, T_world_cam: np.ndarray) -> dict:
        """Everything an observation reports besides the images, read at capture time."""
        self._frame_id += 1
        return {"T_world_cam": T_world_cam, "T_world_body": self.spot.T_world_body(), "stamp": self.world.time,
                "holding": self.holding, "joint_positions": self.spot.joint_positions(), "frame_id": self._frame_id}

    def _make_observation(self, state: dict, frame) -> Observation:
        obs = Observation(rgb=frame.rgb, depth=frame.depth, intrinsics=self.intrinsics, **state)
        self._segmentations[state["frame_id"]] = frame.segmentation
        self._recent[state["frame_id"]] = obs
        while len(self._segmentations) > 16:
            self._segmentations.popitem(last=False)
            self._recent.popitem(last=False)
        return obs

    def frame_for(self, rgb: np.ndarray) -> tuple[Observation, np.ndarray]:
        """Sim-only: the recent observation whose ``rgb`` array this is, and its ground-truth
        segmentation. Lets simulated perception keep the image-only Detector protocol."""
        for obs in reversed(self._recent.values()):
            if obs.rgb is rgb:
                return obs, self._segmentations[obs.frame_id]
        raise KeyError("this image is not one of the last 16 frames this simulated robot captured")

    def segmentation_for(self, obs: Observation) -> np.ndarray:
        """Ground-truth instance segmentation of a recent observation (sim only; for the simulated
        detector and metrics, never for agents). Raw PyBullet ids; decode with ``sim.camera``."""
        try:
            return self._segmentations[obs.frame_id]
        except KeyError:
            raise KeyError(f"segmentation of frame {obs.frame_id} is no longer kept (only the last 16 are)") from None

    def add_frame_listener(self, fn: Callable[[Observation], None]) -> None:
        """Call ``fn`` with a fresh observation every 1/stream_hz simulated seconds during motions.

        With ``stream_renderer="process"`` frames are rendered in a worker process (started here)
        and reach ``fn`` a little later, in order; ``drain_frames()`` waits for all of them.
        """
        self._listeners.append(fn)
        self._next_stream = self.world.time
        if self.config.stream_renderer == "process" and self._render_worker is None and self.config.stream_hz > 0:
            self._render_worker = RenderWorker(self.world)

    @property
    def holding(self) -> bool:
        return self._held is not None

    @property
    def held_body(self) -> int | None:
        return self._held.body_id if self._held else None

    # ================================================================== base
    def navigate_to(self, goal: SE2Pose, via: Sequence[SE2Pose] = ()) -> NavigateResult:
        self._check_open()
        goal = as_se2(goal, "goal")
        via = [as_se2(v, f"via[{i}]") for i, v in enumerate(via)]
        return self.follow_base_path(plan_base(self.spot.base_pose(), [*via, goal], self.config.motion.base))

    def follow_base_path(self, path) -> NavigateResult:
        """Walk the body along a timed SE2 path (anything with ``sample_times(dt)`` and
        ``pose_at(t)``: our ruckig trajectories, or an SE2 trajectory command a robot was sent),
        checking for contact every control step and stopping at the last free pose on contact."""
        self._check_open()
        t0, travelled = self.world.time, 0.0
        prev = self.spot.base_pose()
        times = path.sample_times(self.config.motion.control_dt)
        carry = self._kinematic_carry()
        dynamic = self._physics_needed(held_is_kinematic=carry is not None)
        guard = self._contact_guard("base", carry, dynamic)
        skip = self._poses_skippable(guard)
        placed = True           # the body stands at ``prev``
        for t_prev, t in zip(times[:-1], times[1:]):
            pose = path.pose_at(t)
            placed = not (skip and guard.vouches(pose))
            if not placed:
                self._record_contacts([], "base")
            else:
                self.spot.set_base_pose(pose)
                if carry is not None:
                    carry.follow()
                hits = self._new_base_hits("base", guard, pose)
                if hits:
                    self.spot.set_base_pose(prev)
                    if carry is not None:
                        carry.follow()
                    self._advance(t - t_prev, dynamic)
                    link, body = hits[0]
                    return NavigateResult(False, Reason.COLLISION,
                                          f"{link} touched {self.world.bodies[body].name} at "
                                          f"({pose.x:.2f}, {pose.y:.2f}); stopped at the last free pose",
                                          duration=self.world.time - t0, final_pose=prev, collided=True,
                                          distance=travelled)
                if carry is not None and carry.touching():
                    carry, dynamic = None, True     # pressed against something: physics from here on
            travelled += prev.distance_to(pose)
            prev = pose
            self._advance(t - t_prev, dynamic)
        if not placed:
            self.spot.set_base_pose(prev)
        self._check_slip()
        return NavigateResult(True, Reason.OK, duration=self.world.time - t0, final_pose=self.spot.base_pose(),
                              distance=travelled)

    def _new_base_hits(self, phase: str = "base", guard: ContactGuard | None = None, state=None
                       ) -> list[tuple[str, int]]:
        """Robot-scene overlaps at the current (kinematically set) pose; records contact onsets.
        None, without a query, where ``guard`` vouches for the move's ``state`` (base pose or arm
        joints)."""
        if guard is not None and guard.free(state):
            hits = []
        else:
            exclude = [self._held.body_id] if self._held else []
            hits = self.spot.touching(exclude_bodies=exclude)
        self._record_contacts(hits, phase)
        return hits

    def _record_contacts(self, hits, phase: str) -> None:
        """One collision event per scene body the robot starts touching (not per link pair)."""
        current: dict[int, str] = {}
        for link, body in hits:
            current.setdefault(body, link)
        for body, link in current.items():
            if body not in self._active_contacts:
                self.collision_events.append(CollisionEvent(self.world.time, link, self.world.bodies[body].name, phase))
        self._active_contacts = set(current)

    # ================================================================== shared by every motion
    # Contact guards for kinematic moves, and the held object as base and arm moves see it.
    def _contact_guard(self, kind: str, carry, dynamic: bool) -> ContactGuard | None:
        """The guard that spares a kinematic move's contact queries where they cannot find
        anything (None: check every pose): only while nothing is held and nothing else moves."""
        if carry is not None or dynamic or self._held is not None or self.config.clearance_horizon <= 0:
            return None
        return ContactGuard(self.spot, self.config.clearance_horizon, kind)

    def _poses_skippable(self, guard: ContactGuard | None) -> bool:
        """Whether a kinematic walk may leave out the poses ``guard`` vouches for, putting the body
        only where a query needs it and at the end (one reset call fewer per pose). Nothing reads
        the robot's state between two poses then: no physics steps, no held object follows, no
        listener is streamed (their frames would show the skipped poses), and no pacer plays the
        motion in real time (the fake Spot reports the pose it reads as it walks). Arm moves set every
        pose: skipped the same way, arm poses left an object the robot grasped later 1e-7 m from
        where it came to rest otherwise (trusting, val-00013 and 14): PyBullet keeps something
        of the history of joint resets that a later physics step sees."""
        return guard is not None and not self._listeners and self.pacer is None

    def _kinematic_carry(self) -> "_KinematicCarry | None":
        """The held object's rigid ride on the wrist for the next move (None: nothing held, or
        ``kinematic_carry`` is off)."""
        if self._held is None or not self.config.kinematic_carry:
            return None
        return _KinematicCarry(self.world, self.spot, self._held.body_id)

    def _check_slip(self) -> None:
        """Let go if the object was dragged out of its grasp pose (the hold force is finite, so a
        heavy or snagged object can slip); beyond ``slip_distance`` the claw no longer holds it."""
        if self._held is None:
            return
        expected = self.spot.link_pose("arm0.link_wr1") @ self._held.T_wrist_obj
        actual = self.world.pose(self._held.body_id)
        if np.linalg.norm(expected[:3, 3] - actual[:3, 3]) > self.config.grasp.slip_distance:
            grasping.detach(self.world, self._held.constraint_id, self.spot.id, self._held.body_id)
            self._held = None

    # ================================================================== robot-level primitives
    # What a real Spot executes that the HAL does not name; the fake Spot server uses them to
    # execute SDK commands on this simulation.
    def render_at(self, T_world_cam: np.ndarray) -> Observation:
        """A hand-camera frame rendered from an arbitrary camera pose."""
        T = np.asarray(T_world_cam, dtype=float)
        frame = sim_camera.render(self.world, self.intrinsics, T, self.config.camera)
        return self._make_observation(self._capture_state(T), frame)

    # ================================================================== misc
    def stand(self) -> CommandResult:
        self._check_open()
        return CommandResult(True, Reason.OK, "standing")

    def stop(self) -> CommandResult:
        self._check_open()
        self.spot.command_arm(self.spot.arm_q())
        return CommandResult(True, Reason.OK, "holding position")

    def close(self) -> None:
        if not self._closed:
            self.drain_frames()
            self._closed = True
            if self._render_worker is not None:
                self._render_worker.close()
            if self._owns_world:
                self.world.close()

    def __enter__(self) -> "SimSpotBackend":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _check_open(self) -> None:
        if self._closed:
            raise BackendClosedError("this backend has been closed")

    # ================================================================== time
    def _physics_needed(self, held_is_kinematic: bool = False) -> bool:
        """Physics must run while something can move by itself: a held object (unless it rides
        kinematically on the wrist for this move) or another object still moving."""
        held = self._held.body_id if self._held is not None else None
        if held is not None and not held_is_kinematic:
            return True
        return any(b.body_id != held and not self.world.is_at_rest(b.body_id)
                   for b in self.world.bodies_of_kind(OBJECT))

    def _advance(self, dt: float, dynamic: bool) -> None:
        if dynamic:
            self._step_remainder += dt
            n = int(self._step_remainder / self.world.timestep + 1e-9)
            self._step_remainder -= n * self.world.timestep
            self._step(n)
        else:
            self.world.advance(dt)
            self._stream()
            if self.pacer is not None:
                self.pacer(dt)

    def _step(self, n: int) -> None:
        for _ in range(n):
            self.world.step()
            self._stream()
            if self.pacer is not None:
                self.pacer(self.world.timestep)

    def _stream(self) -> None:
        if not self._listeners or self.config.stream_hz <= 0:
            return
        if self._render_worker is not None and self._render_worker.pending:
            self._deliver(self._render_worker.poll())
        if self.world.time + 1e-9 < self._next_stream:
            return
        period = 1.0 / self.config.stream_hz
        while self._next_stream <= self.world.time + 1e-9:
            self._next_stream += period
        if self.config.stream_renderer == "inline":
            obs = self.observe()
            for fn in self._listeners:
                fn(obs)
            return
        if self._render_worker is None:
            self._render_worker = RenderWorker(self.world)
        T_world_cam = self.spot.T_world_camera()
        poses, joints = moving_state(self.world, self.spot.id, self.spot.moving_joint_indices)
        request = sim_camera.camera_request(self.intrinsics, T_world_cam, self.config.camera, self.world.ground_id)
        done = self._render_worker.submit(poses, joints, request, self.config.camera, self._capture_state(T_world_cam))
        self._deliver(done)

    def _deliver(self, results) -> None:
        for state, frame in results:
            obs = self._make_observation(state, frame)
            for fn in self._listeners:
                fn(obs)

    def drain_frames(self) -> None:
        """Block until every streamed frame has been rendered and handed to the listeners."""
        if self._render_worker is not None:
            self._deliver(self._render_worker.poll(block=True))
