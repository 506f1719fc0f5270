"""Receptacles in the simulated detector are as fallible as a real open-vocabulary detector's:
look-alike labels between furniture categories (table / desk / counter, chair / stool / sofa,
shelf / cabinet / filing cabinet, bed / sofa), phantom receptacles on parts of other furniture, and
overlapping score distributions; all seeded per (seed, body, viewpoint bin), and none of it in
ground-truth mode. Hand-built views of single pieces of furniture on an open floor."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robots.hal import SE2Pose
from robots.spot.sim_backend import SimSpotBackend
from sim import assets
from sim.perception import SimDetector, SimPerceptionConfig, make_sim_perception
from sim.perception.geometry import camera_around
from sim.scenes.catalog import RECEPTACLE_CATEGORIES, make_receptacle
from sim.spot import SpotBody
from sim.world import World

SEEDS = range(24)


@pytest.fixture(scope="module")
def furniture():
    """A table, a sofa and a cabinet far apart on an open floor, and views of each from 24 sides."""
    world = World()
    rng = np.random.default_rng(1)
    bodies = {}
    for name, category, xy in (("table_1", "table", (0.0, 0.0)), ("sofa_1", "sofa", (12.0, 0.0)),
                               ("cabinet_1", "cabinet", (0.0, 12.0))):
        m = make_receptacle(category, rng)
        bodies[name] = assets.add_static(world, name, category, m.parts, (*xy, 0.0), 0.0, m.color)
    spot = SpotBody(world, SE2Pose(-40.0, -40.0, 0.0))
    backend = SimSpotBackend(world, spot)
    yield {"world": world, "backend": backend, "bodies": bodies}
    backend.close()


def _centre(world, body):
    lo, hi = world.aabb(body)
    return (lo + hi) / 2


def _views(world, body, n=24):
    """n cameras around a body: every 15 degrees of azimuth, two distances, two heights."""
    c = _centre(world, body)
    out = []
    for k in range(n):
        d = 2.2 if k % 2 else 3.4
        el = math.radians(25 if k % 4 < 2 else 40)
        out.append(camera_around(c, d, k * 2 * math.pi / n + 0.05, el))
    return out


def test_receptacle_lookalikes_occur_at_about_the_configured_rate_and_persist(furniture):
    """The table seen from 24 sides by 24 seeds: its bad viewpoint bins come at the configured
    rate, give a look-alike label (desk / counter), and give it again from the same bin."""
    world, backend = furniture["world"], furniture["backend"]
    table = furniture["bodies"]["table_1"]
    config = SimPerceptionConfig()
    detectors = [SimDetector(backend, seed=s, config=config) for s in SEEDS]
    expected, bad, wrong_in_bad, detected_in_bad, slips, good = [], 0, 0, 0, 0, 0
    for T in _views(world, table):
        obs = backend.render_at(T)
        for det in detectors:
            frame = det.analyzer.analyse(obs.rgb)
            view = frame.view(table)
            expected.append(det.bad_view_probability("table", view))
            labels = [d.class_name for d in det(obs.rgb, obs.depth, ["table", "desk", "counter"])
                      if np.count_nonzero(d.mask & (frame.ids == table)) > 0.5 * d.mask.sum()
                      and d.mask.sum() > 0.6 * frame.pixels[table]]
            if det.is_bad_view(frame, table):
                bad += 1
                detected_in_bad += bool(labels)
                wrong_in_bad += bool(labels) and all(lb in ("desk", "counter") for lb in labels)
            else:
                good += bool(labels)
                slips += bool(labels) and labels[0] != "table"
    n = len(expected)
    rate, p = bad / n, float(np.mean(expected))
    assert p >= 0.15                                       # receptacles are no longer nearly infallible
    assert abs(rate - p) < 3 * math.sqrt(p * (1 - p) / n) + 0.02, (rate, p)
    assert detected_in_bad >= 0.7 * bad and wrong_in_bad == detected_in_bad   # bad view: a look-alike, always
    slip_rate = slips / good
    assert 0.3 * config.transient_confusion_receptacle < slip_rate < 2.0 * config.transient_confusion_receptacle


def test_phantom_receptacles_appear_on_parts_of_other_furniture(furniture):
    """A chair is 'seen' on part of the sofa (its look-alike) from some viewpoint bins: a region of
    the sofa, not the whole of it, at about the configured rate, and never with the part rate at 0."""
    world, backend = furniture["world"], furniture["backend"]
    sofa = furniture["bodies"]["sofa_1"]
    config = SimPerceptionConfig()
    detectors = [SimDetector(backend, seed=s, config=config) for s in SEEDS]
    off = [SimDetector(backend, seed=s, config=SimPerceptionConfig(receptacle_part_false_positive=0.0))
           for s in SEEDS]
    phantoms, frames, expected = 0, 0, []
    weights = detectors[0].confusion.weights("sofa")
    share = weights["chair"] / sum(weights.get(c, config.receptacle_part_unrelated)
                                   for c in RECEPTACLE_CATEGORIES if c != "sofa")
    for T in _views(world, sofa):
        obs = backend.render_at(T)
        for det, det_off in zip(detectors, off):
            frame = det.analyzer.analyse(obs.rgb)
            frames += 1
            p_det, _ = det.detection_probability(frame, sofa)
            expected.append(config.receptacle_part_false_positive * share * p_det)
            # the whole sofa labelled "chair" is a look-alike label (a bad view); a phantom is a part of it
            chairs = [d for d in det(obs.rgb, obs.depth, ["chair"]) if d.mask.sum() < 0.6 * frame.pixels[sofa]]
            for d in chairs:
                assert np.count_nonzero(d.mask & (frame.ids == sofa)) == d.mask.sum()   # on the sofa only
            phantoms += len(chairs)
            assert not [d for d in det_off(obs.rgb, obs.depth, ["chair"]) if d.mask.sum() < 0.6 * frame.pixels[sofa]]
            # the phantom does not depend on what else is asked for
            with_more = [d for d in det(obs.rgb, obs.depth, ["chair", "table", "mug"])
                         if d.class_name == "chair" and d.mask.sum() < 0.6 * frame.pixels[sofa]]
            assert [(d.score, d.mask.tobytes()) for d in with_more] == [(d.score, d.mask.tobytes()) for d in chairs]
    # reported when the score clears min_score (nearly always): about the expected count
    exp = float(np.sum(expected))
    assert phantoms >= 5 and 0.5 * exp < phantoms < 1.3 * exp + 3, (phantoms, exp)


def test_true_and_false_receptacle_scores_overlap(furniture):
    """Right labels score higher on average, but od_a = 0.35 cuts into both distributions."""
    world, backend = furniture["world"], furniture["backend"]
    detectors = [SimDetector(backend, seed=s) for s in SEEDS]
    right, wrong = [], []
    names = list(RECEPTACLE_CATEGORIES)
    for name, body in furniture["bodies"].items():
        for T in _views(world, body, 12):
            obs = backend.render_at(T)
            for det in detectors:
                frame = det.analyzer.analyse(obs.rgb)
                for d in det(obs.rgb, obs.depth, names):
                    b = int(np.bincount(frame.ids[d.mask] + 1).argmax()) - 1
                    (right if b == body and world.bodies[b].category == d.class_name else wrong).append(d.score)
    right, wrong = np.array(right), np.array(wrong)
    assert len(right) > 200 and len(wrong) > 100
    assert np.median(right) > np.median(wrong) + 0.1
    # Transient confusions are keyed by the backend's frame number, which depends on how many
    # frames the module's shared fixture rendered before this test (xdist order): over 8 frame
    # offsets the share of right labels under od_a was 0.085-0.133 and of wrong ones over it
    # 0.61-0.69 (a 0.1 bound failed run alone), so the bounds say "a real share", not a rate.
    assert np.mean(right < 0.35) > 0.05 and np.mean(wrong >= 0.35) > 0.3


def test_ground_truth_mode_stays_perfect_for_receptacles(furniture):
    world, backend = furniture["world"], furniture["backend"]
    for seed in (0, 1, 2):
        detector, _ = make_sim_perception(backend, seed, SimPerceptionConfig(mode="gt"))
        for name, body in furniture["bodies"].items():
            cat = world.bodies[body].category
            for T in _views(world, body, 8):
                obs = backend.render_at(T)
                ids = detector.analyzer.analyse(obs.rgb).ids
                dets = detector(obs.rgb, obs.depth, list(RECEPTACLE_CATEGORIES))
                visible = {int(b) for b in np.unique(ids) if b >= 0 and world.bodies[b].kind == "furniture"}
                assert sorted(d.class_name for d in dets) == sorted(world.bodies[b].category for b in visible)
                for d in dets:
                    b = int(np.bincount(ids[d.mask] + 1).argmax()) - 1
                    assert np.array_equal(d.mask, ids == b) and d.score == 1.0
                others = [c for c in RECEPTACLE_CATEGORIES if c != cat]
                assert all(world.bodies[int(np.bincount(ids[d.mask] + 1).argmax()) - 1].category != cat
                           for d in detector(obs.rgb, obs.depth, others))


def test_receptacle_errors_are_deterministic_per_seed(furniture):
    """Two detectors with the same seed see the same frames the same way; another seed does not
    (per-frame draws are keyed by the frame id, so each frame is run through all three)."""
    world, backend = furniture["world"], furniture["backend"]
    views = [T for body in furniture["bodies"].values() for T in _views(world, body, 6)]
    names = list(RECEPTACLE_CATEGORIES)
    a, b, c = SimDetector(backend, seed=5), SimDetector(backend, seed=5), SimDetector(backend, seed=6)
    out = {id(d): [] for d in (a, b, c)}
    for T in views:
        obs = backend.render_at(T)
        for d in (a, b, c):
            out[id(d)].append([(x.class_name, round(x.score, 12), x.mask.tobytes())
                               for x in d(obs.rgb, obs.depth, names)])
    assert sum(map(len, out[id(a)])) >= 20
    assert out[id(a)] == out[id(b)]
    assert out[id(a)] != out[id(c)]
    assert [a.phantom_receptacle(k, "sofa", 7) for k in range(50)] == [b.phantom_receptacle(k, "sofa", 7) for k in range(50)]
    assert [a.phantom_receptacle(k, "sofa", 7) for k in range(50)] != [c.phantom_receptacle(k, "sofa", 7) for k in range(50)]
