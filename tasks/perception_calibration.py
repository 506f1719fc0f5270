"""Measuring the simulated detector on random views of a split's scenes (train by default: tune
there, not on val): per-class precision and recall at the paper's thresholds, recall against
distance, and multi-view consistency (how often one view's top label for an object is wrong while
the majority over 5 views is right).

Views come in groups: a random target (a small object 70 % of the time, else furniture) is seen
from random free viewpoints (``sim.perception.views``) until ``group`` of them detect it (at most
3 x ``group`` tries); the consistency numbers use the targets detected in ``group`` views (their
top label per view, and the majority over them). Every view is run through the
detector twice: with the full catalogue as vocabulary (the per-class table) and with a task-like
query of three classes, as HELIOS asks (target object, start and goal receptacle; the per-role
thresholds od_g, od_a, od_b apply).

Matching: a detection belongs to the body covering the majority (>= 50 %) of its mask; it is a
true positive if that body's category is its label. Recall counts instances showing at least
``min_pixels`` pixels (50 px = 0.065 % of a 320x240 image).
"""

from __future__ import annotations

import time
from collections import Counter, defaultdict
from dataclasses import asdict, dataclass, field
from typing import Callable

import numpy as np

from helios.perception.config import DetectionThresholds, role_thresholds
from sim.camera import decode_body_ids
from sim.perception.config import SimPerceptionConfig
from sim.perception.detector import SimDetector
from sim.perception.views import ViewSampling, random_view
from sim.scenes.catalog import ALL_CATEGORIES, OBJECT_CATEGORIES, RECEPTACLE_CATEGORIES
from tasks.episodes import load_split
from tasks.runner import SimEpisode

DISTANCE_EDGES = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0)


@dataclass
class _ClassCounts:
    tp: int = 0
    fp: int = 0
    instances: int = 0
    found: int = 0

    def precision(self) -> float | None:
        n = self.tp + self.fp
        return self.tp / n if n else None

    def recall(self) -> float | None:
        return self.found / self.instances if self.instances else None


@dataclass
class CalibrationSettings:
    split: str = "train"          # tune on train; val is for evaluation
    views: int = 1500
    group: int = 5
    scenes: int = 8
    seed: int = 0
    min_pixels: int = 50
    sampling: ViewSampling = field(default_factory=ViewSampling)


def scene_count(split: str, episodes: list | None = None) -> int:
    """The distinct scenes (homes) of ``split`` (of its ``episodes`` when already loaded): the most
    ``CalibrationSettings.scenes`` can ask for."""
    return len({ep.scene.seed for ep in (load_split(split) if episodes is None else episodes)})


def _match(ids: np.ndarray, mask: np.ndarray) -> int | None:
    under = ids[mask]
    if under.size == 0:
        return None
    counts = np.bincount(under + 1)
    b = int(np.argmax(counts)) - 1
    if b < 0 or counts[b + 1] < 0.5 * under.size:
        return None
    return b


def _majority(labels: list[tuple[str, float]]) -> str | None:
    if not labels:
        return None
    votes = Counter(l for l, _ in labels)
    total = defaultdict(float)
    for l, s in labels:
        total[l] += s
    return max(votes, key=lambda l: (votes[l], total[l]))


