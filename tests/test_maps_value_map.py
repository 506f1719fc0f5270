"""VLFM-style value maps: cone confidence, fusion rule, occlusion, layer handling."""

import math

import numpy as np
import pytest

from helios.config import OccupancyConfig, ValueMapConfig
from helios.maps import GridGeometry, MapInputError, ValueMap
from helios.maps.ground_view import project_to_ground
from robots.transforms import look_at_camera as look_at
from sim.synthetic_boxes import Box, pinhole, render_boxes

CAM = pinhole(160, 120)
OCC = OccupancyConfig(grid_size=400, origin_xy=(-5.0, -5.0))
GEO = GridGeometry.from_config(OCC)
FLOOR = Box((-10.0, -10.0, -0.02), (10.0, 10.0, 0.0), "floor")
POSE = look_at([0.0, 0.0, 1.0], [1.0, 0.0, 1.0 - math.tan(math.radians(15))])   # facing +x


def view_of(boxes, pose=POSE):
    _, depth, _ = render_boxes(boxes, CAM, pose)
    return project_to_ground(depth, CAM, pose, GEO, OCC)


def cell(x, y):
    r, c = GEO.world_to_cell(np.array([x, y]))
    return int(r), int(c)


def test_confidence_is_one_on_the_axis_and_min_at_the_field_of_view_edge():
    vmap = ValueMap(["table"], GEO, ValueMapConfig())
    view = view_of([FLOOR])
    conf = vmap.cone_confidence(view)
    r0, _, c0, _ = view.window
    r, c = cell(3.0, 0.0)
    assert conf[r - r0, c - c0] == pytest.approx(1.0, abs=0.01)
    edge = math.radians(29.0)                                  # hfov is 60 deg
    r, c = cell(3.0 * math.cos(edge), 3.0 * math.sin(edge))
    assert 0.25 <= conf[r - r0, c - c0] < 0.3
    assert conf[view.visible].min() >= 0.25 and conf[~view.visible].max() == 0.0


def test_weighted_fusion_follows_the_vlfm_rule():
    vmap = ValueMap(["table", "counter"], GEO, ValueMapConfig())
    view = view_of([FLOOR])
    r, c = cell(3.0, 0.0)
    vmap.fuse(view, {"table": 0.2, "counter": 0.9})
    c1 = float(vmap.confidence[r, c])
    assert vmap.values[:, r, c] == pytest.approx([0.2, 0.9])
    vmap.fuse(view, {"table": 0.6, "counter": 0.1})
    assert vmap.values[:, r, c] == pytest.approx([0.4, 0.5])              # equal confidences: mean
    assert float(vmap.confidence[r, c]) == pytest.approx(c1)              # (c^2 + c^2) / 2c = c
    vmap.fuse(view, [1.0, 0.5])
    assert vmap.layer("table")[r, c] == pytest.approx(0.7)


def test_low_confidence_views_do_not_dilute_high_confidence_ones():
    vmap = ValueMap(["table"], GEO, ValueMapConfig())
    vmap.fuse(view_of([FLOOR]), [0.9])
    r, c = cell(3.0, 0.0)
    # a camera turned 28 deg away sees the cell near its edge (confidence < 0.35)
    yaw = math.radians(28.0)
    turned = look_at([0.0, 0.0, 1.0], [math.cos(yaw), math.sin(yaw), 1.0 - math.tan(math.radians(15))])
    v = view_of([FLOOR], turned)
    r0, _, c0, _ = v.window
    assert 0 < vmap.cone_confidence(v)[r - r0, c - c0] < 0.35
    vmap.fuse(v, [0.0])
    assert vmap.values[0, r, c] == pytest.approx(0.9)


def test_max_confidence_fusion_keeps_the_best_view():
    vmap = ValueMap(["table"], GEO, ValueMapConfig(fusion="max_confidence"))
    view = view_of([FLOOR])
    vmap.fuse(view, [0.3])
    vmap.fuse(view, [0.8])                                   # same confidence: not better, ignored
    r, c = cell(3.0, 0.0)
    assert vmap.values[0, r, c] == pytest.approx(0.3)


def test_cells_beyond_the_depth_return_are_not_updated():
    wall = Box((1.5, -5.0, 0.0), (1.6, 5.0, 3.0), "wall")
    vmap = ValueMap(["table"], GEO, ValueMapConfig())
    vmap.fuse(view_of([FLOOR, wall]), [0.8])
    front, behind = cell(1.0, 0.0), cell(2.5, 0.0)
    assert vmap.confidence[front] > 0.9 and vmap.values[0][front] == pytest.approx(0.8)
    assert vmap.confidence[behind] == 0.0 and vmap.values[0][behind] == 0.0


def test_value_near_reads_the_median_of_seen_cells():
    vmap = ValueMap(["table"], GEO, ValueMapConfig())
    vmap.fuse(view_of([FLOOR]), [0.6])
    assert vmap.value_near(np.array([3.0, 0.0]), 0.5)[0] == pytest.approx(0.6)
    assert np.isnan(vmap.value_near(np.array([-3.0, 0.0]), 0.5)[0])         # behind the camera: unseen


def test_scores_must_name_exactly_the_layers():
    vmap = ValueMap(["table", "counter"], GEO, ValueMapConfig())
    view = view_of([FLOOR])
    with pytest.raises(MapInputError, match=r"missing \['counter'\], unknown \['sofa'\]"):
        vmap.fuse(view, {"table": 0.1, "sofa": 0.2})
    with pytest.raises(MapInputError, match="got 3 value-map scores for 2 layers"):
        vmap.fuse(view, [0.1, 0.2, 0.3])
    with pytest.raises(MapInputError, match="finite"):
        vmap.fuse(view, [0.1, float("nan")])
    with pytest.raises(MapInputError, match="unknown value-map layer 'sofa'"):
        vmap.layer("sofa")
    with pytest.raises(MapInputError, match="unique"):
        ValueMap(["table", "table"], GEO, ValueMapConfig())
