"""Camera and reach geometry the agent needs: pixels <-> world points, where to stand to reach.

Only HAL types are used (Observation, CameraIntrinsics, SE2Pose): what works on the simulated
Spot works on the real one.
"""

from __future__ import annotations

import math

import numpy as np

from helios.agents.config import ReachConfig, ViewConfig
from helios.planning.footprint import FootprintChecker
from robots.hal import CameraIntrinsics, Observation, SE2Pose
from robots.transforms import invert_transform, look_at_camera


def project(points: np.ndarray, intrinsics: CameraIntrinsics, T_world_cam: np.ndarray):
    """(u, v, z) pixel coordinates and optical depth of world points (N, 3); z <= 0 is behind."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    T = invert_transform(T_world_cam)
    pc = pts @ T[:3, :3].T + T[:3, 3]
    z = pc[:, 2]
    safe = np.where(z > 1e-6, z, 1.0)
    u = intrinsics.fx * pc[:, 0] / safe + intrinsics.cx
    v = intrinsics.fy * pc[:, 1] / safe + intrinsics.cy
    return u, v, z


def backproject(obs: Observation, mask: np.ndarray | None = None, stride: int = 1) -> np.ndarray:
    """World points (N, 3) of the pixels in ``mask`` (all pixels if None) that have depth."""
    depth = obs.depth
    valid = depth > 0
    if mask is not None:
        valid &= mask
    if stride > 1:
        sub = np.zeros_like(valid)
        sub[::stride, ::stride] = True
        valid &= sub
    v, u = np.nonzero(valid)
    pc = obs.intrinsics.backproject(u, v, depth[v, u]).reshape(-1, 3)
    return pc @ obs.T_world_cam[:3, :3].T + obs.T_world_cam[:3, 3]


def predicted_camera(pose: SE2Pose, look_at, body_height: float, view: ViewConfig) -> np.ndarray:
    """T_world_cam of the hand camera when the robot stands at ``pose`` and gazes at ``look_at``."""
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    ox, oy, oz = view.camera_in_body
    eye = np.array([pose.x + c * ox - s * oy, pose.y + s * ox + c * oy, body_height + oz])
    return look_at_camera(eye, np.asarray(look_at, dtype=float))


def reach_distances(target_z: float, reach: ReachConfig) -> tuple[np.ndarray, float]:
    """Body-centre distances to try for a point at height ``target_z``, and the comfortable one."""
    dz = target_z - reach.shoulder_height
    horizontal = math.sqrt(max(reach.arm_reach ** 2 - dz * dz, 0.2 ** 2))
    far = horizontal + reach.shoulder_ahead
    return np.linspace(max(reach.min_standoff, far - reach.band), far, 5), far - 0.12


def gaze_cameras(views, body_height: float, view: ViewConfig) -> list[np.ndarray]:
    """The hand-camera poses the robot would have looking from each gaze point."""
    return [predicted_camera(g.pose, g.look_at, body_height, view) for g in views]


def facing(pose: SE2Pose, xy) -> float:
    """World yaw from ``pose`` towards the point ``xy``."""
    return math.atan2(xy[1] - pose.y, xy[0] - pose.x)


def away_from(points: np.ndarray, others, radius: float) -> np.ndarray:
    """(N,) True for the points (N, 2) at least ``radius`` (m) from every point in ``others``."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    others = np.asarray(list(others), dtype=float).reshape(-1, 2)
    if not len(others) or not len(points):
        return np.ones(len(points), dtype=bool)
    d = np.hypot(points[:, None, 0] - others[None, :, 0], points[:, None, 1] - others[None, :, 1])
    return d.min(axis=1) >= radius


def fresh_views(views, used_xy, distance: float) -> list:
    """The gaze points at least ``distance`` (m) from every place in ``used_xy`` (where earlier
    views of the same candidate were taken), or all of them when none is (or ``distance`` is 0).
    See ``AgentConfig.fresh_view_distance``."""
    if distance <= 0 or not views or not len(used_xy):
        return list(views)
    new = away_from([[g.pose.x, g.pose.y] for g in views], used_xy, distance)
    return [g for g, n in zip(views, new) if n] or list(views)


def approach_poses(target, reach: ReachConfig, checker: FootprintChecker) -> np.ndarray:
    """(K, 3) standing poses (x, y, yaw) facing ``target`` (x, y, z) from which the arm reaches
    it, whose footprint is free on the map; most comfortable first."""
    target = np.asarray(target, dtype=float)
    dists, comfortable = reach_distances(float(target[2]), reach)
    ang = 2 * math.pi * np.arange(reach.n_angles) / reach.n_angles
    d, a = np.meshgrid(dists, ang, indexing="ij")
    d, a = d.ravel(), a.ravel()
    poses = np.stack([target[0] + d * np.cos(a), target[1] + d * np.sin(a), a + math.pi], axis=1)
    poses[:, 2] = np.arctan2(np.sin(poses[:, 2]), np.cos(poses[:, 2]))
    free = checker.poses_free(poses)
    order = np.argsort(np.abs(d - comfortable), kind="stable")
    order = order[free[order]]
    return poses[order]


def body_rectangle(pose: SE2Pose, body: tuple[float, float, float, float], margin: float = 0.0) -> np.ndarray:
    """World corners (4, 2) of the body box ``(x_min, x_max, y_min, y_max)`` in the body frame,
    grown by ``margin``, at ``pose``."""
    x0, x1, y0, y1 = body[0] - margin, body[1] + margin, body[2] - margin, body[3] + margin
    local = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    return local @ np.array([[c, s], [-s, c]]) + np.array([pose.x, pose.y])


def turn_sweep(pose: SE2Pose, body: tuple[float, float, float, float], delta: float, margin: float = 0.0,
               step: float = math.radians(2.0)) -> np.ndarray:
    """The body boxes (K, 4, 2) a turn in place by ``delta`` rad passes through (every ``step``
    and the end), without the one at ``pose``: their union is what the turn sweeps."""
    n = max(1, int(math.ceil(abs(delta) / step)))
    return np.stack([body_rectangle(SE2Pose(pose.x, pose.y, pose.yaw + delta * i / n), body, margin)
                     for i in range(1, n + 1)])


def turn_in_progress(pose: SE2Pose, waypoints, near: float = 0.02, tolerance: float = math.radians(2.0)):
    """The signed turn (rad) a walk stopped in the middle of, or None when it stopped on a straight
    stretch. The planner's walks turn in place, then go straight, so a turn is a run of waypoints
    at one place (arrive, then face the next heading): when the robot stands at such a run
    (within ``near`` m), it was turning to the last heading of the run, unless it already faces it."""
    at = [math.hypot(wp.x - pose.x, wp.y - pose.y) <= near for wp in waypoints]
    if True not in at:
        return None
    last = at.index(True)
    while last + 1 < len(at) and at[last + 1]:
        last += 1
    left = math.remainder(waypoints[last].yaw - pose.yaw, 2 * math.pi)
    return left if abs(left) > tolerance else None
