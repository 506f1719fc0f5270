"""The simulated detector and image-text scorer: determinism, ground-truth mode, view-dependent
persistent errors, recall against distance, the scorer's evidence, and one clear error per bad input."""

from __future__ import annotations

import dataclasses
import functools
import math
from collections import Counter

import numpy as np
import pytest

from helios.perception import Detection
from helios.perception.errors import ImageInputError, PerceptionError, PromptError, UnknownCategoryError
from helios.perception.prompts import value_prompt
from robots.hal import SE2Pose
from robots.spot.sim_backend import SimSpotBackend
from robots.transforms import look_at_camera as look_at
from sim import assets
from sim.camera import decode_body_ids
from sim.perception import (
    GroundTruthDetector,
    GroundTruthScorer,
    SimDetector,
    SimImageTextScorer,
    SimPerceptionConfig,
    make_sim_perception,
)
from sim.perception.geometry import camera_around
from sim.scenes.catalog import ALL_CATEGORIES, OBJECT_CATEGORIES
from sim.spot import SpotBody
from sim.world import World

# A home the search below finds on today's val split (it generates 40 layouts, ~11 s, to get there):
# tried first; if the split no longer has a busy table there, the search runs.
_BUSY_HOME_EPISODE = "val-00195"


@functools.lru_cache(maxsize=1)
def _pick_home():
    """A val home with a table carrying at least 5 objects and a counter in a kitchen (the
    look-alikes on a busy table are the detector's hard cases): (episode, table, its objects, counter)."""
    from sim.scenes.layout import generate_layout
    from tasks.episodes import load_split

    def busy_table(ep):
        layout = generate_layout(ep.scene.seed, ep.scene.layout_config())
        counters = [r.name for r in layout.receptacles if r.category == "counter" and r.room == "kitchen"]
        for r in layout.receptacles:
            on = sorted(o.name for o in layout.objects if o.receptacle == r.name)
            if r.category == "table" and len(on) >= 5 and counters:
                return ep, r.name, tuple(on), counters[0]
        return None

    episodes = load_split("val")
    hinted = [ep for ep in episodes if ep.episode_id == _BUSY_HOME_EPISODE]
    seen = set()
    for ep in hinted + episodes:
        if ep.scene.seed in seen:
            continue
        seen.add(ep.scene.seed)
        if (found := busy_table(ep)) is not None:
            return found
    raise AssertionError("no val home with a busy table and a kitchen counter")


@pytest.fixture(scope="module")
def home():
    """A val home with a kitchen counter and a table full of objects (``home.table``,
    ``home.table_objects``, ``home.counter`` name them)."""
    from tasks.runner import SimEpisode

    episode, table, objects, counter = _pick_home()
    sim = SimEpisode.create(episode)
    sim.table, sim.table_objects, sim.counter = table, objects, counter
    yield sim
    sim.close()


@pytest.fixture(scope="module")
def open_floor():
    """A table with a mug and a can on an open floor (no walls): room for a long distance sweep."""
    world = World()
    table = assets.add_table(world, "table_1", (0.0, 0.0), length=1.0, width=0.7, height=0.72)
    mug = assets.add_mug(world, "mug_1", (-0.15, 0.0, 0.721), radius=0.04, height=0.10)
    can = assets.add_object(world, "can_1", "can", [assets.Part("cylinder", (0.033, 0.12), (0, 0, 0.06))],
                            (0.2, 0.1, 0.721), mass=0.3)
    world.settle([mug, can])
    spot = SpotBody(world, SE2Pose(-30.0, -30.0, 0.0))
    backend = SimSpotBackend(world, spot)
    yield {"world": world, "backend": backend, "table": table, "mug": mug, "can": can}
    backend.close()


def _det_tuple(dets: list[Detection]):
    return [(d.class_name, round(d.score, 12), d.mask.tobytes()) for d in dets]


def _centre(world, body):
    lo, hi = world.aabb(body)
    return (lo + hi) / 2


