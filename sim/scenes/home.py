"""Build a procedural home into a PyBullet world, settle it and validate it.

Validation (``SceneValidationError`` if it fails): every object comes to rest on the receptacle it
was placed on; the robot's start footprint is free; every receptacle surface can be approached
(a standing pose within arm's reach, reachable from the start on the true occupancy grid) — the
list of those that cannot is kept so episode generation never picks them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from robots.hal import SE2Pose
from sim import assets
from sim.grasping import support_body
from sim.scenes.layout import HomeLayout, LayoutConfig, LayoutError, PlacedObject, PlacedReceptacle, generate_layout
from sim.scenes.navigation import NavConfig, NavGrid
from sim.world import FURNITURE, World


class SceneValidationError(LayoutError):
    """A generated scene failed a physical or reachability check (names the seed and the problem).
    A ``LayoutError`` too (like a layout that cannot be completed): ``except LayoutError`` skips both."""


@dataclass
class HomeScene:
    layout: HomeLayout
    world: World
    nav: NavGrid
    receptacle_ids: dict[str, int] = field(default_factory=dict)
    object_ids: dict[str, int] = field(default_factory=dict)
    approachable: set[str] = field(default_factory=set)   # receptacles with an approach pose from the start

    @property
    def robot_start(self) -> SE2Pose:
        return SE2Pose(*self.layout.robot_start)

    def receptacle(self, name: str) -> PlacedReceptacle:
        return self.layout.receptacle(name)

    def placed_object(self, name: str) -> PlacedObject:
        for o in self.layout.objects:
            if o.name == name:
                return o
        raise KeyError(f"no object {name!r} in this scene")

    def front(self, name: str) -> np.ndarray | None:
        """World unit vector of the side a receptacle is reached from, None if from any side."""
        rec = self.receptacle(name)
        if not rec.model.front_only:
            return None
        return np.array([np.sin(rec.yaw), -np.cos(rec.yaw)])   # the body frame's -y axis

    def surface_points(self, name: str) -> list[np.ndarray]:
        """World centre (x, y, z) of each of a receptacle's surfaces."""
        rec = self.receptacle(name)
        out = []
        c, s = np.cos(rec.yaw), np.sin(rec.yaw)
        for surf in rec.model.surfaces:
            x, y, z = surf.centre
            out.append(np.array([rec.x + c * x - s * y, rec.y + s * x + c * y, z]))
        return out


def build_home(world: World, layout: HomeLayout, nav_config: NavConfig = NavConfig(),
               settle_time: float = 3.0) -> HomeScene:
    """Instantiate ``layout`` in ``world``; settle the objects and validate the result."""
    cfg = layout.config
    nav = NavGrid(layout, nav_config)
    scene = HomeScene(layout, world, nav)
    for i, w in enumerate(layout.walls):
        assets.add_wall(world, f"wall_{i}", (w.x0, w.y0), (w.x1, w.y1), height=cfg.wall_height,
                        thickness=cfg.wall_thickness)
    for r in layout.receptacles:
        m = r.model
        scene.receptacle_ids[r.name] = assets.add_static(
            world, r.name, r.category, m.parts, (r.x, r.y, 0.0), r.yaw, m.color, kind=FURNITURE,
            room=r.room, surfaces=[(tuple(s.centre), tuple(s.half)) for s in m.surfaces])
    for o in layout.objects:
        m = o.model
        scene.object_ids[o.name] = assets.add_object(
            world, o.name, o.category, m.parts, (o.x, o.y, o.z + 0.002), o.yaw, m.mass, m.color,
            receptacle=o.receptacle, size=m.size)
    ids = list(scene.object_ids.values())
    if ids:
        settled, _ = world.settle(ids, max_time=settle_time)
        if not settled:
            raise SceneValidationError(f"home seed {layout.seed}: objects did not come to rest in {settle_time} s")
    for o in layout.objects:
        body = scene.object_ids[o.name]
        support = support_body(world, body)
        if support != scene.receptacle_ids[o.receptacle]:
            where = world.bodies[support].name if support is not None else "nothing"
            raise SceneValidationError(f"home seed {layout.seed}: {o.name} should rest on {o.receptacle} "
                                       f"but rests on {where} at {np.round(world.position(body), 3).tolist()}")
    if not nav.footprint_free(scene.robot_start):
        raise SceneValidationError(f"home seed {layout.seed}: the robot's start pose is not free")
    start_xy = layout.robot_start[:2]
    for r in layout.receptacles:
        if any(nav.approach_poses(p, start_xy, scene.front(r.name)) for p in scene.surface_points(r.name)):
            scene.approachable.add(r.name)
    return scene


def generate_home(world: World, seed: int, config: LayoutConfig = LayoutConfig()) -> HomeScene:
    """Generate and build the home for ``seed``."""
    return build_home(world, generate_layout(seed, config))
