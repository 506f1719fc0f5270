"""Random camera views of a scene's objects and furniture (for calibration, benchmarks and tests).

A view stands where a robot could stand (free floor with some clearance on the true navigation
grid), at a hand-camera height, and looks at the target with a little aim jitter so the target
is not always centred.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from robots.transforms import look_at_camera


@dataclass(frozen=True)
class ViewSampling:
    object_distance: tuple[float, float] = (0.7, 4.0)       # m, horizontal, small-object targets
    receptacle_distance: tuple[float, float] = (1.2, 6.0)   # m, horizontal, furniture targets
    height: tuple[float, float] = (0.4, 1.5)                # m, camera height (Spot's hand camera range)
    aim_jitter: float = 0.2                                 # m, uniform offset of the look-at point
    min_clearance: float = 0.15                             # m from the camera's floor point to obstacles
    tries: int = 20


def target_centre(world, body_id: int) -> np.ndarray:
    lo, hi = world.aabb(body_id)
    return (lo + hi) / 2


def random_view(scene, world, body_id: int, rng: np.random.Generator, sampling: ViewSampling = ViewSampling(),
                distance: tuple[float, float] | None = None) -> np.ndarray | None:
    """T_world_cam of a random free viewpoint looking at ``body_id``, or None if none was found."""
    centre = target_centre(world, body_id)
    if distance is None:
        kind = world.bodies[body_id].kind
        distance = sampling.object_distance if kind == "object" else sampling.receptacle_distance
    lo_d, hi_d = distance
    layout = scene.layout
    for _ in range(sampling.tries):
        d = math.exp(rng.uniform(math.log(lo_d), math.log(hi_d)))   # log-uniform: more near views
        a = rng.uniform(-math.pi, math.pi)
        xy = centre[:2] + d * np.array([math.cos(a), math.sin(a)])
        if not (0.05 < xy[0] < layout.width - 0.05 and 0.05 < xy[1] < layout.depth - 0.05):
            continue
        if scene.nav.clearance_at(xy) < sampling.min_clearance:
            continue
        eye = np.array([xy[0], xy[1], rng.uniform(*sampling.height)])
        aim = centre + rng.uniform(-sampling.aim_jitter, sampling.aim_jitter, size=3)
        if np.linalg.norm(aim - eye) < 0.2:
            continue
        return look_at_camera(eye, aim)
    return None
