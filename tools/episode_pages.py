"""One page per episode in the trial report, drawn from the run folder's traces
(``OUT/episodes/<id>.npz``, written during the trials by ``tasks.episode_trace``):

- a top-down picture (:func:`map_picture`): the occupancy map as the agent had it at the end
  (unknown grey, free white, obstacles dark), the path walked (blue, from the start ring), the
  frontiers the global objectives chose (orange: searching for the object, purple: for the goal
  receptacle; numbered in the order first chosen), the candidates with their Psi for their own
  class (dots coloured by role: object, start or goal receptacle), grasps (G), releases (R) and
  collisions (red x), where the episode ended (black square, with its failure reason), and the ground truth from the judge: the target object (red
  diamond; other valid instances of its class lighter), the start receptacle (brown box) and the
  goal receptacles (green boxes);
- a strip of hand-camera frames at the key moments (:func:`key_frame_strip`) and an animated GIF
  of the hand camera (:func:`hand_camera_gif`);
- the record's numbers, the failure reason and the end of the agent's log.

Everything is written next to the report (``OUT/episodes/<run>/``) and linked relatively, so the
report folder works offline and can be moved as a whole.
"""

from __future__ import annotations

import html
import io
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

MAP_COLORS = np.array([(205, 205, 205), (255, 255, 255), (70, 70, 70)], dtype=np.uint8)  # unknown, free, obstacle
PATH = (31, 119, 180)
TARGET = (214, 39, 40)
OTHER_TARGET = (255, 152, 150)
GOAL = (44, 160, 44)
START_RECEPTACLE = (140, 86, 75)
PICK_FRONTIER = (255, 127, 14)
PLACE_FRONTIER = (148, 103, 189)
CANDIDATE = {"object": (227, 119, 194), "start": (188, 189, 34), "goal": (23, 190, 207)}
EVENT = {"grasp": (227, 119, 194), "release": (23, 190, 207), "collision": (255, 0, 0)}
FAILED_TEXT = (178, 24, 43)      # the title of a failed episode (TARGET is kept for the target alone)
MAP_PX = 640            # the map's longer side in pixels (the scale is clamped to 1..12 px per cell)
HEADER = 44
FOOTER = 64            # the legend: up to three rows
THUMB_WIDTH = 240
STRIP_WIDTH = 240


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:                                  # Pillow without FreeType sizes
        return ImageFont.load_default()


@dataclass(frozen=True)
class MapFrame:
    """World (x, y) -> picture pixel for one map picture: ``sx``/``sy`` pixels per cell, the map's
    top-left corner at (0, ``header``), north (+y) up."""

    origin_xy: tuple[float, float]
    cell_size: float
    rows: int
    cols: int
    sx: float
    sy: float
    header: int = HEADER

    def to_pixel(self, x: float, y: float) -> tuple[float, float]:
        return ((x - self.origin_xy[0]) / self.cell_size * self.sx,
                self.header + (self.rows - (y - self.origin_xy[1]) / self.cell_size) * self.sy)


def map_frame(trace: dict, max_px: int = MAP_PX) -> MapFrame:
    rows, cols = trace["map"].shape
    grid = trace["meta"]["grid"]
    scale = min(12.0, max(1.0, max_px / max(rows, cols)))
    w, h = max(1, round(cols * scale)), max(1, round(rows * scale))
    return MapFrame(tuple(grid["origin_xy"]), float(grid["cell_size"]), rows, cols, w / cols, h / rows)


def outcome_text(meta: dict) -> str:
    out = meta["outcome"]
    if out.get("success"):
        return "success"
    reason = out.get("failure_reason") or ("error" if out.get("error") else "unscored")
    return f"failed: {reason}"


