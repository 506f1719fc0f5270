"""Bodies built from primitive shapes: furniture, walls and small graspable objects.

Every body is a single rigid body with a compound collision shape, the cheapest thing for the
solver (static multi-link bodies were measured to cost ~4.5 us per body per physics step). Static
bodies get one merged visual mesh whose faces are cut into cells of at most ``max_cell``: PyBullet's
TinyRenderer scans each triangle's whole screen bounding box, so a wall or a table top drawn as two
huge triangles costs milliseconds per frame even when barely visible. A static body has one colour
(and optionally a texture); dynamic objects use the primitive shapes directly.
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


def box_mesh(half_extents, max_cell: float = 0.25) -> tuple[list, list, list, list]:
    """A box surface cut into cells of at most ``max_cell``: (vertices, indices, normals, uvs).

    UVs run over each face in metres (a texture repeats once per metre). Built with array
    operations that do the very same float operations, in the same order, as the per-vertex loop
    it replaced (a home's 114 boxes took 0.15 s that way, a quarter of building the home;
    ``tests/test_exact_speedups.py`` keeps the loop as the oracle).
    """
    h = np.asarray(half_extents, dtype=float)
    verts, idx, normals, uvs = [], [], [], []
    for axis in range(3):
        u_ax, v_ax = [a for a in range(3) if a != axis]
        nu = max(1, int(math.ceil(2 * h[u_ax] / max_cell)))
        nv = max(1, int(math.ceil(2 * h[v_ax] / max_cell)))
        # grid positions along u and v as the loop computed them: -h + 2 * h * i / n
        pu = -h[u_ax] + 2 * h[u_ax] * np.arange(nu + 1) / nu
        pv = -h[v_ax] + 2 * h[v_ax] * np.arange(nv + 1) / nv
        gu, gv = np.repeat(pu, nv + 1), np.tile(pv, nu + 1)          # i outer, j inner
        uv = np.stack([gu + h[u_ax], gv + h[v_ax]], axis=1).tolist()
        ii, jj = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
        ii, jj = ii.ravel(), jj.ravel()
        for sign in (1.0, -1.0):
            base = len(verts)
            n = [0.0, 0.0, 0.0]
            n[axis] = sign
            p = np.zeros((gu.size, 3))
            p[:, axis] = sign * h[axis]
            p[:, u_ax] = gu
            p[:, v_ax] = gv
            verts += p.tolist()
            normals += [n] * gu.size
            uvs += uv
            # counter-clockwise seen from outside: the (u, v, n) frame is right-handed for axis 0 and
            # 2 with u < v ordering, left-handed for axis 1.
            flip = (sign < 0) != (axis == 1)
            a = base + ii * (nv + 1) + jj
            b = base + (ii + 1) * (nv + 1) + jj
            quad = np.stack([a, b + 1, b, a, a + 1, b + 1] if flip else [a, b, b + 1, a, b + 1, a + 1], axis=1)
            idx += quad.ravel().tolist()
    return verts, idx, normals, uvs


def cylinder_mesh(radius: float, height: float, segments: int = 16, max_cell: float = 0.25):
    """A closed cylinder along z (vertices, indices, normals, uvs), side cut into rings."""
    verts, idx, normals, uvs = [], [], [], []
    rings = max(1, int(math.ceil(height / max_cell)))
    angles = np.linspace(0.0, 2 * math.pi, segments + 1)
    for r in range(rings + 1):
        z = -height / 2 + height * r / rings
        for a in angles:
            verts.append([radius * math.cos(a), radius * math.sin(a), z])
            normals.append([math.cos(a), math.sin(a), 0.0])
            uvs.append([radius * a, z + height / 2])
    for r in range(rings):
        for k in range(segments):
            a, b = r * (segments + 1) + k, (r + 1) * (segments + 1) + k
            idx += [a, a + 1, b + 1, a, b + 1, b]
    for sign in (1.0, -1.0):
        centre = len(verts)
        verts.append([0.0, 0.0, sign * height / 2])
        normals.append([0.0, 0.0, sign])
        uvs.append([0.0, 0.0])
        first = len(verts)
        for a in angles:
            verts.append([radius * math.cos(a), radius * math.sin(a), sign * height / 2])
            normals.append([0.0, 0.0, sign])
            uvs.append([radius * math.cos(a), radius * math.sin(a)])
        for k in range(segments):
            tri = [centre, first + k, first + k + 1]
            idx += tri if sign > 0 else [tri[0], tri[2], tri[1]]
    return verts, idx, normals, uvs


def _part_mesh(part: Part, max_cell: float):
    if part.shape == "box":
        mesh = box_mesh(part.size, max_cell)
    elif part.shape == "cylinder":
        mesh = cylinder_mesh(part.size[0], part.size[1], max_cell=max_cell)
    else:
        r = part.size[0]
        mesh = box_mesh((r, r, r), max_cell)  # spheres only appear as tiny markers on static bodies
    verts, idx, normals, uvs = mesh
    R = rpy_to_matrix(*part.rpy)
    v = np.asarray(verts) @ R.T + np.asarray(part.xyz)
    n = np.asarray(normals) @ R.T
    return v, np.asarray(idx), n, np.asarray(uvs)


def merged_mesh(parts: Sequence[Part], max_cell: float = 0.25):
    """All parts of a static body as one mesh in the body frame."""
    vs, ids, ns, us = [], [], [], []
    offset = 0
    for part in parts:
        v, i, n, u = _part_mesh(part, max_cell)
        vs.append(v)
        ids.append(i + offset)
        ns.append(n)
        us.append(u)
        offset += len(v)
    return (np.concatenate(vs).tolist(), np.concatenate(ids).astype(int).tolist(), np.concatenate(ns).tolist(),
            np.concatenate(us).tolist())


def add_static(world: World, name: str, category: str, parts: Sequence[Part], position, yaw: float = 0.0,
               color: Color = (0.6, 0.45, 0.3, 1.0), kind: str = FURNITURE, friction: float = 0.8,
               texture: int | None = None, max_cell: float = 0.25, **extra) -> int:
    """A static (mass 0) body: compound collision shape, one merged visual mesh, one colour."""
    if not parts:
        raise ValueError(f"body {name!r} needs at least one part")
    c, pb = world.client, world.pb
    col = c.createCollisionShapeArray(**_shape_array(pb, parts))
    verts, idx, normals, uvs = merged_mesh(parts, max_cell)
    vis = c.createVisualShape(pb.GEOM_MESH, vertices=verts, indices=idx, normals=normals, uvs=uvs,
                              rgbaColor=list(color))
    body = c.createMultiBody(baseMass=0.0, baseCollisionShapeIndex=col, baseVisualShapeIndex=vis,
                             basePosition=list(map(float, position)), baseOrientation=_quat((0.0, 0.0, yaw)))
    c.changeDynamics(body, -1, lateralFriction=friction)
    if texture is not None:
        c.changeVisualShape(body, -1, textureUniqueId=texture)
    info = world.register(body, name, category, kind, **extra)
    info.link_names = {-1: name}
    return body


def _shape_array(pb, parts: Sequence[Part]) -> dict:
    types, half, radii, lengths, pos, orn = [], [], [], [], [], []
    for p in parts:
        types.append({"box": pb.GEOM_BOX, "cylinder": pb.GEOM_CYLINDER, "sphere": pb.GEOM_SPHERE}[p.shape])
        half.append(list(p.size) if p.shape == "box" else [0.0, 0.0, 0.0])
        radii.append(p.size[0] if p.shape != "box" else 0.0)
        lengths.append(p.size[1] if p.shape == "cylinder" else 0.0)
        pos.append(list(p.xyz))
        orn.append(_quat(p.rpy))
    return {"shapeTypes": types, "radii": radii, "halfExtents": half, "lengths": lengths,
            "collisionFramePositions": pos, "collisionFrameOrientations": orn}


def add_object(world: World, name: str, category: str, parts: Sequence[Part], position, yaw: float = 0.0,
               mass: float = 0.2, color: Color = (0.8, 0.2, 0.2, 1.0), friction: float = 1.0,
               rolling_friction: float = 0.0005, spinning_friction: float = 0.001, **extra) -> int:
    """A dynamic graspable object: one rigid body with a compound collision shape."""
    if not parts:
        raise ValueError(f"object {name!r} needs at least one part")
    if not (math.isfinite(mass) and mass > 0):
        raise ValueError(f"object {name!r} needs a positive mass, got {mass}")
    c, pb = world.client, world.pb
    arrays = _shape_array(pb, parts)
    col = c.createCollisionShapeArray(**arrays)
    vis = c.createVisualShapeArray(arrays["shapeTypes"], radii=arrays["radii"], halfExtents=arrays["halfExtents"],
                                   lengths=arrays["lengths"], visualFramePositions=arrays["collisionFramePositions"],
                                   visualFrameOrientations=arrays["collisionFrameOrientations"])
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
