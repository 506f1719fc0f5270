"""Instance clustering (0.5 m voxels, 26-connectivity, per class) and stable labels."""

import numpy as np
import pytest

from helios.config import HeliosConfig
from helios.maps import ClassSet, GridGeometry
from helios.maps.gaussians import GaussianMap
from helios.maps.instances import assign_instances, summarize_instances
from helios.maps.labels import label_detections
from helios.perception.detection import Detection
from robots.transforms import look_at_camera as look_at
from sim.synthetic_boxes import Box, pinhole, render_boxes


def blob(centre, n=20, spread=0.1, seed=0):
    return np.asarray(centre) + np.random.default_rng(seed).uniform(-spread, spread, size=(n, 3))


def test_objects_two_metres_apart_get_different_labels_and_touching_ones_share_one():
    means = np.concatenate([blob([1.0, 1.0, 0.5]), blob([3.0, 1.0, 0.5]), blob([3.4, 1.2, 0.5])])
    ids, next_id = assign_instances(means, np.zeros(60, dtype=np.int64), np.full(60, -1), np.ones(60, bool), 0.5, 0)
    assert len(set(ids[:20])) == 1 and len(set(ids[20:])) == 1
    assert ids[0] != ids[20] and next_id == 2


def test_same_place_different_class_are_different_instances():
    means = np.concatenate([blob([1.0, 1.0, 0.5]), blob([1.0, 1.0, 0.7])])
    cls = np.r_[np.zeros(20, dtype=np.int64), np.ones(20, dtype=np.int64)]
    ids, _ = assign_instances(means, cls, np.full(40, -1), np.ones(40, bool), 0.5, 0)
    assert ids[0] != ids[20] and len(set(ids)) == 2


def test_a_new_part_next_to_an_untouched_instance_joins_it():
    old = blob([1.0, 1.0, 0.5])
    new = blob([1.6, 1.0, 0.5], seed=1)                      # adjacent voxel, no overlap
    means = np.concatenate([old, new])
    prev = np.r_[np.full(20, 7), np.full(20, -1)]
    updated = np.r_[np.zeros(20, bool), np.ones(20, bool)]   # only the new part was seen
    ids, next_id = assign_instances(means, np.zeros(40, dtype=np.int64), prev, updated, 0.5, 8)
    assert np.all(ids == 7) and next_id == 8


def test_untouched_instances_keep_their_labels():
    means = np.concatenate([blob([1.0, 1.0, 0.5]), blob([5.0, 5.0, 0.5])])
    prev = np.r_[np.full(20, 3), np.full(20, 4)]
    updated = np.r_[np.ones(20, bool), np.zeros(20, bool)]
    ids, _ = assign_instances(means, np.zeros(40, dtype=np.int64), prev, updated, 0.5, 5)
    assert np.all(ids[:20] == 3) and np.all(ids[20:] == 4)


def test_merge_keeps_the_bigger_label_and_split_leaves_it_with_the_bigger_part():
    small, big = blob([1.0, 1.0, 0.5], n=10), blob([2.0, 1.0, 0.5], n=30, seed=1)
    bridge = np.stack([np.linspace(1.1, 1.9, 5), np.full(5, 1.0), np.full(5, 0.5)], axis=1)
    means = np.concatenate([small, big, bridge])
    prev = np.r_[np.full(10, 0), np.full(30, 1), np.full(5, -1)]
    ids, next_id = assign_instances(means, np.zeros(45, dtype=np.int64), prev, np.ones(45, bool), 0.5, 2)
    assert np.all(ids == 1) and next_id == 2                 # the paper's min rule would relabel all to 0

    apart = np.concatenate([blob([1.0, 1.0, 0.5], n=10), blob([4.0, 1.0, 0.5], n=30, seed=1)])
    ids, next_id = assign_instances(apart, np.zeros(40, dtype=np.int64), np.full(40, 5), np.ones(40, bool), 0.5, 6)
    assert np.all(ids[10:] == 5) and np.all(ids[:10] == 6) and next_id == 7


