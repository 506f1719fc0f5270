"""Occupancy grid, frontiers and the grid geometry."""

import math

import numpy as np
import pytest

from helios.config import FrontierConfig, HeliosConfig, OccupancyConfig
from helios.schema import with_overrides
from helios.maps import GridGeometry, OccupancyGrid, find_frontiers
from helios.maps.hierarchical import HierarchicalMap
from robots.hal import Observation
from robots.transforms import look_at_camera as look_at
from sim.synthetic_boxes import Box, pinhole, render_boxes, wall

CAM = pinhole(320, 240)
SMALL = OccupancyConfig(grid_size=400, origin_xy=(-3.0, -3.0))


def one_door_room():
    """4 m x 4 m room, 2 m walls, a 1 m door in the east wall (x = 4, y in [1.5, 2.5]).
    The floor exists only inside, so nothing is seen through the door."""
    return [Box((0.0, 0.0, -0.02), (4.0, 4.0, 0.0), "floor"),
            wall(0, 0, 4, 0, height=2.0), wall(0, 4, 4, 4, height=2.0), wall(0, 0, 0, 4, height=2.0),
            wall(4, 0, 4, 1.5, height=2.0), wall(4, 2.5, 4, 4, height=2.0)]


def look_around(eye=(2.0, 2.0, 1.0), n=16, pitch_deg=20.0):
    for k in range(n):
        yaw = 2 * math.pi * k / n
        target = np.asarray(eye) + [math.cos(yaw), math.sin(yaw), -math.tan(math.radians(pitch_deg))]
        yield look_at(eye, target)


def scanned_room(cfg=SMALL) -> OccupancyGrid:
    grid = OccupancyGrid(cfg)
    scene = one_door_room()
    for pose in look_around():
        _, depth, _ = render_boxes(scene, CAM, pose)
        grid.integrate_depth(depth, CAM, pose)
    return grid


def test_frontiers_of_a_room_with_one_door_are_exactly_at_the_doorway():
    grid = scanned_room()
    frontiers = find_frontiers(grid, FrontierConfig())
    assert len(frontiers) == 1
    door = frontiers[0]
    assert door.x == pytest.approx(4.0, abs=0.05) and door.y == pytest.approx(2.0, abs=0.05)
    xy = grid.geometry.cell_to_world(door.cells[:, 0], door.cells[:, 1])
    assert np.all((xy[:, 0] > 3.9) & (xy[:, 0] < 4.05))
    assert np.all((xy[:, 1] > 1.5) & (xy[:, 1] < 2.5))
    # the 0.9 m opening between the jambs, less the obstacle clearance at both ends
    assert door.size == pytest.approx(0.9 - 2 * FrontierConfig().obstacle_clearance, abs=0.06)


def test_room_interior_is_free_walls_are_obstacles_outside_is_unexplored():
    grid = scanned_room()
    geo = grid.geometry
    def cell(x, y):
        r, c = geo.world_to_cell(np.array([x, y]))
        return int(r), int(c)
    for x, y in [(1.0, 1.0), (3.0, 3.5), (2.0, 2.0), (3.8, 2.0)]:
        assert grid.free[cell(x, y)]
    for x, y in [(0.05, 2.0), (3.95, 1.0), (2.0, 3.95), (2.0, 0.05)]:     # inner wall faces
        r, c = cell(x, y)
        assert grid.obstacle[r - 1:r + 2, c - 1:c + 2].any()
    for x, y in [(4.5, 2.0), (-0.5, 2.0), (2.0, 4.6), (5.0, 0.5)]:
        assert not grid.explored[cell(x, y)]
    # obstacles come only from the height band: no floor cell inside is an obstacle
    r0, c0 = cell(0.3, 0.3)
    r1, c1 = cell(3.7, 3.7)
    assert not grid.obstacle[r0:r1, c0:c1].any()


def test_small_frontiers_are_dropped():
    grid = scanned_room()
    assert find_frontiers(grid, FrontierConfig(min_size=1.5)) == []


def test_grid_world_conversion_round_trips_and_default_grid_is_centred():
    geo = GridGeometry.from_config(OccupancyConfig())
    assert geo.shape == (2000, 2000) and geo.origin_x == -25.0 and geo.origin_y == -25.0
    xy = np.array([[0.0, 0.0], [1.2345, -3.21], [-24.99, 24.99]])
    rows, cols = geo.world_to_cell(xy)
    back = geo.cell_to_world(rows, cols)
    assert np.all(np.abs(back - xy) <= 0.0125 + 1e-12)
    assert geo.contains(rows, cols).all() and not geo.contains(np.array([2000]), np.array([0])).any()
    assert (rows[1], cols[1]) == (math.floor((-3.21 + 25) / 0.025), math.floor((1.2345 + 25) / 0.025))


def test_bad_depth_pixels_are_no_returns():
    grid = OccupancyGrid(SMALL)
    pose = next(look_around())
    _, depth, _ = render_boxes(one_door_room(), CAM, pose)
    clean = OccupancyGrid(SMALL)
    clean.integrate_depth(depth, CAM, pose)
    noisy = depth.copy()
    bad = np.random.default_rng(0).integers(0, 8, size=depth.shape)   # ~3/8 of pixels broken
    noisy[bad == 0] = np.nan
    noisy[bad == 1] = np.inf
    noisy[bad == 2] = -1.0
    grid.integrate_depth(noisy, CAM, pose)
    assert grid.explored.sum() > 0.9 * clean.explored.sum()
    assert not (grid.obstacle & ~clean.obstacle).any()
    empty = OccupancyGrid(SMALL)
    empty.integrate_depth(np.full(depth.shape, np.nan, dtype=np.float32), CAM, pose)
    assert not empty.explored.any() and empty.explored_bounds is None and find_frontiers(empty, FrontierConfig()) == []


def test_hierarchical_map_frontiers_carry_value_map_values():
    cfg = with_overrides(HeliosConfig(), ["occupancy.grid_size=400", "occupancy.origin_xy=[-3.0, -3.0]"])
    hmap = HierarchicalMap(cfg, ["cup", "table"], ["table", "counter"])
    scene = one_door_room()
    for pose in look_around():
        rgb, depth, _ = render_boxes(scene, CAM, pose)
        obs = Observation(rgb=rgb, depth=depth, intrinsics=CAM, T_world_cam=pose, T_world_body=np.eye(4), stamp=0.0)
        hmap.update(obs, [], {"table": 0.7, "counter": 0.2})
    (door,) = hmap.frontiers()
    assert door.values["table"] == pytest.approx(0.7, abs=1e-5)
    assert door.values["counter"] == pytest.approx(0.2, abs=1e-5)
    assert hmap.world_to_cell(np.array([door.x, door.y]))[1] == hmap.occupancy.geometry.world_to_cell(door.xy)[1]


def test_a_closed_room_seen_obliquely_from_a_corner_has_no_frontiers():
    closed = [Box((0.0, 0.0, -0.02), (4.0, 4.0, 0.0), "floor"),
              wall(0, 0, 4, 0, height=2.0), wall(0, 4, 4, 4, height=2.0), wall(0, 0, 0, 4, height=2.0),
              wall(4, 0, 4, 4, height=2.0)]
    grid = OccupancyGrid(SMALL)
    for pose in look_around(eye=(0.8, 1.0, 1.0), n=24):
        _, depth, _ = render_boxes(closed, CAM, pose)
        grid.integrate_depth(depth, CAM, pose)
    r, c = grid.geometry.world_to_cell(np.array([3.5, 3.5]))
    assert grid.free[r, c]                     # the far corner was seen
    assert find_frontiers(grid, FrontierConfig()) == []
