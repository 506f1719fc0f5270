"""Jerk-limited base and arm trajectories with ruckig (community edition, offline only).

Two ruckig facts shape this module (see notes/): the community build sends any trajectory with
``intermediate_positions`` to a remote service, so multi-point paths are *chained point-to-point
segments* here and that field is never set; and it ignores position limits, so every arm
trajectory's position extrema are checked against Spot's joint limits before it is used.

Base trajectories move (x, y, yaw) in the odometry frame with phase synchronisation (a straight
line in (x, y, yaw), all axes arriving together), yaw unwrapped to take the short way round.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from ruckig import InputParameter, Result, Ruckig, RuckigError, Synchronization, Trajectory

from helios.schema import require_range
from robots.hal import InvalidCommandError, SE2Pose
from robots.spot import model
from robots.transforms import wrap_angle


@dataclass(frozen=True)
class BaseLimits:
    """Spot base motion limits (Spot tops out at 1.6 m/s; these are its comfortable defaults)."""

    linear_velocity: float = 1.0       # m/s, per axis x/y
    linear_acceleration: float = 1.0   # m/s^2
    linear_jerk: float = 4.0           # m/s^3 (a smoothing knob, not a spec)
    angular_velocity: float = 1.0      # rad/s
    angular_acceleration: float = 2.0  # rad/s^2
    angular_jerk: float = 8.0          # rad/s^3

    def __post_init__(self) -> None:
        require_range(self, "linear_velocity linear_acceleration linear_jerk angular_velocity angular_acceleration "
                            "angular_jerk", 0.0, 1000.0, lo_open=True)


@dataclass(frozen=True)
class ArmLimits:
    """Joint-space limits for arm moves: the Spot arm's own defaults for a joint move.

    ``ArmJointTrajectory`` moves any joint at most ``maximum_velocity`` / ``maximum_acceleration``,
    2.5 rad/s and 15 rad/s^2 when the command leaves them unset (Boston Dynamics' Spot SDK example
    ``arm_sensor_inspector``; HomeRobot's Spot client sets the same two values explicitly, see
    notes/ovmm_vlfm_reference.md), well under the joints' 10 rad/s. Until 2026-12-05 the arm moved
    at 1.5 rad/s and 5 rad/s^2, our own gentler choice, slower than the robot's: 1.8 s a gaze and
    2.0 s a stow on train, 40 % of HELIOS's robot time (``sim.motion.arm.velocity=1.5
    sim.motion.arm.acceleration=5`` restores it). ``jerk`` is a smoothing knob of ours (the SDK
    states none)."""

    velocity: float = 2.5       # rad/s
    acceleration: float = 15.0  # rad/s^2
    jerk: float = 40.0          # rad/s^3

    def __post_init__(self) -> None:
        require_range(self, "velocity acceleration jerk", 0.0, 1000.0, lo_open=True)


@dataclass(frozen=True)
class MotionConfig:
    base: BaseLimits = BaseLimits()
    arm: ArmLimits = ArmLimits()
    control_dt: float = 0.05   # s between executed trajectory samples (collision checks happen here)

    def __post_init__(self) -> None:
        require_range(self, "control_dt", 0.0, 1.0, lo_open=True)


def _solve(current, target, vmax, amax, jmax) -> Trajectory:
    n = len(current)
    inp = InputParameter(n)
    inp.current_position = [float(v) for v in current]
    inp.target_position = [float(v) for v in target]
    inp.max_velocity = [float(v) for v in vmax]
    inp.max_acceleration = [float(v) for v in amax]
    inp.max_jerk = [float(v) for v in jmax]
    inp.synchronization = Synchronization.Phase
    traj = Trajectory(n)
    try:
        result = Ruckig(n).calculate(inp, traj)
    except RuckigError as exc:
        raise InvalidCommandError(f"trajectory generation rejected the input: {exc}") from exc
    if result not in (Result.Working, Result.Finished):
        # Phase synchronisation can be infeasible for some state combinations; fall back to time sync.
        inp.synchronization = Synchronization.Time
        result = Ruckig(n).calculate(inp, traj)
        if result not in (Result.Working, Result.Finished):
            raise InvalidCommandError(f"trajectory generation failed ({result})")
    return traj


class SegmentedTrajectory:
    """Point-to-point ruckig segments played back to back, sampled by time."""

    def __init__(self, segments: Sequence[Trajectory]):
        self.segments = list(segments)
        self._starts = np.cumsum([0.0] + [s.duration for s in self.segments])

    @property
    def duration(self) -> float:
        return float(self._starts[-1])

    def at_time(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(position, velocity) at time t, clamped to [0, duration]."""
        if not self.segments:
            raise ValueError("empty trajectory")
        t = min(max(t, 0.0), self.duration)
        i = int(np.searchsorted(self._starts, t, side="right") - 1)
        i = min(max(i, 0), len(self.segments) - 1)
        pos, vel, _ = self.segments[i].at_time(t - self._starts[i])
        return np.array(pos), np.array(vel)

    def sample_times(self, dt: float) -> np.ndarray:
        n = max(1, int(math.ceil(self.duration / dt)))
        return np.linspace(0.0, self.duration, n + 1)

    def position_extrema(self) -> tuple[np.ndarray, np.ndarray]:
        lo = np.min([[b.min for b in s.position_extrema] for s in self.segments], axis=0)
        hi = np.max([[b.max for b in s.position_extrema] for s in self.segments], axis=0)
        return lo, hi


