"""Gaze points for local search (paper Sec. "Local search") on synthetic occupancy grids."""

from __future__ import annotations

import math

import numpy as np
import pytest

from helios.maps.grid import GridGeometry
from helios.planning.footprint import FootprintChecker, FootprintConfig
from helios.search.gaze_points import GazeConfig, GazePoint, contour_points, gaze_points, line_of_sight
from robots.hal import SE2Pose
from robots.transforms import wrap_angle

GEO = GridGeometry(0.025, 400, -5.0, -5.0)
TABLE = (-0.5, 0.5, -0.3, 0.3)          # a 1.0 x 0.6 m table at the origin, 0.75 m tall
TOP = 0.75


class Grid:
    def __init__(self):
        self.obstacle = np.zeros(GEO.shape, dtype=bool)
        self.max_height = np.zeros(GEO.shape, dtype=np.float32)

    def box(self, x0, x1, y0, y1, h):
        s = (slice(int(math.floor((y0 + 5) / 0.025)), int(math.ceil((y1 + 5) / 0.025))),
             slice(int(math.floor((x0 + 5) / 0.025)), int(math.ceil((x1 + 5) / 0.025))))
        self.obstacle[s] = True
        self.max_height[s] = np.maximum(self.max_height[s], h)
        return self

    def checker(self) -> FootprintChecker:
        return FootprintChecker(FootprintConfig(), GEO, self.obstacle, self.max_height)

    def gaze(self, footprint_xy, top=TOP, config=GazeConfig(), centre_xy=None) -> list[GazePoint]:
        return gaze_points(footprint_xy, top, GEO, self.obstacle, self.max_height, self.checker(), config, centre_xy)


def table_grid() -> tuple[Grid, np.ndarray]:
    g = Grid().box(*TABLE, TOP)
    rows, cols = np.nonzero(g.obstacle)
    return g, GEO.cell_to_world(rows, cols)


def ring_poses(footprint_xy, standoff, config=GazeConfig()):
    """The candidate poses of one ring before any filtering (facing the footprint's mean)."""
    ring = contour_points(footprint_xy, standoff, config.spacing, config.min_points)
    centre = np.asarray(footprint_xy).mean(axis=0)
    yaw = np.arctan2(centre[1] - ring[:, 1], centre[0] - ring[:, 0])
    return np.column_stack([ring, yaw])


def assert_valid(points, grid: Grid, centre, top=TOP, config=GazeConfig()):
    checker = grid.checker()
    for p in points:
        pose = p.pose
        assert checker.poses_free([pose.as_tuple()])[0], pose
        r, c = GEO.world_to_cell(np.array([pose.x, pose.y]))
        assert not grid.obstacle[r, c], pose
        facing = math.atan2(centre[1] - pose.y, centre[0] - pose.x)
        assert abs(wrap_angle(pose.yaw - facing)) < 1e-9, (pose, facing)
        np.testing.assert_allclose(p.look_at, [centre[0], centre[1], max(top, config.min_look_height)], atol=1e-12)


# ------------------------------------------------------------------------------------ contour
def test_contour_points_keep_the_standoff_from_the_footprint():
    xs, ys = np.meshgrid(np.linspace(1.5, 2.5, 21), np.linspace(0.7, 1.3, 13))
    fp = np.stack([xs.ravel(), ys.ravel()], axis=1)          # 1.0 x 0.6 m rectangle centred (2, 1)
    pts = contour_points(fp, 0.9, 0.6, 8)
    extent = math.hypot(0.5, 0.3)
    assert len(pts) == max(8, math.ceil(2 * math.pi * (extent + 0.9) / 0.6))
    d = np.min(np.linalg.norm(pts[:, None, :] - fp[None, :, :], axis=2), axis=1)
    assert np.all(d >= 0.9 - 1e-9)
    assert np.all(d <= 0.9 + extent + 1e-9)
    ang = np.arctan2(pts[:, 1] - 1.0, pts[:, 0] - 2.0)
    steps = np.diff(np.unwrap(ang))
    np.testing.assert_allclose(steps, 2 * math.pi / len(pts), atol=1e-9)   # evenly spaced directions
    # axis directions: half width + standoff from the centre
    np.testing.assert_allclose(pts[0], [2.0 + 0.5 + 0.9, 1.0], atol=1e-12)
    # a single point still gives min_points directions on a circle of radius standoff
    one = contour_points(np.array([[0.0, 0.0]]), 1.0, 5.0, 8)
    assert len(one) == 8
    np.testing.assert_allclose(np.linalg.norm(one, axis=1), 1.0)


