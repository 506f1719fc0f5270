"""Arm kinematics of Spot from the model numbers: forward kinematics and closed-form inverse
kinematics for hand poses.

Spot's el1, wr0, wr1 axes (x, y, x) meet in one point, so the arm is a spherical-wrist arm: the
wrist centre fixes sh0, sh1, el0 (a planar two-link problem after the shoulder yaw) and the hand
orientation fixes the wrist as x-y-x Euler angles. Closed form gives every solution at once; we
keep those inside the joint limits and return the one nearest the current configuration.
"""

from __future__ import annotations

import math

import numpy as np

from robots.spot import model
from robots.transforms import make_transform, rot_x, rot_y, rot_z, rpy_to_matrix

_L1 = model.UPPER_ARM[0]
_A, _B = model.FOREARM[0], model.FOREARM[2]
_L2 = math.hypot(_A, _B)
_DELTA = math.atan2(_B, _A)
_SHOULDER = np.array(model.SHOULDER_ORIGIN)
_LO, _HI = model.arm_limits_array()


def forward_kinematics(q) -> dict[str, np.ndarray]:
    """Poses (4x4, body frame) of the arm links, the hand frame and the hand camera for joints q."""
    q0, q1, q2, q3, q4, q5 = (float(v) for v in q)
    T_sh0 = make_transform(rot_z(q0), _SHOULDER)
    T_sh1 = T_sh0 @ make_transform(rot_y(q1))
    T_el0 = T_sh1 @ make_transform(rot_y(q2), model.UPPER_ARM)
    T_el1 = T_el0 @ make_transform(rot_x(q3), model.FOREARM)
    T_wr0 = T_el1 @ make_transform(rot_y(q4))
    T_wr1 = T_wr0 @ make_transform(rot_x(q5))
    T_hand = T_wr1 @ make_transform(None, (model.HAND_OFFSET, 0.0, 0.0))
    cam = model.HAND_CAMERA
    T_cam = T_wr1 @ make_transform(rpy_to_matrix(*(a * model.DEG for a in cam.rpy_deg)), cam.xyz)
    return {"arm0.link_sh0": T_sh0, "arm0.link_sh1": T_sh1, "arm0.link_el0": T_el0, "arm0.link_el1": T_el1,
            "arm0.link_wr0": T_wr0, "arm0.link_wr1": T_wr1, "arm0.hand": T_hand, cam.name: T_cam}


def hand_pose(q) -> np.ndarray:
    """T_body_hand for arm joints q."""
    return forward_kinematics(q)["arm0.hand"]


def within_limits(q, tol: float = 1e-9) -> bool:
    q = np.asarray(q, dtype=float)
    return bool(np.all(q >= _LO - tol) and np.all(q <= _HI + tol))


def _wrist_solutions(M: np.ndarray, q3_hint: float) -> list[tuple[float, float, float]]:
    """All (el1, wr0, wr1) with Rx(el1) Ry(wr0) Rx(wr1) = M."""
    cb = float(np.clip(M[0, 0], -1.0, 1.0))
    b = math.acos(cb)
    if math.sin(b) < 1e-7:
        # Wrist aligned: only el1 + wr1 (or el1 - wr1) is determined; keep el1 at the hint.
        total = math.atan2(M[2, 1], M[1, 1])
        if cb > 0:
            return [(q3_hint, 0.0, total - q3_hint)]
        return [(q3_hint, math.pi, q3_hint - total)]
    out = []
    for sb in (1.0, -1.0):
        bb = sb * b
        s = math.sin(bb)
        a = math.atan2(M[1, 0] / s, -M[2, 0] / s)
        c = math.atan2(M[0, 1] / s, M[0, 2] / s)
        out.append((a, bb, c))
    return out


