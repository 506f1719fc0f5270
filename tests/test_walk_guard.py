"""The clearance guard of kinematic moves (sim.spot.ContactGuard) skips contact queries only
where they cannot find anything: base walks and arm moves end, stop and record collisions
exactly as with a contact query at every pose."""

from __future__ import annotations

import math

import numpy as np

from robots.hal import SE2Pose
from robots.spot.sim_backend import SimBackendConfig, SimSpotBackend
from sim import assets
from sim.spot import ContactGuard, SpotBody
from sim.world import World


def _room(world: World) -> None:
    """Walls on two sides, a table and a loose box: furniture, structure and an object."""
    assets.add_wall(world, "north wall", (-1.0, 1.6), (4.0, 1.6))
    assets.add_wall(world, "east wall", (3.2, -2.0), (3.2, 1.6))
    assets.add_table(world, "table", (1.6, -1.1), height=0.5)
    assets.add_box_object(world, "box", (0.8, 0.9, 0.15), half_extents=(0.15, 0.15, 0.15), mass=5.0)


GOALS = [SE2Pose(1.0, 0.2, 0.0), SE2Pose(1.2, 0.4, 2.5), SE2Pose(2.4, 0.6, -0.8),
         SE2Pose(2.6, 0.8, 0.0),      # into the east wall: a collision
         SE2Pose(0.5, 0.0, math.pi), SE2Pose(1.6, -0.2, -1.6)]   # the last turns over the table


# From the last walk's end, beside the table: reach out over it, down into it (a collision), sideways, stow.
ARM_TARGETS = [(0.0, -1.2, 1.4, 0.0, 0.4, 0.0), (0.0, -0.4, 0.9, 0.0, 0.8, 0.0), (0.0, -1.0, 1.6, 0.0, 0.2, 0.0),
               (1.0, 0.3, 0.5, 0.0, 0.3, 0.0), (0.0, -3.1, 3.1, 0.0, 0.0, 0.0)]


def _walk_all(clearance_horizon: float, listen: bool = False, paced: bool = False):
    world = World()
    _room(world)
    spot = SpotBody(world, SE2Pose(0.0, 0.0, 0.0))
    backend = SimSpotBackend(world, spot, SimBackendConfig(clearance_horizon=clearance_horizon, stream_renderer="inline"),
                             owns_world=False)
    frames = []
    if listen:
        backend.add_frame_listener(lambda obs: frames.append(obs.T_world_body.tobytes()))
    if paced:       # a real-time player (the fake Spot) reads the pose after every stretch of motion
        backend.pacer = lambda dt: frames.append(spot.T_world_body().tobytes())
    queries = 0
    touching = spot.touching

    def counted(*args, **kwargs):
        nonlocal queries
        queries += 1
        return touching(*args, **kwargs)

    spot.touching = counted
    placed = 0
    set_base_pose, set_arm_state = spot.set_base_pose, spot.set_arm_state

    def counted_pose(*args, **kwargs):
        nonlocal placed
        placed += 1
        return set_base_pose(*args, **kwargs)

    def counted_arm(*args, **kwargs):
        nonlocal placed
        placed += 1
        return set_arm_state(*args, **kwargs)

    spot.set_base_pose, spot.set_arm_state = counted_pose, counted_arm
    results = []
    for goal in GOALS:
        r = backend.navigate_to(goal)
        results.append((r.success, r.reason, r.message, r.collided, r.duration, r.distance,
                        None if r.final_pose is None else (r.final_pose.x, r.final_pose.y, r.final_pose.yaw)))
    for q in ARM_TARGETS:
        r = backend.move_arm_joints(q)
        results.append((r.success, r.reason, r.message, r.duration, tuple(spot.arm_q())))
    events = [tuple(vars(e).values()) for e in backend.collision_events]
    poses = {b: world.pose(b).tobytes() for b in world.bodies}
    backend.close()
    world.close()
    return results, events, poses, queries, placed, frames


def test_guarded_walks_end_and_collide_exactly_as_walks_checked_at_every_pose():
    """Poses the guard vouches for are not even set (no reset calls), and nothing tells."""
    guarded, events_g, poses_g, queries_g, placed_g, _ = _walk_all(0.5)
    checked, events_c, poses_c, queries_c, placed_c, _ = _walk_all(0.0)
    assert placed_g < placed_c / 2, (placed_g, placed_c)      # most poses were never set
    assert guarded == checked                       # same outcome, message, time, distance, final pose
    assert events_g == events_c and len(events_c) >= 1   # the walk into the wall is recorded once alike
    assert poses_g == poses_c                       # every body where it was, bit for bit
    walks, arm_moves = checked[:len(GOALS)], checked[len(GOALS):]
    assert any(not ok and collided for ok, _, _, collided, *_ in walks)
    assert any(not ok for ok, *_ in arm_moves) and any(ok for ok, *_ in arm_moves)
    assert queries_g < queries_c / 3, (queries_g, queries_c)    # most poses needed no contact query


def test_a_streamed_move_sets_every_pose_its_frames_show():
    """With a frame listener (rerun recording, a live view) every pose is set, so the frames
    show the robot where it was at each moment, as without the guard."""
    guarded, events_g, poses_g, _, placed_g, frames_g = _walk_all(0.5, listen=True)
    checked, events_c, poses_c, _, placed_c, frames_c = _walk_all(0.0, listen=True)
    assert guarded == checked and events_g == events_c and poses_g == poses_c
    assert placed_g == placed_c and len(frames_c) > 20 and frames_g == frames_c