def calibrate(settings: CalibrationSettings = CalibrationSettings(),
              config: SimPerceptionConfig = SimPerceptionConfig(),
              thresholds: DetectionThresholds = DetectionThresholds(),
              progress: Callable[[str], None] | None = print) -> dict:
    """Run the measurement (``settings.views`` rendered views in all) and return the numbers."""
    rng = np.random.default_rng(settings.seed)
    episodes = load_split(settings.split)
    available = scene_count(settings.split, episodes)
    if settings.scenes > available:      # else fewer scenes would be viewed than the result records
        raise ValueError(f"scenes={settings.scenes}: split {settings.split!r} has {available} distinct scenes")
    if settings.views < settings.scenes:     # likewise: a scene with no share of the views
        raise ValueError(f"views={settings.views} < scenes={settings.scenes}: some scenes would get no view")
    chosen, seen = [], set()
    for i in rng.permutation(len(episodes)):
        ep = episodes[int(i)]
        if ep.scene.seed not in seen:
            seen.add(ep.scene.seed)
            chosen.append(ep)
        if len(chosen) == settings.scenes:
            break
    budgets = [settings.views // len(chosen) + (1 if k < settings.views % len(chosen) else 0)
               for k in range(len(chosen))]
    acc = _Accumulator(settings, thresholds)
    t_start = time.perf_counter()
    for k, (ep, budget) in enumerate(zip(chosen, budgets)):
        t0 = time.perf_counter()
        sim = SimEpisode.create(ep)
        n_targets = 0
        try:
            world, scene = sim.world, sim.scene
            detector = SimDetector(sim.backend, seed=ep.seed, config=config)
            objects = list(scene.object_ids.values())
            furniture = list(scene.receptacle_ids.values())
            while budget > 0:
                small = rng.random() < 0.7 or not furniture
                target = int(rng.choice(objects)) if small else int(rng.choice(furniture))
                labelled, attempts = [], 0
                # views of this target until `group` of them detect it (at most 3 x group views)
                while len(labelled) < settings.group and attempts < 3 * settings.group and budget > 0:
                    attempts += 1
                    T = random_view(scene, world, target, rng, settings.sampling)
                    if T is None:
                        continue
                    budget -= 1
                    top = acc.view(sim, detector, T, target, rng)
                    if top is not None:
                        labelled.append(top)
                n_targets += 1
                acc.groups.append({"kind": world.bodies[target].kind, "category": world.bodies[target].category,
                                   "labels": [list(v) for v in labelled]})
        finally:
            sim.close()
        if progress:
            progress(f"scene {k + 1}/{len(chosen)} (seed {ep.scene.seed}): {n_targets} targets, "
                     f"{acc.n_views} views so far, {time.perf_counter() - t0:.1f} s")
    return acc.summary(config, time.perf_counter() - t_start)


