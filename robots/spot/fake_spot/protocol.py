"""The Spot API messages of the fake Spot: those its RPC handlers (``servicer.py``) answer with,
built from the simulator and the robot's bookkeeping (the robot state with its kinematic tree,
power and e-stop states; image responses; robot command feedback), and the ``RobotCommand``
requests they accept, parsed and checked into a command kind and its arguments, or refused
(:class:`Reject`).

Apart from the handlers because it is the translation between Spot's protos and the fake's world,
read (and checked against the SDK's messages) on its own. ``fake`` is the
:class:`~robots.spot.fake_spot.server.FakeSpot`, named in annotations only: ``server.py`` imports
the handlers, which import this module, so this module cannot import it.
"""

from __future__ import annotations

import math

import numpy as np
from bosdyn.api import (
    arm_command_pb2,
    basic_command_pb2,
    estop_pb2,
    gripper_command_pb2,
    image_pb2,
    robot_command_pb2,
    robot_state_pb2,
)

from robots.hal import Observation
from robots.spot import model
from robots.spot import sdk_conversions as cv
from robots.spot.fake_spot.bookkeeping import Command
from robots.spot.fake_spot.sim_robot import FakeRobotSim, TimedSE2Path
from robots.transforms import invert_transform, make_transform, rot_z

_FB = basic_command_pb2.RobotCommandFeedbackStatus
_MAX_ARM_POINTS = 250


# ====================================================================== robot state and images
def _flat_body(T_world_body: np.ndarray) -> np.ndarray:
    yaw = math.atan2(T_world_body[1, 0], T_world_body[0, 0])
    return make_transform(rot_z(yaw), T_world_body[:3, 3])


def kinematic_tree(sim: FakeRobotSim) -> dict:
    """Frame edges {child: (parent, T_parent_child)} rooted at body, as Spot publishes them."""
    T_wb = sim.spot.T_world_body()
    T_bw = invert_transform(T_wb)
    T_wwr = sim.spot.link_pose(cv.WRIST)
    return {
        cv.BODY: ("", np.eye(4)),
        cv.ODOM: (cv.BODY, T_bw),
        cv.VISION: (cv.BODY, T_bw),
        cv.FLAT_BODY: (cv.BODY, T_bw @ _flat_body(T_wb)),
        cv.HAND: (cv.BODY, T_bw @ sim.spot.T_world_hand()),
        cv.WRIST: (cv.BODY, T_bw @ T_wwr),
        cv.HAND_COLOR_SENSOR: (cv.WRIST, invert_transform(T_wwr) @ sim.spot.T_world_camera()),
    }


def robot_state(fake: FakeSpot) -> robot_state_pb2.RobotState:
    """The robot state message (sim_lock held)."""
    sim = fake.sim
    state = robot_state_pb2.RobotState()
    ks = state.kinematic_state
    ks.acquisition_timestamp.CopyFrom(cv.seconds_to_timestamp(fake.robot_now()))
    ks.transforms_snapshot.CopyFrom(cv.frame_tree(kinematic_tree(sim)))
    joints = sim.spot.joint_positions()
    for name, q in joints.items():
        js = ks.joint_states.add()
        js.name = name
        js.position.value = float(q)
        js.velocity.value = 0.0
    fill_status(fake, state)
    ms = state.manipulator_state
    ms.is_gripper_holding_item = sim.holding
    ms.gripper_open_percentage = float(100.0 * min(1.0, max(0.0, sim.gripper_angle / model.GRIPPER_LIMITS[0])))
    ms.stow_state = (robot_state_pb2.ManipulatorState.STOWSTATE_STOWED if sim.arm_is_stowed()
                     else robot_state_pb2.ManipulatorState.STOWSTATE_DEPLOYED)
    ms.carry_state = (robot_state_pb2.ManipulatorState.CARRY_STATE_CARRIABLE_AND_STOWABLE if sim.holding
                      else robot_state_pb2.ManipulatorState.CARRY_STATE_UNKNOWN)
    return state


