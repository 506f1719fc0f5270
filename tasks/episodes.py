"""Episodes and episode datasets (JSONL, one episode per line, with a schema version).

An episode pins everything needed to reproduce it: the home (seed and layout settings), the task
string and its categories, the target object instance and the receptacle it starts on, the valid
goal receptacle instances, and the robot's start pose. Loading validates every field and reports
``FILE:LINE`` for the first bad record. Datasets are generated deterministically from a seed:
the committed splits (``tasks/data/{smoke,val,train,large}.jsonl``) come out of
``python -m tools episodes generate`` with the seeds and counts of ``SPLIT_RECIPES`` (smoke: seed
0, 20 easy episodes; val: seed 1, 1000; train: seed 2, 1200; large: seed 4040, 500 homes of 18-24
m sides, where the order of the search costs time and search policies rank), and a test
regenerates a sample to check they still match. ``SCHEMA_VERSION`` changes whenever the homes a
seed builds change.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from robots.hal import SE2Pose
from sim.scenes.catalog import GRASPABLE_CATEGORIES
from tasks.spec import TaskSpec, TaskSpecError, parse_task

SCHEMA_VERSION = 2
# What changed with each version: an episode names instances of the home its seed builds, so a
# change of the home generator makes older files point at furniture and objects that moved or no
# longer exist. Older files are refused with this explanation.
SCHEMA_CHANGES = {
    1: "the first format",
    2: "homes from the same seed changed (several instances of the common receptacle categories per room, "
       "chairs drawn up to tables), so version-1 episodes name instances that moved or no longer exist",
}
DATA_DIR = Path(__file__).with_name("data")
SPLITS = ("smoke", "val", "train", "large")
# How the committed splits are made: name -> (seed, count, difficulty, home sides (min, max) m or
# None for the difficulty's) of `python -m tools episodes generate [--home-size MIN MAX]`.
SPLIT_RECIPES = {"smoke": (0, 20, "easy", None), "val": (1, 1000, "normal", None),
                 "train": (2, 1200, "normal", None), "large": (4040, 500, "normal", (18.0, 24.0))}


class DatasetError(ValueError):
    """An episode file or record is invalid; the message names the file and line."""


MIN_HOME_SIZE, MAX_HOME_SIZE = 6.0, 40.0     # m, the footprint sides a home can be generated with


def home_sizes_valid(lo: float, hi: float) -> bool:
    """``MIN_HOME_SIZE <= lo <= hi <= MAX_HOME_SIZE`` (false for NaN): the one bound on a home's
    side lengths, for episode files, generation and the command line."""
    return MIN_HOME_SIZE <= lo <= hi <= MAX_HOME_SIZE


_ID = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,99}")


def is_episode_id(text: object) -> bool:
    """1-100 letters, digits, '-', '_' or '.', not starting with '-' or '.': an id that can name
    files (picture data, episode pages, recordings), for episodes, records and robot trials alike."""
    return isinstance(text, str) and _ID.fullmatch(text) is not None


def _short(value) -> str:
    from helios.schema import short_repr

    return short_repr(value, 100)


@dataclass(frozen=True)
class SceneRef:
    seed: int
    min_size: float = 8.0
    max_size: float = 15.0

    def layout_config(self):
        from sim.scenes.layout import LayoutConfig

        return LayoutConfig(min_size=self.min_size, max_size=self.max_size)


@dataclass(frozen=True)
class Episode:
    episode_id: str
    split: str
    scene: SceneRef
    task: str
    object_category: str
    start_receptacle_category: str
    goal_receptacle_category: str
    target_object: str                 # instance name, e.g. "mug_2"
    start_receptacle: str              # instance the target rests on, e.g. "stool_1"
    goal_receptacles: tuple[str, ...]  # every reachable instance of the goal category
    robot_start: tuple[float, float, float]
    difficulty: str = "normal"
    schema_version: int = SCHEMA_VERSION

    @property
    def spec(self) -> TaskSpec:
        return parse_task(self.task)

    @property
    def start_pose(self) -> SE2Pose:
        return SE2Pose(*self.robot_start)

    @property
    def seed(self) -> int:
        """A per-episode seed for agent/perception randomness, stable under reordering."""
        return int.from_bytes(self.episode_id.encode(), "little") % (2 ** 31 - 1)

    def to_json(self) -> str:
        d = asdict(self)
        d["goal_receptacles"] = list(self.goal_receptacles)
        d["robot_start"] = [round(v, 6) for v in self.robot_start]
        return json.dumps(d, sort_keys=True)


# ----------------------------------------------------------------------------------------------
# Validation and I/O
# ----------------------------------------------------------------------------------------------
_FIELDS = {
    "episode_id": str, "split": str, "scene": dict, "task": str, "object_category": str,
    "start_receptacle_category": str, "goal_receptacle_category": str, "target_object": str,
    "start_receptacle": str, "goal_receptacles": list, "robot_start": list, "difficulty": str,
    "schema_version": int,
}


def episode_from_dict(d: dict, where: str) -> Episode:
    from helios.schema import finite_number

    if not isinstance(d, dict):
        raise DatasetError(f"{where}: expected a JSON object, got {type(d).__name__}")
    if d.get("schema_version") != SCHEMA_VERSION:
        v = d.get("schema_version")
        why = (f": in version {SCHEMA_VERSION} {SCHEMA_CHANGES[SCHEMA_VERSION]}"
               if isinstance(v, int) and not isinstance(v, bool) and v < SCHEMA_VERSION else "")
        raise DatasetError(f"{where}: schema_version {_short(v)} is not supported (this version reads {SCHEMA_VERSION}"
                           f"{why}); regenerate the file with `python -m tools episodes generate --name NAME "
                           f"--seed SEED --count N --out FILE`")
    missing = sorted(set(_FIELDS) - set(d))
    if missing:
        raise DatasetError(f"{where}: missing field(s) {', '.join(missing)}")
    unknown = sorted(set(d) - set(_FIELDS))
    if unknown:
        raise DatasetError(f"{where}: unknown field(s) {', '.join(unknown)}")
    for key, tp in _FIELDS.items():
        if not isinstance(d[key], tp) or (tp is int and isinstance(d[key], bool)):
            raise DatasetError(f"{where}: field {key!r} must be {tp.__name__}, got {type(d[key]).__name__}")
    scene = d["scene"]
    if not isinstance(scene.get("seed"), int) or set(scene) - {"seed", "min_size", "max_size"}:
        raise DatasetError(f"{where}: field 'scene' must be {{seed: int, min_size, max_size}}, got {_short(scene)}")
    sizes = [scene.get("min_size", SceneRef.min_size), scene.get("max_size", SceneRef.max_size)]
    if isinstance(scene["seed"], bool) or not 0 <= scene["seed"] < 2 ** 63 or not all(
            finite_number(v) for v in sizes) or not (
            home_sizes_valid(*sizes)):
        raise DatasetError(f"{where}: field 'scene' needs a seed >= 0 and {MIN_HOME_SIZE:g} <= min_size <= max_size "
                           f"<= {MAX_HOME_SIZE:g} (m), got {_short(scene)}")
    try:
        spec = parse_task(d["task"])
    except TaskSpecError as exc:
        raise DatasetError(f"{where}: {exc}") from None
    if (spec.object, spec.start_receptacle, spec.goal_receptacle) != (
            d["object_category"], d["start_receptacle_category"], d["goal_receptacle_category"]):
        raise DatasetError(f"{where}: the task string disagrees with the category fields")
    start = d["robot_start"]
    if len(start) != 3 or not all(finite_number(v) for v in start):
        raise DatasetError(f"{where}: robot_start must be 3 finite numbers [x, y, yaw], got {_short(start)}")
    if not d["goal_receptacles"] or not all(isinstance(g, str) and g for g in d["goal_receptacles"]):
        raise DatasetError(f"{where}: goal_receptacles must be a non-empty list of instance names")
    goals = d["goal_receptacles"]
    twice = next((g for i, g in enumerate(goals) if g in goals[:i]), None)
    if twice is not None:
        raise DatasetError(f"{where}: goal receptacle {_short(twice)} is listed twice in goal_receptacles")
    if d["start_receptacle"] in goals:
        raise DatasetError(f"{where}: the start receptacle {_short(d['start_receptacle'])} is also a goal receptacle "
                           f"(the episode would be over before it starts)")
    if d["difficulty"] not in DIFFICULTIES:
        raise DatasetError(f"{where}: difficulty {_short(d['difficulty'])} is not one of: {', '.join(DIFFICULTIES)}")
    if not is_episode_id(d["episode_id"]):
        raise DatasetError(f"{where}: episode_id {_short(d['episode_id'])} must be 1-100 letters, digits, '-', '_' "
                           f"or '.' (it names files, e.g. recordings)")
    if d["split"] != "" and not d["episode_id"].startswith(d["split"]):
        raise DatasetError(f"{where}: episode_id {_short(d['episode_id'])} does not belong to split {_short(d['split'])}")
    return Episode(episode_id=d["episode_id"], split=d["split"], scene=SceneRef(**scene), task=d["task"],
                   object_category=d["object_category"], start_receptacle_category=d["start_receptacle_category"],
                   goal_receptacle_category=d["goal_receptacle_category"], target_object=d["target_object"],
                   start_receptacle=d["start_receptacle"], goal_receptacles=tuple(d["goal_receptacles"]),
                   robot_start=tuple(float(v) for v in start), difficulty=d["difficulty"],
                   schema_version=d["schema_version"])


class _DuplicateKey(Exception):
    def __init__(self, key: str):
        super().__init__(key)
        self.key = key


def _unique_keys(pairs: list[tuple[str, object]]) -> dict:
    """``json.loads``'s object hook: a dict, refusing a key given twice (plain JSON keeps the last)."""
    out: dict = {}
    for key, value in pairs:
        if key in out:
            raise _DuplicateKey(key)
        out[key] = value
    return out


