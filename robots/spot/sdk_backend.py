"""The Spot SDK implementation of the HAL: the same agent code drives a real Boston Dynamics Spot.

Bring-up (``SdkSpotBackend(config)``): resolve the host, authenticate over TLS with credentials
from ``BOSDYN_CLIENT_USERNAME`` / ``BOSDYN_CLIENT_PASSWORD`` (never from config, never logged),
time sync, e-stop check (an external e-stop must be released) or our own e-stop endpoint with a
keep-alive, acquire the body lease with a keep-alive, power on, stand.

Commands map onto the SDK as Spot's own examples use it:

| HAL | Spot SDK |
|---|---|
| ``navigate_to(goal, via)`` | one ``SE2TrajectoryCommand`` in ``odom`` whose points sample our ruckig trajectory |
| ``move_arm_joints(q)`` | ``ArmJointMoveCommand``, ruckig samples with velocities, at most 250 points |
| ``move_hand(T)`` / ``place`` | ``ArmCartesianCommand`` (hand frame; reachability checked with our IK first) |
| ``gaze_at(p)`` | ``GazeCommand`` at a point in ``odom`` |
| ``grasp(obs, pixel)`` | ``ManipulationApi`` ``PickObjectInImage`` with the image's own frame snapshot and camera model |
| ``place(p, h)`` | hand over ``p`` (object geometry estimated at grasp time), claw open, retreat, claw close |
| ``stow_arm`` | named ``STOW`` (``CARRY`` while holding) |
| ``observe`` | ``hand_color_image`` + ``hand_depth_in_hand_color_frame``: intrinsics from the response, depth / ``depth_scale``, poses from the shot's frame snapshot |
| ``stop`` / ``close`` | full-body stop / stop, stow, sit + power off, return the lease, deregister our e-stop endpoint, stop every keep-alive thread (bounded in wall time, see ``close``) |

Every command is sent, then its feedback polled every ``feedback_period`` until it ends; a command
that does not end within its planned duration + ``command_margin``, or (walks, arm joint moves)
makes no progress for ``stall_time`` while away from where its plan has it (a pick: for twice that
while the robot reports it moves to the grasp), raises :class:`CommandTimeoutError`. While a
command runs the backend also updates time sync itself every 0.25 s; a pick, whose feedback may
not turn to a failed state when the robot stops it (unverified on a real Spot), also reads the
robot's state (power, e-stop, behavior faults) every 0.25 s and ends in the typed fault. Whatever
error ends a command, a stop is sent first (without waiting long for its reply: a robot on a slow
link acts on it when it arrives). gRPC tracing in the environment (``GRPC_TRACE``) would print the
session token and is refused unless ``allow_grpc_tracing``. Robot faults raise the HAL's typed
errors and most are *sticky*: once
the lease is lost, the robot e-stopped, powered off, the link or time sync lost, every further
command raises the same error without reaching the robot (``stand()`` retries power after an
e-stop is released). TLS verification is never disabled: the backend only ever uses the SDK's
secure channels, checked against BD's root CA or ``cert_path``.

``bosdyn`` is imported lazily (the ``[spot]`` extra); importing this module needs only numpy.
The bring-up (``connect()``) is :mod:`robots.spot.sdk_bringup`, fault handling and the command
loop :mod:`robots.spot.sdk_commands`, the shutdown (``close()``) :mod:`robots.spot.sdk_shutdown`,
the configuration, credentials and their errors :mod:`robots.spot.sdk_config`, the stall test
:mod:`robots.spot.stall_watch`.
"""

from __future__ import annotations

import functools
import logging
import math
import secrets
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from robots.hal import (
    as_hand_pose,
    as_pixel,
    as_point,
    as_se2,
    BackendClosedError,
    CommandResult,
    CommandTimeoutError,
    EstopError,
    GraspResult,
    InvalidCommandError,
    NavigateResult,
    Observation,
    PlaceResult,
    PowerError,
    Reason,
    RobotFault,
    SE2Pose,
    TimeSyncLostError,
)
from robots.spot import kinematics
from robots.spot.motion import check_arm_target, plan_arm, plan_base
from robots.spot.sdk_config import (
    PASSWORD_ENV,
    USERNAME_ENV,
    CommandRejectedError,
    CredentialsError,
    GrpcTracingError,
    NotConnectedError,
    SdkBackendConfig,
    SpotConnectError,
    SpotSdkMissingError,
    credentials_from_env,
)
from robots.spot.sdk_bringup import SdkBringUp
from robots.spot.sdk_commands import SdkCommands
from robots.spot.sdk_shutdown import SdkShutdown
from robots.spot.stall_watch import StallWatch
from robots.transforms import invert_transform, rot_z

_LOG = logging.getLogger("helios.spot")

# s between the grasp loop's reads of the robot state (power, e-stop, behavior faults), which end a
# pick the robot stopped by itself whatever its manipulation feedback says (SdkSpotBackend._fault_in_state)
_GRASP_STATE_PERIOD = 0.25

# What callers import from here: the backend and its vocabulary (configuration, credentials, errors).
__all__ = ["PASSWORD_ENV", "USERNAME_ENV", "CommandRejectedError", "CredentialsError", "GrpcTracingError",
           "NotConnectedError", "SdkBackendConfig", "SdkSpotBackend", "SpotConnectError", "SpotSdkMissingError", "credentials_from_env",
           "estimate_object_base"]