class _Accumulator:
    def __init__(self, settings: CalibrationSettings, thresholds: DetectionThresholds):
        self.settings = settings
        self.thresholds = thresholds
        self.full = {c: _ClassCounts() for c in ALL_CATEGORIES}
        self.task = {"object": _ClassCounts(), "start receptacle": _ClassCounts(), "goal receptacle": _ClassCounts()}
        self.dist = np.zeros((2, len(DISTANCE_EDGES) + 1), dtype=np.int64)   # [found, instances], small objects
        self.groups: list[dict] = []
        self.n_views = 0
        self.thr_full = {c: thresholds.od_object if c in OBJECT_CATEGORIES else thresholds.od_start_receptacle
                         for c in ALL_CATEGORIES}
        self.all_names = list(ALL_CATEGORIES)

    def view(self, sim, detector: SimDetector, T: np.ndarray, target: int, rng) -> tuple[str, float] | None:
        """Render, detect, count; return the target's top (label, score) at threshold, if any."""
        world, backend = sim.world, sim.backend
        obs = backend.render_at(T)
        self.n_views += 1
        ids = decode_body_ids(backend.segmentation_for(obs))
        counts = np.bincount(ids.ravel() + 1)
        visible = [int(b) for b in np.flatnonzero(counts[1:] >= self.settings.min_pixels)
                   if b in world.bodies and world.bodies[b].kind in ("object", "furniture")]
        # ---- full vocabulary
        hit: set[tuple[int, str]] = set()
        top = None
        for det in detector(obs.rgb, obs.depth, self.all_names):
            if det.score < self.thr_full[det.class_name]:
                continue
            b = _match(ids, det.mask)
            cat = world.bodies[b].category if b is not None and b in world.bodies else None
            if cat == det.class_name and (b, cat) not in hit:
                self.full[cat].tp += 1
                hit.add((b, cat))
            else:
                self.full[det.class_name].fp += 1
            # the target's label: detections covering a good part of it (not a phantom on a part of it)
            if (b == target and int(np.count_nonzero(det.mask & (ids == target))) >= 0.3 * counts[target + 1]
                    and (top is None or det.score > top[1])):
                top = (det.class_name, det.score)
        for b in visible:
            cat = world.bodies[b].category
            found = (b, cat) in hit
            self.full[cat].instances += 1
            self.full[cat].found += int(found)
            if world.bodies[b].kind == "object":
                lo, hi = world.aabb(b)
                dbin = int(np.searchsorted(DISTANCE_EDGES, float(np.linalg.norm((lo + hi) / 2 - T[:3, 3]))))
                self.dist[0, dbin] += int(found)
                self.dist[1, dbin] += 1
        # ---- task-like query: HELIOS asks for (object, start receptacle, goal receptacle)
        true_cat = world.bodies[target].category
        obj = true_cat if true_cat in OBJECT_CATEGORIES else str(rng.choice(OBJECT_CATEGORIES))
        start = true_cat if true_cat in RECEPTACLE_CATEGORIES else str(rng.choice(RECEPTACLE_CATEGORIES))
        goal = str(rng.choice([c for c in RECEPTACLE_CATEGORIES if c != start]))
        roles = {obj: "object", start: "start receptacle", goal: "goal receptacle"}
        thr = role_thresholds(self.thresholds, obj, start, goal)
        hit_task: set[tuple[int, str]] = set()
        for det in detector(obs.rgb, obs.depth, [obj, start, goal]):
            if det.score < thr[det.class_name]:
                continue
            b = _match(ids, det.mask)
            cat = world.bodies[b].category if b is not None and b in world.bodies else None
            if cat == det.class_name and (b, cat) not in hit_task:
                self.task[roles[cat]].tp += 1
                hit_task.add((b, cat))
            else:
                self.task[roles[det.class_name]].fp += 1
        for b in visible:
            cat = world.bodies[b].category
            if cat in roles:
                self.task[roles[cat]].instances += 1
                self.task[roles[cat]].found += int((b, cat) in hit_task)
        return top

    def summary(self, config: SimPerceptionConfig, seconds: float) -> dict:
        def row(c: _ClassCounts) -> dict:
            return {"precision": c.precision(), "recall": c.recall(), "tp": c.tp, "fp": c.fp,
                    "instances": c.instances, "found": c.found}

        g = self.settings.group
        return {
            "settings": asdict(self.settings),
            "thresholds": asdict(self.thresholds),
            "config": asdict(config),
            "views": self.n_views,
            "seconds": seconds,
            "per_class": {c: row(x) for c, x in self.full.items()},
            "pooled": {"small objects": row(_pooled(self.full, OBJECT_CATEGORIES)),
                       "receptacles": row(_pooled(self.full, RECEPTACLE_CATEGORIES))},
            "task_query": {k: row(v) for k, v in self.task.items()},
            "recall_by_distance": {"edges_m": list(DISTANCE_EDGES), "found": self.dist[0].tolist(),
                                   "instances": self.dist[1].tolist()},
            "consistency": {"small objects": _consistency(self.groups, "object", g),
                            "receptacles": _consistency(self.groups, "furniture", g),
                            "all": _consistency(self.groups, None, g)},
            "groups": self.groups,
        }


def _pooled(counts: dict[str, _ClassCounts], names) -> _ClassCounts:
    out = _ClassCounts()
    for c in names:
        x = counts[c]
        out.tp += x.tp
        out.fp += x.fp
        out.instances += x.instances
        out.found += x.found
    return out


def _consistency(groups: list[dict], kind: str | None, group: int) -> dict:
    """Over targets detected in ``group`` views: single-view vs majority label accuracy."""
    single_total = single_wrong = rescued = 0
    maj_total = maj_right = 0
    for g in groups:
        if kind is not None and g["kind"] != kind:
            continue
        labels = [tuple(v) for v in g["labels"] if v]
        if len(labels) < group:
            continue
        maj = _majority(labels)
        maj_total += 1
        maj_right += int(maj == g["category"])
        for l, _ in labels:
            single_total += 1
            wrong = l != g["category"]
            single_wrong += int(wrong)
            rescued += int(wrong and maj == g["category"])
    return {"views_with_detection": single_total,
            "single_view_label_accuracy": 1 - single_wrong / single_total if single_total else None,
            "single_wrong_majority_right": rescued / single_total if single_total else None,
            "targets": maj_total,
            "majority_label_accuracy": maj_right / maj_total if maj_total else None}
