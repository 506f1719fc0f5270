"""When a moving command has stalled: the Spot SDK backend samples robot state while a walk, an arm
move or a stow runs, and stops one that makes no progress instead of waiting out its whole time
budget (a robot that accepts commands and never carries them out)."""

from __future__ import annotations

import time

import numpy as np


class StallWatch:
    """Progress of a moving command from robot state samples: stalled when over the last
    ``window`` s the robot moved less than ``tolerance`` (any coordinate: m, rad, or cos/sin of a
    heading) while it is more than four times that away from where its plan has it now (or at
    the plan's end, once the plan is over). A robot that keeps moving, slower or faster than
    planned, is never stalled; nor is one that has arrived.

    A move the robot plans itself (stow) has no plan of ours: ``track`` is then (actual(state),
    None, arrived(state) -> bool), and "away" is the robot's own word that it is not there yet."""

    period = 0.1            # s between state samples
    tolerance = 0.01

    def __init__(self, track, window: float, expected: float):
        self.actual, self.planned = track[0], track[1]
        self.arrived = track[2] if len(track) > 2 else None
        if (self.planned is None) == (self.arrived is None):
            raise ValueError("a stall watch needs either a plan or an arrival test")
        self.window, self.expected = float(window), float(expected)
        self.samples: list[tuple[float, np.ndarray]] = []
        self._away = True
        self._next = time.monotonic() + self.period

    def due(self, now: float) -> bool:
        if now < self._next:
            return False
        self._next = now + self.period
        return True

    def add(self, t: float, state) -> None:
        self.samples.append((t, np.asarray(self.actual(state), dtype=float)))
        while len(self.samples) > 2 and self.samples[1][0] <= t - self.window:
            self.samples.pop(0)
        if self.arrived is not None:
            self._away = not self.arrived(state)

    def stalled(self) -> bool:
        if len(self.samples) < 2:
            return False
        (t_old, _), (t, x) = self.samples[0], self.samples[-1]
        if t - t_old < self.window:
            return False
        # how far any sample in the window lies from the latest: a move out and back within the
        # window (a stow from stowed passes its tuck pose) is motion, though it ends where it began
        moved = max(float(np.max(np.abs(xi - x))) for _, xi in self.samples)
        if self.planned is None:
            return moved < self.tolerance and self._away
        behind = float(np.max(np.abs(np.asarray(self.planned(min(t, self.expected)), dtype=float) - x)))
        return moved < self.tolerance and behind > 4 * self.tolerance
