"""Bodies built from primitive shapes: furniture, walls and small graspable objects.

Static bodies whose parts have different colours are built as one multibody with fixed-joint
links (PyBullet colours a compound shape as a whole), which also gives each part its own link index
in the segmentation image. Dynamic objects are single rigid bodies with a compound collision shape,
the cheapest thing for the solver.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from robots.transforms import matrix_to_quat_xyzw, rpy_to_matrix
from sim.world import FURNITURE, OBJECT, STRUCTURE, World

Color = tuple[float, float, float, float]


@dataclass(frozen=True)
class Part:
    """One primitive of a body, placed in the body frame.

    ``size``: box half extents (x, y, z); cylinder (radius, height) along z; sphere (radius,).
    """

    shape: str
    size: tuple[float, ...]
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    color: Color | None = None
    name: str = ""

    def __post_init__(self) -> None:
        expected = {"box": 3, "cylinder": 2, "sphere": 1}
        if self.shape not in expected:
            raise ValueError(f"unknown part shape {self.shape!r}; use one of {sorted(expected)}")
        if len(self.size) != expected[self.shape] or not all(math.isfinite(s) and s > 0 for s in self.size):
            raise ValueError(f"{self.shape} part needs {expected[self.shape]} positive sizes, got {self.size}")


def _quat(rpy) -> list[float]:
    return matrix_to_quat_xyzw(rpy_to_matrix(*rpy)).tolist()


def _shape_kwargs(pb, part: Part) -> dict:
    if part.shape == "box":
        return {"shapeType": pb.GEOM_BOX, "halfExtents": list(part.size)}
    if part.shape == "cylinder":
        return {"shapeType": pb.GEOM_CYLINDER, "radius": part.size[0], "height": part.size[1]}
    return {"shapeType": pb.GEOM_SPHERE, "radius": part.size[0]}


def _collision(world: World, part: Part) -> int:
    kw = _shape_kwargs(world.pb, part)
    return world.client.createCollisionShape(**kw, collisionFramePosition=list(part.xyz),
                                             collisionFrameOrientation=_quat(part.rpy))


def box_mesh(half_extents, max_cell: float = 0.25) -> tuple[list, list, list]:
    """A box surface as triangles no larger than ``max_cell`` (vertices, indices, normals).

    PyBullet's TinyRenderer scans every triangle's whole screen bounding box, so a large face seen
    from close by (a table top under the hand camera) costs tens of ms; small cells keep each scan
    tight (``tools bench sim`` reports the effect).
    """
    h = np.asarray(half_extents, dtype=float)
    verts, idx, normals = [], [], []
    for axis in range(3):
        u_ax, v_ax = [a for a in range(3) if a != axis]
        nu = max(1, int(math.ceil(2 * h[u_ax] / max_cell)))
        nv = max(1, int(math.ceil(2 * h[v_ax] / max_cell)))
        for sign in (1.0, -1.0):
            base = len(verts)
            for i in range(nu + 1):
                for j in range(nv + 1):
                    p = np.zeros(3)
                    p[axis] = sign * h[axis]
                    p[u_ax] = -h[u_ax] + 2 * h[u_ax] * i / nu
                    p[v_ax] = -h[v_ax] + 2 * h[v_ax] * j / nv
                    verts.append(p.tolist())
                    n = [0.0, 0.0, 0.0]
                    n[axis] = sign
                    normals.append(n)
            for i in range(nu):
                for j in range(nv):
                    a, b = base + i * (nv + 1) + j, base + (i + 1) * (nv + 1) + j
                    tri = [a, b, b + 1, a, b + 1, a + 1]
                    # keep counter-clockwise winding seen from outside the face
                    if (sign > 0) != ((axis == 1)):
                        idx += tri
                    else:
                        idx += [tri[0], tri[2], tri[1], tri[3], tri[5], tri[4]]
    return verts, idx, normals


def _visual(world: World, part: Part, color: Color) -> int:
    if part.shape == "box" and max(part.size) * 2 > 0.3:
        verts, idx, normals = box_mesh(part.size)
        return world.client.createVisualShape(
            world.pb.GEOM_MESH, vertices=verts, indices=idx, normals=normals, uvs=[[0.0, 0.0]] * len(verts),
            rgbaColor=list(color), visualFramePosition=list(part.xyz), visualFrameOrientation=_quat(part.rpy))
    kw = _shape_kwargs(world.pb, part)
    if "height" in kw:  # PyBullet names the cylinder height "length" for visual shapes
        kw["length"] = kw.pop("height")
    return world.client.createVisualShape(**kw, rgbaColor=list(color), visualFramePosition=list(part.xyz),
                                          visualFrameOrientation=_quat(part.rpy))


def add_static(world: World, name: str, category: str, parts: Sequence[Part], position, yaw: float = 0.0,
               color: Color = (0.6, 0.45, 0.3, 1.0), kind: str = FURNITURE, friction: float = 0.8,
               **extra) -> int:
    """A static (mass 0) body: one link per part so parts can differ in colour."""
    if not parts:
        raise ValueError(f"body {name!r} needs at least one part")
    c = world.client
    cols = [_collision(world, p) for p in parts]
    viss = [_visual(world, p, p.color or color) for p in parts]
    n = len(parts) - 1
    body = c.createMultiBody(
        baseMass=0.0, baseCollisionShapeIndex=cols[0], baseVisualShapeIndex=viss[0],
        basePosition=list(map(float, position)), baseOrientation=_quat((0.0, 0.0, yaw)),
        linkMasses=[0.0] * n, linkCollisionShapeIndices=cols[1:], linkVisualShapeIndices=viss[1:],
        linkPositions=[[0.0, 0.0, 0.0]] * n, linkOrientations=[[0.0, 0.0, 0.0, 1.0]] * n,
        linkInertialFramePositions=[[0.0, 0.0, 0.0]] * n, linkInertialFrameOrientations=[[0, 0, 0, 1]] * n,
        linkParentIndices=[0] * n, linkJointTypes=[world.pb.JOINT_FIXED] * n, linkJointAxis=[[0, 0, 1]] * n,
    )
    for link in range(-1, n):
        c.changeDynamics(body, link, lateralFriction=friction)
    info = world.register(body, name, category, kind, **extra)
    info.link_names = {i - 1: (p.name or f"part{i}") for i, p in enumerate(parts)}
    return body


def add_object(world: World, name: str, category: str, parts: Sequence[Part], position, yaw: float = 0.0,
               mass: float = 0.2, color: Color = (0.8, 0.2, 0.2, 1.0), friction: float = 1.0,
               rolling_friction: float = 0.0005, spinning_friction: float = 0.001, **extra) -> int:
    """A dynamic graspable object: one rigid body with a compound collision shape."""
    if not parts:
        raise ValueError(f"object {name!r} needs at least one part")
    if not (math.isfinite(mass) and mass > 0):
        raise ValueError(f"object {name!r} needs a positive mass, got {mass}")
    c, pb = world.client, world.pb
    types, half, radii, lengths, pos, orn = [], [], [], [], [], []
    for p in parts:
        types.append({"box": pb.GEOM_BOX, "cylinder": pb.GEOM_CYLINDER, "sphere": pb.GEOM_SPHERE}[p.shape])
        half.append(list(p.size) if p.shape == "box" else [0.0, 0.0, 0.0])
        radii.append(p.size[0] if p.shape != "box" else 0.0)
        lengths.append(p.size[1] if p.shape == "cylinder" else 0.0)
        pos.append(list(p.xyz))
        orn.append(_quat(p.rpy))
    col = c.createCollisionShapeArray(types, radii=radii, halfExtents=half, lengths=lengths,
                                      collisionFramePositions=pos, collisionFrameOrientations=orn)
    vis = c.createVisualShapeArray(types, radii=radii, halfExtents=half, lengths=lengths,
                                   visualFramePositions=pos, visualFrameOrientations=orn)
    body = c.createMultiBody(mass, col, vis, basePosition=list(map(float, position)),
                             baseOrientation=_quat((0.0, 0.0, yaw)))
    c.changeVisualShape(body, -1, rgbaColor=list(color))
    c.changeDynamics(body, -1, lateralFriction=friction, rollingFriction=rolling_friction,
                     spinningFriction=spinning_friction, restitution=0.05, linearDamping=0.04, angularDamping=0.04)
    world.register(body, name, category, OBJECT, **extra)
    return body


# ------------------------------------------------------------------------------------------------
# Concrete shapes used by the demo scene and the tests (the procedural homes build their own).
# ------------------------------------------------------------------------------------------------
def table_parts(length: float, width: float, height: float, top_color: Color, leg_color: Color,
                top_thickness: float = 0.04, leg: float = 0.05) -> list[Part]:
    """A four-legged table; body origin on the floor under the table centre."""
    parts = [Part("box", (length / 2, width / 2, top_thickness / 2), (0.0, 0.0, height - top_thickness / 2),
                  color=top_color, name="top")]
    leg_h = height - top_thickness
    for i, (sx, sy) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
        parts.append(Part("box", (leg / 2, leg / 2, leg_h / 2),
                          (sx * (length / 2 - leg), sy * (width / 2 - leg), leg_h / 2), color=leg_color,
                          name=f"leg{i}"))
    return parts


def add_table(world: World, name: str, position_xy, yaw: float = 0.0, length: float = 1.0, width: float = 0.6,
              height: float = 0.5, category: str = "table", top_color: Color = (0.62, 0.44, 0.26, 1.0),
              leg_color: Color = (0.25, 0.2, 0.15, 1.0)) -> int:
    x, y = position_xy
    return add_static(world, name, category, table_parts(length, width, height, top_color, leg_color),
                      (x, y, 0.0), yaw, top_height=height, top_half_extents=(length / 2, width / 2))


def mug_parts(radius: float = 0.04, height: float = 0.10) -> list[Part]:
    """A mug: body cylinder plus a handle; origin at the centre of the bottom face."""
    return [Part("cylinder", (radius, height), (0.0, 0.0, height / 2), name="body"),
            Part("box", (0.012, 0.006, height * 0.3), (radius + 0.010, 0.0, height * 0.55), name="handle")]


def add_mug(world: World, name: str, position, yaw: float = 0.0, color: Color = (0.85, 0.15, 0.12, 1.0),
            radius: float = 0.04, height: float = 0.10, mass: float = 0.3) -> int:
    return add_object(world, name, "mug", mug_parts(radius, height), position, yaw, mass, color,
                      bottom_offset=0.0, size=(2 * radius, 2 * radius, height))


def add_box_object(world: World, name: str, position, half_extents=(0.03, 0.03, 0.03), yaw: float = 0.0,
                   mass: float = 0.2, color: Color = (0.2, 0.5, 0.85, 1.0), category: str = "box") -> int:
    """A box whose origin is its centre."""
    return add_object(world, name, category, [Part("box", tuple(half_extents))], position, yaw, mass, color,
                      size=tuple(2 * np.asarray(half_extents)))


def add_wall(world: World, name: str, start_xy, end_xy, height: float = 2.0, thickness: float = 0.1,
             color: Color = (0.88, 0.87, 0.83, 1.0)) -> int:
    """A straight wall segment between two floor points."""
    (x0, y0), (x1, y1) = start_xy, end_xy
    length = math.hypot(x1 - x0, y1 - y0)
    if length < 1e-6:
        raise ValueError(f"wall {name!r} has zero length")
    yaw = math.atan2(y1 - y0, x1 - x0)
    part = Part("box", (length / 2, thickness / 2, height / 2), (0.0, 0.0, height / 2), name="wall")
    return add_static(world, name, "wall", [part], ((x0 + x1) / 2, (y0 + y1) / 2, 0.0), yaw, color, kind=STRUCTURE)