def load_episodes(path: str | Path) -> list[Episode]:
    """Read and validate a JSONL episode file; the first bad line raises DatasetError."""
    from helios.schema import read_text, short_repr, shorten

    p = Path(path)
    if p.is_dir():
        raise DatasetError(f"episode file {short_repr(str(p))} is a directory")
    if not p.is_file():
        raise DatasetError(f"episode file {short_repr(str(p))} "
                           f"{'is not a regular file' if p.exists() else 'does not exist'}")
    episodes, seen = [], set()
    text = read_text(p, f"episode file {short_repr(str(p))}", DatasetError)
    for lineno, line in enumerate(text.split("\n"), 1):
        if not line.strip():
            continue
        where = f"{p}:{lineno}"
        try:
            d = json.loads(line, object_pairs_hook=_unique_keys)
        except _DuplicateKey as exc:
            raise DatasetError(f"{where}: key {_short(exc.key)} appears twice in one JSON object (which one "
                               f"counts is ambiguous)") from None
        except json.JSONDecodeError as exc:
            raise DatasetError(f"{where}: not valid JSON ({exc.msg} at column {exc.colno}); "
                               f"the file may be truncated or corrupted") from None
        except ValueError as exc:           # an integer of over 4,300 digits
            raise DatasetError(f"{where}: not valid JSON ({shorten(exc, 80)})") from None
        except RecursionError:
            raise DatasetError(f"{where}: not valid JSON (nested too deeply)") from None
        ep = episode_from_dict(d, where)
        if ep.episode_id in seen:
            raise DatasetError(f"{where}: duplicate episode_id {_short(ep.episode_id)}")
        seen.add(ep.episode_id)
        episodes.append(ep)
    if not episodes:
        raise DatasetError(f"episode file {short_repr(str(p))} holds no episodes")
    return episodes