class BaseTrajectory(SegmentedTrajectory):
    """A base path in the odometry frame; positions are (x, y, yaw) with yaw unwrapped."""

    def pose_at(self, t: float) -> SE2Pose:
        p, _ = self.at_time(t)
        return SE2Pose(p[0], p[1], wrap_angle(float(p[2])))


def plan_base(start: SE2Pose, waypoints: Sequence[SE2Pose], limits: BaseLimits) -> BaseTrajectory:
    """Chain stop-at-each-waypoint segments from ``start`` through ``waypoints``.

    Stopping at via points keeps every segment a straight line, so the collision checks along it
    are exact and the planner's clearance guarantees carry over.
    """
    if not waypoints:
        raise InvalidCommandError("a base trajectory needs at least one goal pose")
    vmax = [limits.linear_velocity, limits.linear_velocity, limits.angular_velocity]
    amax = [limits.linear_acceleration, limits.linear_acceleration, limits.angular_acceleration]
    jmax = [limits.linear_jerk, limits.linear_jerk, limits.angular_jerk]
    segments = []
    cur = np.array([start.x, start.y, start.yaw])
    for wp in waypoints:
        target = np.array([wp.x, wp.y, cur[2] + wrap_angle(wp.yaw - cur[2])])
        if np.allclose(target, cur, atol=1e-9):
            continue
        segments.append(_solve(cur, target, vmax, amax, jmax))
        cur = target
    if not segments:  # already there: a zero-length segment keeps the interface uniform
        segments.append(_solve(cur, cur, vmax, amax, jmax))
    return BaseTrajectory(segments)


def check_arm_target(q: Sequence[float]) -> np.ndarray:
    """Validate a 6-joint arm target: finite, right length, inside Spot's limits."""
    arr = np.asarray(q, dtype=float)
    if arr.shape != (6,):
        raise InvalidCommandError(f"arm target needs 6 joint angles {list(model.ARM_JOINTS)}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidCommandError(f"arm target has non-finite values: {arr.tolist()}")
    lo, hi = model.arm_limits_array()
    bad = [(n, float(v), (float(a), float(b))) for n, v, a, b in zip(model.ARM_JOINTS, arr, lo, hi)
           if v < a - 1e-9 or v > b + 1e-9]
    if bad:
        desc = "; ".join(f"{n}={v:.4f} outside [{a:.4f}, {b:.4f}]" for n, v, (a, b) in bad)
        raise InvalidCommandError(f"arm target outside joint limits: {desc}")
    return arr


def plan_arm(q_start: Sequence[float], q_goal: Sequence[float], limits: ArmLimits) -> SegmentedTrajectory:
    """One jerk-limited joint-space move; raises if its extrema would leave the joint limits."""
    goal = check_arm_target(q_goal)
    start = np.asarray(q_start, dtype=float)
    n = 6
    traj = SegmentedTrajectory([_solve(start, goal, [limits.velocity] * n, [limits.acceleration] * n,
                                       [limits.jerk] * n)])
    lo, hi = traj.position_extrema()
    jlo, jhi = model.arm_limits_array()
    # Start states a hair outside the limits (numerical noise from the simulator) are tolerated.
    if np.any(lo < np.minimum(jlo, start) - 1e-6) or np.any(hi > np.maximum(jhi, start) + 1e-6):
        raise InvalidCommandError("arm trajectory would overshoot the joint limits")
    return traj
