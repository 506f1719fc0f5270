"""How the fake Spot carries out an accepted command on the simulator: each command kind (SE2
trajectory, arm joint, Cartesian, gaze and named moves, arm stop, claw, pick-in-image) becomes a
call of the sim backend's robot-level primitives, and their result the command's outcome
(success, detail, and what its feedback reports, such as a pick's manipulation state).

Runs on the fake's robot thread with ``sim_lock`` held (``FakeSpot._execute``). Apart from the
robot's state machine (``server.py``) because it is the one place where SDK commands meet the
simulator. ``fake`` is the :class:`~robots.spot.fake_spot.server.FakeSpot`, named in annotations
only: ``server.py`` imports this module, so this module cannot import it.
"""

from __future__ import annotations

from bosdyn.api import arm_command_pb2, manipulation_api_pb2

from robots.hal import Reason
from robots.spot import model
from robots.spot.fake_spot.bookkeeping import Command


def execute_on_sim(fake: FakeSpot, cmd: Command) -> tuple[bool, str, dict]:
    """Run one accepted command on the simulator (robot thread, sim_lock held)."""
    sim = fake.sim
    if cmd.kind == "se2":
        res = sim.follow_base_path(cmd.extra["path"])
        return res.success, res.message, {"blocked": res.reason is Reason.COLLISION}
    if cmd.kind == "arm_joint":
        res = sim.move_arm_joints(cmd.extra["goal"])
        return res.success, res.message, {}
    if cmd.kind == "arm_cartesian":
        res = sim.move_hand(cmd.extra["T_body_hand"])
        return res.success, res.message, {}
    if cmd.kind == "arm_gaze":
        res = sim.gaze_at(cmd.extra["point"])
        return res.success, res.message, {}
    if cmd.kind == "arm_named":
        pos = cmd.extra["position"]
        if pos == arm_command_pb2.NamedArmPositionsCommand.POSITIONS_STOW and sim.holding:
            return False, "cannot stow while holding an item", {"holding_item": True}
        if pos == arm_command_pb2.NamedArmPositionsCommand.POSITIONS_READY:
            res = sim.move_arm_joints(model.ARM_READY)
        else:  # stow, or carry (the sim's stow goes to its carry pose while holding)
            res = sim.stow_arm()
        return res.success, res.message, {}
    if cmd.kind == "arm_stop":
        sim.stop()
        return True, "", {}
    if cmd.kind == "claw":
        sim.set_claw(cmd.extra["angle"])
        return True, "", {}
    if cmd.kind == "pick":
        return _pick_on_sim(fake, cmd)
    return False, f"unsupported command {cmd.kind}", {}


def _pick_on_sim(fake: FakeSpot, cmd: Command) -> tuple[bool, str, dict]:
    sim = fake.sim
    if fake.has_fault("grasp_failure"):
        return False, "grasp failure (fault injection)", {"manip_state": manipulation_api_pb2.MANIP_STATE_GRASP_FAILED}
    T_world_cam = cmd.extra["T_world_cam"]
    obs = fake.find_frame(T_world_cam)
    if obs is None:
        obs = sim.render_at(T_world_cam)
    u, v = cmd.extra["pixel"]
    if not (0 <= u < obs.intrinsics.width and 0 <= v < obs.intrinsics.height):
        return False, "pixel outside the image", {"manip_state": manipulation_api_pb2.MANIP_STATE_GRASP_FAILED_TO_RAYCAST_INTO_MAP}
    sim.last_grasp_hand_pose = None
    res = sim.grasp(obs, (u, v))
    if res.success:
        state = manipulation_api_pb2.MANIP_STATE_GRASP_SUCCEEDED
    elif res.reason in (Reason.OUT_OF_REACH, Reason.IK_FAILED):
        state = manipulation_api_pb2.MANIP_STATE_GRASP_PLANNING_NO_SOLUTION
    elif res.reason is Reason.NO_DEPTH:
        state = manipulation_api_pb2.MANIP_STATE_GRASP_FAILED_TO_RAYCAST_INTO_MAP
    else:
        state = manipulation_api_pb2.MANIP_STATE_GRASP_FAILED
    extra = {"manip_state": state}
    if sim.last_grasp_hand_pose is not None:
        extra["grasp_hand_pose"] = sim.last_grasp_hand_pose
    return res.success, res.message, extra
