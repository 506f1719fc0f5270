"""The HAL contract every backend must meet. The sim backend runs it here; the SDK backend (against
the fake Spot) joins the same suite through the ``backend_factory`` parameter."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robots.hal import (
    CommandResult,
    GraspResult,
    NavigateResult,
    Observation,
    PlaceResult,
    Reason,
    RobotBackend,
    SE2Pose,
)
from robots.spot import kinematics, model


def _sim_backend():
    """Spot in the demo scene. Returns (backend, scene facts the test may use: mug and table tops)."""
    from robots.spot.sim_backend import SimSpotBackend
    from sim.scenes.demo import build_demo_scene
    from sim.spot import SpotBody
    from sim.world import World

    world = World()
    scene = build_demo_scene(world, np.random.default_rng(0))
    backend = SimSpotBackend(world, SpotBody(world, scene["robot_start"]))
    facts = {"mug_position": world.position(scene["mug"]),
             "place_table": world.position(world.body("table_place").body_id)[:2],
             "table_height": scene["layout"].table_height}
    return backend, facts


def _sdk_backend():
    """The Spot SDK backend, through the unmodified bosdyn client over TLS, against the fake Spot
    (gRPC on 127.0.0.1, backed by the same PyBullet demo scene)."""
    pytest.importorskip("bosdyn.client")   # the optional [spot] extra
    from spot_fake_fixtures import sdk_backend_factory

    return sdk_backend_factory()


BACKENDS = {"sim": _sim_backend, "sdk": _sdk_backend}


@pytest.fixture(params=sorted(BACKENDS))
def backend_and_facts(request):
    backend, facts = BACKENDS[request.param]()
    yield backend, facts
    backend.close()


def _pixel_of(obs: Observation, point) -> tuple[int, int]:
    p_cam = np.linalg.inv(obs.T_world_cam) @ np.append(point, 1.0)
    (u, v), _ = obs.intrinsics.project(p_cam[:3])
    return int(round(float(u))), int(round(float(v)))


def test_backend_implements_the_protocol(backend_and_facts):
    backend, _ = backend_and_facts
    assert isinstance(backend, RobotBackend)


def test_observe_returns_a_consistent_frame(backend_and_facts):
    backend, _ = backend_and_facts
    a = backend.observe()
    assert isinstance(a, Observation)
    assert a.rgb.shape == (a.intrinsics.height, a.intrinsics.width, 3)
    assert a.depth.dtype == np.float32 and np.all(a.depth >= 0)
    assert set(model.ARM_JOINTS) <= set(a.joint_positions)
    assert backend.stand().success
    res = backend.navigate_to(SE2Pose(0.3, 0.0, 0.0))
    b = backend.observe()
    assert b.frame_id > a.frame_id and b.stamp >= a.stamp + res.duration - 1e-6


def test_navigate_reaches_the_goal(backend_and_facts):
    backend, _ = backend_and_facts
    goal = SE2Pose(0.6, -0.4, math.radians(30))
    res = backend.navigate_to(goal, via=[SE2Pose(0.3, 0.0, 0.0)])
    assert isinstance(res, NavigateResult) and res.success and res.reason is Reason.OK
    assert res.final_pose.distance_to(goal) < 0.05
    assert abs(res.final_pose.yaw - goal.yaw) < 0.05
    assert backend.observe().body_pose.distance_to(goal) < 0.05


def test_arm_moves_and_gaze(backend_and_facts):
    backend, facts = backend_and_facts
    res = backend.move_arm_joints(model.ARM_READY)
    assert isinstance(res, CommandResult) and res.success
    q = [backend.observe().joint_positions[j] for j in model.ARM_JOINTS]
    np.testing.assert_allclose(q, model.ARM_READY, atol=0.03)
    T = kinematics.hand_pose(model.ARM_READY)
    T[2, 3] -= 0.1
    assert backend.move_hand(T).success
    target = facts["mug_position"]
    assert backend.gaze_at(target).success
    obs = backend.observe()
    u, v = _pixel_of(obs, target)
    assert abs(u - obs.intrinsics.cx) < 0.1 * obs.intrinsics.width
    assert abs(v - obs.intrinsics.cy) < 0.1 * obs.intrinsics.height
    assert backend.stow_arm().success
    assert backend.stop().success


def _grasp_the_mug_from(backend, facts, distance: float):
    """Stand ``distance`` m short of the mug, look at it and grasp at its pixel: (observation,
    pixel, result)."""
    mug = facts["mug_position"]
    assert backend.navigate_to(SE2Pose(mug[0] - distance, mug[1], 0.0)).success
    assert backend.gaze_at(mug + [0, 0, 0.05]).success
    obs = backend.observe()
    pixel = _pixel_of(obs, mug + [0, 0, 0.05])
    return obs, pixel, backend.grasp(obs, pixel)


def test_grasp_and_place_cycle(backend_and_facts):
    backend, facts = backend_and_facts
    mug = facts["mug_position"]
    obs, pixel, res = _grasp_the_mug_from(backend, facts, 0.95)
    assert isinstance(res, GraspResult) and res.success and res.holding
    assert backend.observe().holding
    # where it grasped: the observation's point at the pixel, in the world frame (on the mug)
    np.testing.assert_allclose(res.target_world, obs.point_at_pixel(*pixel), atol=1e-6)
    assert np.linalg.norm(np.asarray(res.target_world)[:2] - mug[:2]) < 0.08
    again = backend.grasp(backend.observe(), (10, 10))
    assert not again.success and again.reason is Reason.ALREADY_HOLDING
    assert backend.stow_arm().success and backend.observe().holding
    tx, ty = facts["place_table"]
    here = backend.observe().body_pose
    heading = math.atan2(ty - here.y, tx - here.x)
    stand = SE2Pose(tx - 1.05 * math.cos(heading), ty - 1.05 * math.sin(heading), heading)
    assert backend.navigate_to(stand).success
    near_edge = np.array([tx, ty]) - 0.25 * np.array([math.cos(heading), math.sin(heading)])
    placed = backend.place([near_edge[0], near_edge[1], facts["table_height"]])
    assert isinstance(placed, PlaceResult) and placed.success
    assert not backend.observe().holding
    # where it let go: over the point, in the world frame, above the table by the release height
    assert np.linalg.norm(np.asarray(placed.release_point[:2]) - near_edge) < 0.1
    assert facts["table_height"] + 0.10 <= placed.release_point[2] <= facts["table_height"] + 0.35
    empty = backend.place([near_edge[0], near_edge[1], facts["table_height"]])
    assert not empty.success and empty.reason is Reason.NOT_HOLDING


@pytest.mark.parametrize("name", sorted(BACKENDS))
def test_every_command_after_close_raises_backend_closed(name):
    from robots.hal import BackendClosedError, HalError

    backend, _ = BACKENDS[name]()
    obs = backend.observe()
    backend.close()
    backend.close()                                   # twice is fine
    commands = [lambda: backend.observe(), lambda: backend.navigate_to(SE2Pose(0.1, 0.0, 0.0)),
                lambda: backend.move_arm_joints(model.ARM_READY), lambda: backend.gaze_at([1.0, 0.0, 0.5]),
                lambda: backend.stow_arm(), lambda: backend.stand(), lambda: backend.stop(),
                lambda: backend.move_hand(kinematics.hand_pose(model.ARM_READY)),
                lambda: backend.grasp(obs, (10, 10)), lambda: backend.place([1.0, 0.0, 0.5])]
    for command in commands:
        with pytest.raises(BackendClosedError, match="closed") as info:
            command()
        assert isinstance(info.value, HalError) and isinstance(info.value, RuntimeError)



# ------------------------------------------------------------------------------------------------
# Obligations a HAL-contract audit found unchecked on one backend or both (2026-12-05): each of
# these tests failed under a realistic break of one backend that the suite above let through
# ------------------------------------------------------------------------------------------------
def test_stop_twice_is_fine_and_the_robot_still_moves_after(backend_and_facts):
    backend, _ = backend_and_facts
    assert backend.stop().success and backend.stop().success
    assert backend.navigate_to(SE2Pose(0.2, 0.0, 0.0)).success


def test_results_report_the_path_walked_and_a_duration(backend_and_facts):
    """``distance`` is the path's length (via the waypoint), not the straight line; every command
    reports how long it took (the sim: the plan's duration on its clock)."""
    from robots.spot.motion import plan_base

    backend, _ = backend_and_facts
    start = backend.observe().body_pose
    via, goal = SE2Pose(0.3, 0.0, 0.0), SE2Pose(0.6, -0.4, 0.0)
    nav = backend.navigate_to(goal, via=[via])
    assert nav.success and nav.duration > 0
    assert nav.distance == pytest.approx(0.3 + math.hypot(0.3, 0.4), abs=0.02)
    if type(backend).__name__ == "SimSpotBackend":      # the unpaced fake's robot clock runs as fast as it can
        assert nav.duration == pytest.approx(plan_base(start, [via, goal], backend.config.motion.base).duration,
                                             abs=0.06)
    for what, res in (("arm", backend.move_arm_joints(model.ARM_READY)), ("gaze", backend.gaze_at([2.0, 0.0, 0.3])),
                      ("stow", backend.stow_arm())):
        assert res.success and res.duration > 0, what


@pytest.mark.parametrize("call", ["gaze", "place", "release_height", "hand", "arm", "via", "non-rigid hand"])
def test_a_bad_argument_raises_before_anything_moves(backend_and_facts, call):
    from robots.hal import InvalidCommandError

    backend, _ = backend_and_facts
    before = backend.observe()
    nan_hand = kinematics.hand_pose(model.ARM_READY)
    nan_hand[0, 3] = np.nan
    sheared = kinematics.hand_pose(model.ARM_READY)
    sheared[0, 1] += 0.2                              # finite, but not a rotation (sim said IK_FAILED, sdk raised)
    calls = {"gaze": lambda: backend.gaze_at([1.0, np.nan, 0.5]),
             "place": lambda: backend.place([1.0, np.nan, 0.5]),
             "release_height": lambda: backend.place([1.0, 0.0, 0.5], release_height=float("nan")),
             "hand": lambda: backend.move_hand(nan_hand), "non-rigid hand": lambda: backend.move_hand(sheared),
             "arm": lambda: backend.move_arm_joints([0, np.nan, 0, 0, 0, 0]),
             "via": lambda: backend.navigate_to(SE2Pose(0.1, 0, 0), via=[(np.nan, 0.0, 0.0)])}
    with pytest.raises(InvalidCommandError):
        calls[call]()
    after = backend.observe()
    assert after.body_pose.distance_to(before.body_pose) < 1e-6
    np.testing.assert_allclose([after.joint_positions[j] for j in model.ARM_JOINTS],
                               [before.joint_positions[j] for j in model.ARM_JOINTS], atol=1e-6)


def test_a_gaze_the_arm_cannot_make_is_unreachable_and_leaves_the_body_where_it_is(backend_and_facts):
    backend, _ = backend_and_facts
    before = backend.observe().body_pose
    res = backend.gaze_at([before.x - 2.0, before.y, 0.5])      # straight behind the robot
    after = backend.observe().body_pose
    assert not res.success and res.reason is Reason.UNREACHABLE
    assert after.distance_to(before) < 1e-3 and abs(after.yaw - before.yaw) < 1e-3


def test_a_grasp_from_too_far_is_out_of_reach(backend_and_facts):
    backend, facts = backend_and_facts
    _, _, res = _grasp_the_mug_from(backend, facts, 1.6)
    assert not res.success and not res.holding and res.reason is Reason.OUT_OF_REACH
    assert not backend.observe().holding


def test_a_hand_pose_out_of_reach_is_ik_failed(backend_and_facts):
    backend, _ = backend_and_facts
    T = np.eye(4)
    T[:3, 3] = (3.0, 0.0, 0.5)
    res = backend.move_hand(T)
    assert not res.success and res.reason is Reason.IK_FAILED


def test_a_walk_into_a_table_is_a_collision_at_the_last_free_pose(backend_and_facts):
    backend, facts = backend_and_facts
    mug = facts["mug_position"]
    goal = SE2Pose(mug[0] + 0.5, mug[1], 0.0)                     # through the pick table
    res = backend.navigate_to(goal)
    assert not res.success and res.reason is Reason.COLLISION and res.collided
    assert res.final_pose.distance_to(goal) > 0.3
    assert backend.observe().body_pose.distance_to(res.final_pose) < 0.02


def test_an_arm_move_to_where_the_arm_already_is_succeeds(backend_and_facts):
    """(safety audit 2026-12-05) The SDK backend sent a one-point trajectory at time 0 for a move
    to the current joints; the robot (the fake) refused it as ill-formed: CommandRejectedError
    where the simulator succeeds."""
    backend, _ = backend_and_facts
    for q in (model.ARM_READY, model.ARM_READY, model.ARM_STOW, model.ARM_STOW):
        res = backend.move_arm_joints(q)
        assert isinstance(res, CommandResult) and res.success, res
        now = [backend.observe().joint_positions[j] for j in model.ARM_JOINTS]
        np.testing.assert_allclose(now, q, atol=0.03)
