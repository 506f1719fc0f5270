"""A synthetic RGB-D world of axis-aligned boxes: a ray-cast pinhole renderer, a furnished
two-room flat and a noisy synthetic detector along a camera path through it.

Pure numpy (no PyBullet): the map tests use it to render exact depth and masks of known geometry,
and ``python -m tools bench maps --maps-synthetic`` replays :func:`synthetic_frames`. Frames are
``(Observation, list[Detection], {layer: score})`` tuples, what the map consumes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator, Mapping, Sequence

import numpy as np

from helios.perception.detection import Detection
from robots.hal import CameraIntrinsics, Observation
from robots.transforms import look_at_camera

WIDTH, HEIGHT = 320, 240
"""Default image size: Spot's hand camera as the simulator renders it."""
HFOV_DEG = 60.0
"""Default horizontal field of view in degrees."""

Frame = tuple[Observation, list[Detection], Mapping[str, float]]


@dataclass(frozen=True)
class Box:
    """An axis-aligned box (world metres) with a class name and a colour; boxes sharing an
    ``object_id`` are parts of one object (one detection mask)."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    class_name: str
    color: tuple[int, int, int] = (180, 180, 180)
    object_id: int | None = None


def pinhole(width: int = WIDTH, height: int = HEIGHT, hfov_deg: float = HFOV_DEG) -> CameraIntrinsics:
    f = width / 2 / math.tan(math.radians(hfov_deg) / 2)
    return CameraIntrinsics(width, height, f, f, (width - 1) / 2, (height - 1) / 2)


def render_boxes(boxes: Sequence[Box], intrinsics: CameraIntrinsics, T_world_cam: np.ndarray,
                 max_range: float = 20.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ray-cast boxes: (rgb uint8 (H, W, 3), depth float32 (0 = no hit), box index int32 (-1))."""
    h, w = intrinsics.height, intrinsics.width
    vv, uu = np.mgrid[0:h, 0:w]
    rays = np.stack([(uu - intrinsics.cx) / intrinsics.fx, (vv - intrinsics.cy) / intrinsics.fy,
                     np.ones((h, w))], axis=-1).reshape(-1, 3) @ T_world_cam[:3, :3].T
    origin = T_world_cam[:3, 3]
    rays = np.where(np.abs(rays) < 1e-12, 1e-12, rays)
    inv = np.ascontiguousarray((1.0 / rays).T)            # (3, P): per-axis slabs are contiguous
    best = np.full(rays.shape[0], np.inf)
    hit = np.full(rays.shape[0], -1, dtype=np.int32)
    for k, box in enumerate(boxes):
        t_near, t_far = None, None
        for axis in range(3):
            t1 = (box.lo[axis] - origin[axis]) * inv[axis]
            t2 = (box.hi[axis] - origin[axis]) * inv[axis]
            lo_t, hi_t = np.minimum(t1, t2), np.maximum(t1, t2)
            t_near = lo_t if t_near is None else np.maximum(t_near, lo_t)
            t_far = hi_t if t_far is None else np.minimum(t_far, hi_t)
        ok = (t_far >= t_near) & (t_near > 1e-6) & (t_near < best)
        best[ok] = t_near[ok]
        hit[ok] = k
    depth = np.where(best <= max_range, best, 0.0).astype(np.float32)   # t is optical depth (ray z = 1)
    hit[depth == 0] = -1
    colors = np.asarray([b.color for b in boxes] + [(0, 0, 0)], dtype=np.float32)
    shade = np.clip(1.0 - depth / (2 * max_range), 0.3, 1.0)[:, None]
    rgb = (colors[hit] * shade).astype(np.uint8)
    return rgb.reshape(h, w, 3), depth.reshape(h, w), hit.reshape(h, w)


def wall(x0: float, y0: float, x1: float, y1: float, height: float = 2.2, thickness: float = 0.1) -> Box:
    """A wall between two points on an axis (thickness centred on the line)."""
    t = thickness / 2
    return Box((min(x0, x1) - t, min(y0, y1) - t, 0.0), (max(x0, x1) + t, max(y0, y1) + t, height), "wall", (200, 195, 185))