def inverse_kinematics(T_body_hand: np.ndarray, q_current=None) -> np.ndarray | None:
    """Joint angles placing the hand frame at ``T_body_hand``, or None if unreachable within limits.

    Among all closed-form solutions inside the joint limits, returns the one closest (in joint
    space, wrapping continuous-looking angles) to ``q_current`` (default: the ready pose).
    """
    T = np.asarray(T_body_hand, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        return None
    q_ref = np.asarray(q_current if q_current is not None else model.ARM_READY, dtype=float)
    R = T[:3, :3]
    wrist = T[:3, 3] - model.HAND_OFFSET * R[:, 0] - _SHOULDER
    base_yaw = math.atan2(wrist[1], wrist[0])
    r_xy = math.hypot(wrist[0], wrist[1])
    h = wrist[2]
    candidates = []
    for q0, r in ((base_yaw, r_xy), (base_yaw + math.pi, -r_xy), (base_yaw - math.pi, -r_xy)):
        # Planar two-link after the shoulder yaw. A positive rotation about y tilts +x downward, so
        # with down = -h: r = L1 cos q1 + L2 cos(psi), down = L1 sin q1 + L2 sin(psi), where
        # psi = q1 + q2 - delta (delta: the forearm's built-in upward kink).
        down = -h
        d2 = r * r + down * down
        c = (d2 - _L1 ** 2 - _L2 ** 2) / (2 * _L1 * _L2)
        if c < -1.0 - 1e-9 or c > 1.0 + 1e-9:
            continue
        c = float(np.clip(c, -1.0, 1.0))
        for elbow in (math.acos(c), -math.acos(c)):
            q2 = _DELTA + elbow
            q1 = math.atan2(down, r) - math.atan2(_L2 * math.sin(elbow), _L1 + _L2 * math.cos(elbow))
            R_el = rot_z(q0) @ rot_y(q1 + q2)
            for q3, q4, q5 in _wrist_solutions(R_el.T @ R, float(q_ref[3])):
                candidates.append(np.array([q0, q1, q2, q3, q4, q5]))
    best, best_cost = None, math.inf
    for q in candidates:
        q = _wrap_into_limits(q)
        if q is None:
            continue
        if np.max(np.abs(hand_pose(q)[:3, 3] - T[:3, 3])) > 1e-6:
            continue
        cost = float(np.sum((q - q_ref) ** 2))
        if cost < best_cost:
            best, best_cost = q, cost
    return best


def _wrap_into_limits(q: np.ndarray) -> np.ndarray | None:
    """Shift each angle by multiples of 2*pi into its limits if possible."""
    out = q.copy()
    for i in range(6):
        v = math.remainder(out[i], 2 * math.pi)
        for cand in (v, v + 2 * math.pi, v - 2 * math.pi):
            if _LO[i] - 1e-9 <= cand <= _HI[i] + 1e-9:
                out[i] = min(max(cand, _LO[i]), _HI[i])
                break
        else:
            return None
    return out


def top_down_hand_pose(point_body, yaw: float, standoff: float = 0.0) -> np.ndarray:
    """Hand pose (body frame) pointing straight down at a point, jaws closing along ``yaw``.

    The hand x axis points down (-z); the hand z axis (the direction the moving jaw opens towards)
    is horizontal at heading ``yaw``. ``standoff`` lifts the hand above the point along +z.
    """
    x_axis = np.array([0.0, 0.0, -1.0])
    z_axis = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    y_axis = np.cross(z_axis, x_axis)
    R = np.column_stack([x_axis, y_axis, z_axis])
    p = np.asarray(point_body, dtype=float) + np.array([0.0, 0.0, standoff])
    return make_transform(R, p)


def look_at_hand_pose(hand_position_body, target_body) -> np.ndarray:
    """Hand pose at a position with its x axis (the camera's viewing direction) toward a target."""
    p = np.asarray(hand_position_body, dtype=float)
    x_axis = np.asarray(target_body, dtype=float) - p
    n = np.linalg.norm(x_axis)
    if n < 1e-9:
        raise ValueError("look-at target coincides with the hand position")
    x_axis /= n
    up = np.array([0.0, 0.0, 1.0])
    y_axis = np.cross(up, x_axis)
    if np.linalg.norm(y_axis) < 1e-6:  # looking straight up/down: pick any horizontal y
        y_axis = np.array([0.0, 1.0, 0.0])
    y_axis /= np.linalg.norm(y_axis)
    z_axis = np.cross(x_axis, y_axis)
    return make_transform(np.column_stack([x_axis, y_axis, z_axis]), p)
