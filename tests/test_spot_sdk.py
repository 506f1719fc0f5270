"""The Spot SDK backend against the fake Spot: what it sends is what Spot's API expects (odom SE2
trajectories from our ruckig plans, <= 250-point arm trajectories, pick-in-image with the image's
own snapshot), what it reads back matches the simulator, and the scripted demo has the same
physical outcome through SDK -> fake Spot -> PyBullet as through the simulator backend."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("bosdyn.client")

from robots.hal import InvalidCommandError, SE2Pose  # noqa: E402
from robots.spot import model  # noqa: E402
from robots.spot.motion import plan_arm, plan_base  # noqa: E402
from spot_fake_fixtures import connect, start_fake  # noqa: E402

pytestmark = pytest.mark.timeout(60)


@pytest.fixture
def session():
    demo = start_fake(seed=0)
    backend = connect(demo, stop_fake_on_close=False)
    yield demo, backend
    backend.close()
    demo.stop()


def test_observe_reports_what_the_robot_sees(session):
    demo, backend = session
    obs = backend.observe()
    with demo.fake.sim_lock:
        sim = demo.fake.sim
        T_cam, T_body = sim.spot.T_world_camera(), sim.spot.T_world_body()
        truth = sim.observe()
    # Intrinsics from the image response, poses from its frame snapshot, depth / depth_scale (999).
    assert obs.intrinsics == sim.intrinsics
    np.testing.assert_allclose(obs.T_world_cam, T_cam, atol=1e-6)
    np.testing.assert_allclose(obs.T_world_body, T_body, atol=1e-6)
    valid = truth.depth > 0
    assert np.array_equal(obs.depth > 0, valid)
    assert np.max(np.abs(obs.depth[valid] - truth.depth[valid])) <= 0.5 / 999.0 + 1e-6
    # JPEG colour: close to the rendered image, not identical.
    assert np.mean(np.abs(obs.rgb.astype(float) - truth.rgb.astype(float))) < 4.0
    assert set(model.ARM_JOINTS) <= set(obs.joint_positions) and not obs.holding
    assert abs(backend.observe().stamp - obs.stamp) < 5.0


def test_raw_images_are_exact(session):
    demo, backend = session
    from dataclasses import replace

    backend.config = replace(backend.config, image_format="raw")
    obs = backend.observe()
    with demo.fake.sim_lock:
        truth = demo.fake.sim.observe()
    assert np.array_equal(obs.rgb, truth.rgb)


def test_navigation_is_one_odom_se2_trajectory_sampled_from_ruckig(session):
    demo, backend = session
    goal, via = SE2Pose(0.8, -0.5, math.radians(40)), [SE2Pose(0.4, 0.0, 0.0)]
    res = backend.navigate_to(goal, via=via)
    assert res.success and res.final_pose.distance_to(goal) < 1e-6
    se2 = [c for c in demo.fake.commands.values() if c.kind == "se2"]
    assert len(se2) == 1
    path = se2[0].extra["path"]
    traj = plan_base(SE2Pose(0, 0, 0), [*via, goal], backend.config.motion.base)
    assert path.duration == pytest.approx(traj.duration, abs=1e-6)
    for t in np.linspace(0.0, traj.duration, 17):
        p, q = path.pose_at(float(t)), traj.pose_at(float(t))
        assert p.distance_to(q) < 5e-3 and abs(math.remainder(p.yaw - q.yaw, 2 * math.pi)) < 5e-3
    assert res.distance == pytest.approx(0.4 + math.hypot(0.4, 0.5), abs=0.01)


def test_arm_joint_trajectories_stay_within_250_points(session):
    demo, backend = session
    from dataclasses import replace

    from robots.spot.motion import MotionConfig

    # A control period so fine that naive sampling would need thousands of points.
    backend.config = replace(backend.config, motion=MotionConfig(control_dt=0.001))
    res = backend.move_arm_joints(model.ARM_READY)
    assert res.success
    request = [c for c in demo.fake.commands.values() if c.kind == "arm_joint"][-1].request
    points = request.synchronized_command.arm_command.arm_joint_move_command.trajectory.points
    duration = plan_arm(model.ARM_STOW, model.ARM_READY, backend.config.motion.arm).duration
    assert len(points) == 250
    assert points[-1].time_since_reference.seconds + points[-1].time_since_reference.nanos * 1e-9 == \
        pytest.approx(duration, abs=1e-6)
    q = [backend.observe().joint_positions[j] for j in model.ARM_JOINTS]
    np.testing.assert_allclose(q, model.ARM_READY, atol=0.03)


def test_bad_arguments_raise_before_anything_is_sent(session):
    demo, backend = session
    sent = len(demo.fake.commands)
    with pytest.raises(InvalidCommandError, match="outside joint limits"):
        backend.move_arm_joints((0.0, -1.0, -0.5, 0.0, 0.0, 0.0))
    with pytest.raises(InvalidCommandError):
        backend.navigate_to((0.0, float("nan"), 0.0))
    with pytest.raises(InvalidCommandError):
        backend.move_hand(np.eye(3))
    with pytest.raises(InvalidCommandError):
        backend.grasp("not an observation", (1, 2))
    with pytest.raises(InvalidCommandError, match="outside the"):
        backend.grasp(backend.observe(), (10_000, 3))
    with pytest.raises(InvalidCommandError):
        backend.place([0.0, 0.0, 0.5], release_height=-1.0)
    assert len(demo.fake.commands) == sent


def test_unreachable_hand_pose_is_an_ik_failure_without_motion(session):
    demo, backend = session
    T = np.eye(4)
    T[:3, 3] = (3.0, 0.0, 0.5)
    sent = len(demo.fake.commands)
    res = backend.move_hand(T)
    assert not res.success and res.reason.value == "ik_failed"
    assert len(demo.fake.commands) == sent


def test_grasp_uses_the_images_own_snapshot_and_camera_model(session):
    demo, backend = session
    mug = demo.facts["mug_position"]
    assert backend.navigate_to(SE2Pose(mug[0] - 0.95, mug[1], 0.0)).success
    assert backend.gaze_at(mug + [0, 0, 0.05]).success
    obs = backend.observe()
    p_cam = np.linalg.inv(obs.T_world_cam) @ np.append(mug + [0, 0, 0.05], 1.0)
    (u, v), _ = obs.intrinsics.project(p_cam[:3])
    res = backend.grasp(obs, (int(round(u)), int(round(v))))
    assert res.success and res.holding
    pick = [c for c in demo.fake.commands.values() if c.kind == "pick"][-1].request.pick_object_in_image
    assert pick.frame_name_image_sensor == "hand_color_image_sensor"
    assert pick.camera_model.intrinsics.focal_length.x == pytest.approx(obs.intrinsics.fx)
    assert pick.walk_gaze_mode == 3   # PICK_NO_AUTO_WALK_OR_GAZE: the HAL's grasp never walks
    np.testing.assert_allclose(res.target_world, obs.point_at_pixel(int(round(u)), int(round(v))), atol=1e-9)
    assert np.linalg.norm(np.asarray(res.target_world)[:2] - mug[:2]) < 0.08   # on the mug


@pytest.mark.parametrize("seed", [0, 3])
def test_scripted_demo_has_the_same_physical_outcome_as_the_simulator(seed):
    """Same agent code, same scene: through SimSpotBackend directly and through SDK -> fake Spot
    -> PyBullet, the mug ends up settled on the place table, within a few cm of each other."""
    from robots.spot.fake_spot.launch import scene_facts
    from robots.spot.sim_backend import SimSpotBackend
    from sim.scenes.demo import build_demo_scene
    from sim.spot import SpotBody
    from sim.world import World
    from tasks.scripted_demo import DemoHints, ScriptedDemo, physical_outcome

    quiet = lambda *_: None  # noqa: E731
    world = World()
    scene = build_demo_scene(world, np.random.default_rng(seed))
    sim_backend = SimSpotBackend(world, SpotBody(world, scene["robot_start"]), owns_world=False)
    try:
        sim_agent = ScriptedDemo(DemoHints.from_facts(scene_facts(world, scene)), say=quiet).run(sim_backend)
        sim_phys = physical_outcome(world, scene, sim_agent.place_target)
    finally:
        sim_backend.close()
        world.close()

    demo = start_fake(seed=seed)
    backend = connect(demo, stop_fake_on_close=False)
    try:
        sdk_agent = ScriptedDemo(DemoHints.from_facts(demo.facts), say=quiet).run(backend)
        backend.close()
        with demo.fake.sim_lock:
            sdk_phys = physical_outcome(demo.world, demo.scene, sdk_agent.place_target)
    finally:
        backend.close()
        demo.stop()
    assert sim_agent.success and sdk_agent.success, (sim_agent, sdk_agent)
    assert [s.name for s in sim_agent.steps] == [s.name for s in sdk_agent.steps]
    assert sim_phys["success"] and sdk_phys["success"], (sim_phys, sdk_phys)
    assert sdk_phys["resting_on"] == sim_phys["resting_on"] == "table_place"
    assert np.linalg.norm(np.subtract(sdk_phys["final_position"], sim_phys["final_position"])) < 0.05


def test_bosdyn_is_imported_lazily():
    """The backend module and the CLI command load without the optional Spot SDK extra."""
    import subprocess
    import sys
    from pathlib import Path

    code = ("import sys; import robots.spot.sdk_backend, tools.spot, tools.cli; tools.cli.build_parser(); "
            "bad = [m for m in sys.modules if m.split('.')[0] in ('bosdyn', 'grpc', 'pybullet')]; "
            "assert not bad, bad")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                          cwd=Path(__file__).resolve().parents[1])
    assert proc.returncode == 0, proc.stderr