# ------------------------------------------------------------------------------------ free poses
def test_gaze_points_around_a_table_in_open_space():
    g, fp = table_grid()
    cfg = GazeConfig(outer_rings="always")
    pts = g.gaze(fp, config=cfg)
    total = sum(len(contour_points(fp, s, cfg.spacing, cfg.min_points)) for s in cfg.standoffs)
    assert len(pts) == total                                  # nothing in the way: every ring point
    assert_valid(pts, g, fp.mean(axis=0))
    near = [p for p in pts][:len(contour_points(fp, cfg.standoffs[0], cfg.spacing, cfg.min_points))]
    for p in near:                                            # nearest ring first
        d = np.min(np.hypot(fp[:, 0] - p.pose.x, fp[:, 1] - p.pose.y))
        assert cfg.standoffs[0] - 1e-9 <= d <= cfg.standoffs[0] + 0.6


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_gaze_points_never_in_occupied_cells(seed):
    rng = np.random.default_rng(seed)
    g, fp = table_grid()
    for _ in range(10):                                       # furniture around the table
        cx, cy = rng.uniform(-2.5, 2.5, 2)
        if abs(cx) < 1.0 and abs(cy) < 0.8:
            continue
        w, h = rng.uniform(0.2, 0.8, 2)
        g.box(cx - w / 2, cx + w / 2, cy - h / 2, cy + h / 2, float(rng.choice([0.3, 0.6, 1.0, 1.8])))
    pts = g.gaze(fp)
    assert_valid(pts, g, fp.mean(axis=0))
    # the filter did something: some ring poses were dropped, and all that remain are free
    all_ring = np.concatenate([ring_poses(fp, s) for s in GazeConfig().standoffs])
    assert len(pts) <= len(all_ring)
    blocked = ~g.checker().poses_free(all_ring)
    kept = {(round(p.pose.x, 9), round(p.pose.y, 9)) for p in pts}
    for pose in all_ring[blocked]:
        assert (round(pose[0], 9), round(pose[1], 9)) not in kept


def test_a_box_on_a_ring_point_removes_it():
    g, fp = table_grid()
    ring = ring_poses(fp, GazeConfig().standoffs[0])
    x, y = ring[0, :2]                                        # the +x point (1.4, 0)
    g.box(x - 0.1, x + 0.1, y - 0.1, y + 0.1, 0.3)
    pts = g.gaze(fp)
    assert all(math.hypot(p.pose.x - x, p.pose.y - y) > 1e-6 for p in pts)
    assert_valid(pts, g, fp.mean(axis=0))


def test_custom_centre_and_low_instances():
    g, fp = table_grid()
    centre = (0.2, -0.1)
    pts = g.gaze(fp, top=0.0, centre_xy=np.array([0.2, -0.1, 0.3]))
    assert pts
    assert_valid(pts, g, centre, top=0.0)                     # look-at height floored at min_look_height
    assert g.gaze(np.zeros((0, 2))) == []


# ------------------------------------------------------------------------------------ line of sight
FAR_RING = GazeConfig(standoffs=(2.0,))       # body centres 2 m from the table edge (x = 2.5 on +x)


def beyond_wall_free_poses(g: Grid, fp) -> np.ndarray:
    ring = ring_poses(fp, 2.0, FAR_RING)
    free = g.checker().poses_free(ring)
    return ring[free & (ring[:, 0] > 1.1)]


