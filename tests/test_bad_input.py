"""Bad input gets one clear error naming what is wrong, and never crashes the process."""

from __future__ import annotations

import numpy as np
import pytest

from cli_helpers import run_cli
from robots.hal import CameraIntrinsics, InvalidCommandError, InvalidObservationError, Observation, SE2Pose
from robots.spot.sim_backend import SimSpotBackend
from robots.spot.urdf import UrdfError, parse_urdf
from sim.spot import SpotBody


def test_missing_urdf_path(world, tmp_path):
    with pytest.raises(UrdfError, match="does not exist"):
        SpotBody(world, urdf_path=tmp_path / "nope.urdf")


def test_malformed_urdf(world, tmp_path):
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot name='x'><link name='a'>")
    with pytest.raises(UrdfError, match="not well-formed XML"):
        SpotBody(world, urdf_path=bad)
    dangling = tmp_path / "dangling.urdf"
    dangling.write_text("<robot name='x'><link name='a'/><joint name='j' type='fixed'><parent link='a'/>"
                        "<child link='b'/></joint></robot>")
    with pytest.raises(UrdfError, match="joint 'j' has a missing or unknown child link"):
        parse_urdf(dangling)
    limits = tmp_path / "limits.urdf"
    limits.write_text("<robot name='x'><link name='a'/><link name='b'/><joint name='j' type='revolute'>"
                      "<parent link='a'/><child link='b'/><limit lower='1' upper='-1' effort='1' velocity='1'/>"
                      "</joint></robot>")
    with pytest.raises(UrdfError, match="invalid limits"):
        parse_urdf(limits)


def test_a_valid_urdf_that_is_not_a_spot(world, tmp_path):
    other = tmp_path / "box.urdf"
    other.write_text("<robot name='box'><link name='base'><inertial><mass value='1'/>"
                     "<inertia ixx='1' ixy='0' ixz='0' iyy='1' iyz='0' izz='1'/></inertial></link></robot>")
    with pytest.raises(UrdfError, match="lacks Spot joints"):
        SpotBody(world, urdf_path=other)


@pytest.fixture
def backend(world):
    b = SimSpotBackend(world, SpotBody(world), owns_world=False)
    yield b
    b.close()


def test_arm_target_outside_limits_moves_nothing(backend):
    before = backend.spot.arm_q()
    with pytest.raises(InvalidCommandError, match=r"arm0.el0=-0.5000 outside \[0.0000, 3.1416\]"):
        backend.move_arm_joints((0.0, -1.0, -0.5, 0.0, 0.0, 0.0))
    np.testing.assert_array_equal(backend.spot.arm_q(), before)


@pytest.mark.parametrize("call,match", [
    (lambda b: b.navigate_to((np.nan, 0.0, 0.0)), "finite"),
    (lambda b: b.navigate_to(SE2Pose(1.0, 0.0, 0.0), via=[(0.5, np.inf, 0.0)]), "finite"),
    (lambda b: b.navigate_to("kitchen"), "SE2Pose or"),
    (lambda b: b.gaze_at([1.0, np.nan, 0.5]), "3 finite numbers"),
    (lambda b: b.place([1.0, 0.0], 0.1), "3 finite numbers"),
    (lambda b: b.place([1.0, 0.0, 0.5], release_height=-1.0), "release_height"),
    (lambda b: b.move_hand(np.full((4, 4), np.nan)), "finite 4x4"),
    (lambda b: b.grasp(b.observe(), (5000, 3)), "outside the 320x240 image"),
    (lambda b: b.grasp("image.png", (1, 1)), "needs the Observation"),
])
def test_malformed_commands_raise_one_clear_error(backend, call, match):
    pose = backend.spot.base_pose()
    with pytest.raises(InvalidCommandError, match=match):
        call(backend)
    assert backend.spot.base_pose() == pose


def test_observations_reject_nan_depth_and_wrong_shapes():
    intr = CameraIntrinsics(4, 3, 2.0, 2.0, 2.0, 1.5)
    ok = dict(rgb=np.zeros((3, 4, 3), np.uint8), depth=np.ones((3, 4), np.float32), intrinsics=intr,
              T_world_cam=np.eye(4), T_world_body=np.eye(4), stamp=0.0)
    Observation(**ok)
    depth = ok["depth"].copy()
    depth[1, 1] = np.nan
    with pytest.raises(InvalidObservationError, match="1 NaN/inf pixels"):
        Observation(**{**ok, "depth": depth})
    with pytest.raises(InvalidObservationError, match="rgb must be a uint8 array of shape"):
        Observation(**{**ok, "rgb": np.zeros((4, 3, 3), np.uint8)})
    with pytest.raises(InvalidObservationError, match="T_world_cam"):
        Observation(**{**ok, "T_world_cam": np.full((4, 4), np.nan)})


def test_cli_reports_bad_config_in_one_line_without_traceback():
    rc, _, err = run_cli(["demo", "--no-record", "camera.width=abc"])
    assert rc == 2
    assert err.strip().splitlines()[-1] == "error: camera.width: expected an integer, got 'abc'"
    assert "Traceback" not in err
    rc, _, err = run_cli(["demo", "--no-record", "camera.widht=320"])
    assert rc == 2 and "unknown config key 'camera.widht'" in err
    assert "Traceback" not in err


def test_backend_refuses_commands_after_close(world):
    b = SimSpotBackend(world, SpotBody(world), owns_world=False)
    b.close()
    b.close()  # idempotent
    with pytest.raises(RuntimeError, match="closed"):
        b.stand()
