"""Does the arm have room to point the hand camera? The agent's two models of where Spot's arm goes.

The agent checks that the arm has room before it looks (``Body.elbow_clear`` / ``arm_clear``,
``make_room``, gaze points' ``can_look_from``). ``ViewConfig.arm_model`` picks the model.

``radius`` (the earlier model) keeps every obstacle taller than
``arm_swing_height`` (0.76 m) out of a circle of ``elbow_radius`` round the shoulder, on any side,
and out of a sector of ``arm_swing_radius`` towards the look direction. Measured against the
simulated arm, it is wrong both ways: the arm never leaves a strip ahead of the body, so walls
beside or behind the shoulder never matter and a counter top 0.35 m ahead of the shoulder does
not either when the camera looks at something on it; but a steep look at the floor dips the
gripper to 0.63 m up to 0.8 m ahead, below a table's top.

``measured`` keeps the arm's lowest point over body-frame ground cells, taken over stow -> gaze ->
stow moves of the simulated Spot (``robots.spot.sim_arm``, the real arm's URDF and joint limits)
towards 450 targets at bearings -105..105 degrees, 0.7-3.5 m away and 0-1.2 m high, by
vertical ray tests at every control sample (2026-12-05; ``python -m tools arm-envelope`` measures
it again). The gripper dips lowest when the camera looks steeply down, so the table is kept per
band of the look's pitch: body-frame boxes (x0, x1, half width, lowest arm height), with 3 cm added
round each box and taken off each height; an occupied cell inside a box blocks the look when the
map's height there exceeds the box's height. Unseen cells are not blocked (as in the radius model
ahead of the body): the envelope lies ahead of the body, where the camera looks.
"""

from __future__ import annotations

import math

import numpy as np

from robots.transforms import wrap_angle


def elbows_clear(view, occupancy, geometry, xs, ys, yaw: float, pitch: float | None = None) -> np.ndarray:
    """(N,) bool: with the body at (xs[i], ys[i]) heading ``yaw``, moving the arm at all has room
    (``view``: the agent's ``ViewConfig``; ``pitch``: the look's, degrees down, used by the
    measured model; None: its steepest band)."""
    if view.arm_model == "measured":
        return envelope_clear(occupancy.obstacle, occupancy.max_height, geometry, xs, ys, yaw, pitch)
    return radius_clear(view, occupancy, geometry, np.asarray(xs, dtype=float), np.asarray(ys, dtype=float), yaw)


def sweep_clear(view, occupancy, geometry, x: float, y: float, yaw: float, now: float, direction: float) -> bool:
    """The hand's turn from world yaw ``now`` to ``direction`` has room: the radius model's arc
    (no tall obstacle on it, nor unseen cells far to the side: a wall the camera has not looked at
    yet); always, for the measured model, whose envelope holds every look direction."""
    if view.arm_model == "measured":
        return True
    sx, sy = _shoulder(view, x, y, yaw)
    sweep = float(wrap_angle(direction - now))
    lo, hi = min(0.0, sweep) - 0.3, max(0.0, sweep) + 0.3
    angles = now + np.linspace(lo, hi, max(7, int((hi - lo) / 0.1) + 1))
    r, a = np.meshgrid(np.linspace(0.1, view.arm_swing_radius, 10), angles)
    pts = np.stack([sx + r * np.cos(a), sy + r * np.sin(a)], axis=-1).reshape(-1, 2)
    side = np.abs(wrap_angle(a.reshape(-1) - yaw)) > math.radians(75)
    rows, cols = geometry.world_to_cell(pts)
    blocked = occupancy.obstacle[rows, cols] & (occupancy.max_height[rows, cols] > view.arm_swing_height)
    blocked |= side & ~occupancy.explored[rows, cols]
    return not bool(blocked.any())


def _shoulder(view, x, y, yaw: float):
    return x + view.shoulder_ahead * math.cos(yaw), y + view.shoulder_ahead * math.sin(yaw)


def radius_clear(view, occupancy, geometry, xs: np.ndarray, ys: np.ndarray, yaw: float) -> np.ndarray:
    """The radius model: no obstacle taller than ``arm_swing_height`` within ``elbow_radius`` of
    the shoulder (moving the arm at all swings its links up to 0.34 m round it, on any side)."""
    sx, sy = _shoulder(view, xs, ys, yaw)
    ring = np.linspace(0.0, 2 * math.pi, 32, endpoint=False)
    rr = np.linspace(0.1, view.elbow_radius, 4)
    disc = np.stack([sx[:, None, None] + np.outer(rr, np.cos(ring)),
                     sy[:, None, None] + np.outer(rr, np.sin(ring))], axis=-1).reshape(-1, 2)
    rows, cols = geometry.world_to_cell(disc)
    tall = occupancy.obstacle[rows, cols] & (occupancy.max_height[rows, cols] > view.arm_swing_height)
    return ~tall.reshape(len(xs), -1).any(axis=1)


# ---------------------------------------------------------------------------- the measured model
MARGIN = 0.03
"""Metres added round every measured box and taken off every measured lowest height."""