def test_points_behind_a_tall_wall_are_removed():
    g, fp = table_grid()
    g.box(1.0, 1.1, -4.0, 4.0, 2.0)                           # a 2 m wall between table and x > 1.1
    behind = beyond_wall_free_poses(g, fp)
    assert len(behind) >= 3                                   # standing there would be fine ...
    pts = g.gaze(fp, config=FAR_RING)
    assert pts                                                # ... the other side is still visible
    assert all(p.pose.x < 1.0 for p in pts)                   # ... but nothing behind the wall is kept
    assert_valid(pts, g, fp.mean(axis=0), config=FAR_RING)


def test_points_behind_a_low_obstacle_are_kept():
    g, fp = table_grid()
    g.box(1.0, 1.1, -4.0, 4.0, 0.4)                           # lower than the table top (0.75)
    behind = beyond_wall_free_poses(g, fp)
    assert len(behind) >= 3
    pts = g.gaze(fp, config=FAR_RING)
    kept = {(round(p.pose.x, 9), round(p.pose.y, 9)) for p in pts}
    for pose in behind:
        assert (round(pose[0], 9), round(pose[1], 9)) in kept
    # as tall as the top: does not hide it either; taller than top + los_margin does
    g2, _ = table_grid()
    g2.box(1.0, 1.1, -4.0, 4.0, TOP)
    assert any(p.pose.x > 1.1 for p in g2.gaze(fp, config=FAR_RING))
    g3, _ = table_grid()
    g3.box(1.0, 1.1, -4.0, 4.0, 0.85)
    assert not any(p.pose.x > 1.1 for p in g3.gaze(fp, config=FAR_RING))
    lenient = GazeConfig(standoffs=(2.0,), los_margin=0.2)
    assert any(p.pose.x > 1.1 for p in g3.gaze(fp, config=lenient))


def test_a_pillar_hides_only_the_points_behind_it():
    g, fp = table_grid()
    g.box(0.9, 1.0, -0.05, 0.05, 2.0)                         # thin tall pillar on the +x axis
    pts = g.gaze(fp, config=FAR_RING)
    ring = ring_poses(fp, 2.0, FAR_RING)
    assert len(pts) == len(ring) - 1                          # exactly the +x point is hidden
    assert all(not (p.pose.x > 2.0 and abs(p.pose.y) < 1e-6) for p in pts)


def test_the_instance_itself_never_blocks_its_view():
    g = Grid().box(*TABLE, 1.5)                               # a cabinet: its own cells are tall
    rows, cols = np.nonzero(g.obstacle)
    fp = GEO.cell_to_world(rows, cols)
    pts = g.gaze(fp, top=1.5, config=GazeConfig(outer_rings="always"))
    assert len(pts) == sum(len(contour_points(fp, s, 0.6, 8)) for s in GazeConfig().standoffs)


def test_an_open_inner_ring_yields_no_outer_points():
    """One ring with fallback (the default): nothing in the way, so only the inner ring."""
    g, fp = table_grid()
    cfg = GazeConfig()
    assert cfg.outer_rings == "fallback"
    pts = g.gaze(fp)
    inner = contour_points(fp, cfg.standoffs[0], cfg.spacing, cfg.min_points)
    assert len(pts) == len(inner)
    got = np.array([[p.pose.x, p.pose.y] for p in pts])
    np.testing.assert_allclose(got, inner, atol=1e-9)


def test_the_agent_searches_with_outer_rings_only_as_a_fallback_by_default():
    """The agent's own gaze settings (``AgentConfig.gaze``) keep the fallback default, not only a
    bare ``GazeConfig``: outer rings only where the inner ring is blocked."""
    from helios.agents.config import AgentConfig

    assert AgentConfig().gaze.outer_rings == "fallback"