def table(x0: float, y0: float, x1: float, y1: float, height: float, object_id: int,
          color: tuple[int, int, int] = (150, 90, 40)) -> list[Box]:
    """A table: a 4 cm top on four 5 cm legs, one object."""
    top = Box((x0, y0, height - 0.04), (x1, y1, height), "table", color, object_id)
    legs = [Box((x, y, 0.0), (x + 0.05, y + 0.05, height - 0.04), "table", color, object_id)
            for x in (x0, x1 - 0.05) for y in (y0, y1 - 0.05)]
    return [top, *legs]


def two_room_flat() -> list[Box]:
    """A furnished 10 m x 6 m flat: a living room and a kitchen-bedroom joined by a 1 m door.

    Task classes are a cup (two, on the tables), a table (two, top and legs) and a counter (one);
    bowls look like cups to the simulated detector. Everything else (walls, floor, 17 pieces of
    furniture and clutter) is what only the full-scene mode models, roughly an OVMM home's mix.
    """
    return [
        Box((0.0, 0.0, -0.02), (10.0, 6.0, 0.0), "floor", (120, 100, 80)),
        wall(0, 0, 10, 0), wall(0, 6, 10, 6), wall(0, 0, 0, 6), wall(10, 0, 10, 6),
        wall(5, 0, 5, 2.5), wall(5, 3.5, 5, 6),
        # living room
        *table(1.4, 4.1, 2.6, 4.9, 0.75, object_id=1),
        Box((1.9, 4.4, 0.75), (2.0, 4.5, 0.87), "cup", (220, 30, 30)),
        Box((2.2, 4.3, 0.75), (2.36, 4.46, 0.82), "bowl", (230, 80, 60)),
        Box((0.4, 0.4, 0.0), (1.2, 1.0, 0.45), "chair", (60, 60, 140)),
        Box((3.6, 0.3, 0.0), (4.7, 1.1, 0.9), "shelf", (90, 140, 90)),
        Box((3.7, 0.5, 0.9), (3.9, 0.7, 1.15), "vase", (200, 200, 90)),
        Box((4.2, 0.4, 0.9), (4.5, 0.6, 1.1), "books", (120, 60, 60)),
        Box((3.0, 4.8, 0.0), (3.8, 5.6, 0.8), "armchair", (100, 70, 120)),
        Box((3.0, 3.8, 0.0), (3.8, 4.3, 0.45), "coffee_table", (110, 80, 50)),
        Box((0.1, 2.0, 0.0), (0.5, 3.6, 0.5), "tv_stand", (70, 70, 70)),
        Box((0.15, 2.2, 0.5), (0.25, 3.4, 1.2), "tv", (20, 20, 20)),
        Box((0.1, 4.2, 0.0), (0.4, 5.8, 1.8), "bookshelf", (140, 110, 70)),
        Box((4.5, 5.4, 0.0), (4.8, 5.7, 1.0), "plant", (40, 140, 40)),
        Box((2.8, 0.2, 0.0), (3.2, 0.5, 0.3), "box", (170, 140, 90)),
        # kitchen and bedroom
        Box((7.8, 0.2, 0.0), (9.8, 0.8, 0.9), "counter", (210, 210, 220)),
        Box((8.6, 0.4, 0.9), (8.7, 0.5, 1.0), "bowl", (230, 80, 60)),
        Box((9.2, 1.0, 0.0), (9.9, 1.8, 1.8), "fridge", (235, 235, 235)),
        Box((5.2, 0.1, 0.0), (6.0, 0.6, 0.9), "cabinet", (160, 120, 80)),
        Box((6.0, 4.6, 0.0), (8.0, 5.6, 0.5), "sofa", (80, 40, 100)),
        Box((6.3, 4.8, 0.5), (6.7, 5.2, 0.65), "cushion", (200, 180, 60)),
        Box((8.6, 4.0, 0.0), (9.9, 5.9, 0.5), "bed", (180, 180, 230)),
        Box((5.3, 5.3, 0.0), (5.7, 5.7, 0.5), "basket", (190, 160, 120)),
        *table(7.2, 2.6, 8.0, 3.4, 0.7, object_id=2),
        Box((7.5, 2.9, 0.7), (7.6, 3.0, 0.8), "cup", (220, 30, 30)),
    ]


