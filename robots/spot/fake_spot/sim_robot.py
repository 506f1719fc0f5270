"""The simulated robot behind the fake Spot: the PyBullet sim backend, whose public robot-level
primitives (``follow_base_path``, ``set_claw``, ``settle_loose_objects``, ``render_at``...) execute
what the SDK commands ask for, and timed SE2 paths as SE2 trajectory commands carry them.

Everything runs on the fake's single "robot" thread under its simulator lock; PyBullet is not
thread-safe.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from robots.hal import SE2Pose
from robots.spot.sim_backend import SimSpotBackend
from robots.transforms import wrap_angle


class TimedSE2Path:
    """A base path given as timed SE2 samples (what an ``SE2TrajectoryCommand`` carries),
    interpolated linearly in (x, y, unwrapped yaw); the same sampling interface as
    ``robots.spot.motion.BaseTrajectory`` so the sim's navigation loop runs on it unchanged."""

    def __init__(self, times: Sequence[float], poses: Sequence[SE2Pose]):
        t = np.asarray(times, dtype=float)
        if len(t) == 0 or len(t) != len(poses):
            raise ValueError("a timed SE2 path needs as many poses as times, at least one")
        if np.any(np.diff(t) <= 0):
            raise ValueError("trajectory times must increase strictly")
        self._t = t - t[0]
        self._start = float(t[0])
        self._x = np.array([p.x for p in poses])
        self._y = np.array([p.y for p in poses])
        self._yaw = np.unwrap(np.array([p.yaw for p in poses]))

    @property
    def duration(self) -> float:
        return float(self._t[-1])

    @property
    def start_offset(self) -> float:
        """Time of the first point after the trajectory's reference time."""
        return self._start

    def sample_times(self, dt: float) -> np.ndarray:
        n = max(1, int(math.ceil(self.duration / dt)))
        return np.linspace(0.0, self.duration, n + 1)

    def pose_at(self, t: float) -> SE2Pose:
        t = min(max(t, 0.0), self.duration)
        return SE2Pose(float(np.interp(t, self._t, self._x)), float(np.interp(t, self._t, self._y)),
                       wrap_angle(float(np.interp(t, self._t, self._yaw))))


# The fake Spot drives the sim backend through its public robot-level primitives
# (follow_base_path, set_claw, settle_loose_objects, render_at, last_grasp_hand_pose, ...).
FakeRobotSim = SimSpotBackend