# --------------------------------------------------------------------------------- determinism
def test_detections_are_deterministic_for_a_seed():
    from tasks.runner import SimEpisode

    episode, table, _objects, _counter = _pick_home()
    names = list(ALL_CATEGORIES)

    def run(seed):
        sim = SimEpisode.create(episode)     # a fresh simulation: the same frames in the same order
        try:
            target = _centre(sim.world, sim.scene.receptacle_ids[table])
            det, scorer = make_sim_perception(sim.backend, seed, rooms=sim.scene.layout.rooms)
            out = []
            for a in (0.3, 1.9, 3.5):
                obs = sim.backend.render_at(camera_around(target, 2.0, a, math.radians(30)))
                first = _det_tuple(det(obs.rgb, obs.depth, names))
                assert _det_tuple(det(obs.rgb, obs.depth, names)) == first      # the same frame twice
                out.append((first, scorer(obs.rgb, [value_prompt("table"), value_prompt("mug")]).tolist()))
            return out
        finally:
            sim.close()

    first = run(11)
    assert sum(len(dets) for dets, _ in first) >= 15
    assert run(11) == first
    assert run(12) != first    # another seed, other draws


def test_the_same_frame_gives_the_same_instance_outcome_whatever_else_is_queried(home):
    obs = home.backend.render_at(camera_around(_centre(home.world, home.scene.receptacle_ids[home.table]),
                                               1.6, 2.0, math.radians(35)))
    det = SimDetector(home.backend, seed=3)
    both = {d.class_name: d.score for d in det(obs.rgb, obs.depth, ["table", "can"])}
    alone = {d.class_name: d.score for d in det(obs.rgb, obs.depth, ["table"])}
    assert "table" in both and both["table"] == alone["table"]


# --------------------------------------------------------------------------------- ground truth
def test_gt_mode_detects_a_fully_visible_large_object_with_its_true_class(home):
    world, backend = home.world, home.backend
    table = home.scene.receptacle_ids[home.table]
    detector, scorer = make_sim_perception(backend, 5, SimPerceptionConfig(mode="gt"), rooms=home.scene.layout.rooms)
    assert isinstance(detector, GroundTruthDetector) and isinstance(scorer, GroundTruthScorer)
    obs = backend.render_at(camera_around(_centre(world, table), 2.8, 3.14, math.radians(35)))
    ids = decode_body_ids(backend.segmentation_for(obs))
    truth = ids == table
    assert truth.sum() > 5000 and not (truth[0].any() or truth[-1].any() or truth[:, 0].any() or truth[:, -1].any())
    dets = detector(obs.rgb, obs.depth, ["table", "counter"])
    tables = [d for d in dets if d.class_name == "table"]
    assert len(tables) == 1
    assert np.array_equal(tables[0].mask, truth) and tables[0].score == 1.0
    assert all(world.bodies[int(np.bincount(ids[d.mask] + 1).argmax() - 1)].category == d.class_name for d in dets)
    # every visible instance of a queried object class, exactly
    on_table = {world.bodies[home.scene.object_ids[n]].category for n in home.table_objects}
    cat = next(world.bodies[b].category for b in np.unique(ids) if b >= 0 and world.bodies[b].category in on_table)
    visible = {b for b in np.unique(ids) if b >= 0 and world.bodies[b].category == cat}
    found = detector(obs.rgb, obs.depth, [cat])
    assert len(found) == len(visible) >= 1 and {d.class_name for d in found} == {cat}
    share = truth.mean()                                          # the scorer: the table's true visibility
    assert scorer(obs.rgb, [value_prompt("table")])[0] == pytest.approx(
        1 - math.exp(-share / SimPerceptionConfig().scorer_saturation_receptacle), abs=1e-9)
    assert share > 0.05 and scorer(obs.rgb, [value_prompt("table")])[0] > 0.45
    in_view = {world.bodies[b].category for b in np.unique(ids) if b >= 0 and b in world.bodies}
    absent = next(c for c in ALL_CATEGORIES if c not in in_view)
    assert scorer(obs.rgb, [value_prompt(absent)])[0] == 0.0