def save_episodes(episodes: Iterable[Episode], path: str | Path) -> None:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_suffix(p.suffix + ".tmp")
    with tmp.open("w", encoding="utf-8") as fh:
        for ep in episodes:
            fh.write(ep.to_json() + "\n")
    tmp.replace(p)


def split_path(name: str) -> Path:
    if name not in SPLITS:
        raise DatasetError(f"unknown split {_short(name)}; valid splits: {', '.join(SPLITS)} "
                           f"(or pass --episodes-file FILE)")
    return DATA_DIR / f"{name}.jsonl"


def load_split(name: str) -> list[Episode]:
    return load_episodes(split_path(name))


# ----------------------------------------------------------------------------------------------
# Generation
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GenerationSettings:
    episodes_per_scene: int
    min_size: float
    max_size: float
    difficulty: str
    same_room: bool            # easy: the start receptacle is in the robot's room
    max_goal_distance: float   # m between the target and the goal receptacle (straight line)


DIFFICULTIES = {
    "easy": GenerationSettings(1, 8.0, 9.5, "easy", True, 6.0),
    "normal": GenerationSettings(5, 8.0, 15.0, "normal", False, math.inf),
}
# Objects that are easiest to see and grasp: used as targets for "easy" episodes.
EASY_OBJECTS = ("mug", "cup", "can", "jar", "bottle", "box", "vase", "candle", "toy")


