"""The demo scene: two tables 3 m apart and a mug on the first, Spot standing between them.

Small on purpose: it exercises walking, looking, grasping by pixel, carrying and dropping in a few
simulated seconds. The seed jitters the mug's position and heading so runs differ by seed and
repeat exactly for the same seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robots.hal import SE2Pose
from sim import assets
from sim.world import World


@dataclass(frozen=True)
class DemoLayout:
    pick_table_xy: tuple[float, float] = (2.0, 0.0)
    place_table_xy: tuple[float, float] = (-1.5, 1.5)
    table_height: float = 0.50
    robot_start: tuple[float, float, float] = (0.0, 0.0, 0.0)


def build_demo_scene(world: World, rng: np.random.Generator, layout: DemoLayout = DemoLayout()) -> dict:
    """Add the tables and the mug; returns names and key poses for the script and the tests."""
    ax, ay = layout.pick_table_xy
    bx, by = layout.place_table_xy
    assets.add_table(world, "table_pick", (ax, ay), yaw=0.0, length=0.8, width=0.8, height=layout.table_height)
    assets.add_table(world, "table_place", (bx, by), yaw=0.3, length=1.0, width=0.7, height=layout.table_height,
                     top_color=(0.35, 0.5, 0.65, 1.0))
    dx, dy = rng.uniform(-0.08, 0.08, size=2)
    mug_yaw = float(rng.uniform(-np.pi, np.pi))
    mug_xy = (ax - 0.22 + dx, ay + dy)
    mug = assets.add_mug(world, "mug", (mug_xy[0], mug_xy[1], layout.table_height + 0.001), yaw=mug_yaw)
    settled, _ = world.settle([mug])
    if not settled:
        raise RuntimeError("demo scene did not settle")
    return {"mug": mug, "pick_table": "table_pick", "place_table": "table_place",
            "robot_start": SE2Pose(*layout.robot_start), "layout": layout}