def test_gt_roles_detect_those_classes_exactly_and_leave_the_others_to_the_noisy_detector(home):
    world, backend = home.world, home.backend
    table = home.scene.receptacle_ids[home.table]
    cat = world.bodies[home.scene.object_ids[home.table_objects[0]]].category
    roles = {"object": cat, "start_receptacle": "table", "goal_receptacle": "counter"}
    config = SimPerceptionConfig(gt_roles=("start_receptacle",))
    partly, scorer = make_sim_perception(backend, 5, config, rooms=home.scene.layout.rooms, role_classes=roles)
    noisy = SimDetector(backend, 5, SimPerceptionConfig())
    truth = GroundTruthDetector(backend, SimPerceptionConfig())
    assert isinstance(scorer, SimImageTextScorer)
    query, differed = [cat, "table", "counter"], 0
    for yaw in (0.0, 1.6, 3.14, 4.7):
        obs = backend.render_at(camera_around(_centre(world, table), 2.2, yaw, math.radians(35)))
        out = partly(obs.rgb, obs.depth, query)
        noisy_dets, true_dets = noisy(obs.rgb, obs.depth, query), truth(obs.rgb, obs.depth, ["table"])
        assert _det_tuple([d for d in out if d.class_name == "table"]) == _det_tuple(true_dets)
        assert _det_tuple([d for d in out if d.class_name != "table"]) == \
            _det_tuple([d for d in noisy_dets if d.class_name != "table"])
        differed += _det_tuple([d for d in noisy_dets if d.class_name == "table"]) != _det_tuple(true_dets)
    assert differed >= 1            # the noisy detector's tables are not the truth, so the role matters
    with pytest.raises(ValueError, match="needs the task's classes by role"):
        make_sim_perception(backend, 5, config)


# --------------------------------------------------------------------------------- view-dependent errors
def test_a_bad_viewpoint_bin_repeats_its_wrong_label_while_the_majority_over_8_views_is_right(home):
    world, backend = home.world, home.backend
    det = SimDetector(backend, seed=home.episode.seed)
    elevation, distance = math.radians(40), 1.1
    case = None
    for name in home.table_objects:          # the first object on the table with a bad bin among 8 sides
        body = home.scene.object_ids[name]
        cat = world.bodies[body].category
        query = [cat, *det.confusion.lookalikes(cat)]
        centre = _centre(world, body)
        views = []
        for k in range(8):
            az = k * math.pi / 4 + 0.2
            obs = backend.render_at(camera_around(centre, distance, az, elevation))
            frame = det.analyzer.analyse(obs.rgb)
            if body not in frame.pixels:
                continue
            labels = [d.class_name for d in det(obs.rgb, obs.depth, query)
                      if np.count_nonzero(d.mask & (frame.ids == body)) > 0.3 * frame.pixels[body]]
            views.append((az, det.is_bad_view(frame, body), labels[0] if labels else None))
        if any(bad for _, bad, label in views if label is not None):
            case = (name, body, cat, query, centre, views)
            break
    assert case is not None, "no object on the table has a bad viewpoint bin"
    name, body, cat, query, centre, views = case
    assert len(views) >= 7
    labels = [label for _, _, label in views if label is not None]
    assert Counter(labels).most_common(1)[0][0] == cat, f"{name}: majority over 8 views should be {cat}: {views}"
    good = [label for _, bad, label in views if label is not None and not bad]
    assert sum(label == cat for label in good) >= 0.75 * len(good)     # good views: the true label (rare per-frame slips)
    # the bad bin, seen again and again from slightly different places in it: the same wrong label
    az_bad, _, wrong = next(v for v in views if v[1] and v[2] is not None)
    assert wrong != cat and wrong in query
    repeats = []
    for k, (daz, dd) in enumerate([(-0.06, 0.0), (0.06, 0.05), (0.0, -0.05), (0.04, 0.08), (-0.04, -0.08), (0.0, 0.03)]):
        obs = backend.render_at(camera_around(centre, distance + dd, az_bad + daz, elevation + 0.02 * (k % 2)))
        frame = det.analyzer.analyse(obs.rgb)
        assert det.is_bad_view(frame, body)
        repeats += [d.class_name for d in det(obs.rgb, obs.depth, query)
                    if np.count_nonzero(d.mask & (frame.ids == body)) > 0.3 * frame.pixels.get(body, 1)]
    assert len(repeats) >= 4 and set(repeats) == {wrong}