def map_picture(trace: dict, max_px: int = MAP_PX):
    """The top-down picture of one episode (a PIL image) and its :class:`MapFrame`."""
    from PIL import Image, ImageDraw

    meta = trace["meta"]
    frame = map_frame(trace, max_px)
    codes = np.clip(trace["map"], 0, len(MAP_COLORS) - 1)
    rgb = MAP_COLORS[codes[::-1]]                      # row 0 (lowest y) at the bottom
    w, h = round(frame.cols * frame.sx), round(frame.rows * frame.sy)
    width = max(w, 420)
    img = Image.new("RGB", (width, HEADER + h + FOOTER), (255, 255, 255))
    img.paste(Image.fromarray(rgb).resize((w, h), Image.NEAREST), (0, HEADER))
    d = ImageDraw.Draw(img)
    small, label, title = _font(11), _font(12), _font(14)
    P = frame.to_pixel
    truth = meta.get("truth") or {}

    taken: list[tuple[float, float, float, float]] = []        # label boxes drawn so far: none overlaps another

    def box(b, color, width):
        (x0, y0), (x1, y1) = P(b["lo"][0], b["hi"][1]), P(b["hi"][0], b["lo"][1])
        d.rectangle([x0, y0, x1, y1], outline=color, width=width)
        _label(d, x0 + 2, y1 + 1, b["name"], small, color, taken)

    for b in truth.get("goals", []):
        box(b, GOAL, 3)
    if truth.get("start_receptacle"):
        box(truth["start_receptacle"], START_RECEPTACLE, 2)
    roles = {meta.get("goal_class"): "goal", meta.get("start_class"): "start", meta.get("object_class"): "object"}
    labels = []
    for c in meta.get("candidates", []):
        x, y = P(*c["xy"])
        psi = c["psi"].get(c["class_name"])
        color = CANDIDATE.get(roles.get(c["class_name"], "start"), CANDIDATE["start"])
        d.ellipse([x - 4, y - 4, x + 4, y + 4], fill=color, outline=(0, 0, 0))
        if psi is not None:
            labels.append((x, y, f"{psi:.2f}"))
    for key, color in (("pick", PICK_FRONTIER), ("place", PLACE_FRONTIER)):
        seen: list[tuple[float, float]] = []
        for fx, fy, _value in meta.get("frontiers", {}).get(key, []):
            if any(abs(fx - a) < 1e-6 and abs(fy - b) < 1e-6 for a, b in seen):
                continue
            seen.append((fx, fy))
            x, y = P(fx, fy)
            d.rectangle([x - 6, y - 6, x + 6, y + 6], fill=color, outline=(0, 0, 0))
            d.text((x - 3 if len(seen) < 10 else x - 6, y - 7), str(len(seen)), fill=(0, 0, 0), font=small)
    path = trace["path"]
    start = truth.get("start_pose") or (list(path[0, 1:3]) if len(path) else None)
    if start is not None:
        x, y = P(start[0], start[1])
        d.ellipse([x - 8, y - 8, x + 8, y + 8], outline=(0, 0, 0), width=2)
        d.text((x + 10, y + 4), "start", fill=(0, 0, 0), font=small)
    pts = [P(float(px), float(py)) for px, py in path[:, 1:3]]
    if len(pts) > 1:
        d.line(pts, fill=PATH, width=3, joint="curve")
    for x, y in pts[:1] + pts[-1:]:
        d.ellipse([x - 2, y - 2, x + 2, y + 2], fill=PATH)
    for o in sorted(truth.get("targets", []), key=lambda o: o["named"]):
        x, y = P(o["xyz"][0], o["xyz"][1])
        r = 7 if o["named"] else 5
        d.polygon([(x, y - r), (x + r, y), (x, y + r), (x - r, y)], fill=TARGET if o["named"] else OTHER_TARGET,
                  outline=(255, 255, 255))
    if len(path):
        x, y = P(float(path[-1, 1]), float(path[-1, 2]))
        d.rectangle([x - 7, y - 7, x + 7, y + 7], outline=(0, 0, 0), width=2)
    for ev in meta.get("events", []):       # over the targets: a grasp is at its target (it was hidden under it)
        x, y = P(*ev["xy"])
        color = EVENT.get(ev["kind"], (0, 0, 0))
        if ev["kind"] == "collision":
            d.line([x - 5, y - 5, x + 5, y + 5], fill=color, width=2)
            d.line([x - 5, y + 5, x + 5, y - 5], fill=color, width=2)
        else:
            d.ellipse([x - 10, y - 10, x + 10, y + 10], outline=color, width=2)
            if not ev.get("ok", True):          # a failed grasp or release: slashed (they looked the same)
                d.line([x - 8, y + 8, x + 8, y - 8], fill=color, width=2)
            _label(d, x + 8, y - 20, ev["kind"][0].upper(), small, color, taken)
    if len(path):
        x, y = P(float(path[-1, 1]), float(path[-1, 2]))
        _label(d, x + 10, y - 8, f"end: {outcome_text(meta)}", label, (0, 0, 0), taken)
    for x, y, text in labels:
        _label(d, x + 6, y - 7, text, small, (0, 0, 0), taken)
    head = f"{meta.get('episode_id')}  ·  {meta.get('agent')}  ·  {outcome_text(meta)}"
    d.text((6, 4), head, fill=(0, 0, 0) if meta["outcome"].get("success") else FAILED_TEXT, font=title)
    d.text((6, 24), str(meta.get("task") or ""), fill=(60, 60, 60), font=label)
    _scale_bar(d, frame, w, h, small)
    _legend(d, 6, HEADER + h + 6, small, meta.get("has_map", False))
    return img, frame


