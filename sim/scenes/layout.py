"""Procedural home layouts as plain data: rooms, walls with doorways, furniture and small objects.

A layout is fully determined by its seed (``numpy.random.Generator`` streams derived from it) and
knows nothing of PyBullet; ``sim.scenes.home`` turns it into bodies. Generation:

1. the footprint (8-15 m a side) is split recursively (binary space partition) into 3-6 rooms, each
   split line getting one doorway, so every room is reachable;
2. rooms get types (kitchen, living room, bedroom, office, hallway) and furniture typical for them,
   several instances of the common categories as real homes have (up to 3 counters, cabinets,
   stools or chairs in a room, 2 tables, shelves, desks): wall-standing pieces along walls away
   from doorways, free-standing ones inside with at least a robot's width of clearance, and chairs
   drawn up to tables (``TABLE_CHAIRS``; one long side of a table is always left free to reach it);
3. small objects go on receptacle surfaces with an edge margin, several instances per category and
   look-alike families side by side (not on the chairs at a table: they are not reachable);
4. Spot starts at a random free spot.
"""

from __future__ import annotations

import copy
import functools
import math
from dataclasses import dataclass, field, replace

import numpy as np

from sim.scenes.catalog import (
    LOOKALIKES,
    OBJECT_CATEGORIES,
    ObjectModel,
    ReceptacleModel,
    make_object,
    make_receptacle,
)

ROOM_FURNITURE: dict[str, list[tuple[str, float, int]]] = {
    # room type -> (category, probability of each extra copy after the first, max count); first entries are
    # always placed when they fit.
    "kitchen": [("counter", 0.6, 3), ("table", 0.3, 2), ("stool", 0.5, 3), ("cabinet", 0.5, 3), ("shelf", 0.0, 1),
                ("plastic box", 0.0, 1)],
    "living room": [("sofa", 0.3, 2), ("table", 0.5, 2), ("shelf", 0.5, 2), ("chair", 0.5, 3), ("cabinet", 0.5, 2),
                    ("stool", 0.3, 2)],
    "bedroom": [("bed", 0.0, 1), ("cabinet", 0.5, 2), ("chair", 0.3, 2), ("shelf", 0.5, 2), ("desk", 0.0, 1),
                ("table", 0.0, 1)],
    "office": [("desk", 0.5, 2), ("chair", 0.5, 3), ("filing cabinet", 0.5, 2), ("shelf", 0.5, 2), ("cabinet", 0.3, 2),
               ("plastic box", 0.3, 1), ("table", 0.0, 1)],
    "hallway": [("cabinet", 0.3, 2), ("shelf", 0.3, 2), ("stool", 0.0, 1), ("plastic box", 0.0, 1), ("table", 0.0, 1)],
}
# Probability that an optional (non-first) furniture entry is placed at all.
OPTIONAL_PROBABILITY = 0.65
# room type -> (min, max) chairs drawn up to each table placed there (where they fit).
TABLE_CHAIRS: dict[str, tuple[int, int]] = {"kitchen": (2, 4), "living room": (0, 2), "office": (1, 2),
                                            "bedroom": (0, 1), "hallway": (0, 0)}
CHAIR_PASSAGE = 0.7   # m kept free between a chair at a table and other furniture


@dataclass(frozen=True)
class LayoutConfig:
    min_size: float = 8.0            # m, footprint side range
    max_size: float = 15.0
    min_room_side: float = 3.0       # m
    max_rooms: int = 6
    door_width: float = 1.1          # m
    wall_thickness: float = 0.1
    wall_height: float = 2.0
    passage: float = 1.0             # m of free floor kept between free-standing furniture (robot width + margin)
    door_clearance: float = 1.0      # m kept free in front of each doorway
    objects_per_m2: float = 0.18     # small objects per square metre of floor
    min_objects: int = 12
    edge_margin: float = 0.07        # m between an object and its surface's edge


@dataclass
class Room:
    kind: str
    x0: float
    y0: float
    x1: float
    y1: float

    @property
    def centre(self) -> tuple[float, float]:
        return (0.5 * (self.x0 + self.x1), 0.5 * (self.y0 + self.y1))

    def contains(self, x: float, y: float, margin: float = 0.0) -> bool:
        return self.x0 + margin <= x <= self.x1 - margin and self.y0 + margin <= y <= self.y1 - margin