def test_recall_falls_monotonically_with_distance(open_floor):
    world, backend = open_floor["world"], open_floor["backend"]
    distances = [1.0, 2.0, 3.0, 4.0, 5.5, 7.5]
    seeds = range(16)
    detectors = [SimDetector(backend, seed=s) for s in seeds]
    recall = []
    for d in distances:
        found = total = 0
        for k in range(12):
            for body, cat in ((open_floor["mug"], "mug"), (open_floor["can"], "can")):
                obs = backend.render_at(camera_around(_centre(world, body), d, k * math.pi / 6 + 0.1, math.radians(25)))
                for det in detectors:
                    frame = det.analyzer.analyse(obs.rgb)
                    total += 1
                    found += any(x.class_name == cat and np.count_nonzero(x.mask & (frame.ids == body)) > 0
                                 and x.score >= 0.25 for x in det(obs.rgb, obs.depth, ["mug", "can", "cup", "glass"]))
        recall.append(found / total)
    assert all(a > b for a, b in zip(recall, recall[1:])), f"recall by distance {distances}: {np.round(recall, 3)}"
    assert recall[0] > 0.7 and recall[-1] < 0.15


def test_scores_are_class_conditional_so_thresholds_matter(home):
    """Small objects (receptacle scores overlap more on purpose: test_perception_receptacles.py)."""
    world, backend = home.world, home.backend
    rng = np.random.default_rng(0)
    from sim.perception.views import random_view

    det = SimDetector(backend, seed=2)
    names = list(OBJECT_CATEGORIES)
    right, wrong = [], []
    bodies = [home.scene.object_ids[n] for n in home.table_objects]
    for i in range(60):
        T = random_view(home.scene, world, bodies[i % len(bodies)], rng)
        if T is None:
            continue
        obs = backend.render_at(T)
        ids = decode_body_ids(backend.segmentation_for(obs))
        for d in det(obs.rgb, obs.depth, names):
            b = int(np.bincount(ids[d.mask] + 1).argmax()) - 1
            (right if b >= 0 and world.bodies[b].category == d.class_name else wrong).append(d.score)
    assert len(right) > 50 and len(wrong) > 15
    assert np.median(right) > 0.65 > 0.45 > np.median(wrong)
    # the goal-receptacle threshold (0.45) keeps most right labels and drops most wrong ones
    assert np.mean(np.array(right) >= 0.45) > 0.8 and np.mean(np.array(wrong) >= 0.45) < 0.5


def test_masks_are_noisy_but_close_and_furniture_parts_give_false_positives(home):
    world, backend = home.world, home.backend
    rng = np.random.default_rng(4)
    from sim.perception.views import random_view

    det = SimDetector(backend, seed=9)
    ious, part_fps = [], 0
    table = home.scene.receptacle_ids[home.table]
    for _ in range(40):
        T = random_view(home.scene, world, table, rng)
        if T is None:
            continue
        obs = backend.render_at(T)
        ids = decode_body_ids(backend.segmentation_for(obs))
        for d in det(obs.rgb, obs.depth, ["table", "mug", "cup"]):
            b = int(np.bincount(ids[d.mask] + 1).argmax()) - 1
            if b < 0:
                continue
            if world.bodies[b].kind == "furniture" and d.class_name in ("mug", "cup"):
                part_fps += 1
                if (ids == b).sum() > 500:                        # (not a sliver of furniture at the image edge)
                    assert d.mask.sum() < 0.5 * (ids == b).sum()     # a part of it, not all of it
            elif world.bodies[b].category == d.class_name and (ids == b).sum() > 3000:
                # large masks (a thin table top or its legs seen from afar lose more to the +-2 px morphology)
                truth = ids == b
                ious.append((d.mask & truth).sum() / (d.mask | truth).sum())
    assert len(ious) > 10
    assert 0.75 < np.median(ious) < 0.995     # boundary noise: never pixel-perfect, never far off
    assert part_fps >= 1