def fill_status(fake: FakeSpot, state: robot_state_pb2.RobotState) -> None:
    """Power, behavior fault and e-stop states (bookkeeping, never stale)."""
    with fake._lock:
        powering_on = fake.powering_on()
        powered = fake.powered
        endpoints = list(fake._endpoints.values())
        hw = "estop" in fake.faults
        fault = fake.behavior_fault
        charge = fake.battery_charge
        system_faults = list(fake.system_faults)
    del state.behavior_fault_state.faults[:]
    if fault is not None:
        state.behavior_fault_state.faults.add().CopyFrom(fault)
    # the battery and the system faults (robot_state.proto: BatteryState, SystemFaultState with its
    # "aggregated" map of the worst severity per attribute, PowerState.locomotion_charge_percentage)
    del state.battery_states[:]
    battery = state.battery_states.add(identifier="battery", status=robot_state_pb2.BatteryState.STATUS_DISCHARGING)
    battery.charge_percentage.value = charge
    battery.timestamp.CopyFrom(cv.seconds_to_timestamp(fake.robot_now()))
    state.power_state.locomotion_charge_percentage.value = charge
    del state.system_fault_state.faults[:]
    state.system_fault_state.aggregated.clear()
    for f in system_faults:
        state.system_fault_state.faults.add().CopyFrom(f)
        for attribute in f.attributes:
            worst = state.system_fault_state.aggregated.get(attribute, 0)
            state.system_fault_state.aggregated[attribute] = max(worst, f.severity)
    del state.estop_states[:]
    PS = robot_state_pb2.PowerState
    state.power_state.motor_power_state = (PS.MOTOR_POWER_STATE_POWERING_ON if powering_on else
                                           PS.MOTOR_POWER_STATE_ON if powered else PS.MOTOR_POWER_STATE_OFF)
    state.power_state.timestamp.CopyFrom(cv.seconds_to_timestamp(fake.robot_now()))
    es = state.estop_states.add()
    es.name, es.type = "hardware_estop", robot_state_pb2.EStopState.TYPE_HARDWARE
    es.state = robot_state_pb2.EStopState.STATE_ESTOPPED if hw else robot_state_pb2.EStopState.STATE_NOT_ESTOPPED
    for ep in endpoints:
        s = state.estop_states.add()
        s.name, s.type = ep.proto.name, robot_state_pb2.EStopState.TYPE_SOFTWARE
        s.state = (robot_state_pb2.EStopState.STATE_NOT_ESTOPPED if ep.level == estop_pb2.ESTOP_LEVEL_NONE
                   else robot_state_pb2.EStopState.STATE_ESTOPPED)


def image_response(fake: FakeSpot, req: image_pb2.ImageRequest, obs: Observation, snapshot,
                    acquired: float) -> image_pb2.ImageResponse:
    resp = image_pb2.ImageResponse()
    name = req.image_source_name
    intr = obs.intrinsics
    resp.source.name = name
    resp.source.rows, resp.source.cols = intr.height, intr.width
    resp.source.pinhole.CopyFrom(cv.intrinsics_to_pinhole(intr))
    resp.shot.acquisition_time.CopyFrom(cv.seconds_to_timestamp(acquired))
    resp.shot.transforms_snapshot.CopyFrom(snapshot)
    resp.shot.frame_name_image_sensor = cv.HAND_COLOR_SENSOR
    img = resp.shot.image
    img.rows, img.cols = intr.height, intr.width
    if name == cv.HAND_COLOR_SOURCE:
        resp.source.image_type = image_pb2.ImageSource.IMAGE_TYPE_VISUAL
        resp.source.pixel_formats.append(image_pb2.Image.PIXEL_FORMAT_RGB_U8)
        resp.source.image_formats.extend([image_pb2.Image.FORMAT_JPEG, image_pb2.Image.FORMAT_RAW])
        fmt = req.image_format or image_pb2.Image.FORMAT_JPEG
        if req.pixel_format not in (image_pb2.Image.PIXEL_FORMAT_UNKNOWN, image_pb2.Image.PIXEL_FORMAT_RGB_U8):
            resp.status = image_pb2.ImageResponse.STATUS_UNSUPPORTED_PIXEL_FORMAT_REQUESTED
            return resp
        if fmt not in (image_pb2.Image.FORMAT_JPEG, image_pb2.Image.FORMAT_RAW):
            resp.status = image_pb2.ImageResponse.STATUS_UNSUPPORTED_IMAGE_FORMAT_REQUESTED
            return resp
        quality = int(req.quality_percent) if req.quality_percent > 0 else fake.jpeg_quality
        img.format, img.pixel_format = fmt, image_pb2.Image.PIXEL_FORMAT_RGB_U8
        img.data = cv.encode_rgb(obs.rgb, fmt, quality)
    else:  # registered depth
        resp.source.image_type = image_pb2.ImageSource.IMAGE_TYPE_DEPTH
        resp.source.depth_scale = fake.depth_scale
        resp.source.pixel_formats.append(image_pb2.Image.PIXEL_FORMAT_DEPTH_U16)
        resp.source.image_formats.append(image_pb2.Image.FORMAT_RAW)
        if req.pixel_format not in (image_pb2.Image.PIXEL_FORMAT_UNKNOWN, image_pb2.Image.PIXEL_FORMAT_DEPTH_U16):
            resp.status = image_pb2.ImageResponse.STATUS_UNSUPPORTED_PIXEL_FORMAT_REQUESTED
            return resp
        if req.image_format not in (image_pb2.Image.FORMAT_UNKNOWN, image_pb2.Image.FORMAT_RAW):
            resp.status = image_pb2.ImageResponse.STATUS_UNSUPPORTED_IMAGE_FORMAT_REQUESTED
            return resp
        img.format, img.pixel_format = image_pb2.Image.FORMAT_RAW, image_pb2.Image.PIXEL_FORMAT_DEPTH_U16
        img.data = cv.encode_depth(obs.depth, fake.depth_scale)
    resp.status = image_pb2.ImageResponse.STATUS_OK
    return resp