def test_a_blocked_inner_point_is_replaced_by_outer_ones():
    """A box on the inner ring's +x point: that direction falls back to the outer ring's points
    nearest to it in angle, and no other outer point appears."""
    g, fp = table_grid()
    cfg = GazeConfig()
    inner = contour_points(fp, cfg.standoffs[0], cfg.spacing, cfg.min_points)
    outer = contour_points(fp, cfg.standoffs[1], cfg.spacing, cfg.min_points)
    x, y = inner[0]                                           # (1.4, 0): on the +x side
    g.box(0.85, 1.0, -0.1, 0.1, 0.3)    # under the front of a body standing there; low: the view is clear
    pts = g.gaze(fp)
    got = np.array([[p.pose.x, p.pose.y] for p in pts])
    assert not np.any(np.hypot(got[:, 0] - x, got[:, 1] - y) < 1e-6)
    middle = fp.mean(axis=0)
    ang = lambda xy: np.arctan2(xy[:, 1] - middle[1], xy[:, 0] - middle[0])   # noqa: E731
    inner_dirs, outer_dirs = ang(inner), ang(outer)
    sector = np.argmin(np.abs(np.angle(np.exp(1j * (outer_dirs[:, None] - inner_dirs[None, :])))), axis=1)
    expected_outer = outer[sector == 0]                       # the outer points of the +x direction
    assert len(expected_outer) >= 1
    from_outer = got[len(inner) - 1:]
    np.testing.assert_allclose(from_outer, expected_outer, atol=1e-9)
    np.testing.assert_allclose(got[:len(inner) - 1], inner[1:], atol=1e-9)
    assert_valid(pts, g, middle)


def test_line_of_sight():
    blocking = np.zeros(GEO.shape, dtype=bool)
    r, c = GEO.world_to_cell(np.array([0.0, 0.0]))
    blocking[r, c] = True
    assert not line_of_sight(np.array([-1.0, 0.01]), np.array([1.0, 0.01]), GEO, blocking)
    assert line_of_sight(np.array([-1.0, 0.2]), np.array([1.0, 0.2]), GEO, blocking)
    assert line_of_sight(np.array([-1.0, -1.0]), np.array([-0.5, 1.0]), GEO, blocking)


def test_gaze_config_validation():
    for bad in (dict(standoffs=()), dict(standoffs=(0.9, -1.0)), dict(spacing=0.0), dict(min_points=2)):
        with pytest.raises(ValueError):
            GazeConfig(**bad)


def test_a_local_search_visits_the_nearest_gaze_point_first_then_the_nearest_to_the_last():
    from helios.search.gaze_points import visiting_order

    pts = [GazePoint(SE2Pose(x, y, 0.0), np.zeros(3)) for x, y in ((3.0, 0.0), (1.0, 0.0), (0.0, 2.5), (2.0, 0.1))]
    order = visiting_order(pts, (0.0, 0.0))
    assert [(g.pose.x, g.pose.y) for g in order] == [(1.0, 0.0), (2.0, 0.1), (3.0, 0.0), (0.0, 2.5)]
    assert len(pts) == 4 and visiting_order([], (0.0, 0.0)) == []      # the caller's list is left alone


