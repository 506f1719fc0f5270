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


def test_grasp_and_place_cycle(backend_and_facts):
    backend, facts = backend_and_facts
    mug = facts["mug_position"]
    assert backend.navigate_to(SE2Pose(mug[0] - 0.95, mug[1], 0.0)).success
    assert backend.gaze_at(mug + [0, 0, 0.05]).success
    obs = backend.observe()
    res = backend.grasp(obs, _pixel_of(obs, mug + [0, 0, 0.05]))
    assert isinstance(res, GraspResult) and res.success and res.holding
    assert backend.observe().holding
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
    empty = backend.place([near_edge[0], near_edge[1], facts["table_height"]])
    assert not empty.success and empty.reason is Reason.NOT_HOLDING


@pytest.mark.parametrize("name", sorted(BACKENDS))
def test_every_command_after_close_raises_backend_closed(name):
    from robots.hal import BackendClosedError, HalError

    backend, _ = BACKENDS[name]()
    backend.close()
    backend.close()                                   # twice is fine
    commands = [lambda: backend.observe(), lambda: backend.navigate_to(SE2Pose(0.1, 0.0, 0.0)),
                lambda: backend.move_arm_joints(model.ARM_READY), lambda: backend.gaze_at([1.0, 0.0, 0.5]),
                lambda: backend.stow_arm(), lambda: backend.stand(), lambda: backend.stop()]
    for command in commands:
        with pytest.raises(BackendClosedError, match="closed") as info:
            command()
        assert isinstance(info.value, HalError) and isinstance(info.value, RuntimeError)
