"""Pick/place decision rule (paper App. "Once the target object has been detected") and the
place-point heuristics (drop / improved) on synthetic point clouds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from helios.agents.config import PlaceConfig
from helios.agents.place import choose_place_point, region_points
from helios.config import DecisionConfig
from helios.search.decisions import Verdict, decide
from robots.hal import SE2Pose

TAU, TAU_INC = 0.5, 0.05


# ------------------------------------------------------------------------------------ decisions
@pytest.mark.parametrize("psi,predicted,expected", [
    (0.5, None, Verdict.ACT),          # psi >= tau (inclusive), no view needed
    (0.9, 0.1, Verdict.ACT),           # psi >= tau whatever the prediction
    (0.2, 0.26, Verdict.LOOK),         # 0.26 >= min(0.5, 0.2 + 0.05) = 0.25: the tau_inc branch
    (0.2, 0.24, Verdict.IGNORE),       # 0.24 <  0.25
    (0.47, 0.5, Verdict.LOOK),         # 0.5 >= min(0.5, 0.52) = 0.5: the tau branch
    (0.47, 0.51, Verdict.LOOK),
    (0.47, 0.49, Verdict.IGNORE),      # +0.02 neither crosses tau nor reaches tau_inc
    (0.2, None, Verdict.IGNORE),       # no view available
    (0.0, 0.049, Verdict.IGNORE),
    (0.0, 0.051, Verdict.LOOK),
])
def test_decide_reproduces_the_papers_inequalities(psi, predicted, expected):
    assert decide(psi, predicted, TAU, TAU_INC) is expected


def test_decide_with_the_default_thresholds_and_both_branches_of_min():
    cfg = DecisionConfig()
    assert (cfg.tau_object, cfg.tau_goal_receptacle, cfg.tau_increase) == (0.5, 0.5, 0.05)
    # brute-force check against the formula on a grid of values
    for psi in np.linspace(0.0, 0.6, 61):
        for pred in np.linspace(0.0, 0.7, 71):
            if psi >= cfg.tau_object:
                want = Verdict.ACT
            elif pred >= min(cfg.tau_object, psi + cfg.tau_increase):
                want = Verdict.LOOK
            else:
                want = Verdict.IGNORE
            assert decide(float(psi), float(pred), cfg.tau_object, cfg.tau_increase) is want
    # a lower tau (e.g. a goal receptacle threshold) changes which branch of the min applies
    assert decide(0.28, 0.3, 0.3, 0.05) is Verdict.LOOK          # via tau = 0.3
    assert decide(0.28, 0.3, 0.6, 0.05) is Verdict.IGNORE        # needs 0.33
    assert decide(0.3, None, 0.3, 0.05) is Verdict.ACT


# ------------------------------------------------------------------------------------ place
TABLE_Z = 0.70
TABLE = (0.5, 1.0, -0.3, 0.3)            # body frame (robot at the origin facing +x)
BOTTLE = (0.95, 1.0, 0.22, 0.30)         # a tall object at the table's far-left corner


def grid_points(x0, x1, y0, y1, z, step=0.01):
    xs, ys = np.meshgrid(np.arange(x0, x1 + 1e-9, step), np.arange(y0, y1 + 1e-9, step))
    return np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)], axis=1)


def table_scene() -> np.ndarray:
    table = grid_points(*TABLE, TABLE_Z)
    bottle = np.concatenate([grid_points(*BOTTLE, z) for z in (0.8, 0.9, 0.95)])
    return np.concatenate([table, bottle])


def edge_distance(xy) -> float:
    x, y = xy[0], xy[1]
    return min(x - TABLE[0], TABLE[1] - x, y - TABLE[2], TABLE[3] - y)


def in_box(xy, box, pad=0.0) -> bool:
    return box[0] - pad <= xy[0] <= box[1] + pad and box[2] - pad <= xy[1] <= box[3] + pad


def to_world(points_body, pose: SE2Pose) -> np.ndarray:
    T = pose.to_matrix()
    return points_body @ T[:3, :3].T + T[:3, 3]


def to_body(point_world, pose: SE2Pose) -> np.ndarray:
    T = pose.to_matrix()
    return (np.asarray(point_world) - T[:3, 3]) @ T[:3, :3]


POSES = [SE2Pose(0.0, 0.0, 0.0), SE2Pose(3.0, -1.0, 2.0), SE2Pose(-2.0, 4.0, -math.pi / 2)]


@pytest.mark.parametrize("pose", POSES)
def test_drop_picks_the_highest_point_in_front(pose):
    pts = to_world(table_scene(), pose)
    cfg = PlaceConfig(mode="drop")
    t = choose_place_point(pts, pose.to_matrix(), cfg)
    assert t is not None
    assert t.point[2] == pytest.approx(0.95)                 # the bottle's top
    assert t.release_height == pytest.approx(cfg.drop_height) == pytest.approx(0.10)
    assert in_box(to_body(t.point, pose), BOTTLE, pad=1e-9)
    assert t.n_points == len(pts)


def test_drop_ignores_a_single_stray_high_point():
    pts = np.concatenate([grid_points(*TABLE, TABLE_Z), [[0.7, 0.0, 1.4]]])
    t = choose_place_point(pts, np.eye(4), PlaceConfig(mode="drop"))
    assert t.point[2] == pytest.approx(TABLE_Z)


@pytest.mark.parametrize("pose", POSES)
def test_improved_picks_an_interior_point_of_the_top_surface(pose):
    pts = to_world(table_scene(), pose)
    drop = choose_place_point(pts, pose.to_matrix(), PlaceConfig(mode="drop"))
    cfg = PlaceConfig(mode="improved")
    t = choose_place_point(pts, pose.to_matrix(), cfg)
    assert t is not None
    assert t.point[2] == pytest.approx(TABLE_Z, abs=1e-6)     # on the table, not on the bottle
    assert t.release_height == pytest.approx(cfg.improved_height) == pytest.approx(0.02)
    body = to_body(t.point, pose)
    assert in_box(body, TABLE)
    assert not in_box(body, BOTTLE, pad=0.05)
    assert edge_distance(body) > edge_distance(to_body(drop.point, pose)) + 0.1
    assert edge_distance(body) >= 0.2                          # the table is 0.6 m wide: near its middle
    assert t.n_points <= len(pts)


def test_improved_on_a_plain_table_is_its_middle():
    pts = grid_points(*TABLE, TABLE_Z)
    t = choose_place_point(pts, np.eye(4), PlaceConfig(mode="improved"))
    # the 0.5 x 0.6 m rectangle's most interior points (0.25 m from every edge) are x = 0.75,
    # |y| <= 0.05; allow a surface cell or two of rasterisation
    assert t.point[0] == pytest.approx(0.75, abs=0.03)
    assert abs(t.point[1]) <= 0.05 + 0.03
    assert edge_distance(t.point) >= 0.22


@pytest.mark.parametrize("mode", ["drop", "improved"])
def test_points_outside_the_region_are_ignored(mode):
    cfg = PlaceConfig(mode=mode)
    x0, x1, y0, y1 = cfg.region
    pose = SE2Pose(1.0, 2.0, 0.7)
    inside = table_scene()
    # a tall shelf just beyond the region, one beside it and one behind the robot: all ignored
    outside = np.concatenate([grid_points(x1 + 0.02, x1 + 0.5, -0.3, 0.3, 1.6),
                              grid_points(0.5, 1.0, y1 + 0.02, y1 + 0.4, 1.6),
                              grid_points(-1.0, -0.5, -0.3, 0.3, 1.6)])
    pts = to_world(np.concatenate([inside, outside]), pose)
    kept = region_points(pts, pose.to_matrix(), cfg)
    assert len(kept) == len(inside)
    np.testing.assert_allclose(np.sort(kept[:, 2]), np.sort(inside[:, 2]))
    t = choose_place_point(pts, pose.to_matrix(), cfg)
    ref = choose_place_point(to_world(inside, pose), pose.to_matrix(), cfg)
    assert t.point[2] < 1.0
    np.testing.assert_allclose(t.point, ref.point, atol=1e-9)
    assert in_box(to_body(t.point, pose), (x0, x1, y0, y1))


@pytest.mark.parametrize("mode", ["drop", "improved"])
def test_none_with_fewer_than_five_points(mode):
    cfg = PlaceConfig(mode=mode)
    four = grid_points(0.7, 0.71, 0.0, 0.01, TABLE_Z)
    assert len(four) == 4
    assert choose_place_point(four, np.eye(4), cfg) is None
    five = np.concatenate([four, [[0.8, 0.1, TABLE_Z]]])
    assert choose_place_point(five, np.eye(4), cfg) is not None
    # many points, but fewer than five in the region
    behind = grid_points(-1.0, -0.5, -0.3, 0.3, TABLE_Z)
    assert choose_place_point(np.concatenate([behind, four]), np.eye(4), cfg) is None
    assert choose_place_point(np.zeros((0, 3)), np.eye(4), cfg) is None
    assert len(region_points(np.zeros((0, 3)), np.eye(4), cfg)) == 0


def test_place_config_validation():
    for bad in (dict(mode="throw"), dict(improved_height=1.2), dict(drop_height=-0.1),
                dict(region=(1.0, 0.5, -0.3, 0.3))):
        with pytest.raises(ValueError):
            PlaceConfig(**bad)
    # each mode reads its own height: an improved height above the drop's is no contradiction
    assert PlaceConfig(mode="improved", improved_height=0.2, drop_height=0.1).improved_height == 0.2