def _camera_path(n: int) -> list[np.ndarray]:
    """Body waypoints through both rooms; the camera sweeps +-40 deg around the heading."""
    waypoints = np.array([[1.2, 2.0], [2.0, 3.0], [3.5, 3.0], [4.4, 3.0], [5.6, 3.0], [7.0, 2.0],
                          [8.5, 2.0], [8.8, 3.8], [6.5, 3.8], [5.6, 3.0], [3.0, 2.0]])
    seg = np.linalg.norm(np.diff(waypoints, axis=0), axis=1)
    s = np.linspace(0, seg.sum(), n)
    cum = np.r_[0, np.cumsum(seg)]
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    frac = (s - cum[k]) / seg[k]
    xy = waypoints[k] + (waypoints[k + 1] - waypoints[k]) * frac[:, None]
    heading = np.arctan2(*(waypoints[k + 1] - waypoints[k])[:, ::-1].T)
    poses = []
    for i in range(n):
        yaw = heading[i] + math.radians(40) * math.sin(i * 2 * math.pi / 40)
        eye = np.array([xy[i, 0], xy[i, 1], 0.9])
        target = eye + np.array([math.cos(yaw), math.sin(yaw), -math.tan(math.radians(25))])
        poses.append(look_at_camera(eye, target))
    return poses


def synthetic_frames(n_frames: int = 300, seed: int = 0, width: int = WIDTH,
                     height: int = HEIGHT) -> Iterator[Frame]:
    """A synthetic trajectory with a noisy simulated detector.

    Detector model (per visible object of >= 20 pixels): task classes are detected with
    probability 0.85 (5 % of those mislabelled as another task class); a bowl is reported as a cup
    with probability 0.3. Scores ~ U(0.3, 0.95). Image-text score of a layer:
    0.15 + 0.6 * sqrt(fraction of the image showing that class) + N(0, 0.02).
    """
    rng = np.random.default_rng(seed)
    boxes = two_room_flat()
    task, layers = ("cup", "table", "counter"), ("table", "counter")
    cam = pinhole(width, height)
    for i, T in enumerate(_camera_path(n_frames)):
        rgb, depth, hit = render_boxes(boxes, cam, T)
        detections = []
        objects = np.array([b.object_id if b.object_id is not None else -1 - k for k, b in enumerate(boxes)])
        for obj in np.unique(objects[hit[hit >= 0]]):
            parts = np.nonzero(objects == obj)[0]
            mask = np.isin(hit, parts)
            name = boxes[parts[0]].class_name
            if mask.sum() < 20:
                continue
            if name in task and rng.random() < 0.85:
                label = name if rng.random() > 0.05 else str(rng.choice([c for c in task if c != name]))
            elif name == "bowl" and rng.random() < 0.3:
                label = "cup"
            else:
                continue
            detections.append(Detection(mask, label, float(rng.uniform(0.3, 0.95))))
        pixels_per_box = np.bincount(hit[hit >= 0], minlength=len(boxes)) / hit.size
        scores = {layer: float(0.15 + 0.6 * math.sqrt(sum(f for b, f in zip(boxes, pixels_per_box) if b.class_name == layer))
                               + rng.normal(0, 0.02)) for layer in layers}
        T_body = np.eye(4)
        T_body[:2, 3] = T[:2, 3]
        obs = Observation(rgb=rgb, depth=depth, intrinsics=cam, T_world_cam=T, T_world_body=T_body,
                          stamp=0.1 * i, frame_id=i)
        yield obs, detections, scores
