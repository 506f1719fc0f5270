"""The simulated robot behind the fake Spot: the PyBullet sim backend plus the robot-level
primitives a real Spot executes that the HAL does not name (follow a timed SE2 trajectory, open
or close the claw, report the pose it grasped in, let released objects come to rest).

Everything here runs on the fake's single "robot" thread under its simulator lock; PyBullet is
not thread-safe.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from robots.hal import NavigateResult, Observation, Reason, SE2Pose
from robots.spot import model
from robots.spot.sim_backend import SimBackendConfig, SimSpotBackend
from robots.transforms import wrap_angle
from sim import camera as sim_camera
from sim.world import OBJECT


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


class FakeRobotSim(SimSpotBackend):
    """The sim backend with the extra robot-level primitives the fake Spot needs."""

    def __init__(self, world, spot, config: SimBackendConfig = SimBackendConfig(), owns_world: bool = True):
        super().__init__(world, spot, config, owns_world)
        self.last_grasp_hand_pose: np.ndarray | None = None   # T_world_hand when the jaws closed

    # ------------------------------------------------------------------ base
    def follow_se2_path(self, path: TimedSE2Path) -> NavigateResult:
        """Walk along a timed path (the robot executes the trajectory it is given), stopping at
        the last free pose on contact. Same loop as ``SimSpotBackend.navigate_to``, which plans
        its own trajectory instead."""
        self._check_open()
        t0, travelled = self.world.time, 0.0
        prev = self.spot.base_pose()
        dynamic = self._physics_needed()
        times = path.sample_times(self.config.motion.control_dt)
        for t_prev, t in zip(times[:-1], times[1:]):
            pose = path.pose_at(t)
            self.spot.set_base_pose(pose)
            hits = self._new_base_hits()
            if hits:
                self.spot.set_base_pose(prev)
                self._advance(t - t_prev, dynamic)
                link, body = hits[0]
                return NavigateResult(False, Reason.COLLISION,
                                      f"{link} touched {self.world.bodies[body].name}; stopped at the last free pose",
                                      duration=self.world.time - t0, final_pose=prev, collided=True,
                                      distance=travelled)
            travelled += prev.distance_to(pose)
            prev = pose
            self._advance(t - t_prev, dynamic)
        self._check_slip()
        return NavigateResult(True, Reason.OK, duration=self.world.time - t0, final_pose=self.spot.base_pose(),
                              distance=travelled)

    # ------------------------------------------------------------------ claw
    def set_claw(self, angle: float) -> None:
        """Drive the claw joint to ``angle`` (0 closed, -pi/2 open). Opening while holding lets go."""
        self._check_open()
        cfg = self.config.grasp
        angle = float(min(max(angle, model.GRIPPER_LIMITS[0]), model.GRIPPER_LIMITS[1]))
        if self._held is not None and angle < -0.05:
            self._release()   # detach and open (exactly what the sim's place() does at release)
            return
        self._gripper_to(angle, cfg.close_force, 4.0, 0.25 if angle < -0.05 else 0.2)

    def _close_until_pinch(self, fixed_link: int, moving_link: int) -> int | None:
        # Spot reports where it grasped (the "grasp_planning_solution" frame); remember it.
        self.last_grasp_hand_pose = self.spot.T_world_hand()
        return super()._close_until_pinch(fixed_link, moving_link)

    # ------------------------------------------------------------------ world time
    def settle_loose_objects(self, max_time: float = 2.0) -> None:
        """Let objects that are still moving (e.g. just dropped) come to rest: real time keeps
        running between a robot's commands; the simulation only runs while it is asked to."""
        if self._held is not None:
            return
        moving = [b.body_id for b in self.world.bodies_of_kind(OBJECT) if not self.world.is_at_rest(b.body_id)]
        if moving:
            self.world.settle(moving, max_time=max_time)

    # ------------------------------------------------------------------ sensing
    def render_at(self, T_world_cam: np.ndarray) -> Observation:
        """A hand-camera frame rendered from an arbitrary camera pose (for grasp requests that
        refer to an image this robot no longer caches)."""
        frame = sim_camera.render(self.world, self.intrinsics, T_world_cam, self.config.camera)
        state = self._capture_state(np.asarray(T_world_cam, dtype=float))
        return self._make_observation(state, frame)

    @property
    def gripper_angle(self) -> float:
        return self.spot.gripper_q()

    def arm_is_stowed(self, tol: float = 0.05) -> bool:
        return bool(np.max(np.abs(self.spot.arm_q() - np.array(model.ARM_STOW))) < tol)