HAND_AHEAD, HAND_ABOVE = 0.45, 0.50
"""Where the hand sits while it points the camera: ``HAND_AHEAD`` m from the body origin towards
the look (the arm swings to the look's bearing), ``HAND_ABOVE`` m above it. A look's pitch is
measured from there, by the agent and by the sweep that made ``BANDS`` alike."""

BANDS: tuple[tuple[float, tuple[tuple[float, float, float, float], ...]], ...] = (
    # (looks pitched down less than this (degrees; negative: up), boxes (x0, x1, half width,
    # lowest arm height in m) as measured)
    (15.0, ((0.10, 0.50, 0.31, 0.69), (0.50, 0.55, 0.26, 0.71), (0.55, 0.60, 0.21, 0.78),
            (0.60, 0.65, 0.09, 0.88), (0.65, 0.70, 0.06, 0.94))),          # level: counter and shelf tops
    (45.0, ((0.10, 0.60, 0.31, 0.69), (0.60, 0.65, 0.16, 0.98))),           # the far look-around views
    (60.0, ((0.10, 0.60, 0.31, 0.69), (0.60, 0.65, 0.21, 0.70), (0.65, 0.70, 0.21, 0.73),
            (0.70, 0.75, 0.19, 0.76), (0.75, 0.80, 0.16, 0.80))),          # the near-floor views
    (math.inf, ((0.10, 0.40, 0.31, 0.69), (0.40, 0.80, 0.24, 0.63))),       # steep looks: the gripper dips
)


def look_pitch(x: float, y: float, body_z: float, target) -> float:
    """Degrees below horizontal from the hand (body origin at (x, y), ``body_z`` high; the hand
    ``HAND_AHEAD`` m towards the target, ``HAND_ABOVE`` m up) to a world point ``target`` (x, y, z).
    The body's heading does not enter: a look to the side is binned like the same look ahead,
    which is how ``tasks.arm_sweep`` binned the measured looks (one measure for both)."""
    horizontal = math.hypot(float(target[0]) - x, float(target[1]) - y) - HAND_AHEAD
    return math.degrees(math.atan2(body_z + HAND_ABOVE - float(target[2]), max(horizontal, 1e-6)))


def pitch_ahead(body_z: float, ahead: float, height: float) -> float:
    """``look_pitch`` of a point ``ahead`` m in front of the body origin at ``height`` m."""
    return look_pitch(0.0, 0.0, body_z, (ahead, 0.0, height))


def band_of(pitch: float | None) -> int:
    """The band of a look pitched ``pitch`` degrees down (None: the steepest, the most cautious)."""
    if pitch is None:
        return len(BANDS) - 1
    return next(i for i, (below, _) in enumerate(BANDS) if pitch < below)


def band_name(band: int) -> str:
    """``BANDS[band]`` in words, e.g. "pitch 15 to 45 deg down"."""
    lo = BANDS[band - 1][0] if band > 0 else -90.0
    below = BANDS[band][0]
    return f"pitch over {lo:g} deg down" if below == math.inf else f"pitch {lo:g} to {below:g} deg down"


def _samples(band: int, step: float = 0.025) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame sample points (N, 2) covering the band's boxes (margin included) and the map
    height above which each blocks (N,)."""
    pts, limits = [], []
    for x0, x1, half, low in BANDS[band][1]:
        xs = np.arange(x0 - MARGIN, x1 + MARGIN + 1e-9, step)
        ys = np.arange(-half - MARGIN, half + MARGIN + 1e-9, step)
        X, Y = np.meshgrid(xs, ys, indexing="ij")
        pts.append(np.stack([X.ravel(), Y.ravel()], axis=1))
        limits.append(np.full(X.size, low - MARGIN))
    return np.concatenate(pts), np.concatenate(limits)


_SAMPLES = [_samples(i) for i in range(len(BANDS))]


def envelope_clear(obstacle: np.ndarray, max_height: np.ndarray, geometry, xs, ys, yaw: float,
                   pitch: float | None = None) -> np.ndarray:
    """(N,) bool: with the body at (xs[i], ys[i]) heading ``yaw``, no occupied cell under the
    arm's measured envelope for a look pitched ``pitch`` degrees down is taller than the arm
    passes there."""
    local, limit = _SAMPLES[band_of(pitch)]
    c, s = math.cos(yaw), math.sin(yaw)
    wx = local[:, 0] * c - local[:, 1] * s
    wy = local[:, 0] * s + local[:, 1] * c
    xs, ys = np.atleast_1d(np.asarray(xs, dtype=float)), np.atleast_1d(np.asarray(ys, dtype=float))
    pts = np.stack([xs[:, None] + wx[None], ys[:, None] + wy[None]], axis=-1).reshape(-1, 2)
    rows, cols = geometry.world_to_cell(pts)
    rows, cols = np.clip(rows, 0, obstacle.shape[0] - 1), np.clip(cols, 0, obstacle.shape[1] - 1)
    blocked = obstacle[rows, cols] & (max_height[rows, cols] > np.tile(limit, len(xs)))
    return ~blocked.reshape(len(xs), -1).any(axis=1)