SCALE_BAR = (25, 25, 25)


def _scale_bar(d, frame: MapFrame, w: int, h: int, font) -> None:
    """A scale bar of 1, 2, 5 or 10 m (the first at least 40 px long) in the map's lower right corner,
    on a white patch: the picture had no distances at all (pictures audit)."""
    per_m = frame.sx / frame.cell_size
    metres = next((m for m in (1, 2, 5, 10) if m * per_m >= 40), 10)
    length = round(metres * per_m)
    x1, y = w - 10, HEADER + h - 10
    x0 = x1 - length
    d.rectangle([x0 - 6, y - 18, x1 + 6, y + 5], fill=(255, 255, 255))
    d.line([x0, y, x1, y], fill=SCALE_BAR, width=2)
    for x in (x0, x1):
        d.line([x, y - 4, x, y + 3], fill=SCALE_BAR, width=1)
    d.text(((x0 + x1) / 2 - 8, y - 17), f"{metres} m", fill=SCALE_BAR, font=font)


def _label(d, x: float, y: float, text: str, font, color, taken: list) -> None:
    """``text`` at (x, y), or the first of a few nearby places (below, above, left of the point)
    where it overlaps no label drawn before (``taken``, which it joins); else at (x, y) anyway."""
    w, h = d.textlength(text, font=font), getattr(font, "size", 11) + 2
    for dx, dy in ((0, 0), (0, h), (0, -h), (0, 2 * h), (0, -2 * h), (-w - 14, 0)):
        box = (x + dx, y + dy, x + dx + w, y + dy + h)
        if not any(box[0] < b[2] and b[0] < box[2] and box[1] < b[3] and b[1] < box[3] for b in taken):
            break
    else:
        box = (x, y, x + w, y + h)
    taken.append(box)
    d.text(box[:2], text, fill=color, font=font)