# --------------------------------------------------------------------------------- scorer
def _blank_kitchen_wall(home):
    """An observation of a kitchen wall from 0.7 m inside the kitchen showing only walls and floor."""
    world, backend = home.world, home.backend
    room = next(r for r in home.scene.layout.rooms if r.kind == "kitchen" and r.contains(*home.scene.receptacle(
        home.counter).footprint_corners().mean(axis=0)))
    for t in np.linspace(0.15, 0.85, 15):
        for (wx, wy), (nx, ny) in (((room.x0 + t * (room.x1 - room.x0), room.y0), (0, 1)),
                                   ((room.x0 + t * (room.x1 - room.x0), room.y1), (0, -1)),
                                   ((room.x0, room.y0 + t * (room.y1 - room.y0)), (1, 0)),
                                   ((room.x1, room.y0 + t * (room.y1 - room.y0)), (-1, 0))):
            obs = backend.render_at(look_at([wx + 0.75 * nx, wy + 0.75 * ny, 1.0], [wx, wy, 1.0]))
            ids = decode_body_ids(backend.segmentation_for(obs))
            if {world.bodies[b].kind for b in np.unique(ids) if b >= 0} <= {"structure", "ground"}:
                return obs
    raise AssertionError("no blank stretch of kitchen wall")


def test_scorer_ranks_the_kitchen_counter_above_a_blank_wall(home):
    world, backend = home.world, home.backend
    counter = home.scene.receptacle_ids[home.counter]
    c = _centre(world, counter)
    front = home.scene.front(home.counter)
    obs_w = _blank_kitchen_wall(home)          # a kitchen wall 0.7 m away, nothing else in view
    obs_c = backend.render_at(look_at([c[0] + 1.8 * front[0], c[1] + 1.8 * front[1], 1.3], c))
    ids_c = decode_body_ids(backend.segmentation_for(obs_c))
    assert (ids_c == counter).mean() > 0.1
    prompt = [value_prompt("counter"), value_prompt("bed")]
    for seed in range(5):
        for rooms in (home.scene.layout.rooms, None):
            scorer = SimImageTextScorer(backend, seed=seed, rooms=rooms)
            sc, sw = scorer(obs_c.rgb, prompt), scorer(obs_w.rgb, prompt)
            assert sc[0] > sw[0] + 0.3, (seed, sc, sw)
            assert sc[0] > sc[1]                       # a counter view says "counter", not "bed"
            assert np.all((0 <= sc) & (sc <= 1)) and np.all((0 <= sw) & (sw <= 1))
    # the room prior: a kitchen wall suggests a counter more than a bed, by the room gain times the kitchen's
    # share of the view. Noise off: its draw hangs on the frame's number, which depends on how many frames the
    # module's other tests rendered first (xdist's order); with it on, a 0.1 margin failed for 15 of 40 numbers
    quiet = dataclasses.replace(SimPerceptionConfig(), scorer_noise=0.0)
    scorer = SimImageTextScorer(backend, seed=0, config=quiet, rooms=home.scene.layout.rooms)
    s = scorer(obs_w.rgb, prompt)
    kitchen = scorer.room_weights(scorer.analyzer.analyse(obs_w.rgb)).get("kitchen", 0.0)
    assert kitchen >= 0.4
    assert s[0] - s[1] == pytest.approx(quiet.scorer_room_gain * kitchen, abs=1e-9)
    assert s[0] > s[1] + 0.05
    gt = GroundTruthScorer(backend)
    assert gt(obs_c.rgb, prompt)[0] > 0.8 and gt(obs_w.rgb, prompt)[0] == 0.0


