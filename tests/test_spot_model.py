"""The Spot URDFs agree with robots.spot.model (the single source of truth) and with our FK/IK."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robots.spot import kinematics, model
from robots.spot.urdf import SIM_URDF_PATH, URDF_PATH, build_urdf, parse_urdf
from robots.transforms import rpy_to_matrix


def _floats(text: str) -> list[float]:
    return [float(v) for v in text.split()]


@pytest.mark.parametrize("path,locked", [(URDF_PATH, False), (SIM_URDF_PATH, True)])
def test_committed_urdf_is_generated_from_the_model(path, locked):
    assert path.read_text() == build_urdf(lock_legs=locked), (
        f"{path.name} is stale: regenerate it with `python -m robots.spot.urdf`")


def test_urdf_joints_links_and_limits_match_model():
    root = parse_urdf(URDF_PATH)
    joints = {j.get("name"): j for j in root.findall("joint")}
    links = {l.get("name"): l for l in root.findall("link")}
    for j in model.joints():
        el = joints[j.name]
        assert el.get("type") == j.kind
        assert el.find("parent").get("link") == j.parent and el.find("child").get("link") == j.child
        np.testing.assert_allclose(_floats(el.find("origin").get("xyz")), j.xyz, atol=1e-6)
        np.testing.assert_allclose(_floats(el.find("origin").get("rpy")), j.rpy, atol=1e-6)
        if j.kind == "revolute":
            np.testing.assert_allclose(_floats(el.find("axis").get("xyz")), j.axis)
            lim = el.find("limit")
            assert float(lim.get("lower")) == pytest.approx(j.lower, abs=1e-6)
            assert float(lim.get("upper")) == pytest.approx(j.upper, abs=1e-6)
            assert float(lim.get("effort")) == pytest.approx(j.effort, rel=1e-5)
    for l in model.links():
        assert float(links[l.name].find("inertial/mass").get("value")) == pytest.approx(l.mass, rel=1e-5)
    # BD facts that must never drift
    assert joints["arm0.el0"].find("origin").get("xyz") == "0.3385 0 0"
    assert _floats(joints["arm0.el1"].find("origin").get("xyz")) == pytest.approx([0.4033, 0.0, 0.075])
    assert float(joints["fl.kn"].find("limit").get("lower")) == pytest.approx(-2.7929)
    assert sum(l.mass for l in model.links() if not l.name.startswith("arm0") and l.name != model.HAND_CAMERA.name) \
        == pytest.approx(31.6, abs=0.1)  # body + legs, BD's 31.6 kg


def test_hand_camera_mount_matches_measured_calibration():
    root = parse_urdf(URDF_PATH)
    cam = [j for j in root.findall("joint") if j.find("child").get("link") == model.HAND_CAMERA.name][0]
    assert cam.find("parent").get("link") == "arm0.link_wr1"
    np.testing.assert_allclose(_floats(cam.find("origin").get("xyz")), (0.13806, 0.020205, 0.02452), atol=1e-6)
    rpy = _floats(cam.find("origin").get("rpy"))
    np.testing.assert_allclose(np.degrees(rpy), (-81.0, 0.0, -90.0), atol=1e-4)
    # Optical axis looks along wr1 +x, tilted about 9 degrees up (SDK docs).
    z = rpy_to_matrix(*rpy)[:, 2]
    assert z[0] > 0.98 and math.degrees(math.asin(z[2])) == pytest.approx(9.0, abs=0.01)
    assert 2 * math.degrees(math.atan(320 / 552.03)) == pytest.approx(60.2, abs=0.05)


def test_sim_urdf_locks_legs_at_the_stand_pose():
    root = parse_urdf(SIM_URDF_PATH)
    joints = {j.get("name"): j for j in root.findall("joint")}
    for name, q in model.stand_pose().items():
        assert joints[name].get("type") == "fixed"
        rpy = _floats(joints[name].find("origin").get("rpy"))
        assert sum(rpy) == pytest.approx(q, abs=1e-6)
    for name in model.ARM_JOINTS:
        assert joints[name].get("type") == "revolute"


def test_stand_height_is_spot_like():
    assert 0.50 < model.stand_body_height() < 0.56


def test_fk_matches_pybullet_link_frames(world, rng):
    from sim.spot import SpotBody

    spot = SpotBody(world)
    lo, hi = model.arm_limits_array()
    for _ in range(20):
        q = rng.uniform(lo, hi)
        spot.reset_arm(q)
        T_body = np.linalg.inv(spot.T_world_body())
        fk = kinematics.forward_kinematics(q)
        for link in ("arm0.link_wr1", "arm0.hand", model.HAND_CAMERA.name):
            np.testing.assert_allclose(T_body @ spot.link_pose(link), fk[link], atol=1e-5)


def test_ik_recovers_random_reachable_hand_poses(rng):
    lo, hi = model.arm_limits_array()
    for _ in range(300):
        q = rng.uniform(lo, hi)
        T = kinematics.hand_pose(q)
        sol = kinematics.inverse_kinematics(T, q)
        assert sol is not None
        assert kinematics.within_limits(sol)
        np.testing.assert_allclose(kinematics.hand_pose(sol), T, atol=1e-9)


def test_ik_rejects_unreachable_and_malformed_poses():
    far = np.eye(4)
    far[:3, 3] = (3.0, 0.0, 0.2)
    assert kinematics.inverse_kinematics(far) is None
    bad = np.eye(4)
    bad[0, 3] = np.nan
    assert kinematics.inverse_kinematics(bad) is None