def _legend(d, x: int, y: int, font, has_map: bool) -> None:
    items = [("path", "line", PATH), ("target (truth)", "diamond", TARGET), ("goal receptacles", "box", GOAL),
             ("start receptacle", "box", START_RECEPTACLE), ("end", "square", (0, 0, 0)),
             ("grasp", "ring G", EVENT["grasp"]), ("release", "ring R", EVENT["release"]),
             ("failed", "slashed", EVENT["grasp"]), ("collision", "cross", EVENT["collision"])]
    if has_map:
        items += [("frontiers: object", "fill", PICK_FRONTIER), ("goal", "fill", PLACE_FRONTIER),
                  ("candidates (Psi): object", "dot", CANDIDATE["object"]), ("start", "dot", CANDIDATE["start"]),
                  ("goal", "dot", CANDIDATE["goal"])]
    x0 = x
    for text, kind, color in items:
        if x > 380:
            x, y = x0, y + 18
        if kind == "line":
            d.line([x, y + 6, x + 14, y + 6], fill=color, width=3)
        elif kind == "diamond":
            d.polygon([(x + 7, y), (x + 14, y + 6), (x + 7, y + 12), (x, y + 6)], fill=color)
        elif kind == "dot":
            d.ellipse([x + 3, y + 2, x + 11, y + 10], fill=color, outline=(0, 0, 0))
        elif kind == "fill":
            d.rectangle([x + 1, y + 1, x + 13, y + 11], fill=color, outline=(0, 0, 0))
        elif kind == "slashed":
            d.ellipse([x + 1, y, x + 13, y + 12], outline=color, width=2)
            d.line([x + 2, y + 11, x + 12, y + 1], fill=color, width=2)
        elif kind.startswith("ring"):
            d.ellipse([x + 1, y, x + 13, y + 12], outline=color, width=2)
            d.text((x + 4, y - 1), kind[-1], fill=color, font=font)
        elif kind == "cross":
            d.line([x + 2, y + 1, x + 12, y + 11], fill=color, width=2)
            d.line([x + 2, y + 11, x + 12, y + 1], fill=color, width=2)
        else:
            d.rectangle([x + 1, y + 1, x + 13, y + 11], outline=color, width=2)
        d.text((x + 18, y), text, fill=(0, 0, 0), font=font)
        x += 26 + int(d.textlength(text, font=font))


def key_frame_strip(trace: dict):
    """The key hand-camera frames side by side with their captions (a PIL image), or None."""
    from PIL import Image, ImageDraw

    frames = []
    for info, data in trace["key_frames"]:
        try:
            im = Image.open(io.BytesIO(data)).convert("RGB")
        except Exception:  # noqa: BLE001 - a damaged frame is left out
            continue
        h = round(im.height * STRIP_WIDTH / im.width)
        frames.append((info, im.resize((STRIP_WIDTH, h), Image.BILINEAR)))
    if not frames:
        return None
    font = _font(11)
    fh = max(im.height for _, im in frames)
    strip = Image.new("RGB", (len(frames) * (STRIP_WIDTH + 6), fh + 34), (255, 255, 255))
    d = ImageDraw.Draw(strip)
    for i, (info, im) in enumerate(frames):
        x = i * (STRIP_WIDTH + 6)
        strip.paste(im, (x, 0))
        d.text((x + 2, fh + 2), info["label"][:42], fill=(0, 0, 0), font=font)
        d.text((x + 2, fh + 17), f"t = {info['t']:.1f} s", fill=(90, 90, 90), font=font)
    return strip


def hand_camera_gif(trace: dict, path) -> bool:
    """An animated GIF of the hand camera (the trace's thinned frames) written to ``path`` (a file
    name or a binary file object); False when there are none."""
    from PIL import Image

    frames = trace["frames"]
    if len(frames) < 2:
        return False
    ims = [Image.fromarray(np.asarray(f, dtype=np.uint8)) for f in frames]
    buf = io.BytesIO()
    ims[0].save(buf, format="GIF", save_all=True, append_images=ims[1:], duration=200, loop=0)
    if hasattr(path, "write"):
        path.write(buf.getvalue())
    else:
        Path(path).write_bytes(buf.getvalue())
    return True


# ------------------------------------------------------------------------------------------------
# Pages
# ------------------------------------------------------------------------------------------------
PAGE_CSS = ("body{font-family:sans-serif;margin:1.5em;max-width:1200px}table{border-collapse:collapse;margin:.6em 0}"
            "td,th{border:1px solid #ccc;padding:3px 8px;text-align:left}img{max-width:100%}"
            ".fail{color:#b00;font-weight:bold}.ok{color:#080;font-weight:bold}nav a{margin-right:1em}"
            "pre{background:#f4f4f4;padding:.6em;white-space:pre-wrap}")


