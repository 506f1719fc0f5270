"""Ground-truth navigation on the true scene: an occupancy grid rasterised from the layout's
walls and furniture footprints, reachability, fast-marching paths, and approach poses from which
Spot's arm reaches a point.

This is simulator knowledge (scene validation, the oracle agent); agents plan on their own maps
built from what the camera saw.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from robots.hal import SE2Pose
from sim.scenes.layout import HomeLayout, _segment_rect

# Spot's plan-view footprint in its body frame (x0, x1, y0, y1), measured from the model at the
# stand pose: body and legs (the hind knees stick out furthest) ...
SPOT_BODY_BOX = (-0.545, 0.43, -0.215, 0.215)
# ... and the stowed arm or a carried object in front, which only meets obstacles taller than
# HIGH_OBSTACLE (the stowed claw's underside is ~0.75 m above the floor).
SPOT_ARM_BOX = (0.43, 0.62, -0.09, 0.09)
HIGH_OBSTACLE = 0.745
SHOULDER_HEIGHT = 0.72   # m above the floor at the stand pose
SHOULDER_AHEAD = 0.29    # m ahead of the body centre


@dataclass(frozen=True)
class NavConfig:
    resolution: float = 0.05      # m per cell
    pass_radius: float = 0.30     # m of clearance the body centre keeps while travelling (half width + margin)
    turn_radius: float = 0.68     # m of clearance to turn in place anywhere (half diagonal with the arm + margin)
    footprint_margin: float = 0.05  # m added around Spot's footprint when testing a pose
    arm_reach: float = 0.82       # m from the shoulder to a grasp/place point the arm handles comfortably


class NavGrid:
    """A 2D occupancy grid of the true scene with clearance (distance to the nearest obstacle)."""

    def __init__(self, layout: HomeLayout, config: NavConfig = NavConfig()):
        self.config = config
        res = config.resolution
        self.origin = np.array([-1.0, -1.0])
        self.shape = (int(math.ceil((layout.depth + 2.0) / res)), int(math.ceil((layout.width + 2.0) / res)))
        occ = np.zeros(self.shape, dtype=np.uint8)
        high = np.zeros(self.shape, dtype=np.uint8)
        half_t = layout.config.wall_thickness / 2
        for w in layout.walls:
            self._fill(occ, _segment_rect(w.x0, w.y0, w.x1, w.y1, half_t))
            self._fill(high, _segment_rect(w.x0, w.y0, w.x1, w.y1, half_t))
        for r in layout.receptacles:
            self._fill(occ, r.footprint_corners())
            if r.model.height > HIGH_OBSTACLE:
                self._fill(high, r.footprint_corners())
        # outside the home is not navigable
        inside = np.zeros_like(occ)
        self._fill(inside, np.array([[0, 0], [layout.width, 0], [layout.width, layout.depth], [0, layout.depth]]))
        occ[inside == 0] = 1
        high[inside == 0] = 1
        self.occupied = occ.astype(bool)
        self.occupied_high = high.astype(bool)
        self.clearance = ndimage.distance_transform_edt(~self.occupied) * res
        self._blocked = None

    # ------------------------------------------------------------------ conversions
    def to_cell(self, xy) -> tuple[int, int]:
        c = (np.asarray(xy, dtype=float) - self.origin) / self.config.resolution
        return int(np.clip(round(c[1]), 0, self.shape[0] - 1)), int(np.clip(round(c[0]), 0, self.shape[1] - 1))

    def to_world(self, rc) -> np.ndarray:
        rc = np.asarray(rc, dtype=float)
        return self.origin + rc[..., ::-1] * self.config.resolution

    def _fill(self, grid: np.ndarray, corners: np.ndarray) -> None:
        pts = np.round((corners - self.origin) / self.config.resolution).astype(np.int32)
        cv2.fillConvexPoly(grid, pts, 1)

    # ------------------------------------------------------------------ queries
    def clearance_at(self, xy) -> float:
        return float(self.clearance[self.to_cell(xy)])

    def component(self, start_xy, radius: float | None = None) -> np.ndarray:
        """Cells reachable from ``start_xy`` keeping ``radius`` of clearance (bool grid)."""
        r = self.config.pass_radius if radius is None else radius
        free = self.clearance >= r
        labels, _ = ndimage.label(free)
        row, col = self.to_cell(start_xy)
        lab = labels[row, col]
        if lab == 0:
            # Standing too close to something (e.g. stopped against a wall): use the nearest free
            # cell within half a metre, which a short step away reaches.
            k = int(0.5 / self.config.resolution)
            window = labels[max(row - k, 0):row + k + 1, max(col - k, 0):col + k + 1]
            rr, cc = np.nonzero(window)
            if len(rr):
                i = int(np.argmin((rr + max(row - k, 0) - row) ** 2 + (cc + max(col - k, 0) - col) ** 2))
                lab = window[rr[i], cc[i]]
        return labels == lab if lab > 0 else np.zeros_like(free)

    # ------------------------------------------------------------------ configuration space
    HEADING_BINS = 24

    def _cspace(self) -> np.ndarray:
        """(HEADING_BINS, H, W) bool: Spot centred on a cell, at a heading within that bin, overlaps
        an obstacle (body and legs against everything, the arm against tall obstacles). Built once
        by dilating the occupancy with the footprint swept over the bin (a conservative check)."""
        if getattr(self, "_blocked", None) is not None:
            return self._blocked
        res = self.config.resolution
        bins = self.HEADING_BINS
        width = 2 * math.pi / bins
        blocked = np.zeros((bins,) + self.shape, dtype=bool)
        occ = self.occupied.astype(np.uint8)
        high = self.occupied_high.astype(np.uint8)
        for k in range(bins):
            kernels = []
            for box in (SPOT_BODY_BOX, SPOT_ARM_BOX):
                pts = self._box_points(box)
                reach = float(np.max(np.linalg.norm(pts, axis=1)))
                r = int(math.ceil(reach / res)) + 1
                kernel = np.zeros((2 * r + 1, 2 * r + 1), dtype=np.uint8)
                for yaw in k * width - math.pi + np.linspace(-width / 2, width / 2, 5):
                    c, s = math.cos(yaw), math.sin(yaw)
                    cols = np.round((c * pts[:, 0] - s * pts[:, 1]) / res).astype(int) + r
                    rows = np.round((s * pts[:, 0] + c * pts[:, 1]) / res).astype(int) + r
                    kernel[rows, cols] = 1
                kernels.append(kernel)
            blocked[k] = (cv2.dilate(occ, kernels[0]) | cv2.dilate(high, kernels[1])).astype(bool)
        self._blocked = blocked
        return blocked

    def _bin(self, yaw) -> np.ndarray:
        width = 2 * math.pi / self.HEADING_BINS
        return np.round((np.asarray(yaw) + math.pi) / width).astype(int) % self.HEADING_BINS

    def _box_points(self, box) -> np.ndarray:
        m = self.config.footprint_margin
        step = self.config.resolution / 2
        xs = np.arange(box[0] - m, box[1] + m + 1e-9, step)
        ys = np.arange(box[2] - m, box[3] + m + 1e-9, step)
        gx, gy = np.meshgrid(xs, ys)
        return np.stack([gx.ravel(), gy.ravel()], axis=1)

    def poses_free(self, poses) -> np.ndarray:
        """Per (x, y, yaw) pose: Spot's footprint (body and legs vs all obstacles, the arm vs tall
        ones) overlaps nothing."""
        poses = np.atleast_2d(np.asarray(poses, dtype=float))
        blocked = self._cspace()
        cols = np.round((poses[:, 0] - self.origin[0]) / self.config.resolution).astype(int)
        rows = np.round((poses[:, 1] - self.origin[1]) / self.config.resolution).astype(int)
        inside = (rows >= 0) & (cols >= 0) & (rows < self.shape[0]) & (cols < self.shape[1])
        free = np.zeros(len(poses), dtype=bool)
        free[inside] = ~blocked[self._bin(poses[inside, 2]), rows[inside], cols[inside]]
        return free

    def footprint_free(self, pose: SE2Pose) -> bool:
        return bool(self.poses_free([pose.as_tuple()])[0])

    def rotation_free(self, x: float, y: float, yaw0: float, yaw1: float) -> bool:
        """Turning in place from yaw0 to yaw1 (the short way) sweeps only free space."""
        delta = math.remainder(yaw1 - yaw0, 2 * math.pi)
        n = max(2, int(abs(delta) / (math.pi / self.HEADING_BINS)) + 2)
        yaws = yaw0 + np.linspace(0.0, delta, n)
        return bool(np.all(self.poses_free(np.stack([np.full(n, x), np.full(n, y), yaws], axis=1))))

    def translation_free(self, a, b, yaw: float, include_start: bool = True) -> bool:
        """Walking straight from a to b at a fixed heading sweeps only free space. With
        ``include_start`` False the walk may begin inside the planning margin (e.g. stepping away
        from a wall the robot stopped against): once clear, it must stay clear."""
        n = max(2, int(math.dist(a, b) / (self.config.resolution / 2)) + 1)
        pts = np.linspace(np.asarray(a, dtype=float), np.asarray(b, dtype=float), n)
        free = self.poses_free(np.column_stack([pts, np.full(len(pts), yaw)]))
        if include_start:
            return bool(np.all(free))
        first = int(np.argmax(free)) if free.any() else len(free)
        return bool(first < len(free) and np.all(free[first:]))

    def plan_walk(self, start: SE2Pose, goal: SE2Pose) -> list[SE2Pose] | None:
        """Like :meth:`plan_walk_from`, but when Spot is boxed in (e.g. right after working at a
        piece of furniture) it first steps straight back or sideways until it has room to move on."""
        for radius in (0.45, self.config.pass_radius):   # prefer wide corridors, fall back to narrow ones
            plan = self.plan_walk_from(start, goal, radius=radius)
            if plan is not None:
                return plan
        for step in (0.15, 0.3, 0.45, 0.6, 0.8):
            for rel in (math.pi, math.pi / 2, -math.pi / 2, 3 * math.pi / 4, -3 * math.pi / 4):
                a = start.yaw + rel
                p = (start.x + step * math.cos(a), start.y + step * math.sin(a))
                if not self.translation_free((start.x, start.y), p, start.yaw, include_start=False):
                    continue
                escape = SE2Pose(p[0], p[1], start.yaw)
                plan = self.plan_walk_from(escape, goal)
                if plan is not None:
                    return [escape] + plan
        return None

    def plan_walk_from(self, start: SE2Pose, goal: SE2Pose, spacing: float = 0.2,
                       radius: float | None = None) -> list[SE2Pose] | None:
        """SE2 waypoints from ``start`` to ``goal`` made of in-place turns and straight walks that
        all keep Spot's footprint free; None if there is none along the fast-marching corridor.

        Dijkstra over (point along the fast-marching path, heading bin) states: walking to the next
        point at a fixed heading (sideways or backwards allowed, Spot is holonomic, but penalised)
        or turning in place to a neighbouring bin. Which of those are free is looked up for all
        bins at once in the configuration-space grids. Consecutive walks at the same heading are
        then merged into single straight segments wherever the straight line is clear.
        """
        import heapq

        path = self.plan((start.x, start.y), (goal.x, goal.y), radius)
        if path is None:
            return None
        pts = _resample([np.array([start.x, start.y])] + path[1:-1] + [np.array([goal.x, goal.y])], spacing)
        blocked = self._cspace()
        bins = self.HEADING_BINS
        width = 2 * math.pi / bins
        res = self.config.resolution
        cells = [self.to_cell(p) for p in pts]
        at_ok = [~blocked[:, r, c] for r, c in cells]
        walk_ok = []
        for a, b in zip(pts[:-1], pts[1:]):
            n = max(2, int(math.dist(a, b) / (res / 2)) + 1)
            line = np.linspace(a, b, n)
            cols = np.round((line[:, 0] - self.origin[0]) / res).astype(int)
            rows = np.round((line[:, 1] - self.origin[1]) / res).astype(int)
            walk_ok.append(~blocked[:, rows, cols].any(axis=1))
        seg_len = [math.dist(a, b) for a, b in zip(pts[:-1], pts[1:])]
        seg_dir = [math.atan2(b[1] - a[1], b[0] - a[0]) for a, b in zip(pts[:-1], pts[1:])]
        k_start, k_goal = int(self._bin(start.yaw)), int(self._bin(goal.yaw))
        yaw_of = [k * width - math.pi for k in range(bins)]
        last = len(pts) - 1
        if not at_ok[0][k_start] and not walk_ok[0][k_start]:
            return None
        dist = {(0, k_start): 0.0}
        prev: dict = {}
        heap = [(0.0, 0, k_start)]
        while heap:
            d, i, k = heapq.heappop(heap)
            if (i, k) == (last, k_goal):
                break
            if d > dist.get((i, k), math.inf):
                continue
            moves = []
            if i < last and walk_ok[i][k]:
                misaligned = 1.0 - math.cos(yaw_of[k] - seg_dir[i])   # 0 forwards, 1 sideways, 2 backwards
                moves.append((i + 1, k, seg_len[i] * (1.0 + 0.9 * misaligned)))
            if at_ok[i][k]:
                for k2 in ((k + 1) % bins, (k - 1) % bins):
                    if at_ok[i][k2]:
                        moves.append((i, k2, 0.3 * width + 0.01))
            for i2, k2, cost in moves:
                nd = d + cost
                if nd < dist.get((i2, k2), math.inf):
                    dist[(i2, k2)] = nd
                    prev[(i2, k2)] = (i, k)
                    heapq.heappush(heap, (nd, i2, k2))
        if (last, k_goal) not in dist:
            return None
        nodes = [(last, k_goal)]
        while nodes[-1] != (0, k_start):
            nodes.append(prev[nodes[-1]])
        nodes.reverse()
        # Bin centres stand in for headings, except the exact start heading (kept until the first
        # turn) and the goal pose itself.
        poses, turned = [], False
        for i, k in nodes:
            turned = turned or k != k_start
            poses.append(SE2Pose(pts[i][0], pts[i][1], yaw_of[k] if turned else start.yaw))
        poses[-1] = goal
        merged = self._merge(poses)
        return merged[1:]

    def _merge(self, poses: list[SE2Pose]) -> list[SE2Pose]:
        """Drop intermediate poses of straight same-heading walks and chained turns."""
        out = [poses[0]]
        i = 0
        while i < len(poses) - 1:
            j = i + 1
            if poses[j].yaw == poses[i].yaw:      # a walk: extend it while straight and clear
                while (j + 1 < len(poses) and poses[j + 1].yaw == poses[i].yaw
                       and self.translation_free(poses[i].as_tuple()[:2], poses[j + 1].as_tuple()[:2], poses[i].yaw)):
                    j += 1
            else:                                 # a turn: extend through consecutive turns at this spot
                while j + 1 < len(poses) and poses[j + 1].as_tuple()[:2] == poses[i].as_tuple()[:2]:
                    j += 1
            out.append(poses[j])
            i = j
        return out

    def plan(self, start_xy, goal_xy, radius: float | None = None) -> list[np.ndarray] | None:
        """Shortest path keeping ``radius`` of clearance, preferring open space; None if unreachable."""
        import skfmm

        r = self.config.pass_radius if radius is None else radius
        free = self.component(start_xy, r)
        goal = self.to_cell(goal_xy)
        if not free[goal]:
            return None
        phi = np.ones(self.shape)
        phi[goal] = -1
        speed = np.clip(self.clearance - r + 0.05, 0.05, 0.6)
        free = free.copy()
        free[self.to_cell(start_xy)] = True    # the start may sit in a tight spot (see component)
        masked = np.ma.MaskedArray(phi, ~free)
        t = skfmm.travel_time(masked, speed, dx=self.config.resolution)
        time = np.ma.filled(t, np.inf)
        cell = self.to_cell(start_xy)
        path = [cell]
        for _ in range(self.shape[0] * self.shape[1]):
            if cell == goal or time[cell] <= 0:
                break
            r0, c0 = cell
            window = time[max(r0 - 1, 0):r0 + 2, max(c0 - 1, 0):c0 + 2]
            dr, dc = np.unravel_index(int(np.argmin(window)), window.shape)
            nxt = (max(r0 - 1, 0) + dr, max(c0 - 1, 0) + dc)
            if time[nxt] >= time[cell]:
                break
            cell = nxt
            path.append(cell)
        if path[-1] != goal and math.dist(path[-1], goal) > 1.5:
            return None
        return [self.to_world(p) for p in path]

    def simplify(self, path: list[np.ndarray], radius: float | None = None) -> list[np.ndarray]:
        """Keep only the points needed for straight segments that stay ``radius`` from obstacles."""
        r = self.config.pass_radius if radius is None else radius
        if len(path) <= 2:
            return list(path)
        out = [path[0]]
        i = 0
        while i < len(path) - 1:
            j = len(path) - 1
            while j > i + 1 and not self._segment_clear(path[i], path[j], r):
                j -= 1
            out.append(path[j])
            i = j
        return out

    def _segment_clear(self, a, b, radius: float) -> bool:
        n = max(2, int(math.dist(a, b) / (self.config.resolution / 2)))
        pts = np.linspace(a, b, n)
        cells = np.round((pts - self.origin) / self.config.resolution).astype(int)
        return bool(np.all(self.clearance[cells[:, 1], cells[:, 0]] >= radius))

    def approach_poses(self, target, start_xy, front=None, n_angles: int = 24,
                       max_off_front: float = math.radians(70)) -> list[SE2Pose]:
        """Standing poses facing ``target`` (x, y[, z]) from which the arm reaches it, with a free
        footprint and reachable from ``start_xy``; best first (a comfortable reach, open space).
        ``front``: unit vector of the only side the target may be approached from (a chair's seat
        is reached from the front, not over its back)."""
        comp = self.component(start_xy)
        target = np.asarray(target, dtype=float)
        z = float(target[2]) if target.size > 2 else SHOULDER_HEIGHT
        dz = z - SHOULDER_HEIGHT
        horizontal = math.sqrt(max(self.config.arm_reach ** 2 - dz * dz, 0.2 ** 2))
        far = horizontal + SHOULDER_AHEAD
        dists = np.linspace(max(0.55, far - 0.35), far, 5)
        poses, keys = [], []
        for dist in dists:
            for k in range(n_angles):
                a = 2 * math.pi * k / n_angles
                if front is not None and math.cos(a - math.atan2(front[1], front[0])) < math.cos(max_off_front):
                    continue
                p = target[:2] + dist * np.array([math.cos(a), math.sin(a)])
                poses.append((p[0], p[1], math.atan2(-math.sin(a), -math.cos(a))))
                keys.append((dist, k))
        if not poses:
            return []
        poses = np.array(poses)
        free = self.poses_free(poses)
        found = []
        for (dist, k), pose, ok in zip(keys, poses, free):
            cell = self.to_cell(pose[:2])
            if not ok or not comp[cell]:
                continue
            score = abs(dist - (far - 0.12)) - 0.2 * min(self.clearance[cell], 1.0)
            found.append((score, k, SE2Pose(*pose)))
        found.sort(key=lambda t: (t[0], t[1]))
        return [p for _, _, p in found]


def _resample(points: list[np.ndarray], spacing: float) -> list[np.ndarray]:
    """Points along a polyline every ``spacing`` metres (first and last kept)."""
    pts = np.asarray(points, dtype=float)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    total = float(seg.sum())
    if total < 1e-9:
        return [pts[0], pts[-1]]
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(1, int(math.ceil(total / spacing)))
    t = np.linspace(0.0, total, n + 1)
    out = np.stack([np.interp(t, s, pts[:, 0]), np.interp(t, s, pts[:, 1])], axis=1)
    return [p for p in out]