# --------------------------------------------------------------------------------- bad input
def test_bad_input_gives_one_clear_error_each(home):
    backend = home.backend
    detector, scorer = make_sim_perception(backend, 0)
    obs = backend.render_at(look_at([7.0, 2.5, 1.2], [7.0, 0.4, 0.6]))
    with pytest.raises(UnknownCategoryError, match=r"unknown class name 'coffee maker'; valid: table, desk"):
        detector(obs.rgb, obs.depth, ["mug", "coffee maker"])
    with pytest.raises(UnknownCategoryError, match="class_names is empty"):
        detector(obs.rgb, obs.depth, [])
    with pytest.raises(UnknownCategoryError, match="single string"):
        detector(obs.rgb, obs.depth, "mug")
    with pytest.raises(PromptError, match="prompt list is empty"):
        scorer(obs.rgb, [])
    with pytest.raises(PromptError, match="cannot interpret prompt 'a counter'"):
        scorer(obs.rgb, ["a counter"])
    with pytest.raises(UnknownCategoryError, match="unknown category 'coffee maker'"):
        scorer(obs.rgb, [value_prompt("coffee maker")])
    with pytest.raises(ImageInputError, match=r"rgb and depth sizes differ: rgb is 320x240 \(W x H\), depth is 160x120"):
        detector(obs.rgb, obs.depth[::2, ::2], ["mug"])
    with pytest.raises(ImageInputError, match="rgb must be an"):
        detector(obs.rgb[..., 0], obs.depth, ["mug"])
    with pytest.raises(PerceptionError, match="not one of the recent frames"):
        detector(obs.rgb.copy(), obs.depth, ["mug"])
    # all of them are ValueErrors the CLI reports in one line
    from tools.cli import user_error_types

    assert issubclass(UnknownCategoryError, user_error_types()) and issubclass(PromptError, user_error_types())


def test_ground_truth_semantics_read_only_the_settings_trials_lets_a_gt_run_set(home, monkeypatch):
    """`tools trials` refuses a -gt run every perception setting outside GT_MODE_READS as one that
    would change nothing; this records what the gt detector and scorer (and their frame analysis)
    really read, so a new read there cannot be refused unnoticed."""
    import sys

    from sim.perception.config import GT_MODE_READS

    reads: set[str] = set()
    plain = object.__getattribute__

    def recording(self, name):
        caller = sys._getframe(1).f_globals.get("__name__", "")
        if caller.startswith("sim.perception") and caller != "sim.perception.config":
            reads.add(name)
        return plain(self, name)

    world, backend = home.world, home.backend
    table = home.scene.receptacle_ids[home.table]
    obs = backend.render_at(camera_around(_centre(world, table), 2.8, 3.14, math.radians(35)))
    monkeypatch.setattr(SimPerceptionConfig, "__getattribute__", recording)
    detector, scorer = make_sim_perception(backend, 5, SimPerceptionConfig(mode="gt"), rooms=home.scene.layout.rooms)
    queries = ["table", "counter", *sorted({world.bodies[home.scene.object_ids[n]].category
                                            for n in home.table_objects})]
    assert detector(obs.rgb, obs.depth, queries)
    assert scorer(obs.rgb, [value_prompt(c) for c in queries]).max() > 0
    fields = {f.name for f in dataclasses.fields(SimPerceptionConfig)}
    assert reads & fields <= GT_MODE_READS, sorted(reads & fields - GT_MODE_READS)
    assert {"mode", "gt_min_pixels", "scorer_saturation_object", "scorer_saturation_receptacle"} <= reads
    # the noisy detector does read what a gt run is refused: the recorder sees it
    reads.clear()
    detector, _ = make_sim_perception(backend, 5, SimPerceptionConfig(), rooms=home.scene.layout.rooms)
    detector(obs.rgb, obs.depth, queries)
    assert {"p_detect_object", "bad_view_object"} <= reads