@dataclass
class EpisodePage:
    episode_id: str
    page: str                 # relative to the report folder
    thumb: str | None         # likewise; None without a trace
    outcome: str              # "success", a failure reason, or "unscored"
    damaged: str | None = None  # why its picture data could not be read or drawn (the page says so too)


MAX_SLUG = 100               # characters of a file name made from a name (file systems allow 255 bytes)


def slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("._")[:MAX_SLUG] or "run"


MAX_MAP_CELLS = 4000         # cells along a side of the map in picture data (real maps: a few hundred)


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)


def _xy(v, n: int = 2) -> bool:
    """``v`` is a list of at least ``n`` finite numbers (a point)."""
    return isinstance(v, (list, tuple)) and len(v) >= n and all(_finite(x) for x in v[:n])


def trace_problem(trace: dict) -> str | None:
    """Why loaded picture data (``tasks.episode_trace.load_trace``) cannot be drawn, or None: the
    shapes and values :func:`map_picture`, :func:`key_frame_strip`, :func:`hand_camera_gif` and the
    page rely on (a file that loads but was damaged or written by something else)."""
    meta = trace.get("meta")
    if not isinstance(meta, dict):
        return "meta is not an object"
    grid = meta.get("grid")
    if not isinstance(grid, dict) or not _xy(grid.get("origin_xy")):
        return "meta.grid.origin_xy is not a point"
    if not (_finite(grid.get("cell_size")) and grid["cell_size"] > 0):
        return "meta.grid.cell_size is not a positive number"
    if not isinstance(meta.get("outcome"), dict):
        return "meta.outcome is not an object"
    m = trace.get("map")
    if not (isinstance(m, np.ndarray) and m.ndim == 2 and m.size and m.dtype.kind in "iu"
            and max(m.shape) <= MAX_MAP_CELLS):
        return f"map is not a 2-D array of cell codes of at most {MAX_MAP_CELLS} cells a side"
    path = trace.get("path")
    if not (isinstance(path, np.ndarray) and path.ndim == 2 and path.shape[1] >= 3 and path.dtype.kind in "biuf"
            and np.isfinite(path).all()):
        return "path is not an (N, 4) array of finite numbers (t, x, y, yaw)"
    frames = trace.get("frames")
    if not (isinstance(frames, np.ndarray) and frames.ndim == 4 and frames.shape[3] == 3 and frames.dtype == np.uint8):
        return "frames is not an (F, h, w, 3) array of 8-bit colours"
    for info, data in trace.get("key_frames") or []:
        if not (isinstance(info, dict) and isinstance(info.get("label"), str) and _finite(info.get("t"))):
            return "meta.key_frames: a key frame has no label or time"
    for key, what in (("events", "an event"), ("candidates", "a candidate")):
        items = meta.get(key, [])
        if not isinstance(items, list) or not all(isinstance(x, dict) and _xy(x.get("xy")) for x in items):
            return f"meta.{key} is not a list of objects with a point xy ({what} has none)"
    if not all(isinstance(ev.get("kind"), str) and ev["kind"] for ev in meta.get("events", [])):
        return "meta.events: an event has no kind"
    for c in meta.get("candidates", []):
        if not (isinstance(c.get("class_name"), str) and isinstance(c.get("psi"), dict)
                and all(v is None or _finite(v) for v in c["psi"].values())):
            return "meta.candidates: a candidate has no class_name or psi"
    fronts = meta.get("frontiers", {})
    if not isinstance(fronts, dict) or not all(
            isinstance(v, list) and all(_xy(f) and len(f) == 3 for f in v) for v in fronts.values()):
        return "meta.frontiers is not an object of lists of (x, y, value)"
    truth = meta.get("truth") or {}
    if not isinstance(truth, dict):
        return "meta.truth is not an object"

    def box(b) -> bool:
        return isinstance(b, dict) and _xy(b.get("lo")) and _xy(b.get("hi")) and isinstance(b.get("name"), str)

    goals = truth.get("goals", [])
    if not isinstance(goals, list) or not all(map(box, goals)) or (truth.get("start_receptacle")
                                                                   and not box(truth["start_receptacle"])):
        return "meta.truth: a receptacle box is malformed"
    targets = truth.get("targets", [])
    if not isinstance(targets, list) or not all(isinstance(o, dict) and _xy(o.get("xyz")) and "named" in o
                                                for o in targets):
        return "meta.truth.targets is malformed"
    if truth.get("start_pose") is not None and not _xy(truth["start_pose"]):
        return "meta.truth.start_pose is not a point"
    for key in ("log", "errors"):
        lines = meta.get(key)
        if lines is not None and not (isinstance(lines, list) and all(isinstance(x, str) for x in lines)):
            return f"meta.{key} is not a list of text lines"
    return None