# --------------------------------------------------------------------------------------------
# Lazy bosdyn import
# --------------------------------------------------------------------------------------------
class _Bosdyn:
    """The bosdyn modules the backend uses, imported on first use."""

    def __init__(self) -> None:
        try:
            import bosdyn.client
            from bosdyn.api import (basic_command_pb2, geometry_pb2, image_pb2, manipulation_api_pb2,
                                    mobility_command_pb2, robot_command_pb2, synchronized_command_pb2)
            from bosdyn.api import arm_command_pb2, gripper_command_pb2, estop_pb2
            from bosdyn.client import auth, estop, exceptions, lease, power, robot_command, time_sync
            from bosdyn.client.image import ImageClient, build_image_request
            from bosdyn.client.manipulation_api_client import ManipulationApiClient
            from bosdyn.client.robot_state import RobotStateClient
            from robots.spot import sdk_conversions
        except ImportError as exc:  # pragma: no cover - exercised only without the extra
            raise SpotSdkMissingError(
                f"the Spot SDK is not installed ({exc}); install it with: pip install -e '.[spot]' (in the checkout)") from exc
        self.client = bosdyn.client
        self.basic = basic_command_pb2
        self.geometry = geometry_pb2
        self.image_pb2 = image_pb2
        self.manip = manipulation_api_pb2
        self.mobility = mobility_command_pb2
        self.robot_command_pb2 = robot_command_pb2
        self.synchro = synchronized_command_pb2
        self.arm = arm_command_pb2
        self.gripper = gripper_command_pb2
        self.estop_pb2 = estop_pb2
        self.auth = auth
        self.estop = estop
        self.exc = exceptions
        self.lease = lease
        self.power = power
        self.rc = robot_command
        self.ts = time_sync
        self.ImageClient = ImageClient
        self.build_image_request = build_image_request
        self.ManipulationApiClient = ManipulationApiClient
        self.RobotStateClient = RobotStateClient
        self.Builder = robot_command.RobotCommandBuilder
        self.cv = sdk_conversions


_BD: _Bosdyn | None = None


def _bosdyn() -> _Bosdyn:
    global _BD
    if _BD is None:
        _BD = _Bosdyn()
    return _BD


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------
def estimate_object_base(obs: Observation, target: np.ndarray, radius: float = 0.12) -> np.ndarray:
    """Bottom centre (world) of the object seen at ``target``, from the observation's depth alone:
    its support is the 90th-percentile height of points just around and below the target, its
    centre the mean of the points above that support near the target (what a robot without an
    object model can know)."""
    v, u = np.nonzero(obs.depth > 0)
    pts = obs.intrinsics.backproject(u, v, obs.depth[v, u]) @ obs.T_world_cam[:3, :3].T + obs.T_world_cam[:3, 3]
    d_xy = np.linalg.norm(pts[:, :2] - target[:2], axis=1)
    below = pts[(d_xy < radius + 0.08) & (pts[:, 2] < target[2] - 0.01)]
    support_z = float(np.percentile(below[:, 2], 90)) if len(below) >= 20 else float(target[2]) - 0.05
    obj = pts[(d_xy < radius) & (pts[:, 2] > support_z + 0.008)]
    centre = obj[:, :2].mean(axis=0) if len(obj) >= 5 else np.asarray(target[:2], dtype=float)
    return np.array([centre[0], centre[1], support_z])


@dataclass
class _Shot:
    """What a pick-in-image request needs about an observation this backend produced."""

    stamp: float
    snapshot: object          # geometry_pb2.FrameTreeSnapshot
    sensor_frame: str
    pinhole: object           # image_pb2.ImageSource.PinholeModel






# --------------------------------------------------------------------------------------------
# The backend
# --------------------------------------------------------------------------------------------


def _closing_aware(method):
    """Public commands called while ``close()`` runs in another thread (or after it) end in one
    typed :class:`BackendClosedError`, whatever the teardown does underneath them (channels closed
    mid-RPC raise gRPC's ValueError, the robot handle becomes None, ...)."""

    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        try:
            return method(self, *args, **kwargs)
        except BackendClosedError:
            raise
        except Exception:
            if self._closed_to_this_thread():
                raise BackendClosedError(f"{method.__name__}() was cut short: the backend was closed "
                                         f"meanwhile (close() from another thread)") from None
            raise

    return wrapper


