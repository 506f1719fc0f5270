"""Exploration and local-search bookkeeping: which frontiers are on offer, which parts of them
the robot walks to, what going to one does when no path reaches it or the first step is blocked
(``AgentConfig.frontier_parts``, ``frontier_approach``, ``unstick_distance``), which way the
robot looks from a frontier (``face_unseen``), and when a local search ends early
(``end_local_search_on_doubt``)."""

from __future__ import annotations

from collections import Counter
from dataclasses import replace

import numpy as np

from helios.agents.config import AgentConfig
from helios.agents.body import MAX_GAZE_YAW, UNSEEN_SIDE_NO_TURN, Body
from helios.agents.frontier_goals import StallWatch, frontier_options, unseen_bearing
from helios.agents.helios_agent import HeliosAgent
from helios.maps.frontiers import Frontier
from helios.maps.grid import GridGeometry
from helios.config import OccupancyConfig
from helios.maps.occupancy import OccupancyGrid
from helios.planning.fmm import PlanResult
from robots.hal import SE2Pose

GEO = GridGeometry(cell_size=0.1, size=200, origin_x=-10.0, origin_y=-10.0)
ON = replace(AgentConfig(), frontier_parts=True, frontier_approach=1.5, unstick_distance=0.5)
"""The three exploration fixes switched on (the defaults are the earlier behaviour)."""
OFF = AgentConfig(face_unseen=False)
"""Every exploration option off: the behaviour before 2026-12-02."""


def test_three_exploration_fixes_are_off_by_default_and_facing_the_unseen_side_is_on():
    default = AgentConfig()
    assert (default.frontier_parts, default.frontier_approach, default.unstick_distance) == (False, 0.0, 0.0)
    assert default.face_unseen is True and replace(default, face_unseen=False) == OFF


def _frontier(points_xy, centre_xy) -> Frontier:
    """A frontier through world points (cell centres on GEO), its centre at ``centre_xy``."""
    rows, cols = GEO.world_to_cell(np.asarray(points_xy, dtype=float))
    return Frontier(float(centre_xy[0]), float(centre_xy[1]), 0.1 * len(rows), np.stack([rows, cols], axis=1),
                    {"table": 0.5})


# a straight frontier from (0, 0) to (3, 0): one end where the robot stands, the other 3 m away
LINE = _frontier([(0.05 + 0.1 * k, 0.05) for k in range(30)], (1.55, 0.05))