def draw_trace(trace: dict) -> dict:
    """The episode's pictures in memory (``map``, ``thumb``, maybe ``strip``, maybe ``gif`` bytes)."""
    img, _ = map_picture(trace)
    only_map = img.crop((0, HEADER, img.width, img.height - FOOTER))       # title and legend: on the page
    out = {"map": img, "thumb": only_map.resize((THUMB_WIDTH, max(1, round(only_map.height * THUMB_WIDTH
                                                                           / only_map.width))))}
    strip = key_frame_strip(trace)
    if strip is not None:
        out["strip"] = strip
    buf = io.BytesIO()
    if hand_camera_gif(trace, buf):
        out["gif"] = buf.getvalue()
    return out


def record_outcome(record: dict) -> str:
    m = record.get("metrics")
    if not m:
        return "unscored"
    return "success" if m.get("success") else (m.get("failure_reason") or "unscored")


def write_episode_pages(report_dir: Path, run_index: int, run, index_name: str = "index.html") -> list[EpisodePage]:
    """Pictures and one HTML page per episode of ``run`` under ``report_dir/episodes/<run>/``."""
    from helios.schema import shorten
    from tasks.episode_trace import load_trace, trace_path

    sub = f"episodes/{run_index + 1}-{slug(run.name)}"
    folder = report_dir / sub
    folder.mkdir(parents=True, exist_ok=True)
    pages: list[EpisodePage] = []
    ids = [r["episode_id"] for r in run.records]
    # a run that kept picture data for some episodes kept it for all: a missing file was lost
    kept_some = any(trace_path(run.path, eid).exists() for eid in ids)
    for i, rec in enumerate(run.records):
        eid = rec["episode_id"]
        name = slug(eid)
        trace, problem, damaged = None, None, None
        tpath = trace_path(run.path, eid)
        if tpath.exists():
            try:
                trace = load_trace(tpath)
            except Exception as exc:  # noqa: BLE001 - a damaged trace: the page says so
                damaged = f"cannot be read ({type(exc).__name__}: {exc})"
            else:
                why = trace_problem(trace)
                damaged = f"is damaged ({why})" if why else None
        elif (run.path / "robot.yaml").is_file():       # tools spot: a robot, or the fake Spot over the SDK
            problem = "no picture data: episodes run through the Spot SDK backend (tools spot) keep none"
        elif kept_some:        # (the page once blamed --no-pictures, and the report said nothing)
            damaged = (f"is missing ({tpath.name}; the run's other episodes have theirs: deleted or moved?); "
                       f"`tools trials` does not make it again for a finished episode")
        else:
            problem = "no picture data: the episode was run with --no-pictures or by an older version"
        files: dict[str, str] = {}
        if trace is not None and damaged is None:
            try:
                drawn = draw_trace(trace)
            except Exception as exc:  # noqa: BLE001 - data the checks let through that still cannot be drawn
                damaged = f"cannot be drawn ({type(exc).__name__}: {exc})"
            else:
                for key, suffix in (("map", ".png"), ("thumb", ".thumb.png"), ("strip", ".frames.png"),
                                    ("gif", ".gif")):
                    if key not in drawn:
                        continue
                    if key == "gif":
                        (folder / f"{name}{suffix}").write_bytes(drawn[key])
                    else:
                        drawn[key].save(folder / f"{name}{suffix}")
                    files[key] = f"{name}{suffix}"
        if damaged is not None:
            damaged = shorten(damaged, 300)
            problem = f"its picture data {tpath} {damaged}"
            trace = None
        prev_id = ids[i - 1] if i > 0 else None
        next_id = ids[i + 1] if i + 1 < len(ids) else None
        (folder / f"{name}.html").write_text(_page_html(run, rec, trace, files, problem, prev_id, next_id, index_name))
        pages.append(EpisodePage(eid, f"{sub}/{name}.html", f"{sub}/{files['thumb']}" if "thumb" in files else None,
                                 record_outcome(rec), damaged))
    return pages