# ------------------------------------------------------------------------------------ arm room
def test_arm_room_treats_a_point_the_arm_cannot_look_from_as_blocked():
    """``GazeConfig.arm_room``: a free, visible point that ``can_look`` rejects falls back to the
    outer ring exactly as a point blocked by the footprint test does; off (the default), the test
    is never asked and the points are those of the paper's contour."""
    g, fp = table_grid()
    cfg = GazeConfig(arm_room=True)
    inner = contour_points(fp, cfg.standoffs[0], cfg.spacing, cfg.min_points)
    x, y = inner[0]
    asked = []

    def can_look(poses, look_at):
        asked.append(np.array(poses))
        np.testing.assert_allclose(look_at, [0.0, 0.0, TOP], atol=1e-12)
        return np.hypot(poses[:, 0] - x, poses[:, 1] - y) > 1e-6      # no room at the +x point only

    got = gaze_points(fp, TOP, GEO, g.obstacle, g.max_height, g.checker(), cfg, None, can_look)
    blocked = Grid().box(*TABLE, TOP).box(0.85, 1.0, -0.1, 0.1, 0.3).gaze(fp)   # the same point blocked by a box
    assert [p.pose.as_tuple() for p in got] == [p.pose.as_tuple() for p in blocked]
    assert len(asked) == 2 and len(asked[0]) == len(inner)       # inner ring, then the +x outer points only
    assert not any(np.hypot(p.pose.x - x, p.pose.y - y) < 1e-6 for p in got)

    def never(poses, look_at):
        raise AssertionError("asked although arm_room is off")

    off = gaze_points(fp, TOP, GEO, g.obstacle, g.max_height, g.checker(), GazeConfig(), None, never)
    assert [p.pose.as_tuple() for p in off] == [p.pose.as_tuple() for p in g.gaze(fp)]
    with pytest.raises(ValueError, match="can_look"):
        gaze_points(fp, TOP, GEO, g.obstacle, g.max_height, g.checker(), cfg)


@pytest.mark.parametrize("arm_model", ["measured", "radius"])
def test_can_look_from_predicts_what_a_visit_finds(arm_model):
    """``Body.can_look_from`` on a pose says what ``view_from`` would find on arrival there: room
    for the arm (or a step ``make_room`` takes to get it) and a clear sweep towards the look
    point, for a look at that pitch. Checked pose by pose against the visit's own calls near a
    tall wall and a shelf, with either arm-room model."""
    from collections import Counter
    from dataclasses import replace
    from types import SimpleNamespace

    from helios.agents.body import Body
    from helios.agents.config import AgentConfig
    from robots.hal import NavigateResult, Reason

    g = Grid().box(-2.0, 2.0, 1.0, 1.1, 2.5).box(0.6, 1.0, -0.4, 0.4, 1.8).box(-0.5, 0.5, -0.3, 0.3, 0.75)
    occupancy = SimpleNamespace(obstacle=g.obstacle, max_height=g.max_height, explored=np.ones(GEO.shape, bool),
                                revision=0, geometry=GEO, explored_bounds=(0, GEO.size, 0, GEO.size))
    observer = SimpleNamespace(map=SimpleNamespace(occupancy=occupancy, geometry=GEO))
    config = AgentConfig()
    body = Body(replace(config, view=replace(config.view, arm_model=arm_model)), None, observer, [], Counter())

    class Robot:           # make_room's step always arrives
        def navigate_to(self, goal, via=()):
            return NavigateResult(True, Reason.OK, final_pose=goal)

    rng = np.random.default_rng(3)
    look_at = np.array([0.0, 0.0, TOP])
    poses = np.column_stack([rng.uniform(-1.6, 1.6, 300), rng.uniform(-1.2, 0.9, 300), rng.uniform(-np.pi, np.pi, 300)])
    predicted = body.can_look_from(poses, look_at)
    actual = []
    for x, y, yaw in poses:
        body.pose, body.arm_stowed, body.arm_direction = SE2Pose(x, y, yaw), True, None   # as on arrival
        actual.append(body.room_to_look(Robot(), look_at))          # view_from's own test
    assert predicted.tolist() == actual
    assert 30 < int(predicted.sum()) < 270            # both answers occur
    assert body.can_look_from(np.zeros((0, 3)), look_at).shape == (0,)


def test_an_instance_off_the_map_grid_has_no_gaze_points():
    """(determinism audit 2026-12-05) With a small map grid a candidate can lie wholly off it: the
    window round it was empty and OpenCV's dilation raised, ending every episode on an error."""
    g, fp = table_grid()
    far = fp + np.array([40.0, 40.0])                    # the grid spans -5..5 m
    assert g.gaze(far) == []
    assert g.gaze(fp)                                     # the same table on the grid: points as before