def test_labels_persist_when_a_new_view_extends_an_object():
    cfg = HeliosConfig()
    classes = ClassSet.from_task(["counter"])
    gmap = GaussianMap(classes, cfg.gaussians, cfg.instances, cfg.scoring, GridGeometry(0.025, 600, -5, -5))
    cam = pinhole(160, 120, hfov_deg=50)
    floor = Box((-2.0, -4.0, -0.02), (6.0, 6.0, 0.0), "floor")
    counter = Box((2.0, -2.0, 0.0), (2.6, 2.0, 0.9), "counter")     # 4 m long
    views = [look_at([0.8, y, 1.3], [2.3, y, 0.9]) for y in (-1.6, -0.5, 0.6, 1.6)]   # walking along it
    seen_y = []
    for pose in views:
        rgb, depth, hit = render_boxes([floor, counter], cam, pose)
        lab = label_detections([Detection(hit == 1, "counter", 0.9)], classes, depth.shape)
        n_before = len(gmap)
        gmap.update(depth, cam, pose, lab.labels, lab.objects, rgb)
        seen_y.append(gmap.means.numpy()[n_before:, 1])
    # each view adds Gaussians only on a stretch of the counter the map did not model yet...
    for before, after in zip(seen_y, seen_y[1:]):
        assert after.size > 500 and np.median(after) > before.max() - 0.05
    # ...and all Gaussians stay one instance with the first view's label
    instances = gmap.instances()
    assert [i.id for i in instances] == [0] and instances[0].class_name == "counter"
    assert instances[0].n_gaussians == len(gmap)
    assert instances[0].footprint_xy[:, 1].min() < -1.0 and instances[0].footprint_xy[:, 1].max() > 1.0
    assert instances[0].max_height == pytest.approx(0.9, abs=0.01)


def test_two_detected_cups_two_metres_apart_are_two_instances():
    cfg = HeliosConfig()
    classes = ClassSet.from_task(["cup"])
    gmap = GaussianMap(classes, cfg.gaussians, cfg.instances, cfg.scoring, GridGeometry(0.025, 600, -5, -5))
    cam = pinhole(160, 120, hfov_deg=70)
    cups = [Box((3.0, -1.1, 0.0), (3.2, -0.9, 0.3), "cup"), Box((3.0, 0.9, 0.0), (3.2, 1.1, 0.3), "cup")]
    pose = look_at([0.0, 0.0, 1.0], [3.0, 0.0, 0.2])
    rgb, depth, hit = render_boxes(cups, cam, pose)
    lab = label_detections([Detection(hit == k, "cup", 0.9) for k in (0, 1)], classes, depth.shape)
    gmap.update(depth, cam, pose, lab.labels, lab.objects, rgb)
    instances = gmap.instances()
    assert len(instances) == 2 and instances[0].id != instances[1].id
    centres = sorted(i.centre[1] for i in instances)
    assert centres[0] == pytest.approx(-1.0, abs=0.1) and centres[1] == pytest.approx(1.0, abs=0.1)
    assert all(i.class_name == "cup" and i.psi["cup"] == pytest.approx(i.class_scores["cup"] - i.uncertainties["cup"])
               for i in instances)


def test_an_instance_takes_the_mode_class_not_the_argmax_of_its_mean_scores():
    """An instance's class is the most common of its Gaussians' most likely classes; its mean
    scores S_c may favour another class (here one confident chair Gaussian outweighs two that
    lean table)."""
    classes = ClassSet.from_task(["table", "chair"])                                  # table, chair, other
    exp = np.array([[0.40, 0.35, 0.25], [0.40, 0.35, 0.25], [0.0, 1.0, 0.0]])       # S = (0.267, 0.567, 0.167)
    means = np.array([[0.0, 0.0, 0.7], [0.1, 0.0, 0.7], [0.2, 0.0, 0.7]])
    inst, = summarize_instances(means, exp, np.full((3, 3), 0.1), exp.argmax(axis=1), np.zeros(3, dtype=int),
                                classes, 1.0, GridGeometry(0.025, 100, -1, -1))
    assert inst.class_scores["chair"] > inst.class_scores["table"]
    assert inst.class_name == "table"                                                 # 2 of 3 Gaussians vote table
