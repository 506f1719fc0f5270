"""The measured arm-room model (``ViewConfig.arm_model = "measured"``) against the simulated arm:
wherever it says the arm has room for a look, the simulated gaze completes without touching the
furniture; and it gives room where the earlier radius model refused it (a counter top)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from helios.agents.arm_room import envelope_clear, look_pitch
from helios.maps.grid import GridGeometry
from robots.hal import Reason, SE2Pose
from robots.spot.sim_backend import SimSpotBackend
from sim import assets
from sim.spot import SpotBody
from sim.world import World

GEO = GridGeometry(0.025, 240, -3.0, -3.0)
BODY_Z = 0.53        # the standing body origin's height in sim


def _grid_with_box(x0, x1, y0, y1, height):
    obstacle = np.zeros(GEO.shape, dtype=bool)
    max_height = np.zeros(GEO.shape, dtype=np.float32)
    rows, cols = np.mgrid[0:GEO.size, 0:GEO.size]
    cx = GEO.origin_x + (cols + 0.5) * GEO.cell_size
    cy = GEO.origin_y + (rows + 0.5) * GEO.cell_size
    inside = (cx >= x0) & (cx <= x1) & (cy >= y0) & (cy <= y1)
    obstacle[inside] = True
    max_height[inside] = height
    return obstacle, max_height


def _gaze_touches(box_centre, half, height, pose: SE2Pose, target) -> bool:
    world = World()
    assets.add_static(world, "counter", "counter", [assets.Part("box", (half[0], half[1], height / 2), (0, 0, height / 2))],
                      (box_centre[0], box_centre[1], 0.0))
    backend = SimSpotBackend(world, SpotBody(world, pose), owns_world=False)
    try:
        res = backend.gaze_at(target)
        return not res.success and res.reason is Reason.COLLISION
    finally:
        backend.close()


# (counter height, body centre's distance to the counter front, body yaw (deg), look target: "top"
# or "floor" 1.2 m ahead, whether the envelope gives room)
CASES = [(0.9, 0.70, 0, "top", True), (0.9, 0.80, 0, "top", True), (1.05, 0.75, 0, "top", True),
         (0.9, 0.70, 0, "floor", False), (0.9, 0.95, 0, "floor", True), (0.72, 0.80, 0, "floor", True),
         (0.72, 0.95, 0, "floor", True), (0.9, 0.40, 90, "top", True), (1.05, 0.62, 30, "top", False)]


@pytest.mark.parametrize("height,dist,yaw_deg,target,expected", CASES)
def test_a_look_the_envelope_allows_does_not_touch_the_furniture(height, dist, yaw_deg, target, expected):
    front = 1.0
    centre, half = (front + 0.3, 0.0), (0.3, 1.5)
    pose = SE2Pose(front - dist, 0.0, math.radians(yaw_deg))
    look = [front + 0.1, 0.0, height + 0.03] if target == "top" else \
        [pose.x + 1.2 * math.cos(pose.yaw), pose.y + 1.2 * math.sin(pose.yaw), 0.0]
    obstacle, max_height = _grid_with_box(front, front + 0.6, -1.5, 1.5, height)
    pitch = look_pitch(pose.x, pose.y, BODY_Z, look)
    clear = bool(envelope_clear(obstacle, max_height, GEO, [pose.x], [pose.y], pose.yaw, pitch)[0])
    assert clear is expected
    if clear:
        assert not _gaze_touches(centre, half, height, pose, look), "the envelope gave room the arm did not have"


def test_the_envelope_gives_room_over_a_counter_top_the_radius_model_refused():
    # body centre 0.7 m from a 0.9 m counter's front, looking at something on it: the radius
    # model's sweep (0.55 m from a shoulder 0.29 m ahead) reaches 0.84 m and refused the look
    obstacle, max_height = _grid_with_box(1.0, 1.6, -1.5, 1.5, 0.9)
    top = look_pitch(0.3, 0.0, BODY_Z, [1.1, 0.0, 0.93])
    assert envelope_clear(obstacle, max_height, GEO, [0.3], [0.0], 0.0, top)[0]
    assert not _gaze_touches((1.3, 0.0), (0.3, 1.5), 0.9, SE2Pose(0.3, 0.0, 0.0), [1.1, 0.0, 0.93])
    # the same counter refuses a steep look at the floor from there: the gripper dips to 0.63 m
    steep = look_pitch(0.3, 0.0, BODY_Z, [1.2, 0.0, 0.0])
    assert steep > 60 and not envelope_clear(obstacle, max_height, GEO, [0.3], [0.0], 0.0, steep)[0]
    # a table top (0.72 m) 0.6 m ahead of the body centre refuses a steep look, not a level one
    obstacle, max_height = _grid_with_box(0.6, 1.2, -1.5, 1.5, 0.72)
    assert not envelope_clear(obstacle, max_height, GEO, [0.0], [0.0], 0.0, 70.0)[0]
    assert envelope_clear(obstacle, max_height, GEO, [0.0], [0.0], 0.0, 5.0)[0]


def test_walls_beside_and_behind_the_shoulder_leave_the_envelope_clear():
    # a wall 0.4 m to the side of the body centre line and one just behind the body
    obstacle, max_height = _grid_with_box(-1.0, 1.0, 0.4, 0.5, 2.0)
    o2, h2 = _grid_with_box(-0.7, -0.6, -1.0, 1.0, 2.0)
    obstacle |= o2
    max_height = np.maximum(max_height, h2)
    for pitch in (None, -10.0, 20.0, 50.0, 80.0):
        assert envelope_clear(obstacle, max_height, GEO, [0.0], [0.0], 0.0, pitch)[0]
    assert not _gaze_touches((0.0, 0.45), (1.0, 0.05), 2.0, SE2Pose(0.0, 0.0, 0.0), [1.5, 1.5, 0.3])


def test_the_table_covers_where_the_simulated_arm_goes():
    """``python -m tools arm-envelope`` on a few looks of every band: the agent's table misses no
    cell the arm passes over lower than the table says (the full 450-look sweep made the table)."""
    from helios.agents.arm_room import BANDS, MARGIN
    from tasks.arm_sweep import Targets, measure, uncovered

    env = measure(Targets(bearings_deg=(-100, 0, 60), distances=(0.7, 1.3, 3.5), heights=(0.0, 0.9)))
    assert all(n > 0 for n in env.looks), env.looks          # every band was exercised
    assert env.failed == 0
    for band in range(len(BANDS)):
        assert uncovered(env, band, MARGIN) == [], f"band {band}"
    # and the measurement is not vacuous: a steep look dips the arm below a table top ahead
    steep = env.lowest[len(BANDS) - 1]
    assert np.nanmin(np.where(np.isfinite(steep), steep, np.nan)) < 0.70


def test_a_look_is_binned_by_its_distance_not_its_bearing():
    """The agent bins a look as ``tasks.arm_sweep`` binned the measured ones: from the hand swung
    towards the target, whatever the body's heading. A floor point 0.7 m to the side is a steep
    look (the arm dips for it, as for the same point ahead), not the moderate one a hand fixed
    ahead of the body would see."""
    from helios.agents.arm_room import BANDS, band_of

    ahead = look_pitch(0.0, 0.0, BODY_Z, [0.7, 0.0, 0.0])
    for bearing in (-100, -45, 30, 90):
        b = math.radians(bearing)
        assert look_pitch(0.0, 0.0, BODY_Z, [0.7 * math.cos(b), 0.7 * math.sin(b), 0.0]) == pytest.approx(ahead)
    assert band_of(look_pitch(0.0, 0.0, BODY_Z, [0.0, 0.7, 0.0])) == len(BANDS) - 1
    assert look_pitch(2.0, -1.0, BODY_Z, [2.0, -0.3, 0.0]) == pytest.approx(ahead)     # anywhere on the map
