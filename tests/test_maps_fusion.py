"""The paper's multi-view fusion example (Fig. 'Example of multi-view fusion') end to end.

A toy rocket on a table is detected as "knife" in the first view and as background ("other") in
the second; the table is detected as "table" in both. Fusing the second view lowers the rocket's
knife probability and raises the table's table probability, and the table's uncertainty keeps
falling as consistent views accumulate.
"""

import numpy as np
import pytest

from helios.config import HeliosConfig
from helios.schema import with_overrides
from helios.maps.hierarchical import HierarchicalMap
from helios.perception.detection import Detection
from robots.hal import Observation
from robots.transforms import look_at_camera as look_at
from sim.synthetic_boxes import Box, pinhole, render_boxes

CAM = pinhole(160, 120)
FLOOR = Box((-2.0, -3.0, -0.02), (5.0, 3.0, 0.0), "floor")
TABLE = Box((1.5, -0.5, 0.0), (2.5, 0.5, 0.7), "table")
ROCKET = Box((1.96, -0.04, 0.7), (2.04, 0.04, 0.95), "rocket")
SCENE = [FLOOR, TABLE, ROCKET]
VIEWS = [look_at(eye, [2.0, 0.0, 0.75]) for eye in
         ([0.3, 0.0, 1.4], [0.6, -1.0, 1.4], [0.4, 0.7, 1.5], [0.5, -0.4, 1.3], [0.3, 0.3, 1.4])]


def observe(hmap, pose, rocket_label):
    rgb, depth, hit = render_boxes(SCENE, CAM, pose)
    obs = Observation(rgb=rgb, depth=depth, intrinsics=CAM, T_world_cam=pose, T_world_body=np.eye(4), stamp=0.0)
    detections = [Detection(hit == 1, "table", 0.8), Detection(hit == 2, rocket_label, 0.4)]
    return hmap.update(obs, detections, {"table": 0.5})


def by_id(hmap, instance_id):
    return next(i for i in hmap.instances() if i.id == instance_id)


def test_wrong_detection_fades_and_consistent_detection_strengthens():
    hmap = HierarchicalMap(with_overrides(HeliosConfig(), ["occupancy.grid_size=400"]), ["knife", "table"], ["table"])
    observe(hmap, VIEWS[0], "knife")
    first = {i.class_name: i for i in hmap.instances()}
    assert set(first) == {"knife", "table"}
    rocket1, table1 = first["knife"], first["table"]
    assert rocket1.id != table1.id
    assert rocket1.n_gaussians > 20 and table1.n_gaussians > 1000
    # the knife instance is the rocket: its Gaussians sit on the rocket, on or above the table top
    on_rocket = hmap.objects.means.numpy()[rocket1.gaussian_indices]
    assert np.all(on_rocket[:, 2] > 0.7 - 1e-3) and np.all(np.abs(on_rocket[:, :2] - [2.0, 0.0]) < 0.08)

    knife_before = hmap.objects.expectations()[rocket1.gaussian_indices, 0].mean().item()

    observe(hmap, VIEWS[1], "other")
    rocket2, table2 = by_id(hmap, rocket1.id), by_id(hmap, table1.id)
    # the object's knife probability (its view-1 Gaussians) drops; the instance keeps its id
    knife_after = hmap.objects.expectations()[rocket1.gaussian_indices, 0].mean().item()
    assert knife_after < knife_before - 0.1
    assert rocket2.class_scores["knife"] < rocket1.class_scores["knife"] - 0.1
    assert rocket2.class_scores["other"] > rocket1.class_scores["other"]
    assert table2.class_scores["table"] > table1.class_scores["table"]
    assert table2.psi["table"] > table1.psi["table"]

    # expectations of every Gaussian sum to one
    np.testing.assert_allclose(hmap.objects.expectations().sum(dim=1).numpy(), 1.0, atol=1e-12)
    # instance-level scores too
    assert sum(table2.class_scores.values()) == pytest.approx(1.0, abs=1e-12)

    # variance falls as consistent views of the table accumulate
    uncertainty = [table1.uncertainties["table"], table2.uncertainties["table"]]
    for pose in VIEWS[2:]:
        observe(hmap, pose, "other")
        uncertainty.append(by_id(hmap, table1.id).uncertainties["table"])
    assert all(b < a for a, b in zip(uncertainty, uncertainty[1:])), uncertainty
    assert uncertainty[-1] < 0.7 * uncertainty[0]