@dataclass(frozen=True)
class Wall:
    x0: float
    y0: float
    x1: float
    y1: float


@dataclass(frozen=True)
class Door:
    x: float
    y: float
    horizontal: bool   # the wall it sits in runs along x


@dataclass
class PlacedReceptacle:
    name: str
    model: ReceptacleModel
    x: float
    y: float
    yaw: float
    room: str
    at: str | None = None     # a chair drawn up to this table (no objects on it; not reachable)

    @property
    def category(self) -> str:
        return self.model.category

    def footprint_corners(self, pad: float = 0.0) -> np.ndarray:
        hx, hy = self.model.half_footprint
        return _obb_corners(self.x, self.y, self.yaw, hx + pad, hy + pad)


@dataclass
class PlacedObject:
    name: str
    model: ObjectModel
    receptacle: str
    surface: int
    x: float       # world position of the object's bottom centre
    y: float
    z: float
    yaw: float

    @property
    def category(self) -> str:
        return self.model.category


@dataclass
class HomeLayout:
    seed: int
    width: float
    depth: float
    rooms: list[Room]
    walls: list[Wall]
    doors: list[Door]
    receptacles: list[PlacedReceptacle]
    objects: list[PlacedObject]
    robot_start: tuple[float, float, float]
    config: LayoutConfig = field(default_factory=LayoutConfig)

    def receptacle(self, name: str) -> PlacedReceptacle:
        for r in self.receptacles:
            if r.name == name:
                return r
        raise KeyError(f"no receptacle {name!r} in this layout")

    def categories(self) -> set[str]:
        return {r.category for r in self.receptacles} | {o.category for o in self.objects}


