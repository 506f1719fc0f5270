"""The PyBullet implementation of the HAL: a simulated Spot that walks (kinematically, along ruckig
trajectories, stopping on contact), looks through its hand camera and grasps and drops objects
with real physics.

It exposes exactly the ``robots.hal.RobotBackend`` contract. Simulation-only facilities (the
world, collision events, ground-truth segmentation for the simulated detector, a frame stream for
recordings) are separate attributes that agents never receive.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass
from typing import Callable, Literal, Sequence

import numpy as np

from helios.schema import ConfigValueError, require_range
from robots.hal import (
    as_hand_pose,
    as_pixel,
    as_point,
    as_se2,
    BackendClosedError,
    CameraIntrinsics,
    CommandResult,
    GraspResult,
    InvalidCommandError,
    NavigateResult,
    Observation,
    PlaceResult,
    Reason,
    SE2Pose,
)
from robots.spot import kinematics, model
from robots.spot.motion import MotionConfig, check_arm_target, plan_arm, plan_base
from robots.transforms import invert_transform, rot_y, rot_z, transform_points, transform_to_pose
from sim import camera as sim_camera
from sim import grasping
from sim.camera import CameraConfig
from sim.grasping import GraspConfig
from sim.render_worker import RenderWorker, moving_state
from sim.spot import ContactGuard, SpotBody
from sim.world import FURNITURE, OBJECT, STRUCTURE, World, WorldConfig


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


@dataclass
class _Held:
    body_id: int
    constraint_id: int
    T_wrist_obj: np.ndarray   # where the object sat in the claw when the constraint was made


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


class SimSpotBackend:
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

    # ================================================================== arm
    def move_arm_joints(self, joints: Sequence[float]) -> CommandResult:
        self._check_open()
        q = check_arm_target(joints)
        return self._move_arm(q, phase="arm")

    def move_hand(self, T_body_hand: np.ndarray) -> CommandResult:
        self._check_open()
        T = as_hand_pose(T_body_hand)
        q = kinematics.inverse_kinematics(T, self.spot.arm_q())
        if q is None:
            return CommandResult(False, Reason.IK_FAILED, "no arm configuration within limits reaches that hand pose")
        return self._move_arm(q, phase="arm")

    def gaze_at(self, point: Sequence[float]) -> CommandResult:
        self._check_open()
        p_world = as_point(point, "gaze point")
        T_body_world = invert_transform(self.spot.T_world_body())
        p_body = transform_points(T_body_world, p_world[None])[0]
        q = self._gaze_solution(p_body)
        if q is None:
            return CommandResult(False, Reason.UNREACHABLE,
                                 f"cannot point the hand camera at ({p_world[0]:.2f}, {p_world[1]:.2f}, "
                                 f"{p_world[2]:.2f}) from here; turn the body towards it")
        return self._move_arm(q, phase="gaze")

    def _gaze_solution(self, p_body: np.ndarray) -> np.ndarray | None:
        cam = model.HAND_CAMERA
        R_hand_cam = kinematics.forward_kinematics(model.ARM_READY)
        R_hand_cam = (invert_transform(R_hand_cam["arm0.hand"]) @ R_hand_cam[cam.name])[:3, :3]
        axis = R_hand_cam[:, 2]
        tilt = math.atan2(axis[2], axis[0])  # the camera looks ~9 degrees above the hand's x axis
        base = np.array(self.config.gaze_hand_position)
        for dz, dx in ((0.0, 0.0), (-0.15, 0.1), (0.1, -0.1), (-0.3, 0.15), (0.0, -0.2)):
            hand_p = base + np.array([dx, 0.0, dz])
            if np.linalg.norm(p_body - hand_p) < 0.15:
                continue
            try:
                T = kinematics.look_at_hand_pose(hand_p, p_body)
            except ValueError:
                continue
            T[:3, :3] = T[:3, :3] @ rot_y(tilt)
            q = kinematics.inverse_kinematics(T, self.spot.arm_q())
            if q is not None:
                return q
        return None

    def stow_arm(self) -> CommandResult:
        """Stow; with an object in the claw, go to the carry pose instead (Spot refuses to stow it).

        From an extended arm the hand first retracts along a straight line: back towards the body
        at its current height, then up to the carry/gaze height, so neither the hand nor a held
        object is dragged through the furniture it was just working on.
        """
        self._check_open()
        t0 = self.world.time
        holding = self._held is not None
        T_cur = kinematics.hand_pose(self.spot.arm_q())
        x = T_cur[:3, 0]
        R_fwd = rot_z(-math.atan2(x[1], x[0])) @ T_cur[:3, :3]   # same pitch/roll, facing forward
        tuck = np.array(self.config.carry_hand_position if holding else self.config.gaze_hand_position)
        waypoints = []
        if T_cur[0, 3] > tuck[0] + 0.05 or T_cur[2, 3] < tuck[2] - 0.15:
            back = T_cur.copy()
            back[:3, 3] = [tuck[0], T_cur[1, 3] * 0.5, max(T_cur[2, 3], tuck[2] - 0.3)]
            waypoints.append(back)
            up = np.eye(4)
            up[:3, :3] = R_fwd if holding else kinematics.look_at_hand_pose(tuck, tuck + [1.0, 0.0, -0.3])[:3, :3]
            up[:3, 3] = tuck
            waypoints.append(up)
        phase = "carry" if holding else "stow"
        res = self._move_hand_linear(waypoints, phase)
        if not res:
            return res
        if holding:
            T = np.eye(4)
            T[:3, :3] = R_fwd
            T[:3, 3] = tuck
            q = kinematics.inverse_kinematics(T, self.spot.arm_q())
            if q is None:
                return CommandResult(False, Reason.IK_FAILED, "carry pose unreachable", duration=self.world.time - t0)
        else:
            q = np.array(model.ARM_STOW)
        res = self._move_arm(q, phase=phase)
        return CommandResult(res.success, res.reason, res.message, duration=self.world.time - t0)

    def _move_hand_linear(self, waypoints, phase: str, steps_per_metre: float = 12.0,
                          allow_gripper_contact: bool = False) -> CommandResult:
        """Move the hand through body-frame poses along (approximately) straight lines: each leg
        is cut into short joint-space moves between IK solutions of interpolated poses."""
        t0 = self.world.time
        T_prev = kinematics.hand_pose(self.spot.arm_q())
        for T_next in waypoints:
            n = max(1, int(math.ceil(np.linalg.norm(T_next[:3, 3] - T_prev[:3, 3]) * steps_per_metre)))
            for k in range(1, n + 1):
                T = T_prev.copy()
                T[:3, 3] = T_prev[:3, 3] + (T_next[:3, 3] - T_prev[:3, 3]) * k / n
                T[:3, :3] = T_prev[:3, :3] if k < n else T_next[:3, :3]
                q = kinematics.inverse_kinematics(T, self.spot.arm_q())
                if q is None:
                    continue   # skip an unreachable intermediate pose; the next one may be fine
                res = self._move_arm(q, phase, allow_gripper_contact)
                if not res:
                    return CommandResult(False, res.reason, res.message, duration=self.world.time - t0)
            T_prev = T_next
        return CommandResult(True, Reason.OK, duration=self.world.time - t0)

    def _move_arm(self, q_goal: np.ndarray, phase: str, allow_gripper_contact: bool = False) -> CommandResult:
        t0 = self.world.time
        traj = plan_arm(self.spot.arm_q(), q_goal, self.config.motion.arm)
        kinematic = self.config.kinematic_carry if self._held is not None else self.config.kinematic_free_arm
        if kinematic and not allow_gripper_contact:
            result = self._follow_arm_kinematically(traj, q_goal, phase, t0)
            if result is not None:
                return result
            traj = plan_arm(self.spot.arm_q(), q_goal, self.config.motion.arm)  # continue under physics
        ts = self.world.timestep
        n = max(1, int(math.ceil(traj.duration / ts)))
        every = self.config.contact_check_every
        for k in range(1, n + 1):
            q, qd = traj.at_time(k * ts)
            self.spot.command_arm(q, qd)
            self._step(1)
            if k % every == 0 or k == n:
                hit = self._new_arm_hits(phase, allow_gripper_contact)
                if hit:
                    self.spot.command_arm(self.spot.arm_q())
                    self._step(every)
                    link, body = hit
                    return CommandResult(False, Reason.COLLISION,
                                         f"{link} touched {self.world.bodies[body].name} during the {phase} move",
                                         duration=self.world.time - t0)
        # Let the position controllers converge on the final target.
        self.spot.command_arm(q_goal)
        settle_steps = int(self.config.arm_settle_time / ts)
        for _ in range(settle_steps):
            if np.max(np.abs(self.spot.arm_q() - q_goal)) < self.config.arm_tolerance:
                break
            self._step(1)
        self._check_slip()
        q_now = self.spot.arm_q()
        err = float(np.max(np.abs(q_now - q_goal)))
        hand_err = float(np.linalg.norm(kinematics.hand_pose(q_now)[:3, 3] - kinematics.hand_pose(q_goal)[:3, 3]))
        if err >= self.config.arm_tolerance and hand_err >= self.config.hand_tolerance:
            return CommandResult(False, Reason.TIMEOUT, f"arm stopped {err:.3f} rad ({100 * hand_err:.1f} cm) short "
                                                        f"of the target", duration=self.world.time - t0)
        return CommandResult(True, Reason.OK, duration=self.world.time - t0)

    def _follow_arm_kinematically(self, traj, q_goal: np.ndarray, phase: str, t0: float) -> CommandResult | None:
        """Replay an arm trajectory pose by pose (free space, or carrying with the held object
        moved along); None means 'touched an object, or the held object touched anything: use
        physics from here'."""
        times = traj.sample_times(self.config.motion.control_dt)
        carry = self._kinematic_carry()
        dynamic = self._physics_needed(held_is_kinematic=carry is not None)
        q_prev = self.spot.arm_q()
        guard = self._contact_guard("arm", carry, dynamic)
        for t_prev, t in zip(times[:-1], times[1:]):
            q, qd = traj.at_time(t)
            self.spot.set_arm_state(q, qd)
            if carry is not None:
                carry.follow()
            hits = self._new_base_hits(phase, guard, q)
            if hits:
                static = [(l, b) for l, b in hits if self.world.bodies[b].kind != OBJECT]
                if not static:
                    return None
                self.spot.set_arm_state(q_prev)
                if carry is not None:
                    carry.follow()
                self._advance(t - t_prev, dynamic)
                link, body = static[0]
                return CommandResult(False, Reason.COLLISION,
                                     f"{link} touched {self.world.bodies[body].name} during the {phase} move",
                                     duration=self.world.time - t0)
            if carry is not None and carry.touching():
                return None
            q_prev = q
            self._advance(t - t_prev, dynamic)
        self.spot.set_arm_state(q_goal)
        if carry is not None:
            carry.follow()
        return CommandResult(True, Reason.OK, duration=self.world.time - t0)

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

    def _new_arm_hits(self, phase: str, allow_gripper_contact: bool) -> tuple[str, int] | None:
        held = self._held.body_id if self._held else None
        current = set()
        for pt in self.world.contacts(self.spot.id):
            body, link = pt[2], pt[3]
            if body == held or body == self.spot.id:
                continue
            if allow_gripper_contact and link in self.spot.gripper_link_ids:
                continue
            current.add((self.spot.link_name.get(link, str(link)), body))
        self._record_contacts(sorted(current), phase)
        if held is not None and not allow_gripper_contact:
            # Outside grasping and placing, the held object is part of what the arm moves: jammed
            # against furniture or a wall it stops the arm and counts as a collision.
            for pt in self.world.contacts(held):
                other = pt[2]
                if other != self.spot.id and self.world.bodies.get(other) is not None and \
                        self.world.bodies[other].kind in (FURNITURE, STRUCTURE):
                    self._record_contacts(sorted(current) + [("held object", other)], phase)
                    return ("held object", other)
        if not current:
            return None
        # Only contacts with the static scene stop the arm; nudging a small object is allowed.
        static = [(l, b) for l, b in sorted(current) if self.world.bodies[b].kind != OBJECT]
        return static[0] if static else None

    # ================================================================== grasp and place
    def grasp(self, observation: Observation, pixel: tuple[int, int]) -> GraspResult:
        self._check_open()
        if not isinstance(observation, Observation):
            raise InvalidCommandError(f"grasp needs the Observation the pixel refers to, got {type(observation).__name__}")
        u, v = as_pixel(pixel, observation)
        t0 = self.world.time
        if self._held is not None:
            return GraspResult(False, Reason.ALREADY_HOLDING, "the claw already holds an object", holding=True)
        target = observation.point_at_pixel(u, v)
        if target is None:
            return GraspResult(False, Reason.NO_DEPTH, f"no depth at pixel ({u}, {v})")
        tgt = tuple(float(x) for x in target)
        cfg = self.config.grasp
        T_world_body = self.spot.T_world_body()
        shoulder = (T_world_body @ np.array([*model.SHOULDER_ORIGIN, 1.0]))[:3]
        reach = model.UPPER_ARM[0] + math.hypot(model.FOREARM[0], model.FOREARM[2]) + model.HAND_OFFSET
        dist = float(np.linalg.norm(target - shoulder))
        plan = grasping.plan_side_grasp(observation, target, T_world_body[:2, 3], cfg, model.HAND_OFFSET)
        T_body_world = invert_transform(T_world_body)
        solution = None
        for T_world_grasp in plan.hand_poses:
            T_grasp = T_body_world @ T_world_grasp
            T_pre = T_grasp.copy()
            T_pre[:3, 3] -= cfg.approach_back * T_grasp[:3, 0]
            T_pre[:3, 3] += cfg.approach_up * (T_body_world[:3, :3] @ np.array([0.0, 0.0, 1.0]))
            q_pre = kinematics.inverse_kinematics(T_pre, self.spot.arm_q())
            q_grasp = kinematics.inverse_kinematics(T_grasp, q_pre) if q_pre is not None else None
            if q_pre is not None and q_grasp is not None:
                solution = (T_grasp, q_pre, q_grasp)
                break
        if solution is None:
            reason = Reason.OUT_OF_REACH if dist > reach - 0.3 else Reason.IK_FAILED
            return GraspResult(False, reason, f"grasp point {dist:.2f} m from the shoulder cannot be reached from "
                                              f"here (arm length {reach:.2f} m); move closer", target_world=tgt)
        T_grasp, q_pre, q_grasp = solution
        res = self._move_arm(q_pre, "grasp")  # free-space move to the pre-grasp pose
        if not res:
            return GraspResult(False, res.reason, f"approach failed: {res.message}", target_world=tgt,
                               duration=self.world.time - t0)
        self._gripper_to(cfg.open_angle, cfg.close_force, cfg.close_speed * 2, 0.4)
        res = self._move_arm(q_grasp, "grasp", allow_gripper_contact=True)
        if res.reason == Reason.COLLISION:
            self._retreat_after_failed_grasp()
            return GraspResult(False, Reason.COLLISION, f"approach hit the scene: {res.message}", target_world=tgt,
                               duration=self.world.time - t0)
        fixed_link = self.spot.link_index["arm0.link_wr1"]
        moving_link = self.spot.link_index["arm0.link_fngr"]
        body = self._close_until_pinch(fixed_link, moving_link)
        if body is None:
            self._retreat_after_failed_grasp()
            return GraspResult(False, Reason.GRASP_MISSED, "the jaws closed without both touching an object",
                               target_world=tgt, duration=self.world.time - t0)
        cid = grasping.attach(self.world, self.spot.id, fixed_link, body, cfg.hold_force)
        T_wrist_obj = invert_transform(self.spot.link_pose("arm0.link_wr1")) @ self.world.pose(body)
        self._held = _Held(body, cid, T_wrist_obj)
        self._lift(T_body_world[:3, :3] @ np.array([0.0, 0.0, 1.0]))
        self._check_slip()
        if self._held is None:
            self._retreat_after_failed_grasp()
            return GraspResult(False, Reason.GRASP_SLIPPED, "the object slipped out of the claw during the lift",
                               target_world=tgt, duration=self.world.time - t0)
        return GraspResult(True, Reason.OK, f"holding {self.world.bodies[body].name}", holding=True,
                           target_world=tgt, duration=self.world.time - t0)

    def _lift(self, up_body: np.ndarray) -> None:
        """Raise the grasped object clear of its support: straight up by ``lift_height`` if the arm
        reaches, otherwise up and back towards the body (an arm at full stretch cannot go straight up)."""
        cfg = self.config.grasp
        T0 = kinematics.hand_pose(self.spot.arm_q())
        back = -np.array([T0[0, 0], T0[1, 0], 0.0])
        back /= max(np.linalg.norm(back), 1e-9)
        for up, away in ((1.0, 0.0), (0.8, 0.5), (0.6, 0.9), (0.4, 1.2)):
            T = T0.copy()
            T[:3, 3] += cfg.lift_height * (up * up_body + away * back)
            if kinematics.inverse_kinematics(T, self.spot.arm_q()) is not None:
                self._move_hand_linear([T], "grasp", allow_gripper_contact=True)
                return

    def _retreat_after_failed_grasp(self) -> None:
        """Open, back the hand out along its approach axis, close again."""
        cfg = self.config.grasp
        self._gripper_to(cfg.open_angle, cfg.close_force, 4.0, 0.3)
        T = kinematics.hand_pose(self.spot.arm_q())
        T[:3, 3] -= cfg.approach_back * T[:3, 0]
        q = kinematics.inverse_kinematics(T, self.spot.arm_q())
        if q is not None:
            self._move_arm(q, "grasp", allow_gripper_contact=True)
        self._gripper_to(0.0, cfg.close_force, 4.0, 0.3)

    def _close_until_pinch(self, fixed_link: int, moving_link: int) -> int | None:
        """Close the claw under motor force; return the object as soon as both jaws touch it.

        Attaching at the first pinch (rather than after the jaw stops) keeps the sweeping jaw from
        pushing the object out past the jaw tips.
        """
        cfg = self.config.grasp
        self.last_grasp_hand_pose = self.spot.T_world_hand()
        self.spot.command_gripper(0.0, cfg.close_force, cfg.close_speed)
        for _ in range(max(1, int(cfg.close_time / self.world.timestep))):
            self._step(1)
            body = grasping.pinched_object(self.world, self.spot.id, fixed_link, moving_link)
            if body is not None:
                self._step(4)  # let the jaw press in before the constraint freezes the relative pose
                return body
        return None

    def _gripper_to(self, angle: float, force: float, speed: float, duration: float) -> None:
        self.spot.command_gripper(angle, force, speed)
        self._step(max(1, int(duration / self.world.timestep)))

    def place(self, point: Sequence[float], release_height: float = 0.10) -> PlaceResult:
        self._check_open()
        p_world = as_point(point, "place point")
        if not (math.isfinite(release_height) and 0.0 <= release_height <= 1.0):
            raise InvalidCommandError(f"release_height must be within [0, 1] m, got {release_height}")
        if self._held is None:
            return PlaceResult(False, Reason.NOT_HOLDING, "nothing in the claw to place")
        t0 = self.world.time
        held = self._held.body_id
        T_world_hand = self.spot.T_world_hand()
        lo, hi = self.world.aabb(held)
        below = T_world_hand[2, 3] - lo[2]   # how far the object hangs below the hand frame
        centre_hand = invert_transform(T_world_hand) @ np.array([*(lo[:2] + hi[:2]) / 2, T_world_hand[2, 3], 1.0])
        T_world_body = self.spot.T_world_body()
        yaw = math.atan2(p_world[1] - T_world_body[1, 3], p_world[0] - T_world_body[0, 3])
        # Turn the hand (about world z) to face the release point, keeping its roll and the grip.
        x = T_world_hand[:3, 0]
        R = rot_z(yaw - math.atan2(x[1], x[0])) @ T_world_hand[:3, :3]
        T_target = np.eye(4)
        T_target[:3, :3] = R
        offset = R @ centre_hand[:3]
        T_target[:3, 3] = [p_world[0] - offset[0], p_world[1] - offset[1], p_world[2] + release_height + below]
        T_body = invert_transform(T_world_body) @ T_target
        q = kinematics.inverse_kinematics(T_body, self.spot.arm_q())
        if q is None:
            return PlaceResult(False, Reason.OUT_OF_REACH, "the release point cannot be reached from here; move closer",
                               duration=self.world.time - t0)
        res = self._move_arm(q, "place", allow_gripper_contact=True)
        if not res.success:   # never let go somewhere it was not meant to
            return PlaceResult(False, res.reason, f"did not reach the release pose: {res.message}",
                               duration=self.world.time - t0)
        release = tuple(float(v) for v in self.spot.T_world_hand()[:3, 3])
        self._release()
        T_back = kinematics.hand_pose(self.spot.arm_q())
        T_back[:3, 3] -= self.config.grasp.release_retreat * T_back[:3, 0]
        T_back[:3, 3] += 0.05 * (invert_transform(T_world_body)[:3, :3] @ np.array([0.0, 0.0, 1.0]))
        q_back = kinematics.inverse_kinematics(T_back, self.spot.arm_q())
        if q_back is not None:
            self._move_arm(q_back, "place", allow_gripper_contact=True)
        self._gripper_to(0.0, self.config.grasp.close_force, 4.0, 0.2)
        self.world.settle([held])
        return PlaceResult(True, Reason.OK, f"released {self.world.bodies[held].name}", duration=self.world.time - t0,
                           release_point=release)

    def _release(self) -> None:
        if self._held is None:
            return
        self.last_release = (self._held.body_id, self.world.position(self._held.body_id))
        grasping.detach(self.world, self._held.constraint_id, self.spot.id, self._held.body_id)
        self._held = None
        self._gripper_to(self.config.grasp.open_angle, self.config.grasp.close_force, 4.0, 0.25)

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
    def set_claw(self, angle: float) -> None:
        """Drive the claw joint to ``angle`` (0 closed, -pi/2 open). Opening while holding lets go."""
        self._check_open()
        cfg = self.config.grasp
        angle = float(min(max(angle, model.GRIPPER_LIMITS[0]), model.GRIPPER_LIMITS[1]))
        if self._held is not None and angle < -0.05:
            self._release()
            return
        self._gripper_to(angle, cfg.close_force, 4.0, 0.25 if angle < -0.05 else 0.2)

    def settle_loose_objects(self, max_time: float = 2.0) -> None:
        """Let objects still moving (e.g. just dropped) come to rest: real time runs on between a
        robot's commands, while the simulation only runs while asked to."""
        if self._held is not None:
            return
        moving = [b.body_id for b in self.world.bodies_of_kind(OBJECT) if not self.world.is_at_rest(b.body_id)]
        if moving:
            self.world.settle(moving, max_time=max_time)

    def render_at(self, T_world_cam: np.ndarray) -> Observation:
        """A hand-camera frame rendered from an arbitrary camera pose."""
        T = np.asarray(T_world_cam, dtype=float)
        frame = sim_camera.render(self.world, self.intrinsics, T, self.config.camera)
        return self._make_observation(self._capture_state(T), frame)

    @property
    def gripper_angle(self) -> float:
        return self.spot.gripper_q()

    def arm_is_stowed(self, tol: float = 0.05) -> bool:
        return bool(np.max(np.abs(self.spot.arm_q() - np.array(model.ARM_STOW))) < tol)

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