def _scene_seed(split_seed: int, index: int) -> int:
    return int(np.random.SeedSequence([split_seed, index]).generate_state(1)[0] % (2 ** 31 - 1))


def _walkable(scene, start: SE2Pose, target, front) -> bool:
    """Spot can walk from ``start`` to a pose from which its arm reaches ``target``."""
    for pose in scene.nav.approach_poses(target, (start.x, start.y), front)[:3]:
        if scene.nav.plan_walk(start, pose) is not None:
            return True
    return False


def _episodes_for_scene(scene, scene_ref: SceneRef, rng: np.random.Generator, settings: GenerationSettings,
                        name: str, next_index: Callable[[], int]) -> list[Episode]:
    layout = scene.layout
    recs = {r.name: r for r in layout.receptacles}
    objects = [o for o in layout.objects if o.category in GRASPABLE_CATEGORIES and o.receptacle in scene.approachable]
    if settings.difficulty == "easy":
        objects = [o for o in objects if o.category in EASY_OBJECTS]
    rng.shuffle(objects)
    out = []
    used = set()
    for obj in objects:
        if len(out) >= settings.episodes_per_scene:
            break
        start_cat = recs[obj.receptacle].category
        key = (obj.category, start_cat)
        if key in used:
            continue
        goal_cats = sorted({r.category for r in layout.receptacles if r.name in scene.approachable} - {start_cat})
        if settings.max_goal_distance < math.inf:
            goal_cats = [c for c in goal_cats if any(
                math.hypot(r.x - obj.x, r.y - obj.y) <= settings.max_goal_distance
                for r in layout.receptacles if r.category == c and r.name in scene.approachable)]
        if not goal_cats:
            continue
        goal_cat = goal_cats[int(rng.integers(len(goal_cats)))]
        start = _sample_start(scene, rng, room=_room_of(layout.rooms, obj.x, obj.y) if settings.same_room else None)
        if start is None:
            continue
        pose = SE2Pose(*start)
        # Provably doable: a walk to the object, and from there to a goal receptacle, exists.
        target = (obj.x, obj.y, obj.z + 0.5 * obj.model.size[2] + 0.15)
        if not _walkable(scene, pose, target, scene.front(obj.receptacle)):
            continue
        goals = tuple(sorted(r.name for r in layout.receptacles if r.category == goal_cat and any(
            _walkable(scene, pose, p + [0.0, 0.0, 0.25], scene.front(r.name)) for p in scene.surface_points(r.name))))
        if not goals:
            continue
        used.add(key)
        spec = TaskSpec(obj.category, start_cat, goal_cat)
        out.append(Episode(
            episode_id=f"{name}-{next_index():05d}", split=name, scene=scene_ref, task=str(spec),
            object_category=obj.category, start_receptacle_category=start_cat, goal_receptacle_category=goal_cat,
            target_object=obj.name, start_receptacle=obj.receptacle, goal_receptacles=goals,
            robot_start=tuple(round(float(v), 6) for v in start), difficulty=settings.difficulty))
    return out


