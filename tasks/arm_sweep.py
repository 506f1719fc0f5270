"""Where the simulated Spot arm goes when it points the hand camera: the lowest point of its links
over body-frame ground cells, per band of the look's pitch.

The measurement behind :mod:`helios.agents.arm_room` (``python -m tools arm-envelope``): a
robot alone on an empty floor points the camera at each target (bearing, distance, height) and
stows again; at every control sample a vertical ray from the floor through each 2.5 cm cell of a
body-frame window finds the lowest arm link above it. The body's own cells are hidden (a ray hits
the body first), which is where no obstacle can be anyway.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from helios.agents.arm_room import BANDS, band_of, look_pitch
from helios.planning.footprint import FootprintConfig
from robots.hal import SE2Pose

CELL = 0.025
WINDOW_X = (-0.6, 1.2)      # body frame, m
WINDOW_Y = (-0.8, 0.8)


@dataclass(frozen=True)
class Targets:
    bearings_deg: Sequence[float] = tuple(range(-105, 106, 15))
    distances: Sequence[float] = (0.7, 1.0, 1.3, 1.7, 2.5, 3.5)
    heights: Sequence[float] = (0.0, 0.3, 0.6, 0.9, 1.2)

    @property
    def count(self) -> int:
        return len(self.bearings_deg) * len(self.distances) * len(self.heights)


QUICK = Targets(bearings_deg=tuple(range(-105, 106, 35)), distances=(0.7, 1.3, 2.5), heights=(0.0, 0.6, 1.2))


@dataclass
class Envelope:
    xs: np.ndarray              # cell centres along the body's x (forward), m
    ys: np.ndarray              # ... and y (left), m
    lowest: list[np.ndarray]    # per band of ``helios.agents.arm_room.BANDS``: (len(xs), len(ys)) m, inf: never
    looks: list[int]            # looks per band
    failed: int                 # looks the arm could not make (no IK solution, or a touch)


def measure(targets: Targets = Targets(), progress: Callable[[int, int], None] | None = None) -> Envelope:
    from robots.spot.sim_backend import SimSpotBackend
    from sim.spot import SpotBody
    from sim.world import World

    world = World()
    spot = SpotBody(world, SE2Pose(0.0, 0.0, 0.0))
    backend = SimSpotBackend(world, spot, owns_world=False)
    xs = np.arange(WINDOW_X[0], WINDOW_X[1], CELL) + CELL / 2
    ys = np.arange(WINDOW_Y[0], WINDOW_Y[1], CELL) + CELL / 2
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    starts = np.stack([X.ravel(), Y.ravel(), np.full(X.size, 0.02)], axis=1).tolist()
    ends = np.stack([X.ravel(), Y.ravel(), np.full(X.size, 2.0)], axis=1).tolist()
    arm_links = {i for name, i in spot.link_index.items() if name.startswith("arm0")}
    lowest = [np.full(X.size, np.inf) for _ in BANDS]
    looks = [0] * len(BANDS)
    current: list[np.ndarray] = [lowest[0]]

    def sample() -> None:
        out = current[0]
        for k, hit in enumerate(world.client.rayTestBatch(starts, ends)):
            if hit[0] == spot.id and hit[1] in arm_links and hit[3][2] < out[k]:
                out[k] = hit[3][2]

    # sample after every physics step and every kinematic arm pose (the backend replays free-arm
    # moves pose by pose)
    step, set_arm = world.step, spot.set_arm_state

    def stepped(n: int = 1) -> None:
        step(n)
        sample()

    def arm_set(q, qd=None) -> None:
        set_arm(q, qd)
        sample()

    world.step, spot.set_arm_state = stepped, arm_set
    body_z = spot.T_world_body()[2, 3]
    failed, done = 0, 0
    try:
        for bearing in targets.bearings_deg:
            for dist in targets.distances:
                for h in targets.heights:
                    b = math.radians(bearing)
                    target = (dist * math.cos(b), dist * math.sin(b), h)
                    # binned as the agent bins a look (``look_pitch``)
                    band = band_of(look_pitch(0.0, 0.0, body_z, target))
                    current[0] = lowest[band]
                    looks[band] += 1
                    if not backend.gaze_at(target).success:
                        failed += 1
                    backend.stow_arm()
                    done += 1
                    if progress is not None:
                        progress(done, targets.count)
    finally:
        backend.close()
    return Envelope(xs, ys, [m.reshape(X.shape) for m in lowest], looks, failed)


def slices(env: Envelope, band: int, width: float = 0.05) -> list[tuple[float, float, float, float]]:
    """(x0, x1, half width, lowest height) of the band's measured cells in ``width`` slices along x."""
    grid = env.lowest[band]
    out = []
    for x0 in np.arange(WINDOW_X[0], WINDOW_X[1], width):
        sel = (env.xs >= x0 - 1e-9) & (env.xs < x0 + width - 1e-9)
        part = grid[sel]
        seen = np.isfinite(part)
        if not seen.any():
            continue
        ys = np.broadcast_to(env.ys, part.shape)[seen]
        out.append((float(x0), float(x0 + width), float(np.max(np.abs(ys)) + CELL / 2), float(part[seen].min())))
    return out


def uncovered(env: Envelope, band: int, margin: float, body=FootprintConfig().body) -> list[tuple[float, float, float]]:
    """Measured cells of a band outside the body's footprint (``body``: x0, x1, y0, y1, where no
    obstacle can stand) that the table's boxes (grown by ``margin``) do not cover at or below the
    measured height: (x, y, measured lowest height) each, the table's errors."""
    grid = env.lowest[band]
    bad = []
    for i, j in zip(*np.nonzero(np.isfinite(grid))):
        x, y, z = float(env.xs[i]), float(env.ys[j]), float(grid[i, j])
        if body[0] <= x <= body[1] and body[2] <= y <= body[3]:
            continue
        covered = any(x0 - margin <= x <= x1 + margin and abs(y) <= half + margin and z >= low - margin
                      for x0, x1, half, low in BANDS[band][1])
        if not covered:
            bad.append((x, y, z))
    return bad
