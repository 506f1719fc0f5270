"""Per-episode pictures: what a trial keeps of each episode for its page in the trial report.

The trial instrumentation (:class:`tasks.instrument.InstrumentedAgent`) hands every observation
and command to an :class:`EpisodeTracer`, which keeps

- the path walked (body poses from the observations, the via points and end poses of walks),
- hand-camera frames at the key moments: the agent's first detection of the target's class (for
  agents with an observer, :func:`helios.agents.trace.latest_detection`; captioned whether a mask
  covers a true target, as the first is often a false detection), the judge's FindObj and
  FindRec moments, every grasp (the frame it used, the grasp pixel marked), every release (the
  last frame before it, the drop point marked) and the last frame,
- a thinned sequence of small hand-camera frames for an animation,
- the ground truth from the judge and the scene: where every valid target object, the named
  start receptacle and the goal receptacles really were when the episode began,
- at the end, the agent's map as it had it (:func:`helios.agents.trace.snapshot`: occupancy,
  chosen frontiers, candidates with their Psi) and the episode's outcome.

:meth:`EpisodeTracer.finish` packs it into one compressed ``.npz`` (a few tens of kB), which the
batch writes atomically to ``OUT/episodes/<episode_id>.npz`` (:data:`TRACE_DIR`); ``tools report``
draws the pictures from it (:func:`load_trace` reads one back). Tracing only reads: an episode's
record is the same with pictures on or off (``tests/test_episode_pictures.py``), and a failure
inside the tracer is kept in the trace's ``errors``, never raised into the episode.
"""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import numpy as np

TRACE_DIR = "episodes"          # run-folder subfolder of the per-episode traces
TRACE_VERSION = 1
GIF_WIDTH = 128                 # px, animation frames
KEY_WIDTH = 320                 # px, key frames (smaller frames are kept as they are)
MAX_GIF_FRAMES = 60
MAX_KEY_FRAMES = 10
JPEG_QUALITY = 85
MARGIN_M = 1.0                  # m of map kept around everything drawn
UNKNOWN, FREE, OBSTACLE = 0, 1, 2   # map codes


def trace_path(out: str | Path, episode_id: str) -> Path:
    """Where a run folder keeps an episode's trace."""
    return Path(out) / TRACE_DIR / f"{episode_id}.npz"