def _room_of(rooms, x: float, y: float):
    for r in rooms:
        if r.contains(x, y):
            return r
    return None


def _sample_start(scene, rng: np.random.Generator, room=None):
    """A start pose with room to turn in place, in the component everything was validated from."""
    nav = scene.nav
    comp = nav.component(scene.layout.robot_start[:2])
    cand = np.argwhere(comp & (nav.clearance >= nav.config.turn_radius))
    if room is not None:
        pts = nav.to_world(cand)
        keep = (pts[:, 0] > room.x0) & (pts[:, 0] < room.x1) & (pts[:, 1] > room.y0) & (pts[:, 1] < room.y1)
        cand = cand[keep]
    if len(cand) == 0:
        return None
    x, y = nav.to_world(cand[int(rng.integers(len(cand)))])
    return (float(x), float(y), float(rng.uniform(-math.pi, math.pi)))


def generate_episodes(name: str, seed: int, count: int, difficulty: str = "normal",
                      progress: Callable[[int, int], None] | None = None,
                      home_size: tuple[float, float] | None = None) -> list[Episode]:
    """``count`` validated episodes for a split called ``name``, deterministic in (name, seed, count,
    home_size). ``home_size`` (min, max) m bounds the sides of each home's footprint instead of the
    difficulty's (normal: 8-15 m, easy: 8-9.5 m): a split of only large homes, say."""
    from sim.scenes.home import build_home
    from sim.scenes.layout import LayoutError, generate_layout
    from sim.world import World

    if difficulty not in DIFFICULTIES:
        raise DatasetError(f"unknown difficulty {difficulty!r}; valid: {', '.join(DIFFICULTIES)}")
    if count <= 0:
        raise DatasetError(f"count must be positive, got {count}")
    settings = DIFFICULTIES[difficulty]
    if home_size is not None:
        lo, hi = (float(v) for v in home_size)
        if not home_sizes_valid(lo, hi):
            raise DatasetError(f"home sizes must satisfy {MIN_HOME_SIZE:g} <= min <= max <= {MAX_HOME_SIZE:g} m, "
                               f"got {lo:g} and {hi:g}")
        settings = dataclasses.replace(settings, min_size=lo, max_size=hi)
    episodes: list[Episode] = []
    counter = iter(range(10 ** 9))
    scene_index = 0
    while len(episodes) < count:
        scene_ref = SceneRef(_scene_seed(seed, scene_index), settings.min_size, settings.max_size)
        rng = np.random.default_rng([seed, scene_index, 7])
        scene_index += 1
        if scene_index > 50 * count + 100:
            raise DatasetError(f"could not generate {count} episodes (got {len(episodes)}); check the settings")
        world = World()
        try:
            scene = build_home(world, generate_layout(scene_ref.seed, scene_ref.layout_config()))
            new = _episodes_for_scene(scene, scene_ref, rng, settings, name, lambda: next(counter))
        except LayoutError:
            new = []   # rare: a scene that cannot be laid out or does not validate is skipped, deterministically
        finally:
            world.close()
        episodes += new[:count - len(episodes)]
        if progress:
            progress(len(episodes), count)
    return episodes
