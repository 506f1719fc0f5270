"""ruckig base and arm trajectories: limits, wrap-around, chained segments, position-limit checks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robots.hal import InvalidCommandError, SE2Pose
from robots.spot import model
from robots.spot.motion import ArmLimits, BaseLimits, check_arm_target, plan_arm, plan_base


def _samples(traj, dt=0.01):
    t = np.arange(0.0, traj.duration + dt, dt)
    return t, np.array([traj.at_time(x)[0] for x in t]), np.array([traj.at_time(x)[1] for x in t])


def test_base_trajectory_reaches_goal_within_limits():
    lim = BaseLimits()
    traj = plan_base(SE2Pose(0, 0, 0), [SE2Pose(2.0, -1.0, 1.0)], lim)
    _, pos, vel = _samples(traj)
    np.testing.assert_allclose(pos[-1], [2.0, -1.0, 1.0], atol=1e-6)
    assert np.all(np.abs(vel[:, :2]) <= lim.linear_velocity + 1e-6)
    assert np.all(np.abs(vel[:, 2]) <= lim.angular_velocity + 1e-6)
    # phase synchronisation: a straight line in (x, y)
    d = pos[:, :2] / np.array([2.0, -1.0])
    np.testing.assert_allclose(d[5:, 0], d[5:, 1], atol=1e-6)
    # jerk-limited: velocity starts and ends at zero
    assert np.allclose(vel[0], 0) and np.allclose(vel[-1], 0, atol=1e-6)


def test_yaw_takes_the_short_way_round():
    traj = plan_base(SE2Pose(0, 0, math.radians(170)), [SE2Pose(0, 0, math.radians(-170))], BaseLimits())
    _, pos, _ = _samples(traj)
    travelled = pos[-1, 2] - pos[0, 2]
    assert math.degrees(travelled) == pytest.approx(20.0, abs=1e-4)
    assert traj.pose_at(traj.duration).yaw == pytest.approx(math.radians(-170), abs=1e-9)


def test_via_points_are_chained_segments_through_each_point():
    vias = [SE2Pose(1.0, 0.0, 0.0), SE2Pose(1.0, 1.0, math.pi / 2)]
    traj = plan_base(SE2Pose(0, 0, 0), vias + [SE2Pose(0.0, 1.0, math.pi)], BaseLimits())
    assert len(traj.segments) == 3
    t_end_first = traj.segments[0].duration
    np.testing.assert_allclose(traj.at_time(t_end_first)[0], [1.0, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(traj.at_time(t_end_first)[1], 0.0, atol=1e-6)


def test_arm_trajectory_respects_joint_limits_and_reaches_target():
    traj = plan_arm(model.ARM_STOW, model.ARM_READY, ArmLimits())
    _, pos, vel = _samples(traj)
    np.testing.assert_allclose(pos[-1], model.ARM_READY, atol=1e-6)
    lo, hi = model.arm_limits_array()
    assert np.all(pos >= lo - 1e-6) and np.all(pos <= hi + 1e-6)
    assert np.all(np.abs(vel) <= ArmLimits().velocity + 1e-6)


@pytest.mark.parametrize("target,match", [
    ((0, 0, 0, 0, 0, 4.0), "arm0.wr1=4.0000 outside"),
    ((0, 0.9, 1.0, 0, 0, 0), "arm0.sh1=0.9000 outside"),
    ((0, 0, 0, 0, 0), "needs 6 joint angles"),
    ((0, 0, float("nan"), 0, 0, 0), "non-finite"),
])
def test_bad_arm_targets_are_rejected_with_the_joint_named(target, match):
    with pytest.raises(InvalidCommandError, match=match):
        check_arm_target(target)


def test_nan_base_goal_is_rejected():
    with pytest.raises(InvalidCommandError, match="finite"):
        SE2Pose(float("nan"), 0.0, 0.0)