def test_a_paced_move_sets_every_pose_the_pacer_reads():
    guarded, _, poses_g, _, placed_g, read_g = _walk_all(0.5, paced=True)
    checked, _, poses_c, _, placed_c, read_c = _walk_all(0.0, paced=True)
    assert guarded == checked and poses_g == poses_c
    assert placed_g == placed_c and len(read_c) > 100 and read_g == read_c


def _guarded_random_walk(spot: SpotBody, guard: ContactGuard, start, propose, place, steps: int) -> tuple[int, int]:
    """``steps`` random steps (``propose(state, k)``, put in place by ``place``) that bounce back
    from contact, as a move stops at its last free pose; the guard must never vouch for a state
    in contact. Returns (states vouched for, states in contact handed back)."""
    state, vouched, refused_in_contact = start, 0, 0
    for k in range(steps):
        step = propose(state, k)
        place(step)
        contact = bool(spot.touching())
        if guard.free(step):
            vouched += 1
            assert not contact, f"the guard vouched for {step}, where the robot touches {spot.touching()}"
        elif contact:
            refused_in_contact += 1
        if contact:
            place(state)
        else:
            state = step
    return vouched, refused_in_contact


def test_the_guard_never_vouches_for_a_pose_in_contact(world):
    _room(world)
    spot = SpotBody(world, SE2Pose(0.0, 0.0, 0.0))
    guard = ContactGuard(spot, 0.5, "base")
    rng = np.random.default_rng(7)

    def propose(pose, _k):   # ~5 cm / 0.06 rad steps that bump into walls and furniture
        return SE2Pose(pose.x + rng.normal(0.03, 0.05), pose.y + rng.normal(0.0, 0.05), pose.yaw + rng.normal(0.0, 0.06))

    vouched, refused_in_contact = _guarded_random_walk(spot, guard, SE2Pose(0.0, 0.0, 0.0), propose,
                                                       spot.set_base_pose, 600)
    assert refused_in_contact > 10          # the walk did reach things, and the guard handed those back
    assert vouched > 200 and guard.skipped > 100, (vouched, guard.skipped, refused_in_contact)


def test_clearance_measures_the_gap_to_the_nearest_body_and_the_robots_reach(world):
    near = assets.add_box_object(world, "near", (1.2, 0.0, 0.6), half_extents=(0.05, 0.3, 0.6))   # a tall slab
    spot = SpotBody(world, SE2Pose(0.0, 0.0, 0.0))
    distance, reach = spot.clearance(1.0, turning_axis=(0.0, 0.0))
    assert 0.4 < distance < 0.7                       # Spot's nose is ~0.55 m ahead of its base pose
    spot.set_base_pose(SE2Pose(distance - 0.005, 0.0, 0.0))    # the gap is the walk left to contact
    assert spot.touching() == []
    spot.set_base_pose(SE2Pose(distance + 0.005, 0.0, 0.0))
    assert {body for _, body in spot.touching()} == {near}
    spot.set_base_pose(SE2Pose(0.0, 0.0, 0.0))
    assert 0.5 < reach < 1.5                          # Spot's half length and a bit
    assert spot.clearance(0.1, turning_axis=(0.0, 0.0)) == (0.1, reach)   # nothing within 10 cm: the horizon
    assert spot.clearance(1.0, exclude_bodies=[near]) == (1.0, 0.0)        # no axis, no reach
    assert spot.clearance(1.0, turning_axis=(-1.0, 0.0))[1] > reach + 0.9    # about an axis 1 m behind it


def test_the_arm_guard_never_vouches_for_a_configuration_in_contact(world):
    assets.add_table(world, "table", (1.35, 0.0), height=0.55)
    assets.add_wall(world, "wall", (-1.0, 0.75), (2.0, 0.75))
    spot = SpotBody(world, SE2Pose(0.0, 0.0, 0.0))
    guard = ContactGuard(spot, 0.5, "arm")
    rng = np.random.default_rng(3)
    goals = [np.array(g) for g in ((0.0, 0.3, 0.5, 0.0, 0.3, 0.0), (1.4, -0.6, 1.0, 0.0, 0.5, 0.0),
                                   (0.0, -3.1, 3.1, 0.0, 0.0, 0.0))]    # down on the table, at the wall, stowed

    def propose(q, k):       # ~0.03 rad steps drifting to each goal in turn
        goal = goals[(k // 150) % len(goals)]
        return q + 0.02 * np.sign(goal - q) + rng.normal(0.0, 0.02, 6)

    vouched, refused_in_contact = _guarded_random_walk(spot, guard, np.array(spot.arm_q()), propose,
                                                       spot.set_arm_state, 1500)
    assert refused_in_contact > 10
    assert vouched > 100 and guard.skipped > 50, (vouched, guard.skipped, refused_in_contact)


def test_arm_reach_bounds_how_far_any_arm_point_moves(world):
    spot = SpotBody(world, SE2Pose(0.0, 0.0, 0.0))
    reach = spot.arm_reach()
    assert 0.8 < reach < 1.3                  # Spot's arm and claw: about a metre from the shoulder
    rng = np.random.default_rng(0)
    for _ in range(50):                       # the bound, tried on each collider link's box corners
        qa = rng.uniform(-1.5, 1.5, 6)
        qb = qa + rng.normal(0.0, 0.2, 6)
        spot.set_arm_state(qa)
        a = [np.array(world.aabb(spot.id, link)) for link in spot._collider_links]
        spot.set_arm_state(qb)
        b = [np.array(world.aabb(spot.id, link)) for link in spot._collider_links]
        moved = max(float(np.abs(x - y).max()) for x, y in zip(a, b))
        assert moved <= reach * float(np.abs(qb - qa).sum()) + 0.05   # (boxes, not points: a little slack)