class SdkSpotBackend(SdkBringUp, SdkCommands, SdkShutdown):
    """A real (or fake) Spot behind the :class:`robots.hal.RobotBackend` contract.

    Threads: one thread drives the robot; ``stop()`` and ``close()`` may come from any other (a
    safety monitor). While ``close()`` shuts the robot down, the other threads' commands end in
    :class:`BackendClosedError` and send nothing more (no stop of their own over close()'s stow and
    sit); a second ``close()`` waits for the first."""

    def __init__(self, config: SdkBackendConfig, *, connect: bool = True):
        if not isinstance(config, SdkBackendConfig):
            raise TypeError(f"config must be an SdkBackendConfig, got {type(config).__name__}")
        if not config.hostname or not config.hostname.strip():
            raise SpotConnectError("no robot hostname given")
        self.config = config
        self._bd = _bosdyn()
        self._sdk = None
        self.robot = None
        self.robot_id = None
        self._fault: RobotFault | None = None
        self.close_problem: str | None = None
        """Set by close() when it could not stop, sit and power off the robot because the body lease
        was not ours (``robots.spot.sdk_shutdown``): one line for the operator, or None."""
        self._lease_lost: str | None = None
        """Why the body lease is no longer ours, once the robot said so (a revoke or take), even
        after another fault came first: close() then neither commands nor returns it and says so."""
        self._lease_returning = False           # our own return was sent: the wallet's refusals are ours
        self._retain_confirmed_at: float | None = None   # when the robot last confirmed a RetainLease of ours
        self._retain_failing = False            # retains go unanswered since then (sdk_bringup._note_retain)
        self._comms_loss_seen = False           # a fault was put down to the robot's comms-loss behaviour
        self._close_steps: set[str] = set()     # the shutdown steps the robot confirmed (close())
        self._estop_note: str | None = None      # close(): our e-stop endpoint stays registered, said once
        self._closed = False
        self._closing = False
        self._close_lock = threading.Lock()
        self._close_thread: threading.Thread | None = None
        self._close_done = threading.Event()
        # Motion commands other threads are sending right now: close() lets them reach the robot
        # before its own stop, so none can arrive after it and cut its stow or sit short.
        self._sends = threading.Condition(self._close_lock)
        self._sending = 0
        # A bring-up in progress (connect()): close() from another thread waits for it to stop at
        # its next step, then shuts down whatever it had brought up.
        self._connecting: threading.Thread | None = None
        self._connect_done = threading.Event()
        self._connect_done.set()
        self._lease_keepalive = None
        self._estop_keepalive = None
        self._estop_endpoint = None
        # Names this session goes by on the robot, unique to it (also among backends in one process):
        # the SDK's request-header client name (a lease's owner) and our e-stop endpoint's name. The
        # clean-up after an unanswered bring-up call recognises what is ours by them alone.
        self._session = secrets.token_hex(3)
        # What a bring-up call that went unanswered may have left on the robot (asked about at close)
        self._estop_unconfirmed: tuple[str, frozenset] | None = None   # (our name, endpoint ids before)
        self._lease_unconfirmed = False
        self._token_manager_thread: threading.Thread | None = None
        self._frame_id = 0
        self._shots: OrderedDict[int, _Shot] = OrderedDict()
        self._grip: np.ndarray | None = None     # held object's bottom centre in the hand frame
        self._on_close: list[Callable[[], None]] = []
        self._power_wanted = False
        self._unresponsive = False               # the last command timed out (skip arm moves at close)
        if connect:
            try:
                self.connect()
            except BaseException:
                self.close()
                raise

    # ================================================================== observation
    @_closing_aware
    def observe(self) -> Observation:
        self._guard(sensing=True)
        cfg, bd = self.config, self._bd
        cv, I = bd.cv, bd.image_pb2.Image
        fmt = I.FORMAT_JPEG if cfg.image_format == "jpeg" else I.FORMAT_RAW
        requests = [bd.build_image_request(cv.HAND_COLOR_SOURCE, quality_percent=cfg.jpeg_quality, image_format=fmt,
                                           pixel_format=I.PIXEL_FORMAT_RGB_U8),
                    bd.build_image_request(cv.HAND_DEPTH_SOURCE, image_format=I.FORMAT_RAW,
                                           pixel_format=I.PIXEL_FORMAT_DEPTH_U16)]
        color, depth = self._call(self._image_client.get_image, requests, timeout=cfg.image_rpc_timeout,
                                  during="capturing hand-camera images")
        for r in (color, depth):
            if r.status != bd.image_pb2.ImageResponse.STATUS_OK:
                raise CommandRejectedError(f"image source {r.source.name!r} returned "
                                           f"{bd.image_pb2.ImageResponse.Status.Name(r.status)}")
        try:
            intr = cv.pinhole_to_intrinsics(color.source)
            rgb = cv.decode_rgb(color.shot.image)
            dep = cv.decode_depth(depth.shot.image, depth.source.depth_scale)
            snap = color.shot.transforms_snapshot
            sensor = color.shot.frame_name_image_sensor
            T_world_cam = cv.tform(snap, cv.ODOM, sensor)
            T_world_body = cv.tform(snap, cv.ODOM, cv.BODY)
        except (ValueError, KeyError) as exc:
            raise CommandRejectedError(f"the robot's images cannot be used: {exc}") from None
        if dep.shape != rgb.shape[:2]:
            raise CommandRejectedError(f"depth {dep.shape[::-1]} is not registered to colour {rgb.shape[1::-1]}: "
                                       f"use {cv.HAND_DEPTH_SOURCE}")
        state = self._state("reading the robot state")
        joints = {j.name: float(j.position.value) for j in state.kinematic_state.joint_states}
        acquired = self._robot_to_local(color.shot.acquisition_time)
        self._frame_id += 1
        self._shots[self._frame_id] = _Shot(acquired, snap, sensor, color.source.pinhole)
        while len(self._shots) > 16:
            self._shots.popitem(last=False)
        return Observation(rgb=rgb, depth=dep, intrinsics=intr, T_world_cam=T_world_cam, T_world_body=T_world_body,
                           stamp=acquired, holding=bool(state.manipulator_state.is_gripper_holding_item),
                           joint_positions=joints, frame_id=self._frame_id, camera=cv.HAND_COLOR_SOURCE)

    def _robot_to_local(self, ts) -> float:
        try:
            conv = self.robot.time_sync.get_robot_time_converter()
            return float(conv.local_seconds_from_robot_timestamp(ts))
        except self._bd.ts.TimeSyncError:
            raise self._set_fault(TimeSyncLostError("time sync with the robot was lost")) from None

    # ================================================================== base
    @_closing_aware
    def navigate_to(self, goal: SE2Pose, via: Sequence[SE2Pose] = ()) -> NavigateResult:
        goal = as_se2(goal, "goal")
        via = [as_se2(v, f"via[{i}]") for i, v in enumerate(via)]
        self._guard()
        cfg, bd = self.config, self._bd
        cv = bd.cv
        state = self._state("planning a base move")
        start = SE2Pose.from_matrix(self._T(state, cv.ODOM, cv.BODY))
        traj = plan_base(start, [*via, goal], cfg.motion.base)
        times = cv.resample_times(traj.duration, cfg.motion.control_dt, cfg.max_trajectory_points)
        poses = [traj.pose_at(float(t)) for t in times]
        se2 = cv.se2_trajectory(times, poses)
        se2.reference_time.CopyFrom(self._local_now_ts(cv))
        params = bd.Builder.mobility_params()
        mob = bd.mobility.MobilityCommand.Request(
            se2_trajectory_request=bd.basic.SE2TrajectoryCommand.Request(trajectory=se2, se2_frame_name=cv.ODOM))
        mob.params.Pack(params)
        command = bd.robot_command_pb2.RobotCommand(
            synchronized_command=bd.synchro.SynchronizedCommand.Request(mobility_command=mob))
        F = bd.basic.SE2TrajectoryCommand.Feedback

        def done(fb):
            se2_fb = fb.feedback.synchronized_feedback.mobility_command_feedback.se2_trajectory_feedback
            return se2_fb.status == F.STATUS_AT_GOAL, se2_fb.final_goal_status != F.FINAL_GOAL_STATUS_BLOCKED

        end_time = time.time() + traj.duration + cfg.command_margin

        def actual(state):
            p = SE2Pose.from_matrix(self._T(state, cv.ODOM, cv.BODY))
            return (p.x, p.y, math.cos(p.yaw), math.sin(p.yaw))

        def planned(t):
            p = traj.pose_at(t)
            return (p.x, p.y, math.cos(p.yaw), math.sin(p.yaw))

        ok, fb, took = self._run_command(command, during="walking to the goal", expected=traj.duration,
                                         done=done, end_time_secs=end_time, track=(actual, planned))
        final = SE2Pose.from_matrix(self._T(self._state("checking the base pose"), cv.ODOM, cv.BODY))
        travelled = self._travelled(poses, final)
        if ok is None:
            mobility = fb.feedback.synchronized_feedback.mobility_command_feedback
            if mobility.status == bd.basic.RobotCommandFeedbackStatus.STATUS_COMMAND_TIMED_OUT:
                return NavigateResult(False, Reason.TIMEOUT, f"the robot ended the walk at its end time, at "
                                      f"({final.x:.2f}, {final.y:.2f}), {final.distance_to(goal):.2f} m from the goal",
                                      duration=took, final_pose=final, distance=travelled)
            return NavigateResult(False, Reason.STOPPED, f"interrupted at ({final.x:.2f}, {final.y:.2f})",
                                  duration=took, final_pose=final, distance=travelled)
        arrived = final.distance_to(goal) <= cfg.goal_tolerance and \
            abs(math.remainder(final.yaw - goal.yaw, 2 * math.pi)) <= cfg.goal_tolerance
        if ok and arrived:
            return NavigateResult(True, Reason.OK, duration=took, final_pose=final, distance=travelled)
        if ok:                  # AT_GOAL and STOPPED are one status: stopped short, maybe to move on
            self._stop_quietly()
        blocked = fb.feedback.synchronized_feedback.mobility_command_feedback.se2_trajectory_feedback \
            .final_goal_status == F.FINAL_GOAL_STATUS_BLOCKED
        if blocked:
            return NavigateResult(False, Reason.COLLISION, f"the path is blocked; stopped at ({final.x:.2f}, "
                                  f"{final.y:.2f})", duration=took, final_pose=final, collided=True, distance=travelled)
        return NavigateResult(False, Reason.UNREACHABLE, f"stopped {final.distance_to(goal):.2f} m from the goal",
                              duration=took, final_pose=final, distance=travelled)

    @staticmethod
    def _travelled(poses: Sequence[SE2Pose], final: SE2Pose) -> float:
        """Path length along the planned samples up to the one nearest where the body stopped."""
        k = int(np.argmin([p.distance_to(final) for p in poses]))
        return float(sum(a.distance_to(b) for a, b in zip(poses[:k], poses[1:k + 1])))

    # ================================================================== arm
    @_closing_aware
    def move_arm_joints(self, joints: Sequence[float]) -> CommandResult:
        q_goal = check_arm_target(joints)
        self._guard()
        cfg, bd = self.config, self._bd
        cv = bd.cv
        q_now = self._arm_q(self._state("planning an arm move"))
        if np.allclose(q_now, q_goal, atol=1e-3, rtol=0.0):
            # already there: a trajectory of one point at time 0 is ill-formed to a robot (the fake
            # refused it as INVALID_REQUEST, a CommandRejectedError); the simulator's move succeeds
            return CommandResult(True, Reason.OK, "the arm is already at the joint target", duration=0.0)
        traj = plan_arm(q_now, q_goal, cfg.motion.arm)
        times = cv.resample_times(traj.duration, cfg.motion.control_dt, cfg.max_trajectory_points)
        samples = [traj.at_time(float(t)) for t in times]
        limits = cfg.motion.arm
        command = bd.Builder.arm_joint_move_helper(
            joint_positions=[list(map(float, p)) for p, _ in samples], times=[float(t) for t in times],
            joint_velocities=[list(map(float, v)) for _, v in samples], ref_time=self._local_now_ts(cv),
            max_vel=1.05 * limits.velocity, max_acc=1.05 * limits.acceleration)
        S = bd.arm.ArmJointMoveCommand.Feedback

        def done(fb):
            st = fb.feedback.synchronized_feedback.arm_command_feedback.arm_joint_move_feedback.status
            return st in (S.STATUS_COMPLETE, S.STATUS_STALLED), st == S.STATUS_COMPLETE

        ok, _, took = self._run_command(command, during="moving the arm joints", expected=traj.duration, done=done,
                                        track=(self._arm_q, lambda t: traj.at_time(t)[0]))
        if ok is None:
            return CommandResult(False, Reason.STOPPED, "the arm move was interrupted", duration=took)
        if ok:
            return CommandResult(True, Reason.OK, duration=took)
        return CommandResult(False, Reason.COLLISION, "the arm stalled before reaching the joint target", duration=took)

    @_closing_aware
    def move_hand(self, T_body_hand: np.ndarray) -> CommandResult:
        T = as_hand_pose(T_body_hand)
        self._guard()
        q_now = self._arm_q(self._state("planning a hand move"))
        q = kinematics.inverse_kinematics(T, q_now)
        if q is None:
            return CommandResult(False, Reason.IK_FAILED, "no arm configuration within limits reaches that hand pose")
        return self._hand_to(T, self._bd.cv.BODY, plan_arm(q_now, q, self.config.motion.arm).duration, "moving the hand")

    def _hand_to(self, T_frame_hand: np.ndarray, frame: str, seconds: float, during: str) -> CommandResult:
        bd = self._bd
        seconds = max(float(seconds), 0.2)
        command = bd.Builder.arm_pose_command_from_pose(bd.cv.matrix_to_se3(T_frame_hand), frame, seconds=seconds)
        command.synchronized_command.arm_command.arm_cartesian_command.pose_trajectory_in_task.reference_time \
            .CopyFrom(self._local_now_ts(bd.cv))
        S = bd.arm.ArmCartesianCommand.Feedback

        def done(fb):
            st = fb.feedback.synchronized_feedback.arm_command_feedback.arm_cartesian_feedback.status
            return (st in (S.STATUS_TRAJECTORY_COMPLETE, S.STATUS_TRAJECTORY_STALLED, S.STATUS_TRAJECTORY_CANCELLED),
                    st == S.STATUS_TRAJECTORY_COMPLETE)

        ok, fb, took = self._run_command(command, during=during, expected=seconds, done=done)
        if ok:
            return CommandResult(True, Reason.OK, duration=took)
        st = fb.feedback.synchronized_feedback.arm_command_feedback.arm_cartesian_feedback.status
        if ok is None or st == S.STATUS_TRAJECTORY_CANCELLED:
            return CommandResult(False, Reason.STOPPED, "the hand move was cancelled", duration=took)
        return CommandResult(False, Reason.COLLISION, "the arm stalled before reaching the hand pose", duration=took)

    @_closing_aware
    def gaze_at(self, point: Sequence[float]) -> CommandResult:
        p = as_point(point, "gaze point")
        self._guard()
        bd = self._bd
        command = bd.Builder.arm_gaze_command(float(p[0]), float(p[1]), float(p[2]), bd.cv.ODOM)
        S = bd.arm.GazeCommand.Feedback

        def done(fb):
            st = fb.feedback.synchronized_feedback.arm_command_feedback.arm_gaze_feedback.status
            return st in (S.STATUS_TRAJECTORY_COMPLETE, S.STATUS_TOOL_TRAJECTORY_STALLED), \
                st == S.STATUS_TRAJECTORY_COMPLETE

        ok, _, took = self._run_command(command, during="pointing the hand camera", expected=self.config.arm_move_timeout,
                                        done=done)
        if ok:
            return CommandResult(True, Reason.OK, duration=took)
        if ok is None:
            return CommandResult(False, Reason.STOPPED, "the gaze was interrupted", duration=took)
        return CommandResult(False, Reason.UNREACHABLE,
                             f"cannot point the hand camera at ({p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f}) from here; "
                             f"turn the body towards it", duration=took)

    @_closing_aware
    def stow_arm(self) -> CommandResult:
        """Stow; with an object in the claw, go to the carry pose instead (Spot refuses to stow it)."""
        self._guard()
        return self._stow_or_carry(bool(self._state("checking the gripper").manipulator_state.is_gripper_holding_item))

    def _stow_or_carry(self, holding: bool) -> CommandResult:
        """:meth:`stow_arm` once the claw's state is known: ``close()`` has just read it with its
        stop, and reading it again cost one more round trip on a slow link."""
        bd = self._bd
        command = bd.Builder.arm_carry_command() if holding else bd.Builder.arm_stow_command()
        S = bd.arm.NamedArmPositionsCommand.Feedback

        def done(fb):
            st = fb.feedback.synchronized_feedback.arm_command_feedback.named_arm_position_feedback.status
            return st in (S.STATUS_COMPLETE, S.STATUS_STALLED_HOLDING_ITEM), st == S.STATUS_COMPLETE

        # A stow that makes no progress (arm or claw) for stall_time while the robot does not report
        # the arm stowed is given up: close() stows, and a robot that takes commands and never
        # carries them out must not hold the shutdown for arm_move_timeout + command_margin (12 s).
        # The carry pose has no arrival signal in robot state, so a carry waits its whole budget.
        track = None if holding else (self._arm_and_gripper_q, None, self._arm_stowed)
        ok, _, took = self._run_command(command, during="carrying" if holding else "stowing the arm",
                                        expected=self.config.arm_move_timeout, done=done, track=track)
        if ok:
            return CommandResult(True, Reason.OK, duration=took)
        if ok is None:
            return CommandResult(False, Reason.STOPPED, "the arm move was interrupted", duration=took)
        return CommandResult(False, Reason.COLLISION, "the arm stalled before reaching the "
                                                      f"{'carry' if holding else 'stow'} pose", duration=took)

    def _claw(self, open_fraction: float, during: str) -> CommandResult:
        bd = self._bd
        command = bd.Builder.claw_gripper_open_fraction_command(open_fraction)
        C = bd.gripper.ClawGripperCommand.Feedback

        def done(fb):
            st = fb.feedback.synchronized_feedback.gripper_command_feedback.claw_gripper_feedback.status
            return st in (C.STATUS_AT_GOAL, C.STATUS_APPLYING_FORCE), True

        ok, _, took = self._run_command(command, during=during, expected=2.0, done=done)
        return CommandResult(bool(ok), Reason.OK if ok else Reason.STOPPED, duration=took)

    # ================================================================== grasp and place
    @_closing_aware
    def grasp(self, observation: Observation, pixel: tuple[int, int]) -> GraspResult:
        if not isinstance(observation, Observation):
            raise InvalidCommandError(f"grasp needs the Observation the pixel refers to, got "
                                      f"{type(observation).__name__}")
        u, v = as_pixel(pixel, observation)
        self._guard()
        cfg, bd = self.config, self._bd
        M = bd.manip
        if self._state("checking the gripper").manipulator_state.is_gripper_holding_item:
            return GraspResult(False, Reason.ALREADY_HOLDING, "the claw already holds an object", holding=True)
        target = observation.point_at_pixel(u, v)
        if target is None:
            return GraspResult(False, Reason.NO_DEPTH, f"no depth at pixel ({u}, {v})")
        tgt = tuple(float(x) for x in target)
        snapshot, sensor, pinhole = self._shot_for(observation)
        pick = M.PickObjectInImage(pixel_xy=bd.geometry.Vec2(x=u, y=v), transforms_snapshot_for_camera=snapshot,
                                   frame_name_image_sensor=sensor, camera_model=pinhole,
                                   walk_gaze_mode=M.PICK_NO_AUTO_WALK_OR_GAZE)
        t0 = time.monotonic()
        try:
            resp = self._call(self._manip_client.manipulation_api_command, moves=True,
                              manipulation_api_request=M.ManipulationApiRequest(pick_object_in_image=pick),
                              timeout=cfg.rpc_timeout, during="starting a grasp")
            request = M.ManipulationApiFeedbackRequest(manipulation_cmd_id=resp.manipulation_cmd_id)
            terminal = {M.MANIP_STATE_GRASP_SUCCEEDED, M.MANIP_STATE_GRASP_FAILED,
                        M.MANIP_STATE_GRASP_PLANNING_NO_SOLUTION, M.MANIP_STATE_GRASP_FAILED_TO_RAYCAST_INTO_MAP,
                        M.MANIP_STATE_DONE}
            deadline = t0 + cfg.grasp_timeout
            at_edge_since = None
            reach: StallWatch | None = None       # while the robot reports it moves to the grasp
            next_check = t0 + _GRASP_STATE_PERIOD   # the robot's own state, whatever the feedback says
            while True:
                fb = self._call(self._manip_client.manipulation_api_feedback_command,
                                manipulation_api_feedback_request=request, timeout=cfg.rpc_timeout, during="grasping")
                if fb.current_state in terminal:
                    break
                if fb.current_state == M.MANIP_STATE_GRASP_PLANNING_WAITING_DATA_AT_EDGE:
                    # the target sits at the image's edge and, without auto gaze, the robot waits for a
                    # better view that never comes: it held the grasp to its timeout (fidelity audit)
                    at_edge_since = at_edge_since or time.monotonic()
                    if time.monotonic() - at_edge_since >= cfg.grasp_edge_wait:
                        self._stop_quietly()
                        return GraspResult(False, Reason.UNREACHABLE, f"the target at pixel ({u}, {v}) is at the "
                                           f"image's edge and the robot waits for a better view; look at it so it "
                                           f"sits nearer the image centre", target_world=tgt,
                                           duration=time.monotonic() - t0)
                else:
                    at_edge_since = None
                now = time.monotonic()
                if fb.current_state != M.MANIP_STATE_MOVING_TO_GRASP:
                    reach = None
                elif reach is None:
                    # The reach must move: a pick whose arm is blocked mid-reach goes on reporting
                    # MOVING_TO_GRASP (the feedback has no state for a stall), and was left pushing
                    # for the whole grasp_timeout (20 s) before it was stopped (audit 2026-12-06).
                    # Twice the stall time: the reach may pause briefly between its phases.
                    reach = StallWatch((self._pick_progress, None, lambda _state: False), 2 * cfg.stall_time,
                                       cfg.grasp_timeout)
                stall_due = reach is not None and reach.due(now)
                if stall_due or now >= next_check:        # one state read serves both checks
                    state = self._state("grasping")
                    next_check = now + _GRASP_STATE_PERIOD
                    self._fault_in_state(state, "grasping")     # a power cut is no stall
                    if stall_due:
                        self._end_if_stalled(reach, now - t0, state,
                                             f"while grasping ({reach.window:.1f} s without motion of the arm, "
                                             f"claw or base while it reports moving to the grasp)")
                self._guard()                 # a sticky fault (the keep-alive's lost lease, ...)
                if time.monotonic() > deadline:
                    self._unresponsive = True
                    raise CommandTimeoutError(f"the grasp did not finish within {cfg.grasp_timeout:.0f} s; "
                                              f"the robot was told to stop")
                time.sleep(cfg.feedback_period)
        except BaseException:         # a HalError, a bug of ours in this loop, Ctrl-C: a stop goes out first,
            self._stop_quietly()      # a pick left running finishes on its own once the link recovers
            raise                     # (QA 2026-12-04)
        took = time.monotonic() - t0
        state_name = M.ManipulationFeedbackState.Name(fb.current_state)
        if fb.current_state != M.MANIP_STATE_GRASP_SUCCEEDED:
            fault = self._diagnose("grasping")
            if fault is not None:
                raise type(fault)(str(fault))
        state = self._state("checking the grasp")
        holding = bool(state.manipulator_state.is_gripper_holding_item)
        if fb.current_state == M.MANIP_STATE_GRASP_SUCCEEDED and holding:
            self._remember_grip(observation, np.asarray(tgt), fb, state)
            return GraspResult(True, Reason.OK, "holding the object", holding=True, target_world=tgt, duration=took)
        if fb.current_state == M.MANIP_STATE_GRASP_SUCCEEDED:
            return GraspResult(False, Reason.GRASP_SLIPPED, "the grasp succeeded but the object is no longer held",
                               target_world=tgt, duration=took)
        reason = {M.MANIP_STATE_GRASP_PLANNING_NO_SOLUTION: Reason.OUT_OF_REACH,
                  M.MANIP_STATE_GRASP_FAILED_TO_RAYCAST_INTO_MAP: Reason.NO_DEPTH}.get(fb.current_state,
                                                                                      Reason.GRASP_MISSED)
        return GraspResult(False, reason, f"the robot reported {state_name}", holding=holding, target_world=tgt,
                           duration=took)

    def _fault_in_state(self, state, during: str) -> None:
        """Raise the typed fault (EstopError, PowerError naming a critical fault or the comms-loss
        behaviour, BehaviorFaultError, LeaseLostError: :meth:`_diagnose`) when the robot's state
        says it cannot be carrying out a command: motor power not on while we want it on, an
        e-stop engaged, a behavior fault. The grasp loop reads this every
        :data:`_GRASP_STATE_PERIOD` s (the reach's stall watch's state when it has one) instead of
        relying on the manipulation feedback to turn to a failed state after an e-stop or a power
        cut: whether a real Spot's does is unverified, and one that kept reporting its last state
        (MOVING_TO_GRASP, a planning state) left the fault to ``grasp_timeout`` (20 s)."""
        PS = state.power_state
        if not ((self._power_wanted and PS.motor_power_state != PS.MOTOR_POWER_STATE_ON)
                or any(e.state == e.STATE_ESTOPPED for e in state.estop_states)
                or state.behavior_fault_state.faults):
            return
        fault = self._diagnose(during)
        if fault is not None:
            raise type(fault)(str(fault))

    def _pick_progress(self, state) -> np.ndarray:
        """What moves while a pick reaches: arm and claw joints, and the base (a pick may walk)."""
        body = SE2Pose.from_matrix(self._T(state, self._bd.cv.ODOM, self._bd.cv.BODY))
        return np.concatenate([self._arm_and_gripper_q(state), [body.x, body.y, math.cos(body.yaw),
                                                                 math.sin(body.yaw)]])

    def _shot_for(self, obs: Observation):
        """The frame snapshot, sensor frame and camera model of an observation: the robot's own
        when this backend produced it, else synthesised from the observation's poses."""
        bd = self._bd
        cv = bd.cv
        shot = self._shots.get(obs.frame_id)
        if shot is not None and abs(shot.stamp - obs.stamp) < 1e-9:
            return shot.snapshot, shot.sensor_frame, shot.pinhole
        T_body_world = invert_transform(obs.T_world_body)
        snapshot = cv.frame_tree({cv.BODY: ("", np.eye(4)), cv.ODOM: (cv.BODY, T_body_world),
                                  cv.VISION: (cv.BODY, T_body_world),
                                  cv.HAND_COLOR_SENSOR: (cv.BODY, T_body_world @ obs.T_world_cam)})
        return snapshot, cv.HAND_COLOR_SENSOR, cv.intrinsics_to_pinhole(obs.intrinsics)

    def _remember_grip(self, obs: Observation, target: np.ndarray, fb, state) -> None:
        """Where the held object sits in the hand: its bottom centre (estimated from the grasp
        image) in the hand frame at the grasp, from Spot's reported grasp pose when available."""
        cv = self._bd.cv
        base = estimate_object_base(obs, target)
        snap = fb.transforms_snapshot_manipulation_data
        try:
            T_world_grasp = cv.tform(snap, cv.ODOM, cv.GRASP_SOLUTION_FRAME)
        except (KeyError, ValueError):
            T_world_grasp = self._T(state, cv.ODOM, cv.HAND)
        self._grip = (invert_transform(T_world_grasp) @ np.append(base, 1.0))[:3]

    @_closing_aware
    def place(self, point: Sequence[float], release_height: float = 0.10) -> PlaceResult:
        p = as_point(point, "place point")
        if not (math.isfinite(release_height) and 0.0 <= release_height <= 1.0):
            raise InvalidCommandError(f"release_height must be within [0, 1] m, got {release_height}")
        self._guard()
        cfg, bd = self.config, self._bd
        cv = bd.cv
        t0 = time.monotonic()
        state = self._state("checking the gripper")
        if not state.manipulator_state.is_gripper_holding_item:
            return PlaceResult(False, Reason.NOT_HOLDING, "nothing in the claw to place")
        T_world_hand = self._T(state, cv.ODOM, cv.HAND)
        T_world_body = self._T(state, cv.ODOM, cv.BODY)
        # The held object's bottom centre in the hand frame (unknown grasp: assume 5 cm below the hand).
        b_hand = self._grip if self._grip is not None else np.array([0.0, 0.0, -0.05])
        yaw = math.atan2(p[1] - T_world_body[1, 3], p[0] - T_world_body[0, 3])
        x = T_world_hand[:3, 0]
        R = rot_z(yaw - math.atan2(x[1], x[0])) @ T_world_hand[:3, :3]   # face the release point, keep the roll
        T_target = np.eye(4)
        T_target[:3, :3] = R
        T_target[:3, 3] = p + np.array([0.0, 0.0, release_height]) - R @ b_hand
        q_now = self._arm_q(state)
        q = kinematics.inverse_kinematics(invert_transform(T_world_body) @ T_target, q_now)
        if q is None:
            return PlaceResult(False, Reason.OUT_OF_REACH, "the release point cannot be reached from here; move closer",
                               duration=time.monotonic() - t0)
        res = self._hand_to(T_target, cv.ODOM, plan_arm(q_now, q, cfg.motion.arm).duration,
                            "carrying the object over the release point")
        if not res:
            return PlaceResult(False, res.reason, res.message, duration=time.monotonic() - t0)
        state = self._state("checking the hand")
        release = tuple(float(v) for v in self._T(state, cv.ODOM, cv.HAND)[:3, 3])
        self._claw(1.0, "opening the claw")
        self._grip = None
        # Back off along the hand's approach axis and up a little, then close the claw.
        state = self._state("checking the hand")
        T_back = self._T(state, cv.ODOM, cv.HAND)
        T_back[:3, 3] += -cfg.release_retreat * T_back[:3, 0] + np.array([0.0, 0.0, 0.05])
        q_now = self._arm_q(state)
        q_back = kinematics.inverse_kinematics(invert_transform(self._T(state, cv.ODOM, cv.BODY)) @ T_back, q_now)
        if q_back is not None:
            self._hand_to(T_back, cv.ODOM, plan_arm(q_now, q_back, cfg.motion.arm).duration, "backing off")
        self._claw(0.0, "closing the claw")
        if self._state("checking the gripper").manipulator_state.is_gripper_holding_item:
            return PlaceResult(False, Reason.GRASP_SLIPPED, "the object is still in the claw after opening",
                               duration=time.monotonic() - t0)
        return PlaceResult(True, Reason.OK, "released the object", duration=time.monotonic() - t0,
                           release_point=release)

    # ================================================================== misc
    @_closing_aware
    def stand(self) -> CommandResult:
        """Power on (if needed) and stand. After an e-stop was released, this re-powers the robot."""
        self._check_open()
        if isinstance(self._fault, (EstopError, PowerError)):
            self._fault = None            # retry: the checks below raise again if nothing changed
        self._guard()
        cfg, bd = self.config, self._bd
        t0 = time.monotonic()
        self._power_wanted = True
        state = self._state("checking motor power")
        if state.power_state.motor_power_state != state.power_state.MOTOR_POWER_STATE_ON:
            _LOG.info("powering on")
            self._call(self.robot.power_on, timeout_sec=cfg.power_on_timeout,
                       update_frequency=1.0 / cfg.feedback_period, timeout=cfg.rpc_timeout, during="powering on")
        S = bd.basic.StandCommand.Feedback

        def done(fb):
            st = fb.feedback.synchronized_feedback.mobility_command_feedback.stand_feedback.status
            return st == S.STATUS_IS_STANDING, True

        ok, _, _ = self._run_command(bd.Builder.synchro_stand_command(), during="standing up",
                                     expected=cfg.stand_timeout, done=done)
        ok = bool(ok)
        took = time.monotonic() - t0
        return CommandResult(ok, Reason.OK if ok else Reason.STOPPED, "standing" if ok else "stand was interrupted",
                             duration=took)

    @_closing_aware
    def stop(self) -> CommandResult:
        if self._closing_elsewhere() and not self._closed:
            return CommandResult(True, Reason.OK, "close() is stopping the robot and shutting it down")
        self._check_open()
        if isinstance(self._fault, (EstopError, PowerError)):
            return CommandResult(True, Reason.OK, f"motion is already cut: {self._fault}")
        self._guard()
        t0 = time.monotonic()
        self._call(self._cmd_client.robot_command, self._bd.Builder.stop_command(), moves=True,
                   timeout=self.config.rpc_timeout,
                   during="stopping")
        return CommandResult(True, Reason.OK, "holding position", duration=time.monotonic() - t0)

    def __enter__(self) -> "SdkSpotBackend":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