def _page_html(run, rec: dict, trace: dict | None, files: dict, problem: str | None, prev_id, next_id,
               index_name: str) -> str:
    e = html.escape
    m = rec.get("metrics") or {}
    outcome = record_outcome(rec)
    nav = [f"<a href='../../{e(index_name)}'>report</a>"]
    if prev_id:
        nav.append(f"<a href='{e(slug(prev_id))}.html'>&larr; {e(prev_id)}</a>")
    if next_id:
        nav.append(f"<a href='{e(slug(next_id))}.html'>{e(next_id)} &rarr;</a>")
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{e(rec['episode_id'])} ({e(run.name)})</title>"
             f"<style>{PAGE_CSS}</style></head><body><nav>{''.join(nav)}</nav>",
             f"<h1>{e(rec['episode_id'])} <small>({e(run.name)}, agent {e(str(rec.get('agent')))})</small></h1>",
             f"<p>{e(str(rec.get('task')))}</p>"]
    if outcome == "success":
        parts.append("<p class='ok' id='outcome'>Success</p>")
    else:
        parts.append(f"<p class='fail' id='outcome'>Failed: <span id='failure-reason'>{e(outcome)}</span></p>")
    if rec.get("error"):
        parts.append(f"<p>Error:</p><pre>{e(str(rec['error']))}</pre>")
    phases = "".join(f"<td>{'&#10003;' if m.get(k) else '&#10007;'}</td>" for k in
                     ("find_obj", "pick", "find_rec", "place", "success"))
    parts.append("<table><tr><th>FindObj</th><th>Pick</th><th>FindRec</th><th>Place</th><th>SR</th><th>commands</th>"
                 "<th>sim s</th><th>wall s</th><th>collisions</th><th>pick attempts</th><th>released on</th>"
                 f"<th>budget used up</th></tr><tr>{phases}<td>{e(str(rec.get('commands')))}</td>"
                 f"<td>{float(rec.get('sim_time') or 0):.1f}</td><td>{float(rec.get('wall_time') or 0):.1f}</td>"
                 f"<td>{e(str(m.get('collisions', '-')))}</td><td>{e(str(m.get('pick_attempts', '-')))}</td>"
                 f"<td>{e(str(m.get('released_on') or '-'))}</td><td>{'yes' if rec.get('limit_hit') else 'no'}</td>"
                 "</tr></table>")
    if problem:
        parts.append(f"<p><i>{e(problem)}</i></p>")
    if "map" in files:
        parts.append(f"<h2>Top-down</h2><img id='map' alt='top-down picture of {e(rec['episode_id'])}' "
                     f"src='{e(files['map'])}'>")
    if "strip" in files:
        parts.append(f"<h2>Hand camera at the key moments</h2><img id='frames' alt='key frames' "
                     f"src='{e(files['strip'])}'>")
    if "gif" in files:
        parts.append(f"<h2>Hand camera</h2><img id='hand-camera' alt='hand camera animation' "
                     f"src='{e(files['gif'])}' width='384'>")
    events = rec.get("collision_events") or []
    if isinstance(events, list) and events and all(isinstance(c, dict) for c in events):
        parts.append("<h2>Collisions</h2><ul>" + "".join(
            f"<li>t={float(c.get('time') or 0):.1f} s: {e(str(c.get('robot_link')))} touched {e(str(c.get('body')))} "
            f"({e(str(c.get('phase')))})</li>" for c in events) + "</ul>")
    if trace is not None:
        meta = trace["meta"]
        if meta.get("log"):
            parts.append("<h2>End of the agent's log</h2><pre>" + e("\n".join(meta["log"])) + "</pre>")
        if meta.get("errors"):
            parts.append("<p><i>picture problems: " + e("; ".join(meta["errors"])) + "</i></p>")
    extra = rec.get("extra") if isinstance(rec.get("extra"), dict) else {}
    if isinstance(extra.get("decisions"), dict) and extra["decisions"]:
        d = {k: v for k, v in extra["decisions"].items() if not isinstance(v, list)}
        parts.append("<h2>Decisions</h2><table><tr>" + "".join(f"<th>{e(k)}</th>" for k in d) + "</tr><tr>"
                     + "".join(f"<td>{e(str(v))}</td>" for v in d.values()) + "</tr></table>")
    if isinstance(extra.get("activity_time"), dict) and extra["activity_time"]:
        a = extra["activity_time"]
        parts.append("<h2>Simulated time per phase (s)</h2><table><tr>" + "".join(f"<th>{e(k)}</th>" for k in a)
                     + "</tr><tr>" + "".join(f"<td>{float(v or 0):.1f}</td>" for v in a.values()) + "</tr></table>")
    parts.append("</body></html>")
    return "\n".join(parts)