class EpisodeTracer:
    """Collects one episode's picture data (see the module doc). ``on_*`` are called by the
    instrumentation; ``bind_sim`` once the simulated episode exists; ``finish`` at the end."""

    def __init__(self):
        self.path: list[tuple[float, float, float, float]] = []      # (t, x, y, yaw)
        self.events: list[dict] = []
        self.key_frames: list[tuple[dict, bytes]] = []
        self.frames: list[np.ndarray] = []
        self.frame_t: list[float] = []
        self.truth: dict = {}
        self.errors: list[str] = []
        self.object_class: str | None = None
        self.classes: dict[str, str] = {}
        self._stride = 1
        self._observations = 0
        self._last_obs = None
        self._last_t = 0.0
        self._judge = None
        self._t0_world = 0.0
        self._seen: set[str] = set()
        self._detected = False
        self._checked_frame = None

    # ------------------------------------------------------------------ set-up
    def bind_sim(self, sim, episode) -> None:
        """Ground truth from the judge and the scene (read once, before the agent acts)."""
        world, judge = sim.world, sim.judge
        self._judge = judge
        self._t0_world = float(world.time)
        spec = episode.spec
        self.object_class = spec.object
        self.classes = {"object_class": spec.object, "start_class": spec.start_receptacle,
                        "goal_class": spec.goal_receptacle}

        def box(body_id: int) -> dict:
            lo, hi = world.body_aabb(body_id)
            return {"name": world.bodies[body_id].name, "lo": [float(lo[0]), float(lo[1])],
                    "hi": [float(hi[0]), float(hi[1])]}

        targets = []
        for b in sorted(judge.valid_targets):
            p = world.position(b)
            name = world.bodies[b].name
            targets.append({"name": name, "xyz": [float(v) for v in p], "named": name == episode.target_object})
        start = sim.scene.receptacle_ids.get(episode.start_receptacle)
        self.truth = {"targets": targets, "goals": [box(b) for b in sorted(judge.goal_ids)],
                      "start_receptacle": box(start) if start is not None else None,
                      "start_pose": [float(v) for v in episode.robot_start]}

    # ------------------------------------------------------------------ during the episode
    def on_command(self, name: str, args: tuple, result, t: float, agent=None) -> None:
        """After every HAL call the agent made (``name == "observe"``: ``result`` is the frame)."""
        self._last_t = float(t)
        if name == "observe":
            self._observation(result, t)
        elif name == "navigate_to":
            self._walk(args, result, t)
        elif name == "grasp":
            self._grasp(args, result, t)
        elif name == "place":
            self._place(args, result, t)
        if agent is not None:
            self.on_step(agent, t)

    def on_step(self, agent, t: float | None = None) -> None:
        """Keep the first frame in which the agent detected the target object."""
        if self._detected or self.object_class is None:
            return
        from helios.agents.trace import latest_detection

        seen = latest_detection(agent, self.object_class)
        if seen is None:
            return
        obs, masks = seen
        frame = (obs.frame_id, obs.stamp)
        if frame == self._checked_frame:
            return
        self._checked_frame = frame
        if masks:
            self._detected = True
            rgb = obs.rgb.copy()
            union = np.logical_or.reduce(masks)
            rgb[union] = (0.5 * rgb[union] + 0.5 * np.array([255, 0, 255])).astype(np.uint8)
            self._key("detected", self._detection_label(obs, masks), rgb, self._last_t if t is None else t)

    def _detection_label(self, obs, masks: list) -> str:
        """The key frame's caption: the detector's first kept detection of the target's class is of
        any instance, so say whether a mask covers where a true target (the judge's) projects."""
        if not self.truth.get("targets"):
            return f"first detection of a {self.object_class}"       # no ground truth (a real robot)
        union = np.logical_or.reduce(masks)
        pixels = (_project(obs, np.asarray(target["xyz"], dtype=float)) for target in self.truth["targets"])
        on_target = any(uv is not None and bool(union[uv[1], uv[0]]) for uv in pixels)
        where = "on a true target" if on_target else "not on a true target: a false or misplaced detection"
        return f"first detection of a {self.object_class} ({where})"

    def _observation(self, obs, t: float) -> None:
        self._last_obs = obs
        self._pose(obs.T_world_body, t)
        i = self._observations
        self._observations += 1
        if i % self._stride == 0:
            import cv2

            h, w = obs.rgb.shape[:2]
            size = (GIF_WIDTH, max(1, round(h * GIF_WIDTH / w)))
            self.frames.append(cv2.resize(obs.rgb, size, interpolation=cv2.INTER_AREA))
            self.frame_t.append(float(t))
            if len(self.frames) >= 2 * MAX_GIF_FRAMES:      # keep every other one: bounded, evenly spread
                self.frames, self.frame_t = self.frames[::2], self.frame_t[::2]
                self._stride *= 2
        m = getattr(self._judge, "metrics", None)
        if m is not None:
            for key, text in (("find_obj", "FindObj: the target in view (judge)"),
                              ("find_rec", "FindRec: a goal receptacle in view (judge)")):
                if key not in self._seen and getattr(m, key, False):
                    self._seen.add(key)
                    self._key(key, text, obs.rgb, t)

    def _pose(self, T: np.ndarray, t: float) -> None:
        x, y = float(T[0, 3]), float(T[1, 3])
        yaw = math.atan2(float(T[1, 0]), float(T[0, 0]))
        self._add_point(t, x, y, yaw)

    def _add_point(self, t: float, x: float, y: float, yaw: float) -> None:
        if self.path and math.hypot(x - self.path[-1][1], y - self.path[-1][2]) < 0.01:
            self.path[-1] = (self.path[-1][0], self.path[-1][1], self.path[-1][2], yaw)
            return
        self.path.append((float(t), x, y, float(yaw)))

    def _walk(self, args: tuple, result, t: float) -> None:
        goal, via = (args + ((),))[:2]
        end = getattr(result, "final_pose", None)
        if getattr(result, "success", False):
            for p in via:
                self._add_point(t, float(p.x), float(p.y), float(p.yaw))
        if end is not None:
            self._add_point(t, float(end.x), float(end.y), float(end.yaw))
        if getattr(result, "collided", False) and end is not None:
            self.events.append({"kind": "collision", "t": float(t), "xy": [float(end.x), float(end.y)]})

    def _grasp(self, args: tuple, result, t: float) -> None:
        obs, pixel = args[0], args[1]
        holding = bool(getattr(result, "holding", False))
        rgb = obs.rgb.copy()
        _cross(rgb, int(pixel[0]), int(pixel[1]), (255, 0, 255))
        n = sum(e["kind"] == "grasp" for e in self.events) + 1
        why = "" if holding else f" ({getattr(getattr(result, 'reason', None), 'value', 'failed')})"
        self._key("grasp", f"grasp {n}: {'holding' if holding else 'failed'}{why}", rgb, t)
        target = getattr(result, "target_world", None)
        xy = [float(target[0]), float(target[1])] if target is not None else self._here()
        self.events.append({"kind": "grasp", "t": float(t), "xy": xy, "ok": holding})

    def _place(self, args: tuple, result, t: float) -> None:
        point = np.asarray(args[0], dtype=float)
        if self._last_obs is not None:
            rgb = self._last_obs.rgb.copy()
            uv = _project(self._last_obs, point)
            if uv is not None:
                _cross(rgb, uv[0], uv[1], (0, 200, 255))
            self._key("release", "release: the last frame before letting go", rgb, t)
        self.events.append({"kind": "release", "t": float(t), "xy": [float(point[0]), float(point[1])],
                            "ok": bool(getattr(result, "success", False))})

    def _here(self) -> list[float]:
        return [self.path[-1][1], self.path[-1][2]] if self.path else [0.0, 0.0]

    def _key(self, kind: str, label: str, rgb: np.ndarray, t: float) -> None:
        if len(self.key_frames) >= MAX_KEY_FRAMES - 1:      # one place stays for the last frame
            return
        self.key_frames.append(({"kind": kind, "label": label, "t": round(float(t), 2)}, _jpeg(rgb)))

    def failed(self, what: str) -> None:
        if len(self.errors) < 5:
            self.errors.append(what)

    # ------------------------------------------------------------------ the end
    def finish(self, agent, record: dict) -> bytes:
        """The trace as ``.npz`` bytes: the agent's map (cropped), path, events, frames, truth, outcome."""
        if self._last_obs is not None:
            self.key_frames.append(({"kind": "end", "label": "the last frame", "t": round(self._last_t, 2)},
                                    _jpeg(self._last_obs.rgb)))
        snap = None
        try:
            from helios.agents.trace import snapshot

            snap = snapshot(agent)
        except Exception as exc:  # noqa: BLE001 - a picture problem never changes the episode
            self.failed(f"agent snapshot: {type(exc).__name__}: {exc}")
        for ev in record.get("collision_events") or []:    # robot-scene contacts, at the pose of their time
            t = float(ev.get("time", 0.0)) - self._t0_world
            self.events.append({"kind": "collision", "t": round(t, 2), "xy": self._pose_at(t),
                                "what": f"{ev.get('robot_link')} touched {ev.get('body')}"})
        grid, codes = self._map(snap)
        m = record.get("metrics") or {}
        error = record.get("error")
        meta = {"version": TRACE_VERSION, "episode_id": record.get("episode_id"), "task": record.get("task"),
                "agent": record.get("agent"), "object_class": self.object_class, **self.classes,
                "outcome": {"success": bool(record.get("success")), "failure_reason": m.get("failure_reason"),
                            "phases": {k: bool(m.get(k)) for k in ("find_obj", "pick", "find_rec", "place", "success")},
                            "limit_hit": bool(record.get("limit_hit")), "commands": record.get("commands"),
                            "sim_time": record.get("sim_time"), "collisions": m.get("collisions"),
                            "object_final": m.get("object_final"), "released_on": m.get("released_on"),
                            "error": error.strip().splitlines()[0] if error else None},
                "truth": self.truth, "grid": grid, "has_map": grid["agent_map"],
                "frontiers": (snap or {}).get("frontiers", {"pick": [], "place": []}),
                "candidates": (snap or {}).get("candidates", []), "phase": (snap or {}).get("phase"),
                "log": (snap or {}).get("log") or [str(s) for s in list(getattr(agent, "log", []) or [])[-15:]],
                "events": self.events, "key_frames": [k for k, _ in self.key_frames],
                "frame_t": [round(t, 2) for t in self._gif_times()], "errors": self.errors}
        arrays = {"map": codes, "path": np.asarray(self.path, dtype=np.float32).reshape(-1, 4),
                  "meta": np.array(json.dumps(meta, default=_plain))}
        for i, (_, data) in enumerate(self.key_frames):
            arrays[f"key_{i}"] = np.frombuffer(data, dtype=np.uint8)
        frames = self._gif_frames()
        if frames:
            arrays["frames"] = np.stack(frames)
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        return buf.getvalue()

    def _pose_at(self, t: float) -> list[float]:
        if not self.path:
            return [0.0, 0.0]
        times = [p[0] for p in self.path]
        i = max(0, int(np.searchsorted(times, t, side="right")) - 1)
        return [self.path[i][1], self.path[i][2]]

    def _gif_idx(self) -> np.ndarray:
        n = len(self.frames)
        return np.unique(np.linspace(0, n - 1, min(n, MAX_GIF_FRAMES)).round().astype(int)) if n else np.zeros(0, int)

    def _gif_frames(self) -> list[np.ndarray]:
        return [self.frames[i] for i in self._gif_idx()]

    def _gif_times(self) -> list[float]:
        return [self.frame_t[i] for i in self._gif_idx()]

    def _map(self, snap: dict | None) -> tuple[dict, np.ndarray]:
        """The window of the map to draw: the explored cells, the path and the ground truth, plus a margin."""
        pts = [(p[1], p[2]) for p in self.path]
        truth = self.truth
        pts += [tuple(o["xyz"][:2]) for o in truth.get("targets", [])]
        for b in [*truth.get("goals", []), truth.get("start_receptacle")]:
            if b:
                pts += [tuple(b["lo"]), tuple(b["hi"])]
        if truth.get("start_pose"):
            pts.append(tuple(truth["start_pose"][:2]))
        if snap is not None:
            pts += [(f[0], f[1]) for fs in snap["frontiers"].values() for f in fs]
            pts += [tuple(c["xy"]) for c in snap["candidates"]]
        cell = snap["cell_size"] if snap is not None else 0.05
        ox, oy = snap["origin_xy"] if snap is not None else (0.0, 0.0)
        xy = np.asarray(pts, dtype=float).reshape(-1, 2)
        margin = int(math.ceil(MARGIN_M / cell))
        if len(xy):
            c0, r0 = np.floor((xy.min(axis=0) - (ox, oy)) / cell).astype(int) - margin
            c1, r1 = np.floor((xy.max(axis=0) - (ox, oy)) / cell).astype(int) + margin + 1
        else:
            r0 = c0 = 0
            r1 = c1 = 2 * margin
        if snap is not None:
            b = snap["explored_bounds"]
            if b is not None:
                r0, r1 = min(r0, b[0] - margin), max(r1, b[1] + margin)
                c0, c1 = min(c0, b[2] - margin), max(c1, b[3] + margin)
            n_rows, n_cols = snap["obstacle"].shape
            if min(n_rows, r1) <= max(0, r0) or min(n_cols, c1) <= max(0, c0):
                snap = None                  # nothing of it inside the agent's grid: draw without the map
        if snap is not None:
            r0, c0 = max(0, r0), max(0, c0)
            r1, c1 = min(n_rows, r1), min(n_cols, c1)
            explored = snap["explored"][r0:r1, c0:c1]
            codes = np.where(snap["obstacle"][r0:r1, c0:c1], OBSTACLE,
                             np.where(explored, FREE, UNKNOWN)).astype(np.uint8)
        else:
            codes = np.zeros((max(1, r1 - r0), max(1, c1 - c0)), dtype=np.uint8)
        grid = {"cell_size": cell, "origin_xy": [ox + c0 * cell, oy + r0 * cell], "agent_map": snap is not None}
        return grid, codes


