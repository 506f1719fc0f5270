"""The object and receptacle catalogue of the procedural homes: what each category looks like
(primitive parts, size ranges, colours), where objects can rest on it, and which objects a claw
grasp can pick.

Categories carry the names used in task strings ("filing cabinet", "plastic box"). Sizes follow
real furniture and household objects; small objects are 5-20 cm. Look-alike families (mug / cup /
glass, bowl / plate, apple / orange, phone / remote, table / desk / counter, stool / chair, ...)
exist on purpose: the simulated detector confuses them the way open-vocabulary detectors do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from sim.assets import Part

Color = tuple[float, float, float, float]


@dataclass(frozen=True)
class Surface:
    """A horizontal rectangle (in the body frame) where objects can rest; z is its height."""

    centre: tuple[float, float, float]
    half: tuple[float, float]


@dataclass(frozen=True)
class ReceptacleModel:
    category: str
    parts: tuple[Part, ...]
    surfaces: tuple[Surface, ...]
    half_footprint: tuple[float, float]   # half extents of the xy footprint in the body frame
    height: float                          # overall height
    color: Color
    against_wall: bool                     # placed along a wall (back towards it) rather than free-standing
    front_only: bool = False               # reachable only from its front (-y body side): backs, walls


@dataclass(frozen=True)
class ObjectModel:
    category: str
    parts: tuple[Part, ...]
    mass: float
    color: Color
    size: tuple[float, float, float]      # bounding box (x, y, z) in the body frame; origin at the bottom centre
    graspable: bool                        # a claw grasp can lift it (target categories are graspable)
    rolls: bool = False


# ----------------------------------------------------------------------------------------------
# Palettes
# ----------------------------------------------------------------------------------------------
WOODS = [(0.62, 0.44, 0.26, 1), (0.45, 0.30, 0.18, 1), (0.76, 0.60, 0.42, 1), (0.35, 0.22, 0.13, 1),
         (0.85, 0.75, 0.60, 1)]
PAINTS = [(0.92, 0.92, 0.9, 1), (0.25, 0.27, 0.3, 1), (0.55, 0.6, 0.65, 1), (0.7, 0.78, 0.72, 1),
          (0.35, 0.45, 0.6, 1), (0.8, 0.72, 0.55, 1)]
FABRICS = [(0.45, 0.5, 0.58, 1), (0.6, 0.25, 0.2, 1), (0.3, 0.45, 0.35, 1), (0.75, 0.7, 0.6, 1),
           (0.2, 0.2, 0.25, 1)]
PLASTICS = [(0.2, 0.45, 0.8, 1), (0.85, 0.85, 0.85, 0.9), (0.9, 0.5, 0.1, 1), (0.3, 0.7, 0.4, 1)]
BRIGHT = [(0.85, 0.15, 0.12, 1), (0.15, 0.45, 0.85, 1), (0.95, 0.8, 0.15, 1), (0.2, 0.7, 0.3, 1),
          (0.6, 0.25, 0.7, 1), (0.95, 0.55, 0.1, 1), (0.1, 0.1, 0.1, 1), (0.95, 0.95, 0.95, 1),
          (0.55, 0.35, 0.2, 1), (0.9, 0.4, 0.6, 1)]


def _pick(rng: np.random.Generator, palette: list) -> Color:
    return tuple(palette[int(rng.integers(len(palette)))])


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _box(half, xyz) -> Part:
    return Part("box", tuple(float(h) for h in half), tuple(float(v) for v in xyz))


def _front(hx: float, hy: float, z: float, depth: float = 0.34, side_margin: float = 0.0) -> Surface:
    """The strip of a wall-standing piece's top that an arm reaches: ``depth`` back from the front
    edge (the body frame's -y side faces the room)."""
    d = min(depth, 2 * hy)
    return Surface((0.0, -hy + d / 2, z), (hx - side_margin, d / 2))


def _legs(hx: float, hy: float, height: float, leg: float, inset: float = 0.0) -> list[Part]:
    return [_box((leg / 2, leg / 2, height / 2), (sx * (hx - leg / 2 - inset), sy * (hy - leg / 2 - inset), height / 2))
            for sx in (1, -1) for sy in (1, -1)]


# ----------------------------------------------------------------------------------------------
# Receptacles
# ----------------------------------------------------------------------------------------------
def _table(rng, category="table") -> ReceptacleModel:
    # at most 0.74 m: Spot's stowed claw passes over at ~0.75 m
    hx, hy, h, t = _u(rng, 0.45, 0.8), _u(rng, 0.3, 0.4), _u(rng, 0.68, 0.74), 0.04
    parts = [_box((hx, hy, t / 2), (0, 0, h - t / 2))] + _legs(hx, hy, h - t, 0.05, 0.02)
    return ReceptacleModel(category, tuple(parts), (Surface((0, 0, h), (hx, hy)),), (hx, hy), h,
                           _pick(rng, WOODS), against_wall=False)


def _desk(rng) -> ReceptacleModel:
    hx, hy, h, t = _u(rng, 0.55, 0.8), _u(rng, 0.3, 0.38), _u(rng, 0.70, 0.74), 0.035
    side = [_box((0.015, hy, (h - t) / 2), (sx * (hx - 0.015), 0, (h - t) / 2)) for sx in (1, -1)]
    back = [_box((hx - 0.03, 0.01, 0.18), (0, hy - 0.01, h - t - 0.18))]
    parts = [_box((hx, hy, t / 2), (0, 0, h - t / 2))] + side + back
    return ReceptacleModel("desk", tuple(parts), (_front(hx, hy, h),), (hx, hy), h,
                           _pick(rng, WOODS + PAINTS[:2]), against_wall=True, front_only=True)


def _counter(rng) -> ReceptacleModel:
    hx, hy, h = _u(rng, 0.6, 1.2), 0.3, _u(rng, 0.88, 0.92)
    parts = [_box((hx, hy, 0.02), (0, 0, h - 0.02)), _box((hx - 0.02, hy - 0.05, (h - 0.04) / 2), (0, 0.03, (h - 0.04) / 2))]
    return ReceptacleModel("counter", tuple(parts), (_front(hx, hy, h),), (hx, hy), h,
                           _pick(rng, PAINTS), against_wall=True, front_only=True)


def _stool(rng) -> ReceptacleModel:
    r, h = _u(rng, 0.16, 0.2), _u(rng, 0.45, 0.62)
    parts = [Part("cylinder", (r, 0.04), (0, 0, h - 0.02)), Part("cylinder", (0.035, h - 0.04), (0, 0, (h - 0.04) / 2)),
             Part("cylinder", (r * 0.9, 0.02), (0, 0, 0.01))]
    half = r / math.sqrt(2)
    return ReceptacleModel("stool", tuple(parts), (Surface((0, 0, h), (half, half)),), (r, r), h,
                           _pick(rng, WOODS + PAINTS), against_wall=False)


def _chair(rng) -> ReceptacleModel:
    hx, hy, seat = _u(rng, 0.21, 0.25), _u(rng, 0.21, 0.25), _u(rng, 0.44, 0.48)
    parts = [_box((hx, hy, 0.025), (0, 0, seat - 0.025)), _box((hx, 0.02, 0.22), (0, hy - 0.02, seat + 0.22))]
    parts += _legs(hx, hy, seat - 0.05, 0.04)
    return ReceptacleModel("chair", tuple(parts), (Surface((0, -0.02, seat), (hx, hy - 0.04)),), (hx, hy), seat + 0.44,
                           _pick(rng, WOODS + FABRICS), against_wall=False, front_only=True)


def _cabinet(rng, category="cabinet") -> ReceptacleModel:
    hx, hy, h = _u(rng, 0.35, 0.6), _u(rng, 0.22, 0.28), _u(rng, 0.75, 0.95)
    parts = [_box((hx, hy, h / 2), (0, 0, h / 2))]
    return ReceptacleModel(category, tuple(parts), (_front(hx, hy, h),), (hx, hy), h,
                           _pick(rng, PAINTS + WOODS), against_wall=True, front_only=True)


def _filing_cabinet(rng) -> ReceptacleModel:
    hx, hy, h = _u(rng, 0.2, 0.24), _u(rng, 0.28, 0.32), _u(rng, 0.7, 1.0)
    parts = [_box((hx, hy, h / 2), (0, 0, h / 2))]
    for k in range(3):  # drawer handles
        parts.append(_box((0.05, 0.01, 0.01), (0, -hy - 0.01, h * (0.25 + 0.3 * k))))
    return ReceptacleModel("filing cabinet", tuple(parts), (Surface((0, 0, h), (hx, hy)),), (hx, hy + 0.02), h,
                           _pick(rng, PAINTS[1:4]), against_wall=True, front_only=True)


def _shelf(rng) -> ReceptacleModel:
    hx, hy, h = _u(rng, 0.35, 0.55), _u(rng, 0.15, 0.18), _u(rng, 0.9, 1.1)
    boards = [0.02, 0.45, h - 0.02]
    parts = [_box((0.015, hy, h / 2), (sx * (hx - 0.015), 0, h / 2)) for sx in (1, -1)]
    parts += [_box((hx - 0.03, hy, 0.015), (0, 0, z)) for z in boards]
    parts += [_box((hx, 0.01, h / 2), (0, hy - 0.01, h / 2))]
    # Only the top board is a surface: reaching onto an inner board would take the arm under the one above.
    surfaces = (Surface((0, -0.01, boards[-1] + 0.015), (hx - 0.04, hy - 0.03)),)
    return ReceptacleModel("shelf", tuple(parts), surfaces, (hx, hy), h, _pick(rng, WOODS + PAINTS), against_wall=True, front_only=True)


def _sofa(rng) -> ReceptacleModel:
    hx, hy, seat = _u(rng, 0.8, 1.1), 0.45, _u(rng, 0.42, 0.47)
    parts = [_box((hx, hy - 0.1, seat / 2), (0, -0.1, seat / 2)), _box((hx, 0.1, 0.42), (0, hy - 0.1, 0.42)),
             _box((0.1, hy, 0.3), (hx - 0.1, 0, 0.3)), _box((0.1, hy, 0.3), (-hx + 0.1, 0, 0.3))]
    return ReceptacleModel("sofa", tuple(parts), (Surface((0, -hy + 0.17, seat), (hx - 0.25, 0.15)),), (hx, hy), 0.84,
                           _pick(rng, FABRICS), against_wall=True, front_only=True)


def _bed(rng) -> ReceptacleModel:
    hx, hy, top = _u(rng, 0.7, 0.9), 1.0, _u(rng, 0.5, 0.58)
    parts = [_box((hx, hy, top / 2), (0, 0, top / 2)), _box((hx, 0.04, 0.5), (0, hy - 0.04, 0.5))]
    # reachable strip along the foot end (the head is against the wall)
    return ReceptacleModel("bed", tuple(parts), (Surface((0, -hy + 0.2, top), (hx - 0.1, 0.17)),), (hx, hy), 1.0,
                           _pick(rng, FABRICS + [(0.9, 0.9, 0.92, 1)]), against_wall=True, front_only=True)


def _plastic_box(rng) -> ReceptacleModel:
    hx, hy, h, t = _u(rng, 0.22, 0.28), _u(rng, 0.17, 0.2), _u(rng, 0.22, 0.28), 0.012
    parts = [_box((hx, hy, t / 2), (0, 0, t / 2))]
    parts += [_box((t / 2, hy, h / 2), (sx * (hx - t / 2), 0, h / 2)) for sx in (1, -1)]
    parts += [_box((hx - t, t / 2, h / 2), (0, sy * (hy - t / 2), h / 2)) for sy in (1, -1)]
    return ReceptacleModel("plastic box", tuple(parts), (Surface((0, 0, t), (hx - 0.05, hy - 0.05)),), (hx, hy), h,
                           _pick(rng, PLASTICS), against_wall=False)


RECEPTACLES: dict[str, Callable[[np.random.Generator], ReceptacleModel]] = {
    "table": _table, "desk": _desk, "counter": _counter, "stool": _stool, "chair": _chair, "cabinet": _cabinet,
    "filing cabinet": _filing_cabinet, "shelf": _shelf, "sofa": _sofa, "bed": _bed, "plastic box": _plastic_box,
}


# ----------------------------------------------------------------------------------------------
# Small objects (origin at the bottom centre)
# ----------------------------------------------------------------------------------------------
def _cyl(category, rng, r, h, mass, palette, graspable=True, extra=()) -> ObjectModel:
    parts = (Part("cylinder", (r, h), (0, 0, h / 2)),) + tuple(extra)
    return ObjectModel(category, parts, mass, _pick(rng, palette), (2 * r, 2 * r, h), graspable)


def _cuboid(category, rng, x, y, z, mass, palette, graspable=True) -> ObjectModel:
    return ObjectModel(category, (Part("box", (x / 2, y / 2, z / 2), (0, 0, z / 2)),), mass, _pick(rng, palette),
                       (x, y, z), graspable)


def _mug(rng):
    r, h = _u(rng, 0.035, 0.042), _u(rng, 0.09, 0.11)
    handle = Part("box", (0.012, 0.006, h * 0.3), (r + 0.010, 0, h * 0.55))
    m = _cyl("mug", rng, r, h, 0.3, BRIGHT, extra=(handle,))
    return ObjectModel("mug", m.parts, m.mass, m.color, (2 * r + 0.022, 2 * r, h), True)


def _bottle(rng):
    r, h = _u(rng, 0.028, 0.034), _u(rng, 0.14, 0.17)
    neck = Part("cylinder", (0.012, 0.04), (0, 0, h + 0.02))
    m = _cyl("bottle", rng, r, h, 0.4, PLASTICS + BRIGHT[:3], extra=(neck,))
    return ObjectModel("bottle", m.parts, m.mass, m.color, (2 * r, 2 * r, h + 0.04), True)


def _sphere(category, rng, r_lo, r_hi, mass, palette):
    r = _u(rng, r_lo, r_hi)
    return ObjectModel(category, (Part("sphere", (r,), (0, 0, r)),), mass, _pick(rng, palette), (2 * r, 2 * r, 2 * r),
                       True, rolls=True)


OBJECTS: dict[str, Callable[[np.random.Generator], ObjectModel]] = {
    "mug": _mug,
    "cup": lambda rng: _cyl("cup", rng, _u(rng, 0.03, 0.037), _u(rng, 0.08, 0.11), 0.15, BRIGHT),
    "glass": lambda rng: _cyl("glass", rng, _u(rng, 0.03, 0.035), _u(rng, 0.11, 0.14), 0.2,
                              [(0.75, 0.85, 0.9, 0.6), (0.85, 0.9, 0.85, 0.6)]),
    "bowl": lambda rng: _cyl("bowl", rng, _u(rng, 0.05, 0.058), _u(rng, 0.05, 0.065), 0.25, BRIGHT + PAINTS[:1]),
    "plate": lambda rng: _cyl("plate", rng, _u(rng, 0.08, 0.1), 0.02, 0.3, BRIGHT + PAINTS[:1], graspable=False),
    "can": lambda rng: _cyl("can", rng, 0.033, _u(rng, 0.11, 0.123), 0.35, BRIGHT),
    "jar": lambda rng: _cyl("jar", rng, _u(rng, 0.035, 0.045), _u(rng, 0.08, 0.12), 0.35, PLASTICS + BRIGHT),
    "candle": lambda rng: _cyl("candle", rng, _u(rng, 0.025, 0.035), _u(rng, 0.07, 0.12), 0.15,
                               [(0.95, 0.93, 0.85, 1), (0.9, 0.3, 0.3, 1), (0.95, 0.8, 0.5, 1)]),
    "vase": lambda rng: _cyl("vase", rng, _u(rng, 0.035, 0.045), _u(rng, 0.14, 0.19), 0.4, BRIGHT + PAINTS),
    "bottle": _bottle,
    "apple": lambda rng: _sphere("apple", rng, 0.035, 0.04, 0.18, [(0.8, 0.1, 0.1, 1), (0.5, 0.75, 0.2, 1)]),
    "orange": lambda rng: _sphere("orange", rng, 0.035, 0.04, 0.18, [(0.95, 0.55, 0.1, 1)]),
    "banana": lambda rng: _cuboid("banana", rng, _u(rng, 0.16, 0.19), 0.035, 0.035, 0.12, [(0.95, 0.85, 0.2, 1)]),
    "book": lambda rng: _cuboid("book", rng, _u(rng, 0.15, 0.2), _u(rng, 0.11, 0.14), _u(rng, 0.025, 0.04), 0.35,
                                BRIGHT, graspable=False),
    "toy": lambda rng: _cuboid("toy", rng, *(_u(rng, 0.05, 0.07),) * 3, 0.1, BRIGHT),
    "box": lambda rng: _cuboid("box", rng, _u(rng, 0.08, 0.12), _u(rng, 0.06, 0.09), _u(rng, 0.06, 0.1), 0.2,
                               [(0.72, 0.58, 0.4, 1), (0.85, 0.8, 0.7, 1)]),
    "tissue box": lambda rng: _cuboid("tissue box", rng, 0.2, _u(rng, 0.08, 0.1), _u(rng, 0.08, 0.1), 0.15, PAINTS),
    "sponge": lambda rng: _cuboid("sponge", rng, _u(rng, 0.09, 0.11), 0.065, _u(rng, 0.04, 0.05), 0.04,
                                  [(0.95, 0.85, 0.2, 1), (0.3, 0.7, 0.4, 1)]),
    "phone": lambda rng: _cuboid("phone", rng, 0.15, 0.075, 0.01, 0.18, [(0.1, 0.1, 0.1, 1), (0.9, 0.9, 0.9, 1)],
                                 graspable=False),
    "remote": lambda rng: _cuboid("remote", rng, 0.18, 0.05, 0.022, 0.12, [(0.1, 0.1, 0.1, 1), (0.3, 0.3, 0.35, 1)],
                                  graspable=False),
    "spray bottle": lambda rng: _cuboid("spray bottle", rng, 0.08, 0.05, _u(rng, 0.17, 0.2), 0.35, PLASTICS),
    "soap": lambda rng: _cuboid("soap", rng, 0.09, 0.06, 0.035, 0.1, [(0.95, 0.9, 0.95, 1), (0.6, 0.85, 0.9, 1)],
                                graspable=False),
}

# Look-alike families: the simulated detector confuses members of a family.
LOOKALIKES: tuple[tuple[str, ...], ...] = (
    ("mug", "cup", "glass", "jar"), ("bowl", "plate"), ("apple", "orange"), ("phone", "remote"),
    ("box", "tissue box", "toy", "book"), ("bottle", "vase", "spray bottle", "can"), ("candle", "can"),
    ("sponge", "soap"), ("table", "desk", "counter"), ("stool", "chair"), ("cabinet", "filing cabinet", "shelf"),
    ("sofa", "bed"), ("plastic box", "cabinet"),
)

RECEPTACLE_CATEGORIES = tuple(RECEPTACLES)
OBJECT_CATEGORIES = tuple(OBJECTS)
GRASPABLE_CATEGORIES = tuple(c for c in OBJECTS if OBJECTS[c](np.random.default_rng(0)).graspable)
ALL_CATEGORIES = RECEPTACLE_CATEGORIES + OBJECT_CATEGORIES


def make_receptacle(category: str, rng: np.random.Generator) -> ReceptacleModel:
    try:
        return RECEPTACLES[category](rng)
    except KeyError:
        raise KeyError(f"unknown receptacle category {category!r}; known: {', '.join(RECEPTACLE_CATEGORIES)}") from None


def make_object(category: str, rng: np.random.Generator) -> ObjectModel:
    try:
        return OBJECTS[category](rng)
    except KeyError:
        raise KeyError(f"unknown object category {category!r}; known: {', '.join(OBJECT_CATEGORIES)}") from None