def episode_table_html(run, pages: list[EpisodePage]) -> str:
    """The per-episode table of one run: every row links to its episode page."""
    e = html.escape
    by_id = {p.episode_id: p for p in pages}
    head = ("<tr><th>episode</th><th>outcome</th><th>FindObj</th><th>Pick</th><th>FindRec</th><th>Place</th>"
            "<th>SR</th><th>collisions</th><th>commands</th><th>sim s</th><th>task</th></tr>")
    rows = []
    for rec in run.records:
        p = by_id[rec["episode_id"]]
        m = rec.get("metrics") or {}
        marks = "".join(f"<td>{'&#10003;' if m.get(k) else '&middot;'}</td>"
                        for k in ("find_obj", "pick", "find_rec", "place", "success"))
        rows.append(f"<tr class='episode-row'><td><a href='{e(p.page)}'>{e(rec['episode_id'])}</a></td>"
                    f"<td>{e(p.outcome)}</td>{marks}<td>{e(str(m.get('collisions', '-')))}</td>"
                    f"<td>{e(str(rec.get('commands')))}</td>"
                    f"<td>{float(rec.get('sim_time') or 0):.0f}</td><td>{e(str(rec.get('task', '')))}</td></tr>")
    return f"<table class='episodes'><thead>{head}</thead><tbody>{''.join(rows)}</tbody></table>"


def failure_gallery_html(pages: list[EpisodePage]) -> str:
    """Thumbnails of the failed episodes, grouped by failure reason (each links to its page)."""
    from tasks.metrics import FAILURE_REASONS

    e = html.escape
    failed = [p for p in pages if p.outcome != "success"]
    if not failed:
        return "<p>No failed episodes.</p>"
    order = [r for r in FAILURE_REASONS] + sorted({p.outcome for p in failed} - set(FAILURE_REASONS))
    parts = ["<div class='gallery'>"]
    for reason in order:
        group = [p for p in failed if p.outcome == reason]
        if not group:
            continue
        parts.append(f"<h3 class='reason'>{e(reason)} ({len(group)})</h3><div class='thumbs'>")
        for p in group:
            pic = f"<img alt='{e(p.episode_id)}' src='{e(p.thumb)}' width='{THUMB_WIDTH}'>" if p.thumb else \
                "<span class='nopic'>no picture</span>"
            parts.append(f"<figure><a href='{e(p.page)}'>{pic}</a><figcaption><a href='{e(p.page)}'>"
                         f"{e(p.episode_id)}</a></figcaption></figure>")
        parts.append("</div>")
    parts.append("</div>")
    return "".join(parts)