def test_a_frontier_stays_on_offer_while_part_of_it_is_unreached():
    cfg = ON
    options, goals = frontier_options([LINE], "table", GEO, reached=[np.array([0.05, 0.05])], unreachable=[],
                                      config=cfg)
    assert len(options) == 1 and options[0].value == 0.5
    pts = goals[0]
    assert np.allclose(pts[0], LINE.xy)                                   # the centre comes first
    assert np.linalg.norm(pts - [0.05, 0.05], axis=1).min() >= cfg.frontier_blacklist_radius
    assert pts[:, 0].max() > 2.5                                          # the far end is still a goal
    # every part reached: off offer
    everywhere = [np.array([x, 0.05]) for x in np.arange(0.05, 3.1, 0.5)]
    assert frontier_options([LINE], "table", GEO, everywhere, [], cfg)[0] == []
    # the earlier reading: all parts stay goals, and only the centre decides
    old = replace(cfg, frontier_parts=False)
    opts, goals = frontier_options([LINE], "table", GEO, everywhere[:1], [], old)
    assert len(opts) == 1 and len(goals[0]) == 1 + len(LINE.cells[:: max(1, len(LINE.cells) // 16)])
    # a centre found unreachable takes the frontier off offer under both readings
    for c in (cfg, old):
        assert frontier_options([LINE], "table", GEO, [], [LINE.xy + 0.1], c)[0] == []


class _Body:
    """Plans from a script of PlanResults; walking moves the pose to the last waypoint."""

    def __init__(self, plans, pose=SE2Pose(0.05, 0.05, 0.0), unsticks=False):
        self.plans, self.pose, self.calls, self.looks = list(plans), pose, [], 0
        self.unsticks, self.unstick_calls = unsticks, 0

    def unstick(self, robot):
        self.unstick_calls += 1
        return self.unsticks

    def xy(self):
        return np.array([self.pose.x, self.pose.y])

    def plan(self, goals, radius, *args, **kwargs):
        self.calls.append((np.array(goals), radius))
        return self.plans.pop(0)

    def execute(self, robot, plan):
        self.pose = plan.waypoints[-1]
        return True

    def look(self, robot, yaws, facing=None):
        self.looks += 1

    def look_from_frontier(self, robot, direction, parts):
        self.looks += 1


class _Observer:
    def __init__(self):
        self.changes = 0

    def goals_changed(self):
        self.changes += 1


class _Objective:
    def note_frontier_chosen(self, frontier):
        pass


class _GridMap:
    def __init__(self, occupancy):
        self.occupancy = occupancy


def _agent(config: AgentConfig, body: _Body) -> HeliosAgent:
    agent = HeliosAgent.__new__(HeliosAgent)
    agent.config, agent.body, agent.observer, agent.log = config, body, _Observer(), []
    agent.reached, agent.unreachable, agent.last_frontier, agent.stats = [], [], None, Counter()
    agent.stall = StallWatch(config) if config.stall_steps else None
    agent.observer.map = _GridMap(OccupancyGrid(OccupancyConfig(grid_size=400, cell_size=0.05, origin_xy=(-10.0, -10.0))))
    options, agent._frontier_cells = frontier_options([LINE], "table", GEO, [], [], config)
    return agent, options[0]


def _plan(success=True, waypoints=(), reaches=True, goal_index=0, blocked=False, reason="ok"):
    return PlanResult(success, reason, np.zeros((0, 2)), waypoints=list(waypoints), reaches_goal=reaches,
                      goal_index=goal_index, blocked_ahead=blocked)


def test_standing_at_one_end_of_a_frontier_does_not_reach_it():
    """The earlier reading counted the robot as arrived when any sampled cell lay within
    ``frontier_reach``; now it walks to a part that is not within reach, and arriving there
    reaches the whole frontier (its centre is remembered)."""
    far = SE2Pose(2.8, 0.05, 0.0)
    body = _Body([_plan(waypoints=[far], goal_index=0)])
    agent, option = _agent(ON, body)
    agent._explore(None, option, _Objective())
    goals, radius = body.calls[0]
    assert radius == agent.config.frontier_reach
    assert np.linalg.norm(goals - [0.05, 0.05], axis=1).min() >= agent.config.frontier_reach
    assert body.pose == far and body.looks == 1
    assert len(agent.reached) == 1 and np.allclose(agent.reached[0], LINE.xy)
    # the earlier reading: arrived without a step, the whole frontier reached at its centre
    body = _Body([_plan(waypoints=[], goal_index=3)])
    agent, option = _agent(OFF, body)
    agent._explore(None, option, _Objective())
    assert len(body.calls[0][0]) == 1 + len(LINE.cells[:: max(1, len(LINE.cells) // 16)])
    assert np.allclose(agent.reached, [LINE.xy])


def test_a_frontier_wholly_within_reach_is_looked_at_and_reached_without_planning():
    body = _Body([], pose=SE2Pose(1.55, 0.05, 0.0))
    config = replace(ON, frontier_reach=2.0)
    agent, option = _agent(config, body)
    agent._explore(None, option, _Objective())
    assert body.calls == [] and body.looks == 1
    assert len(agent.reached) == len(agent._frontier_cells[0])


def test_a_frontier_out_of_reach_is_looked_at_from_nearer_or_marked_unreachable():
    """No path ends within ``frontier_reach``: with ``frontier_approach`` the robot walks to within
    that distance instead and looks; with 0 the frontier is marked unreachable at once."""
    near = SE2Pose(1.9, 0.9, 0.0)
    body = _Body([_plan(success=False, reason="unreachable"), _plan(waypoints=[near])])
    agent, option = _agent(ON, body)
    agent._explore(None, option, _Objective())
    assert [r for _, r in body.calls] == [agent.config.frontier_reach, agent.config.frontier_approach]
    assert body.pose == near and body.looks == 1 and agent.unreachable == []
    assert any("out of reach" in line for line in agent.log)
    body = _Body([_plan(success=False, reason="unreachable")])
    agent, option = _agent(replace(ON, frontier_approach=0.0), body)
    agent._explore(None, option, _Objective())
    assert len(body.calls) == 1 and body.looks == 0
    assert len(agent.unreachable) == 1 and agent.observer.changes == 1


def test_blocked_at_the_first_step_marks_the_frontier_unreachable_instead_of_looping():
    here = SE2Pose(0.05, 0.05, 0.0)
    body = _Body([_plan(waypoints=[SE2Pose(0.05, 0.05, 1.0)], reaches=False, blocked=True)], pose=here)
    agent, option = _agent(ON, body)
    agent._explore(None, option, _Objective())
    assert len(agent.unreachable) == 1 and np.allclose(agent.unreachable[0], LINE.xy)
    assert frontier_options([LINE], "table", GEO, agent.reached, agent.unreachable, agent.config)[0] == []
    body = _Body([_plan(waypoints=[SE2Pose(0.05, 0.05, 1.0)], reaches=False, blocked=True)], pose=here)
    agent, option = _agent(OFF, body)
    agent._explore(None, option, _Objective())
    assert agent.unreachable == []


def test_stall_watch_counts_steps_towards_one_frontier_that_end_in_one_place_and_see_nothing_new():
    """``AgentConfig.stall_steps``: after a first step, ``stall_steps`` more towards the same
    frontier that end within ``stall_radius`` of it and see under ``stall_new_area`` of new floor
    give the frontier up; a step that sees new floor, ends elsewhere or heads for another frontier
    starts the count again."""
    grid = OccupancyGrid(OccupancyConfig(grid_size=400, cell_size=0.05, origin_xy=(-10.0, -10.0)))
    grid.mark_seen((0.0, 0.0), 1.0)
    config = replace(AgentConfig(), stall_steps=3)
    watch, f = StallWatch(config), (3.0, 0.0)
    assert [watch.stalled(f, (0.1 * (i % 2), 0.0), grid) for i in range(4)] == [0, 0, 0, 3]
    assert [watch.stalled(f, (0.0, 0.0), grid) for _ in range(4)] == [0, 0, 0, 3]   # afresh after giving up
    # new floor (a disc of 0.3 m radius: 0.28 m^2 >= stall_new_area) between steps restarts the count
    watch = StallWatch(config)
    got = [watch.stalled(f, (0.0, 0.0), grid) for _ in range(3)]
    grid.mark_seen((-3.0, -3.0), 0.3)
    got += [watch.stalled(f, (0.0, 0.0), grid) for _ in range(3)]
    assert got == [0, 0, 0, 0, 0, 0] and watch.stalled(f, (0.0, 0.0), grid) == 3
    # a little new floor (0.2 m radius: 0.13 m^2) does not
    watch = StallWatch(config)
    got = [watch.stalled(f, (0.0, 0.0), grid) for _ in range(2)]
    grid.mark_seen((-5.0, -5.0), 0.2)
    assert got + [watch.stalled(f, (0.0, 0.0), grid) for _ in range(2)] == [0, 0, 0, 3]
    # ending elsewhere, or a step towards another frontier, restarts it
    watch = StallWatch(config)
    assert [watch.stalled(f, (0.0, 0.0), grid) for _ in range(3)] == [0, 0, 0]
    assert watch.stalled(f, (0.0, 0.6), grid) == 0 and watch.stalled((3.0, 1.0), (0.0, 0.6), grid) == 0
    assert [watch.stalled((3.0, 1.0), (0.0, 0.6), grid) for _ in range(3)] == [0, 0, 3]


def test_a_frontier_walked_at_without_getting_anywhere_is_given_up_after_stall_steps():
    """The loop of train-00086: each step towards the frontier ends where the last one did (the
    robot walks up to a wall and steps back to give the arm room) and sees nothing new. With
    ``stall_steps`` = 4 the fifth such step marks the frontier unreachable; with 0 (default) the
    robot keeps at it."""
    stuck = SE2Pose(0.4, 0.05, 0.0)
    for steps, given_up_after in ((4, 5), (0, None)):
        body = _Body([_plan(waypoints=[stuck], reaches=False) for _ in range(8)])
        agent, option = _agent(replace(AgentConfig(), stall_steps=steps), body)
        for n in range(1, 9):
            agent._explore(None, option, _Objective())
            if agent.unreachable:
                break
        assert (n if agent.unreachable else None) == given_up_after
        if given_up_after:
            assert np.allclose(agent.unreachable[0], LINE.xy) and agent.observer.changes == 1
            assert agent.log[-1] == f"frontier ({LINE.xy[0]:.1f}, {LINE.xy[1]:.1f}): 5 steps without progress, given up"
            assert frontier_options([LINE], "table", GEO, agent.reached, agent.unreachable, agent.config)[0] == []
        else:
            assert body.looks == 8 and agent.reached == []


def test_a_plan_blocked_at_the_first_step_steps_aside_before_giving_up_on_the_frontier():
    """A "blocked" plan (the path exists, the first turn or step does not fit) asks the body to
    unstick; only when it cannot is the frontier marked unreachable."""
    for unsticks in (True, False):
        body = _Body([_plan(success=False, reason="blocked"), _plan(success=False, reason="blocked")],
                     unsticks=unsticks)
        agent, option = _agent(ON, body)
        agent._explore(None, option, _Objective())
        assert body.unstick_calls == 1
        assert (agent.unreachable == []) is unsticks
    body = _Body([_plan(success=False, reason="unreachable"), _plan(success=False, reason="unreachable")],
                 unsticks=True)
    agent, option = _agent(ON, body)
    agent._explore(None, option, _Objective())
    assert body.unstick_calls == 0 and len(agent.unreachable) == 1


class _Instance:
    def __init__(self, iid, scores):
        self.id, self.class_scores = iid, scores
        self.class_name = max(scores, key=scores.get)


class _Seer:
    """Observer stand-in that lists instances; the body stand-in counts views."""

    def __init__(self, instances):
        self.list = instances

    def instances(self):
        return self.list


class _Viewer:
    def __init__(self):
        self.views = []

    def view_from(self, robot, gp):
        self.views.append(gp)
        return True


def test_a_local_search_ends_once_its_location_is_no_longer_a_candidate_when_asked():
    """``end_local_search_on_doubt``: a closer look showed the "desk" is a table (or the instance
    merged away): the remaining gaze points are dropped and the location counts as searched; by
    default (the paper) every gaze point is visited."""
    from helios.agents.helios_agent import _LocalSearch
    from helios.config import HeliosConfig

    cs = HeliosConfig().search.cs_start_receptacle
    desk = {"desk": cs + 0.1, "table": cs - 0.1}
    table = {"desk": cs + 0.05, "table": cs + 0.2}           # above cs_a, but most likely a table
    for scores, ends in ((desk, False), (table, True), (None, True)):
        for on in (True, False):
            agent = HeliosAgent.__new__(HeliosAgent)
            agent.config = replace(AgentConfig(), end_local_search_on_doubt=on)
            agent.method, agent.start_class, agent.log, agent.stats = HeliosConfig(), "desk", [], Counter()
            agent.observer = _Seer([] if scores is None else [_Instance(7, scores)])
            agent.body, agent.visited = _Viewer(), set()
            agent.local = _LocalSearch(7, ["a", "b", "c"])
            agent.local_search_sizes = [3]
            agent._continue_local_search(None)
            if on and ends:
                assert agent.body.views == [] and agent.local is None and agent.visited == {7}
                assert "no longer a desk candidate" in agent.log[-1]
            else:
                assert agent.body.views == ["a"] and agent.local.queue == ["b", "c"] and agent.visited == set()


# ---------------------------------------------------------------- facing the unseen side
def _room_seen_north_of(y_edge: float, wall_x: float | None = None) -> np.ndarray:
    """GEO's explored mask: everything north of ``y_edge`` seen, the south unseen; with
    ``wall_x``, also everything east of a wall at that x left unseen (its far side)."""
    rows, cols = np.mgrid[:GEO.size, :GEO.size]
    xy = GEO.cell_to_world(rows.ravel(), cols.ravel()).reshape(GEO.size, GEO.size, 2)
    seen = xy[..., 1] >= y_edge
    if wall_x is not None:
        seen &= xy[..., 0] <= wall_x
    return seen


def _edge_parts(y: float, x0: float, x1: float) -> np.ndarray:
    return np.array([(x, y) for x in np.arange(x0, x1, 0.1)])


def test_the_unseen_side_of_a_frontier_is_found_from_a_robot_standing_on_it():
    explored = _room_seen_north_of(0.0)
    parts = _edge_parts(0.05, -1.0, 1.0)            # the frontier row: seen, with unseen cells south
    bearing = unseen_bearing(explored, GEO, (0.0, 0.05), parts, 1.8)
    assert abs(bearing - (-np.pi / 2)) < np.radians(5)
    # from 1 m north-east of the frontier's east end, the unseen side lies south-west
    bearing = unseen_bearing(explored, GEO, (1.9, 1.0), parts, 1.8)
    assert -np.pi < bearing < -np.pi / 2
    # seen since: nothing to face
    assert unseen_bearing(np.ones_like(explored), GEO, (0.0, 0.05), parts, 1.8) is None
    assert unseen_bearing(explored, GEO, (0.0, 0.05), np.zeros((0, 2)), 1.8) is None


def test_the_far_side_of_a_wall_does_not_pull_the_bearing():
    """Unexplored cells beyond a wall east of the robot are not next to any frontier part: the
    bearing stays on the frontier's unseen side (south), not east."""
    explored = _room_seen_north_of(0.0, wall_x=0.5)
    parts = _edge_parts(0.05, -1.5, 0.4)
    bearing = unseen_bearing(explored, GEO, (0.3, 0.6), parts, 1.8)
    assert np.degrees(bearing) < -60 and np.degrees(bearing) > -135


class _Occupancy:
    def __init__(self, explored):
        self.explored = explored


class _Map:
    def __init__(self, explored):
        self.occupancy, self.geometry = _Occupancy(explored), GEO


def _looking_body(config: AgentConfig, pose: SE2Pose, can_turn: bool) -> Body:
    """A Body on GEO's half-seen room whose turns and looks are recorded, not sent."""
    body = Body.__new__(Body)
    body.config, body.pose, body.log = config, pose, []
    body.observer = type("O", (), {"map": _Map(_room_seen_north_of(0.0))})()
    body.turns, body.looks = [], []

    def turn_to(robot, yaw):
        body.turns.append(yaw)
        if can_turn:
            body.pose = SE2Pose(body.pose.x, body.pose.y, yaw)
        return can_turn

    body.turn_to = turn_to
    body.look = lambda robot, yaws, facing=None: body.looks.append(facing)
    return body


def test_looking_from_a_frontier_faces_its_unseen_side_and_turns_when_it_lies_behind():
    parts = _edge_parts(0.05, -1.0, 1.0)
    north = SE2Pose(0.0, 0.1, np.pi / 2)              # arrived heading north; the unseen floor is behind
    on = replace(OFF, face_unseen=True)
    body = _looking_body(on, north, can_turn=True)
    body.look_from_frontier(None, None, parts)
    assert len(body.turns) == 1 and abs(body.turns[0] + np.pi / 2) < np.radians(5)
    assert abs(body.looks[0] + np.pi / 2) < np.radians(5) and abs(body.pose.yaw + np.pi / 2) < np.radians(5)
    assert any("unseen side" in line for line in body.log)
    # no room to turn: the views lean that way as far as the arm still reaches (the unseen side
    # is straight behind, so either side will do); looking straight behind would skip every view
    body = _looking_body(on, north, can_turn=False)
    body.look_from_frontier(None, 1.0, parts)
    assert len(body.turns) == 1 and body.pose.yaw == north.yaw
    assert abs(abs(body.looks[0] - north.yaw) - UNSEEN_SIDE_NO_TURN) < 1e-9
    assert abs(body.looks[0] - north.yaw) + max(abs(d) for d in np.radians(on.view.look_yaws_deg)) <= MAX_GAZE_YAW
    # the unseen side already within 90 degrees of the heading: no turn
    body = _looking_body(on, SE2Pose(0.0, 0.1, -np.pi / 4), can_turn=True)
    body.look_from_frontier(None, None, parts)
    assert body.turns == [] and abs(body.looks[0] + np.pi / 2) < np.radians(5)
    # off (the earlier behaviour): the given direction, never a turn; on by default
    assert AgentConfig().face_unseen is True
    body = _looking_body(OFF, north, can_turn=True)
    body.look_from_frontier(None, 0.3, parts)
    body.look_from_frontier(None, None, parts)
    assert body.turns == [] and body.looks == [0.3, None]
