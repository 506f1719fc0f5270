"""A target: the one thing the agent acts on (grasps, or places onto), whether it came from the
object map (an instance) or from a detection the trusting baseline believed."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Target:
    """Something to act on: a target-object or goal-receptacle candidate."""

    key: tuple                       # ("instance", id) or ("detection", n)
    centre: np.ndarray               # (3,) world
    footprint_xy: np.ndarray         # (K, 2) world
    top: float                       # highest point, m
    psi: float                       # uncertainty-weighted score (1 for trusted detections)
    points: np.ndarray | None = None  # (N, 3) its Gaussian centres or detected points, when chosen
    instance_id: int | None = None