# ====================================================================== request parsing
class Reject(Exception):
    """A command the robot refuses: carries the RobotCommandResponse status and a message."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


def _world_from(fake: FakeSpot, frame: str, T: np.ndarray) -> np.ndarray:
    """A pose given in a Spot frame (odom, vision, body, flat_body) to world (sim_lock held)."""
    if frame in cv.WORLD_FRAMES:
        return T
    T_wb = fake.sim.spot.T_world_body()
    if frame == cv.BODY:
        return T_wb @ T
    if frame == cv.FLAT_BODY:
        return _flat_body(T_wb) @ T
    raise Reject(robot_command_pb2.RobotCommandResponse.STATUS_UNKNOWN_FRAME, f"unknown frame {frame!r}")


def parse_command(fake: FakeSpot, cmd: robot_command_pb2.RobotCommand, request) -> tuple[str, dict]:
    """(kind, extra) of a RobotCommand, or raise Reject. One sub-command per request."""
    R = robot_command_pb2.RobotCommandResponse
    if cmd.HasField("full_body_command"):
        which = cmd.full_body_command.WhichOneof("command")
        if which == "stop_request":
            return "stop", {"full_body": True}
        if which == "safe_power_off_request":
            return "safe_power_off", {}
        raise Reject(R.STATUS_UNSUPPORTED, f"full-body {which} is not supported by the fake")
    sync = cmd.synchronized_command
    parts = [p for p in ("mobility_command", "arm_command", "gripper_command") if sync.HasField(p)]
    if len(parts) != 1:
        raise Reject(R.STATUS_UNSUPPORTED, "the fake executes exactly one sub-command per RobotCommand")
    part = parts[0]
    if part == "mobility_command":
        which = sync.mobility_command.WhichOneof("command")
        if which == "stand_request":
            return "stand", {}
        if which == "sit_request":
            return "sit", {}
        if which == "stop_request":
            return "stop", {"full_body": False}
        if which == "se2_trajectory_request":
            se2 = sync.mobility_command.se2_trajectory_request
            if se2.se2_frame_name not in cv.WORLD_FRAMES:
                raise Reject(R.STATUS_UNKNOWN_FRAME, f"SE2 trajectories must be in odom or vision, "
                                                      f"not {se2.se2_frame_name!r}")
            if not se2.HasField("end_time"):
                raise Reject(R.STATUS_INVALID_REQUEST, "trajectory commands need an end time")
            if cv.timestamp_to_seconds(se2.end_time) < fake.robot_now():
                raise Reject(R.STATUS_EXPIRED, "the command's end time has passed")
            if cv.timestamp_to_seconds(se2.end_time) > fake.robot_now() + 600.0:
                raise Reject(R.STATUS_TOO_DISTANT, "the command's end time is too far in the future")
            pts = se2.trajectory.points
            if not pts:
                raise Reject(R.STATUS_INVALID_REQUEST, "empty SE2 trajectory")
            try:
                path = TimedSE2Path([cv.duration_to_seconds(p.time_since_reference) for p in pts],
                                    [cv.proto_to_se2(p.pose) for p in pts])
            except ValueError as exc:
                raise Reject(R.STATUS_INVALID_REQUEST, str(exc)) from None
            return "se2", {"path": path, "end_time": cv.timestamp_to_seconds(se2.end_time)}
        raise Reject(R.STATUS_UNSUPPORTED, f"mobility {which} is not supported by the fake")
    if part == "gripper_command":
        claw = sync.gripper_command.claw_gripper_command
        if not sync.gripper_command.HasField("claw_gripper_command") or not claw.trajectory.points:
            raise Reject(R.STATUS_INVALID_REQUEST, "gripper commands need a claw trajectory")
        return "claw", {"angle": float(claw.trajectory.points[-1].point)}
    arm = sync.arm_command
    which = arm.WhichOneof("command")
    if which == "arm_joint_move_command":
        pts = arm.arm_joint_move_command.trajectory.points
        if not pts or len(pts) > _MAX_ARM_POINTS:
            raise Reject(R.STATUS_INVALID_REQUEST, f"arm joint trajectories need 1..{_MAX_ARM_POINTS} points, "
                                                    f"got {len(pts)}")
        times = [cv.duration_to_seconds(p.time_since_reference) for p in pts]
        if any(b <= a for a, b in zip(times[:-1], times[1:])):
            raise Reject(R.STATUS_INVALID_REQUEST, "arm trajectory times must increase strictly")
        with fake.sim_for_rpc("reading the arm"):
            current = fake.sim.spot.arm_q()
        goal = current.copy()
        last = pts[-1].position
        for i, name in enumerate(("sh0", "sh1", "el0", "el1", "wr0", "wr1")):
            if last.HasField(name):
                goal[i] = getattr(last, name).value
        lo, hi = model.arm_limits_array()
        if np.any(goal < lo - 1e-6) or np.any(goal > hi + 1e-6):
            raise Reject(R.STATUS_INVALID_REQUEST, "arm trajectory leaves the joint limits")
        return "arm_joint", {"goal": np.clip(goal, lo, hi)}
    if which == "arm_cartesian_command":
        c = arm.arm_cartesian_command
        if not c.pose_trajectory_in_task.points:
            raise Reject(R.STATUS_INVALID_REQUEST, "empty hand trajectory")
        T_task_hand = cv.se3_to_matrix(c.pose_trajectory_in_task.points[-1].pose)
        T_root_task = cv.se3_to_matrix(c.root_tform_task) if c.HasField("root_tform_task") else np.eye(4)
        if c.HasField("wrist_tform_tool"):
            raise Reject(R.STATUS_UNSUPPORTED, "the fake supports the default tool frame (hand) only")
        with fake.sim_for_rpc("reading the hand frame"):
            T_world_hand = _world_from(fake, c.root_frame_name, T_root_task @ T_task_hand)
            T_body_hand = invert_transform(fake.sim.spot.T_world_body()) @ T_world_hand
        return "arm_cartesian", {"T_body_hand": T_body_hand}
    if which == "arm_gaze_command":
        g = arm.arm_gaze_command
        if not g.target_trajectory_in_frame1.points:
            raise Reject(R.STATUS_INVALID_REQUEST, "empty gaze target trajectory")
        p = g.target_trajectory_in_frame1.points[-1].point
        with fake.sim_for_rpc("reading the gaze frame"):
            T = _world_from(fake, g.frame1_name, make_transform(None, (p.x, p.y, p.z)))
        return "arm_gaze", {"point": T[:3, 3].copy()}
    if which == "named_arm_position_command":
        return "arm_named", {"position": arm.named_arm_position_command.position}
    if which == "arm_stop_command":
        return "arm_stop", {}
    raise Reject(R.STATUS_UNSUPPORTED, f"arm {which} is not supported by the fake")


def untimed(cmd: robot_command_pb2.RobotCommand) -> bool:
    """Stop, sit and safe power off: commands without a time, which need no time sync."""
    if cmd.HasField("full_body_command"):
        return cmd.full_body_command.WhichOneof("command") in ("stop_request", "safe_power_off_request")
    sync = cmd.synchronized_command
    parts = [p for p in ("mobility_command", "arm_command", "gripper_command") if sync.HasField(p)]
    return parts == ["mobility_command"] and \
        sync.mobility_command.WhichOneof("command") in ("stop_request", "sit_request")


# ====================================================================== feedback
def feedback(cmd: Command) -> robot_command_pb2.RobotCommandFeedback:
    fb = robot_command_pb2.RobotCommandFeedback()
    done = cmd.state == "done"
    ended = cmd.state in ("overridden", "frozen", "timed_out")
    outer = (_FB.STATUS_PROCESSING if not ended else
             _FB.STATUS_COMMAND_OVERRIDDEN if cmd.state == "overridden" else
             _FB.STATUS_COMMAND_TIMED_OUT if cmd.state == "timed_out" else _FB.STATUS_ROBOT_FROZEN)
    ok = done and cmd.success
    k = cmd.kind
    if k in ("stop", "safe_power_off") and cmd.extra.get("full_body", True):
        fb.full_body_feedback.status = outer
        if k == "stop":
            fb.full_body_feedback.stop_feedback.SetInParent()
        else:
            fb.full_body_feedback.safe_power_off_feedback.status = (
                basic_command_pb2.SafePowerOffCommand.Feedback.STATUS_POWERED_OFF if done
                else basic_command_pb2.SafePowerOffCommand.Feedback.STATUS_IN_PROGRESS)
        return fb
    sync = fb.synchronized_feedback
    if k in ("stand", "sit", "se2", "stop"):
        mob = sync.mobility_command_feedback
        mob.status = outer
        if k == "stand":
            mob.stand_feedback.status = (basic_command_pb2.StandCommand.Feedback.STATUS_IS_STANDING if done
                                         else basic_command_pb2.StandCommand.Feedback.STATUS_IN_PROGRESS)
        elif k == "sit":
            mob.sit_feedback.status = (basic_command_pb2.SitCommand.Feedback.STATUS_IS_SITTING if done
                                       else basic_command_pb2.SitCommand.Feedback.STATUS_IN_PROGRESS)
        elif k == "stop":
            mob.stop_feedback.SetInParent()
        else:
            F = basic_command_pb2.SE2TrajectoryCommand.Feedback
            se2 = mob.se2_trajectory_feedback
            if done:
                se2.status = F.STATUS_AT_GOAL if ok else F.STATUS_STOPPED
                se2.body_movement_status = F.BODY_STATUS_SETTLED
                se2.final_goal_status = (F.FINAL_GOAL_STATUS_BLOCKED if cmd.extra.get("blocked")
                                         else F.FINAL_GOAL_STATUS_ACHIEVABLE)
            else:
                se2.status = F.STATUS_GOING_TO_GOAL if not ended else F.STATUS_STOPPED
                se2.body_movement_status = F.BODY_STATUS_MOVING
                se2.final_goal_status = F.FINAL_GOAL_STATUS_IN_PROGRESS
        return fb
    if k == "claw":
        g = sync.gripper_command_feedback
        g.status = outer
        C = gripper_command_pb2.ClawGripperCommand.Feedback
        g.claw_gripper_feedback.status = C.STATUS_AT_GOAL if done else C.STATUS_IN_PROGRESS
        return fb
    arm = sync.arm_command_feedback
    arm.status = outer
    A = arm_command_pb2
    if k == "arm_joint":
        S = A.ArmJointMoveCommand.Feedback
        arm.arm_joint_move_feedback.status = (S.STATUS_COMPLETE if ok else S.STATUS_STALLED if done
                                              else S.STATUS_IN_PROGRESS)
    elif k == "arm_cartesian":
        S = A.ArmCartesianCommand.Feedback
        arm.arm_cartesian_feedback.status = (S.STATUS_TRAJECTORY_COMPLETE if ok else S.STATUS_TRAJECTORY_STALLED
                                             if done else S.STATUS_TRAJECTORY_CANCELLED if ended
                                             else S.STATUS_IN_PROGRESS)
    elif k == "arm_gaze":
        S = A.GazeCommand.Feedback
        arm.arm_gaze_feedback.status = (S.STATUS_TRAJECTORY_COMPLETE if ok else S.STATUS_TOOL_TRAJECTORY_STALLED
                                        if done else S.STATUS_IN_PROGRESS)
    elif k == "arm_named":
        S = A.NamedArmPositionsCommand.Feedback
        arm.named_arm_position_feedback.status = (S.STATUS_COMPLETE if ok else S.STATUS_STALLED_HOLDING_ITEM
                                                  if done else S.STATUS_IN_PROGRESS)
    elif k == "arm_stop":
        arm.arm_stop_feedback.SetInParent()
    return fb
