"""Camera and reach geometry of the agent (helios.agents.geometry, robots.transforms.look_at_camera)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from helios.agents.config import ReachConfig, ViewConfig
from helios.agents.geometry import approach_poses, backproject, predicted_camera, project, reach_distances
from helios.maps.grid import GridGeometry
from helios.planning.footprint import FootprintChecker, FootprintConfig
from robots.hal import CameraIntrinsics, Observation, SE2Pose
from robots.transforms import is_valid_transform, look_at_camera, wrap_angle

K = CameraIntrinsics(64, 48, 50.0, 52.0, 31.5, 23.5)
GEO = GridGeometry(0.025, 400, -5.0, -5.0)


def observation(depth: np.ndarray, T_world_cam: np.ndarray) -> Observation:
    return Observation(rgb=np.zeros((K.height, K.width, 3), dtype=np.uint8), depth=depth.astype(np.float32),
                       intrinsics=K, T_world_cam=T_world_cam, T_world_body=SE2Pose(0.5, -0.2, 0.3).to_matrix(),
                       stamp=1.0)


# ------------------------------------------------------------------------------------ look_at
@pytest.mark.parametrize("eye,target", [
    ((1.0, 2.0, 1.5), (3.0, -1.0, 0.2)),
    ((0.0, 0.0, 0.6), (2.0, 0.0, 0.6)),       # level
    ((-1.0, 0.5, 0.3), (-1.2, 0.4, 1.8)),     # steeply up
])
def test_look_at_camera_puts_the_target_on_the_optical_axis_without_roll(eye, target):
    eye, target = np.array(eye), np.array(target)
    T = look_at_camera(eye, target)
    assert is_valid_transform(T)
    R = T[:3, :3]
    np.testing.assert_allclose(T[:3, 3], eye)
    np.testing.assert_allclose(R[:, 2], (target - eye) / np.linalg.norm(target - eye), atol=1e-12)
    assert abs(R[2, 0]) < 1e-12                  # image x axis level: no roll
    assert R[2, 1] < 0 or math.isclose(R[2, 1], 0.0, abs_tol=1e-12)   # image y points down (or level)
    u, v, z = project(target[None], K, T)
    assert u[0] == pytest.approx(K.cx) and v[0] == pytest.approx(K.cy)
    assert z[0] == pytest.approx(np.linalg.norm(target - eye))
    # a point above the target appears higher in the image (smaller v)
    _, v_up, _ = project((target + [0, 0, 0.1])[None], K, T)
    assert v_up[0] < K.cy


def test_look_at_camera_straight_down_and_degenerate():
    T = look_at_camera([0.0, 0.0, 2.0], [0.0, 0.0, 0.0])
    assert is_valid_transform(T)
    np.testing.assert_allclose(T[:3, 2], [0.0, 0.0, -1.0])
    with pytest.raises(ValueError):
        look_at_camera([1.0, 1.0, 1.0], [1.0, 1.0, 1.0])


# ------------------------------------------------------------------------------------ project / backproject
def test_project_backproject_round_trip():
    rng = np.random.default_rng(7)
    depth = rng.uniform(0.4, 4.0, (K.height, K.width))
    depth[rng.random(depth.shape) < 0.2] = 0.0           # no-return pixels
    T = look_at_camera([1.0, -2.0, 1.2], [3.0, 0.5, 0.4])
    obs = observation(depth, T)
    pts = backproject(obs)
    v, u = np.nonzero(obs.depth > 0)
    assert pts.shape == (len(u), 3)
    pu, pv, pz = project(pts, K, T)
    np.testing.assert_allclose(pu, u, atol=1e-6)
    np.testing.assert_allclose(pv, v, atol=1e-6)
    np.testing.assert_allclose(pz, obs.depth[v, u], rtol=1e-6)
    # agrees with the HAL's own per-pixel back-projection
    i = len(u) // 2
    p_cam = K.backproject(u[i], v[i], obs.depth[v[i], u[i]])
    np.testing.assert_allclose(pts[i], T[:3, :3] @ p_cam + T[:3, 3], atol=1e-9)


def test_backproject_mask_and_stride():
    depth = np.full((K.height, K.width), 2.0)
    depth[0, 0] = 0.0
    T = look_at_camera([0.0, 0.0, 1.0], [2.0, 0.0, 1.0])
    obs = observation(depth, T)
    mask = np.zeros(depth.shape, dtype=bool)
    mask[10:20, 5:15] = True
    mask[0, 0] = True                                    # masked but without depth: dropped
    assert len(backproject(obs, mask)) == 100
    assert len(backproject(obs, stride=4)) == (K.height // 4) * (K.width // 4) - 1
    # a fronto-parallel wall 2 m ahead of a level camera looking along +x: every point has x = 2
    np.testing.assert_allclose(backproject(obs)[:, 0], 2.0, atol=1e-9)


def test_points_behind_the_camera_have_non_positive_depth():
    T = look_at_camera([0.0, 0.0, 1.0], [2.0, 0.0, 1.0])
    _, _, z = project(np.array([[-1.0, 0.0, 1.0], [1.0, 0.0, 1.0]]), K, T)
    assert z[0] < 0 < z[1]


def test_predicted_camera_gazes_at_the_point_from_the_hand_position():
    view = ViewConfig()
    pose = SE2Pose(1.0, -1.0, 0.6)
    look = np.array([2.5, 0.5, 0.4])
    T = predicted_camera(pose, look, 0.5, view)
    ox, oy, oz = view.camera_in_body
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    np.testing.assert_allclose(T[:3, 3], [pose.x + c * ox - s * oy, pose.y + s * ox + c * oy, 0.5 + oz])
    u, v, _ = project(look[None], K, T)
    assert u[0] == pytest.approx(K.cx) and v[0] == pytest.approx(K.cy)


# ------------------------------------------------------------------------------------ approach poses
def table_checker(extra_wall=False) -> FootprintChecker:
    obstacle = np.zeros(GEO.shape, dtype=bool)
    height = np.zeros(GEO.shape, dtype=np.float32)

    def box(x0, x1, y0, y1, h):
        s = (slice(int((y0 + 5) / 0.025), int(math.ceil((y1 + 5) / 0.025))),
             slice(int((x0 + 5) / 0.025), int(math.ceil((x1 + 5) / 0.025))))
        obstacle[s] = True
        height[s] = h

    box(-0.5, 0.5, -0.3, 0.3, 0.75)                      # table at the origin
    if extra_wall:
        box(-3.0, 3.0, 1.0, 1.1, 2.0)                    # a wall 1 m to the table's +y side
    return FootprintChecker(FootprintConfig(), GEO, obstacle, height)


@pytest.mark.parametrize("wall", [False, True])
def test_approach_poses_face_the_target_and_are_footprint_free(wall):
    reach = ReachConfig()
    checker = table_checker(wall)
    target = np.array([0.2, 0.1, 0.75 + reach.place_lift])
    poses = approach_poses(target, reach, checker)
    dists, comfortable = reach_distances(float(target[2]), reach)
    assert 0 < len(poses) < len(dists) * reach.n_angles     # the table rules some out, not all
    assert checker.poses_free(poses).all()
    d = np.hypot(poses[:, 0] - target[0], poses[:, 1] - target[1])
    assert np.all(d >= dists.min() - 1e-9) and np.all(d <= dists.max() + 1e-9)
    facing = np.arctan2(target[1] - poses[:, 1], target[0] - poses[:, 0])
    assert np.all(np.abs(wrap_angle(poses[:, 2] - facing)) < 1e-9)
    err = np.abs(d - comfortable)
    assert np.all(np.diff(err) >= -1e-9)                   # most comfortable first
    if wall:
        # no pose on the far side of the wall, and none overlapping it
        assert np.all(poses[:, 1] < 1.0)


def test_reach_distances_shrink_for_high_and_low_targets():
    reach = ReachConfig()
    d_mid, c_mid = reach_distances(reach.shoulder_height, reach)
    d_low, _ = reach_distances(0.05, reach)
    assert d_mid.max() == pytest.approx(reach.arm_reach + reach.shoulder_ahead)
    assert d_low.max() < d_mid.max()
    assert d_mid.min() >= reach.min_standoff and c_mid < d_mid.max()
    assert len(d_mid) == 5 and np.all(np.diff(d_mid) >= 0)


# ------------------------------------------------------------------------------ bumps while turning
def test_a_stop_in_a_turn_in_place_is_told_from_a_stop_on_a_straight_stretch():
    """``turn_in_progress``: a walk turns in place, then goes straight. train-00018's walk (turn
    to 90 degrees, 15 cm north, turn to 0) stopped at 63.6 degrees, still at its start: a turn of
    +26.4 degrees was left. Stopped between two places: None. At the far place, having arrived
    heading north, the turn left is to 0 (the run's last heading), not back to north."""
    from helios.agents.geometry import turn_in_progress

    walk = [SE2Pose(3.1, 5.2, 1.5708), SE2Pose(3.1, 5.35, 1.5708), SE2Pose(3.1, 5.35, 0.0)]
    assert turn_in_progress(SE2Pose(3.1, 5.2, 1.11), walk) == pytest.approx(1.5708 - 1.11)
    assert turn_in_progress(SE2Pose(3.1, 5.27, 1.5708), walk) is None
    assert turn_in_progress(SE2Pose(3.1, 5.35, 1.0), walk) == pytest.approx(-1.0)
    assert turn_in_progress(SE2Pose(3.1, 5.2, 1.5708), walk[:2]) is None       # already faces it: moving on
    assert turn_in_progress(SE2Pose(3.1, 5.2, 3.0), [SE2Pose(3.1, 5.2, -3.0)]) == pytest.approx(
        2 * math.pi - 6.0)                                                          # the short way round


def test_a_bump_while_turning_marks_the_unseen_part_of_the_turns_sweep():
    """``mark_turn_bump``: the robot turning left (counter-clockwise) hit something; all floor is
    seen except a patch behind its right hind corner, which a left turn swings into. The unseen
    cells the next 10 degrees of the turn sweep are marked occupied (and seen), nothing inside the
    body, nothing elsewhere in the patch; with every cell seen, the sweep outside the body."""
    from helios.agents.body import mark_turn_bump
    from helios.agents.geometry import body_rectangle, turn_sweep
    from helios.config import OccupancyConfig
    from helios.maps.occupancy import OccupancyGrid

    fp = FootprintConfig()
    pose = SE2Pose(1.0, 2.0, 0.0)                      # facing +x: the right hind corner is at (-0.545, -0.215)
    occ = OccupancyGrid(OccupancyConfig(grid_size=200, origin_xy=(-1.5, -0.5)))
    occ.explored[:] = True
    rows, cols = np.mgrid[0:200, 0:200]
    xy = occ.geometry.cell_to_world(rows.ravel(), cols.ravel()).reshape(200, 200, 2)
    patch = (xy[..., 0] < pose.x - 0.3) & (xy[..., 1] < pose.y - 0.1)   # unseen floor behind-right
    occ.explored[patch] = False
    n, which = mark_turn_bump(occ, pose, fp, math.radians(40))
    assert which == "unseen"
    marked = occ.obstacle
    assert n == marked.sum() > 10
    assert not (marked & ~patch).any()                 # only unseen cells
    assert occ.explored[marked].all()
    inside = np.zeros_like(marked)
    for box in turn_sweep(pose, fp.body, math.radians(10), fp.margin + 0.025):   # + a cell: rasterised edges
        inside |= _in_polygon(xy, box)
    assert not (marked & ~inside).any()                # only within the next 10 degrees of the turn
    assert not (marked & _in_polygon(xy, body_rectangle(pose, fp.body, fp.margin - 0.03))).any()
    assert (patch & ~marked).sum() > 1000              # the rest of the patch stays unseen, not an obstacle
    # the rear swings to the right in a left turn: the marks lie behind the body and to its right
    assert (xy[marked][:, 0] < pose.x - 0.3).all() and (xy[marked][:, 1] < pose.y).all()
    # everything seen: the map missed it; the sweep outside the body is marked instead
    seen = OccupancyGrid(OccupancyConfig(grid_size=200, origin_xy=(-1.5, -0.5)))
    seen.explored[:] = True
    m, which = mark_turn_bump(seen, pose, fp, -math.radians(5))
    assert which == "seen" and m == seen.obstacle.sum() > 10
    assert not (seen.obstacle & _in_polygon(xy, body_rectangle(pose, fp.body, fp.margin - 0.03))).any()
    # the whole sweep, however many body boxes it is made of (overlapping polygons filled in one
    # call leave holes): every cell well inside a box and well outside the body is marked
    for turn in (8, -8, 10, -20):
        seen = OccupancyGrid(OccupancyConfig(grid_size=200, origin_xy=(-1.5, -0.5)))
        seen.explored[:] = True
        mark_turn_bump(seen, pose, fp, math.radians(turn))
        deep = np.zeros_like(seen.obstacle)
        for box in turn_sweep(pose, fp.body, math.radians(math.copysign(min(abs(turn), 10), turn)), fp.margin):
            deep |= _in_polygon(xy, box)          # the next 10 degrees of the turn at most
        deep &= ~_in_polygon(xy, body_rectangle(pose, fp.body, fp.margin + 0.03))
        assert deep.sum() > 10 and seen.obstacle[deep].all(), turn


def _in_polygon(xy: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Points (..., 2) inside a convex polygon (P, 2) listed counter-clockwise."""
    inside = np.ones(xy.shape[:-1], dtype=bool)
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        inside &= (b[0] - a[0]) * (xy[..., 1] - a[1]) - (b[1] - a[1]) * (xy[..., 0] - a[0]) >= -1e-9
    return inside