# ----------------------------------------------------------------------------------------------
# Geometry helpers
# ----------------------------------------------------------------------------------------------
def _obb_corners(x: float, y: float, yaw: float, hx: float, hy: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    local = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
    return local @ np.array([[c, s], [-s, c]]) + np.array([x, y])


def obb_overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Separating-axis test for two convex quadrilaterals given as (4, 2) corner arrays."""
    for poly in (a, b):
        for i in range(4):
            edge = poly[(i + 1) % 4] - poly[i]
            axis = np.array([-edge[1], edge[0]])
            pa, pb = a @ axis, b @ axis
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
    return True


def _segment_rect(x0, y0, x1, y1, half_thickness: float) -> np.ndarray:
    yaw = math.atan2(y1 - y0, x1 - x0)
    length = math.hypot(x1 - x0, y1 - y0)
    return _obb_corners((x0 + x1) / 2, (y0 + y1) / 2, yaw, length / 2 + half_thickness, half_thickness)


# ----------------------------------------------------------------------------------------------
# Generation
# ----------------------------------------------------------------------------------------------
def _split_rooms(rng, cfg: LayoutConfig, w: float, d: float, target: int):
    """Binary space partition; returns leaf rectangles and (split line, door) pairs."""
    leaves = [(0.0, 0.0, w, d)]
    splits = []
    attempts = 0
    while len(leaves) < target and attempts < 50:
        attempts += 1
        leaves.sort(key=lambda r: (r[2] - r[0]) * (r[3] - r[1]), reverse=True)
        x0, y0, x1, y1 = leaves[0]
        along_x = (x1 - x0) >= (y1 - y0)
        span = (x1 - x0) if along_x else (y1 - y0)
        if span < 2 * cfg.min_room_side:
            break
        cut = float(rng.uniform(cfg.min_room_side, span - cfg.min_room_side))
        leaves.pop(0)
        if along_x:
            xc = x0 + cut
            leaves += [(x0, y0, xc, y1), (xc, y0, x1, y1)]
            door_y = float(rng.uniform(y0 + 0.3 + cfg.door_width / 2, y1 - 0.3 - cfg.door_width / 2))
            splits.append(((xc, y0, xc, y1), Door(xc, door_y, horizontal=False)))
        else:
            yc = y0 + cut
            leaves += [(x0, y0, x1, yc), (x0, yc, x1, y1)]
            door_x = float(rng.uniform(x0 + 0.3 + cfg.door_width / 2, x1 - 0.3 - cfg.door_width / 2))
            splits.append(((x0, yc, x1, yc), Door(door_x, yc, horizontal=True)))
    return leaves, splits


def _assign_room_types(rng, rects) -> list[str]:
    areas = [(r[2] - r[0]) * (r[3] - r[1]) for r in rects]
    order = list(np.argsort(areas)[::-1])
    kinds = [""] * len(rects)
    for i, r in enumerate(rects):
        w, d = r[2] - r[0], r[3] - r[1]
        if max(w, d) / min(w, d) > 2.3 and "hallway" not in kinds:
            kinds[i] = "hallway"
    queue = ["living room", "kitchen", "bedroom", "office"]
    extra = ["bedroom", "office", "kitchen", "living room"]
    for i in order:
        if kinds[i]:
            continue
        kinds[i] = queue.pop(0) if queue else extra[int(rng.integers(len(extra)))]
    return kinds


def _walls(cfg: LayoutConfig, w: float, d: float, splits) -> list[Wall]:
    walls = [Wall(0, 0, w, 0), Wall(w, 0, w, d), Wall(w, d, 0, d), Wall(0, d, 0, 0)]
    half = cfg.door_width / 2
    for (x0, y0, x1, y1), door in splits:
        if door.horizontal:
            pieces = [(x0, door.x - half), (door.x + half, x1)]
            walls += [Wall(a, y0, b, y0) for a, b in pieces if b - a > 0.05]
        else:
            pieces = [(y0, door.y - half), (door.y + half, y1)]
            walls += [Wall(x0, a, x0, b) for a, b in pieces if b - a > 0.05]
    return walls


def _blocked(x: float, y: float, yaw: float, hx: float, hy: float, walls, doors, placed, cfg: LayoutConfig,
             free_standing: bool) -> bool:
    corners = _obb_corners(x, y, yaw, hx, hy)
    half_t = cfg.wall_thickness / 2 + 0.02
    for wall in walls:
        if obb_overlap(corners, _segment_rect(wall.x0, wall.y0, wall.x1, wall.y1, half_t)):
            return True
    c = cfg.door_clearance
    for door in doors:
        # keep door_clearance free on both sides of every doorway
        zone = _obb_corners(door.x, door.y, 0.0, cfg.door_width / 2 + 0.2 if door.horizontal else c,
                            c if door.horizontal else cfg.door_width / 2 + 0.2)
        if obb_overlap(corners, zone):
            return True
    for other in placed:
        # a robot's passage between anything free-standing and its neighbours; wall pieces may touch
        gap = cfg.passage if (free_standing or not other.model.against_wall) else 0.05
        if obb_overlap(_obb_corners(x, y, yaw, hx + gap / 2, hy + gap / 2), other.footprint_corners(gap / 2)):
            return True
    return False


def _room_doors(room: Room, doors) -> list[tuple[float, float]]:
    """Points just inside ``room`` in front of each of its doorways."""
    out = []
    for d in doors:
        if d.horizontal and room.x0 <= d.x <= room.x1 and abs(d.y - room.y0) < 1e-6:
            out.append((d.x, room.y0 + 0.35))
        elif d.horizontal and room.x0 <= d.x <= room.x1 and abs(d.y - room.y1) < 1e-6:
            out.append((d.x, room.y1 - 0.35))
        elif not d.horizontal and room.y0 <= d.y <= room.y1 and abs(d.x - room.x0) < 1e-6:
            out.append((room.x0 + 0.35, d.y))
        elif not d.horizontal and room.y0 <= d.y <= room.y1 and abs(d.x - room.x1) < 1e-6:
            out.append((room.x1 - 0.35, d.y))
    return out


def _room_stays_open(room: Room, doors, pieces, robot_half_width: float = 0.32, cell: float = 0.1) -> bool:
    """With ``pieces`` in the room, Spot (as a disc of the given radius) can still get from every
    doorway to every other and over at least half of the floor."""
    import cv2
    from scipy import ndimage

    w = int(math.ceil((room.x1 - room.x0) / cell))
    h = int(math.ceil((room.y1 - room.y0) / cell))
    occ = np.zeros((h, w), dtype=np.uint8)
    for p in pieces:
        corners = p.footprint_corners(robot_half_width)
        pts = np.round((corners - [room.x0, room.y0]) / cell).astype(np.int32)
        cv2.fillConvexPoly(occ, pts, 1)
    margin = int(math.ceil((robot_half_width + 0.05) / cell))   # walls
    occ[:margin, :] = occ[-margin:, :] = 1
    occ[:, :margin] = occ[:, -margin:] = 1
    labels, _ = ndimage.label(occ == 0)
    door_labels = set()
    for x, y in _room_doors(room, doors):
        r = int(np.clip((y - room.y0) / cell, 0, h - 1))
        c = int(np.clip((x - room.x0) / cell, 0, w - 1))
        window = labels[max(r - margin, 0):r + margin + 1, max(c - margin, 0):c + margin + 1]
        found = set(np.unique(window[window > 0]).tolist())
        if not found:
            return False
        door_labels |= {min(found)}
    if len(door_labels) > 1:
        return False
    main = door_labels.pop() if door_labels else (np.bincount(labels.ravel())[1:].argmax() + 1 if labels.max() else 0)
    return main > 0 and np.count_nonzero(labels == main) >= 0.5 * np.count_nonzero(occ == 0)


def _place_furniture(rng, cfg: LayoutConfig, room: Room, kind_list, walls, doors, placed, counters) -> None:
    for idx, (category, p_extra, max_count) in enumerate(kind_list):
        if idx > 0 and rng.random() > OPTIONAL_PROBABILITY:
            continue
        count = 1 + sum(rng.random() < p_extra for _ in range(max_count - 1))
        for _ in range(count):
            model = make_receptacle(category, rng)
            hx, hy = model.half_footprint
            for _attempt in range(40):
                if model.against_wall:
                    side = int(rng.integers(4))
                    off = cfg.wall_thickness / 2 + 0.04   # gap between the piece's back and the wall surface
                    # back (+y in the body frame) against the chosen wall
                    if side == 0:    # south wall, facing north
                        x, y, yaw = rng.uniform(room.x0 + hx + 0.1, room.x1 - hx - 0.1), room.y0 + hy + off, math.pi
                    elif side == 1:  # north wall
                        x, y, yaw = rng.uniform(room.x0 + hx + 0.1, room.x1 - hx - 0.1), room.y1 - hy - off, 0.0
                    elif side == 2:  # west wall
                        x, y, yaw = room.x0 + hy + off, rng.uniform(room.y0 + hx + 0.1, room.y1 - hx - 0.1), math.pi / 2
                    else:            # east wall
                        x, y, yaw = room.x1 - hy - off, rng.uniform(room.y0 + hx + 0.1, room.y1 - hx - 0.1), -math.pi / 2
                    if side in (0, 1) and room.x1 - room.x0 < 2 * hx + 0.2:
                        continue
                    if side in (2, 3) and room.y1 - room.y0 < 2 * hx + 0.2:
                        continue
                else:
                    margin = max(hx, hy) + cfg.passage
                    if room.x1 - room.x0 < 2 * margin or room.y1 - room.y0 < 2 * margin:
                        break
                    x = rng.uniform(room.x0 + margin, room.x1 - margin)
                    y = rng.uniform(room.y0 + margin, room.y1 - margin)
                    yaw = float(rng.integers(4)) * math.pi / 2 + float(rng.uniform(-0.25, 0.25))
                x, y, yaw = float(x), float(y), float(yaw)
                if _blocked(x, y, yaw, hx, hy, walls, doors, placed, cfg, not model.against_wall):
                    continue
                candidate = PlacedReceptacle("", model, x, y, yaw, room.kind)
                in_room = [p for p in placed if room.contains(p.x, p.y)] + [candidate]
                if not _room_stays_open(room, doors, in_room):
                    continue
                counters[category] = counters.get(category, 0) + 1
                candidate.name = f"{category.replace(' ', '_')}_{counters[category]}"
                placed.append(candidate)
                if category == "table":
                    _place_table_chairs(rng, cfg, room, candidate, walls, doors, placed, counters)
                break


def _place_table_chairs(rng, cfg: LayoutConfig, room: Room, table: PlacedReceptacle, walls, doors, placed,
                        counters) -> None:
    """Chairs drawn up to ``table`` (facing it, 5-15 cm from its edge): at most two along one long
    side and one at each end, so the other long side stays free for the robot. A slot is skipped
    where the chair would block a wall, a doorway, another piece's passage or the room's paths."""
    lo, hi = TABLE_CHAIRS.get(room.kind, (0, 0))
    n = int(rng.integers(lo, hi + 1)) if hi > 0 else 0
    if n == 0:
        return
    hx, hy = table.model.half_footprint
    side = 1.0 if rng.random() < 0.5 else -1.0
    # (x, y) in the table frame of the chair centre before the chair's half depth is added, and the
    # chair's yaw relative to the table (its front, the body's -y side, faces the table)
    long_xs = (-hx / 2, hx / 2) if hx >= 0.55 else (0.0,)
    slots = [((x, side * hy), 0.0 if side > 0 else math.pi) for x in long_xs]
    slots += [((hx, 0.0), -math.pi / 2), ((-hx, 0.0), math.pi / 2)]
    order = rng.permutation(len(slots))
    c, s = math.cos(table.yaw), math.sin(table.yaw)
    group = [table]
    # a chair may stand closer to other furniture than free-standing pieces do (room for Spot's
    # width, not its turning circle); the room's paths are still checked below
    chair_cfg = replace(cfg, passage=CHAIR_PASSAGE)
    for k in order[:n]:
        (sx, sy), dyaw = slots[int(k)]
        model = make_receptacle("chair", rng)
        chx, chy = model.half_footprint
        gap = float(rng.uniform(0.05, 0.15)) + chy
        if abs(sy) > 0:                       # a long side: push out along y
            lx, ly = sx, sy + math.copysign(gap, sy)
        else:                                 # an end: push out along x
            lx, ly = sx + math.copysign(gap, sx), sy
        x, y = table.x + c * lx - s * ly, table.y + s * lx + c * ly
        yaw = table.yaw + dyaw + float(rng.uniform(-0.15, 0.15))
        others = [p for p in placed if p not in group]
        if _blocked(x, y, yaw, chx, chy, walls, doors, others, chair_cfg, True):
            continue
        corners = _obb_corners(x, y, yaw, chx + 0.02, chy + 0.02)
        if any(obb_overlap(corners, g.footprint_corners(0.02)) for g in group):
            continue
        candidate = PlacedReceptacle("", model, x, y, yaw, room.kind, at=table.name)
        in_room = [p for p in placed if room.contains(p.x, p.y)] + [candidate]
        if not _room_stays_open(room, doors, in_room):
            continue
        counters["chair"] = counters.get("chair", 0) + 1
        candidate.name = f"chair_{counters['chair']}"
        placed.append(candidate)
        group.append(candidate)


def _surface_world(rec: PlacedReceptacle, surface_index: int):
    s = rec.model.surfaces[surface_index]
    c, sn = math.cos(rec.yaw), math.sin(rec.yaw)
    cx = rec.x + c * s.centre[0] - sn * s.centre[1]
    cy = rec.y + sn * s.centre[0] + c * s.centre[1]
    return cx, cy, s.centre[2], s.half, rec.yaw


def _place_objects(rng, cfg: LayoutConfig, receptacles, n_objects: int) -> list[PlacedObject]:
    """Objects on surfaces; categories drawn so that several instances and look-alikes co-occur."""
    surfaces = [(r, i) for r in receptacles if r.at is None for i in range(len(r.model.surfaces))]
    if not surfaces:
        return []
    families = [f for f in LOOKALIKES if all(c in OBJECT_CATEGORIES for c in f)]
    chosen: list[str] = []
    while len(chosen) < n_objects:
        roll = rng.random()
        if roll < 0.45:      # a look-alike pair (the detector's hard cases)
            fam = families[int(rng.integers(len(families)))]
            pair = rng.choice(len(fam), size=min(2, len(fam)), replace=False)
            chosen += [fam[int(i)] for i in pair]
        elif roll < 0.7 and chosen:   # another instance of a category already present
            chosen.append(chosen[int(rng.integers(len(chosen)))])
        else:
            chosen.append(OBJECT_CATEGORIES[int(rng.integers(len(OBJECT_CATEGORIES)))])
    chosen = chosen[:n_objects]
    occupied: dict[tuple[str, int], list[tuple[float, float, float]]] = {}
    counters: dict[str, int] = {}
    objects = []
    for category in chosen:
        model = make_object(category, rng)
        radius = 0.5 * math.hypot(model.size[0], model.size[1])
        for _attempt in range(30):
            rec, si = surfaces[int(rng.integers(len(surfaces)))]
            cx, cy, cz, (hx, hy), yaw = _surface_world(rec, si)
            mx, my = hx - cfg.edge_margin - radius, hy - cfg.edge_margin - radius
            if mx <= 0 or my <= 0:
                continue
            lx, ly = rng.uniform(-mx, mx), rng.uniform(-my, my)
            c, sn = math.cos(yaw), math.sin(yaw)
            x, y = cx + c * lx - sn * ly, cy + sn * lx + c * ly
            others = occupied.setdefault((rec.name, si), [])
            if any(math.hypot(x - ox, y - oy) < radius + orad + 0.03 for ox, oy, orad in others):
                continue
            others.append((x, y, radius))
            counters[category] = counters.get(category, 0) + 1
            objects.append(PlacedObject(f"{category.replace(' ', '_')}_{counters[category]}", model, rec.name, si,
                                        float(x), float(y), float(cz), float(rng.uniform(-math.pi, math.pi))))
            break
    return objects


class LayoutError(RuntimeError):
    """A layout could not be completed (no free start pose for the robot); names the seed."""


def _start_free(x: float, y: float, walls, receptacles, cfg: LayoutConfig) -> bool:
    foot = _obb_corners(float(x), float(y), 0.0, 0.75, 0.75)   # room to turn in place
    if any(obb_overlap(foot, r.footprint_corners(0.05)) for r in receptacles):
        return False
    return not any(obb_overlap(foot, _segment_rect(w.x0, w.y0, w.x1, w.y1, cfg.wall_thickness / 2)) for w in walls)


def _robot_start(rng, rooms, walls, receptacles, cfg: LayoutConfig, seed: int = 0):
    for _ in range(200):
        room = rooms[int(rng.integers(len(rooms)))]
        x, y = rng.uniform(room.x0 + 0.8, room.x1 - 0.8), rng.uniform(room.y0 + 0.8, room.y1 - 0.8)
        yaw = float(rng.uniform(-math.pi, math.pi))
        if _start_free(x, y, walls, receptacles, cfg):
            return (float(x), float(y), yaw)
    # furnished homes: scan every room on a 0.2 m grid before giving up
    for room in rooms:
        for x in np.arange(room.x0 + 0.8, room.x1 - 0.8 + 1e-9, 0.2):
            for y in np.arange(room.y0 + 0.8, room.y1 - 0.8 + 1e-9, 0.2):
                if _start_free(x, y, walls, receptacles, cfg):
                    return (float(x), float(y), float(rng.uniform(-math.pi, math.pi)))
    raise LayoutError(f"home seed {seed}: no free start pose found for the robot")


def generate_layout(seed: int, config: LayoutConfig = LayoutConfig()) -> HomeLayout:
    """A home layout from a seed; the same seed always gives the same layout.

    A split holds five consecutive episodes per home, and generating a layout is about half of
    building a home (0.27 of 0.6 s): a worker keeps the last few layouts it generated and hands out
    a deep copy (the layout is mutable; a caller's changes never reach the next episode). Layouts
    that fail (``LayoutError``) are not kept."""
    return copy.deepcopy(_layout_of(seed, config))


@functools.lru_cache(maxsize=8)
def _layout_of(seed: int, config: LayoutConfig) -> HomeLayout:
    rng = np.random.default_rng(seed)
    w = float(rng.uniform(config.min_size, config.max_size))
    d = float(rng.uniform(config.min_size, config.max_size))
    target = int(np.clip(round(w * d / 22.0), 3, config.max_rooms))
    rects, splits = _split_rooms(rng, config, w, d, target)
    kinds = _assign_room_types(rng, rects)
    rooms = [Room(k, *r) for k, r in zip(kinds, rects)]
    walls = _walls(config, w, d, splits)
    doors = [door for _, door in splits]
    placed: list[PlacedReceptacle] = []
    counters: dict[str, int] = {}
    for room in sorted(rooms, key=lambda r: (r.x1 - r.x0) * (r.y1 - r.y0), reverse=True):
        _place_furniture(rng, config, room, ROOM_FURNITURE[room.kind], walls, doors, placed, counters)
    n_objects = max(config.min_objects, int(round(config.objects_per_m2 * w * d)))
    objects = _place_objects(rng, config, placed, n_objects)
    start = _robot_start(rng, rooms, walls, placed, config, seed)
    return HomeLayout(seed, w, d, rooms, walls, doors, placed, objects, start, config)