def load_trace(path) -> dict:
    """A trace file (a path or a binary file object) as a dict: ``meta`` (the JSON part), ``map``
    (uint8 codes, [row (y), col (x)], row 0 at ``meta["grid"]["origin_xy"]``), ``path`` ((N, 4):
    t, x, y, yaw), ``key_frames`` (list of (info, JPEG bytes)) and ``frames`` ((F, h, w, 3) uint8,
    maybe none)."""
    with np.load(path if hasattr(path, "read") else Path(path), allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
        keys = [(info, z[f"key_{i}"].tobytes()) for i, info in enumerate(meta["key_frames"]) if f"key_{i}" in z]
        frames = z["frames"] if "frames" in z else np.zeros((0, 1, 1, 3), np.uint8)
        return {"meta": meta, "map": z["map"], "path": z["path"], "key_frames": keys, "frames": frames}


# ------------------------------------------------------------------------------------------------
def _jpeg(rgb: np.ndarray) -> bytes:
    import cv2

    h, w = rgb.shape[:2]
    if w > KEY_WIDTH:
        rgb = cv2.resize(rgb, (KEY_WIDTH, max(1, round(h * KEY_WIDTH / w))), interpolation=cv2.INTER_AREA)
    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    return data.tobytes() if ok else b""


def _cross(rgb: np.ndarray, u: int, v: int, color) -> None:
    import cv2

    cv2.drawMarker(rgb, (int(u), int(v)), tuple(int(c) for c in color), cv2.MARKER_CROSS, 16, 2)
    cv2.circle(rgb, (int(u), int(v)), 9, tuple(int(c) for c in color), 1)


def _project(obs, point: np.ndarray) -> tuple[int, int] | None:
    T = np.linalg.inv(obs.T_world_cam)
    pc = T[:3, :3] @ point[:3] + T[:3, 3]
    if pc[2] <= 0.05:
        return None
    uv, _ = obs.intrinsics.project(pc[None])      # pixel coordinates and depth
    u, v = float(uv[0, 0]), float(uv[0, 1])
    h, w = obs.rgb.shape[:2]
    return (int(round(u)), int(round(v))) if 0 <= u < w and 0 <= v < h else None


def _plain(o):
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)
