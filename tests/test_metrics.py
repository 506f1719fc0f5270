"""Metrics judged from ground truth, on constructed situations in a hand-built kitchen: success, a
held object, an object on the wrong receptacle, one that falls off, a collision, a wrong pick, a
timeout and never looking."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robots.hal import SE2Pose
from robots.spot.sim_backend import SimSpotBackend
from sim.camera import decode_body_ids
from sim.scenes.catalog import make_object, make_receptacle
from sim.scenes.home import build_home
from sim.scenes.layout import HomeLayout, PlacedObject, PlacedReceptacle, Room, Wall
from sim.spot import SpotBody
from sim.world import World
from tasks.episodes import Episode, SceneRef
from tasks.metrics import FAILURE_REASONS, EpisodeJudge, MetricsConfig
from tasks.oracle import OracleAgent
from tasks.runner import RunnerConfig, SimEpisode, run_episode
from tasks.trial_summary import summarize


def _kitchen() -> HomeLayout:
    rng = np.random.default_rng(0)
    table, desk, stool = make_receptacle("table", rng), make_receptacle("desk", rng), make_receptacle("stool", rng)
    mug, cup = make_object("mug", rng), make_object("cup", rng)
    d_hy = desk.half_footprint[1]
    recs = [PlacedReceptacle("table_1", table, 2.0, 2.5, 0.0, "kitchen"),
            PlacedReceptacle("desk_1", desk, 5.0, 6.0 - 0.09 - d_hy, 0.0, "kitchen"),
            PlacedReceptacle("stool_1", stool, 5.5, 1.2, 0.0, "kitchen")]
    objs = [PlacedObject("mug_1", mug, "table_1", 0, 1.85, 2.45, table.surfaces[0].centre[2], 0.3),
            PlacedObject("cup_1", cup, "stool_1", 0, 5.5, 1.2, stool.surfaces[0].centre[2], 0.0)]
    walls = [Wall(0, 0, 7, 0), Wall(7, 0, 7, 6), Wall(7, 6, 0, 6), Wall(0, 6, 0, 0)]
    return HomeLayout(0, 7.0, 6.0, [Room("kitchen", 0, 0, 7, 6)], walls, [], recs, objs, (3.6, 3.6, math.pi))


def _episode(goal="desk") -> Episode:
    return Episode(episode_id="test-00000", split="test", scene=SceneRef(0), task=f"Move the mug from the table to the {goal}",
                   object_category="mug", start_receptacle_category="table", goal_receptacle_category=goal,
                   target_object="mug_1", start_receptacle="table_1", goal_receptacles=(f"{goal}_1",),
                   robot_start=(3.6, 3.6, math.pi))


def _sim(goal="desk") -> SimEpisode:
    world = World()
    scene = build_home(world, _kitchen())
    ep = _episode(goal)
    backend = SimSpotBackend(world, SpotBody(world, ep.start_pose))
    return SimEpisode(ep, world, scene, backend, EpisodeJudge(backend, scene, ep))


def _run(agent_factory, goal="desk", config=RunnerConfig()):
    sim = _sim(goal)
    try:
        agent = agent_factory(sim)
        result = run_episode(agent, sim.backend, sim.episode, config, sim.judge, start_time=sim.world.time)
        return result, sim.judge, agent
    finally:
        sim.close()


class _Bump(OracleAgent):
    """Walks into the wall first, then does the task."""

    def act(self, robot):
        if self._phase == "fetch":
            robot.navigate_to(SE2Pose(6.9, 3.6, 0.0))
        return super().act(robot)


class _WrongPick(OracleAgent):
    """Picks the cup on the stool (a look-alike) instead of the mug."""

    def __init__(self, sim):
        super().__init__(sim)
        self._targets = [sim.scene.object_ids["cup_1"]]
        self._support = {self._targets[0]: "stool_1"}


class _HoldOn(OracleAgent):
    """Grasps, walks to the desk and looks at it, then declares itself done without placing."""

    def act(self, robot):
        super().act(robot)
        if self._phase == "deliver":
            centre = self._scene.surface_points("desk_1")[0]
            here = robot.observe().body_pose
            pose = self._scene.nav.approach_poses(centre + [0, 0, 0.25], (here.x, here.y), self._scene.front("desk_1"))[0]
            self._walk(robot, pose)
            robot.gaze_at(centre)
            robot.observe()
        return True


class _Idle:
    name = "idle"

    def reset(self, task, rng):
        pass

    def act(self, robot):
        robot.observe()
        return True


def test_oracle_success_latches_every_phase():
    grasped_at = []

    def factory(sim):
        t0, grasp = sim.world.time, sim.backend.grasp

        def timed_grasp(*args, **kwargs):
            result = grasp(*args, **kwargs)
            grasped_at.append(sim.world.time - t0)
            return result

        sim.backend.grasp = timed_grasp
        return OracleAgent(sim)

    result, judge, agent = _run(factory)
    m = result.metrics
    assert (m.find_obj, m.pick, m.find_rec, m.place, m.success) == (True, True, True, True, True), agent.log
    assert m.failure_reason is None and m.collisions == 0 and m.pick_attempts == 1
    # each phase's first moment, in simulated seconds from the start, in the order the task needs them;
    # Pick is the moment the (only) grasp command returned holding the mug
    assert 0.0 < m.find_obj_time < m.pick_time < m.find_rec_time <= result.sim_time
    assert len(grasped_at) == 1 and m.pick_time == pytest.approx(grasped_at[0], abs=1e-3)


def test_object_put_on_the_wrong_receptacle_is_misidentified():
    def factory(sim):
        agent = OracleAgent(sim)
        agent._goals = ["stool_1"]
        return agent

    result, _, agent = _run(factory)
    m = result.metrics
    assert m.pick and not m.place and not m.success
    assert m.released_on == "stool_1" and m.failure_reason == "misidentified"


def test_object_released_at_the_edge_falls_off():
    def factory(sim):
        return OracleAgent(sim, edge_inset=-0.04)   # release 4 cm beyond the near edge

    result, _, agent = _run(factory)
    m = result.metrics
    assert m.find_rec and not m.place and m.failure_reason == "fell_off", agent.log
    assert m.released_on in ("ground", "floor")


def test_a_collision_turns_a_placed_object_into_a_failure():
    result, _, agent = _run(_Bump)
    m = result.metrics
    assert m.place and m.collisions >= 1 and not m.success and m.failure_reason == "collision", agent.log


def test_grasping_a_lookalike_is_misidentified_and_pick_stays_false():
    result, _, agent = _run(_WrongPick)
    m = result.metrics
    assert m.picked_wrong_object and not m.pick and m.failure_reason == "misidentified", agent.log


def test_holding_at_the_end_is_a_failed_place_or_a_timeout():
    result, _, _ = _run(_HoldOn)
    assert result.metrics.pick and not result.metrics.place and result.metrics.failure_reason == "place_failed"
    result, _, _ = _run(OracleAgent, config=RunnerConfig(max_sim_time=45.0))   # out of time while carrying
    assert result.limit_hit and result.metrics.pick and result.metrics.failure_reason == "timeout"


def test_never_finding_the_object():
    result, _, _ = _run(lambda sim: _Idle())
    m = result.metrics
    assert not m.find_obj and m.failure_reason == "not_found"
    assert result.commands == 1
    assert (m.find_obj_time, m.pick_time, m.find_rec_time) == (None, None, None)


def test_a_lookalike_grasp_keeps_the_pick_time_empty_and_the_find_time_of_the_first_sighting():
    result, judge, agent = _run(_WrongPick)
    m = result.metrics
    assert m.picked_wrong_object and m.pick_time is None and m.find_rec_time is None
    if m.find_obj:                 # the true mug may have been in view on the way: then when first seen
        assert 0.0 < m.find_obj_time <= result.sim_time
    else:
        assert m.find_obj_time is None


def test_summary_rates_and_standard_errors():
    recs = [{"metrics": {"find_obj": True, "pick": i < 3, "find_rec": i < 2, "place": i < 1, "success": i < 1,
                         "failure_reason": None if i < 1 else "pick_failed", "collisions": 0},
             "sim_time": 10.0, "wall_time": 1.0, "error": None} for i in range(4)]
    s = summarize(recs)
    assert s["FindObj"]["percent"] == 100.0 and s["FindObj"]["se"] == 0.0
    assert s["Pick"]["percent"] == 75.0 and s["Pick"]["se"] == pytest.approx(100 * math.sqrt(0.75 * 0.25 / 4))
    assert s["SR"]["count"] == 1 and s["failure_reasons"]["pick_failed"] == 3
    assert set(s["failure_reasons"]) == set(FAILURE_REASONS)


def test_the_judge_checks_the_searchs_candidates_against_the_true_start_receptacle():
    """The mug rests on table_1; a candidate within 0.2 m of the table's footprint is that table,
    one 0.3 m off it or on the desk is not. Offered, chosen and the first offer are counted per
    decision."""
    sim = _sim()
    try:
        lo, hi = sim.world.aabb(sim.scene.receptacle_ids["table_1"])
        cx, cy = (lo[:2] + hi[:2]) / 2
        desk = sim.world.position(sim.scene.receptacle_ids["desk_1"])
        assert sim.judge.target_supports == [sim.scene.receptacle_ids["table_1"]]
        near, far = [hi[0] + 0.15, cy], [hi[0] + 0.3, cy]        # beside the table, x beyond its footprint
        choices = [{"chosen": None, "candidates": [[4, float(desk[0]), float(desk[1])], [5, *far]]},
                   {"chosen": 4, "candidates": [[4, float(desk[0]), float(desk[1])], [7, float(cx), float(cy)]]},
                   {"chosen": None, "candidates": [[7, float(cx), float(cy)]]},
                   {"chosen": 9, "candidates": [[9, *near]]}]
        assert sim.judge.start_receptacle_truth(choices) == {"decisions": 4, "offered": 3, "chosen": 1,
                                                             "first_offered": 2, "in_view": None, "viewed": None}
        assert sim.judge.start_receptacle_truth(choices[:1]) == {"decisions": 1, "offered": 0, "chosen": 0,
                                                                 "first_offered": None, "in_view": None, "viewed": 0}
        # viewed: of the decisions that chose the table, those whose local search took a view
        blind = [dict(c, views=3) if c["chosen"] == 4 else dict(c, views=0) if c["chosen"] == 9 else c for c in choices]
        assert sim.judge.start_receptacle_truth(blind)["viewed"] == 0       # the desk's 3 views do not count
        seen = [dict(c, views=1) if c["chosen"] is not None else c for c in choices]
        assert sim.judge.start_receptacle_truth(seen)["viewed"] == 1
        # in view: the first frame the agent took in which the table covers min_coverage of the pixels
        robot = sim.backend
        robot.gaze_at(np.array([float(cx), float(cy), 0.5]))
        look = robot.observe()
        table_px = np.count_nonzero(decode_body_ids(robot.segmentation_for(look)) == sim.scene.receptacle_ids["table_1"])
        assert table_px > 0.05 * look.depth.size
        strict = EpisodeJudge(robot, sim.scene, sim.episode, MetricsConfig(min_coverage=0.9))
        strict.on_observation(look)
        assert strict.support_seen_time is None        # 5 % of the frame is not 90 %
        sim.judge.on_observation(look)
        assert sim.judge.support_seen_time is not None and sim.judge.support_seen_time >= 0.0
        assert sim.judge.start_receptacle_truth([])["in_view"] == sim.judge.support_seen_time
    finally:
        sim.close()


def test_the_findrec_check_view_is_rendered_only_near_a_goal_receptacle(monkeypatch):
    """The judge's check view (a second render of a frame, near plane past the held object) only
    where FindRec can be decided: some goal receptacle within ``rec_radius``. FindRec is still
    judged as before (the oracle's episode succeeds with every phase in order)."""
    import sim.camera

    checks, frames = [], []
    real_render = sim.camera.render

    def counting_render(world, intr, T_world_cam, config):
        if config.near > 0.2:                   # the check view (held_clip); agent frames use the camera's
            checks.append(np.asarray(T_world_cam)[:2, 3].copy())
        return real_render(world, intr, T_world_cam, config)

    monkeypatch.setattr(sim.camera, "render", counting_render)

    def factory(sim_episode):
        judge, observe = sim_episode.judge, sim_episode.judge.on_observation

        def watched(obs):
            if judge.metrics.pick and not judge.metrics.find_rec:
                frames.append(min(judge._footprint_distance(rid, obs.T_world_body[:2, 3]) for rid in judge.goal_ids))
            observe(obs)

        judge.on_observation = watched
        return OracleAgent(sim_episode)

    result, judge, agent = _run(factory)
    m = result.metrics
    assert (m.find_obj, m.pick, m.find_rec, m.place, m.success) == (True, True, True, True, True), agent.log
    rec_radius = MetricsConfig().rec_radius
    near = [d for d in frames if d <= rec_radius]
    assert frames and len(checks) == len(near) >= 1          # one check view per frame near the desk, none elsewhere
    assert len(near) < len(frames)                            # the carry had frames far from it (skipped)


# ------------------------------------------------------------------------------------------------
# The phase chain and the wait period, each shown to fail under a mutation the suite let through
# ------------------------------------------------------------------------------------------------
def _look_at(sim, name):
    """Stand in front of receptacle ``name``, look at its top, return the frame (judge not told)."""
    centre = sim.scene.surface_points(name)[0]
    here = sim.backend.observe().body_pose
    pose = sim.scene.nav.approach_poses(centre + [0, 0, 0.25], (here.x, here.y), sim.scene.front(name))[0]
    sim.backend.spot.set_base_pose(pose)
    sim.backend.gaze_at(centre)
    return sim.backend.observe()


def test_findrec_needs_pick():
    """(metrics audit 2026-12-05: FindRec without Pick went unnoticed but for a CPU-gated record)"""
    sim = _sim()
    try:
        j = sim.judge
        j.metrics.find_obj = True                      # found, never picked
        j.on_observation(_look_at(sim, "desk_1"))
        assert not j.metrics.find_rec                  # FindRec = Pick AND near/visible goal
        j.metrics.pick = True
        j.on_observation(_look_at(sim, "desk_1"))
        assert j.metrics.find_rec                      # the same frame counts once picked
    finally:
        sim.close()


def test_pick_needs_findobj(monkeypatch):
    """(metrics audit 2026-12-05: Pick without FindObj went unnoticed)"""
    sim = _sim()
    try:
        j, mug = sim.judge, sim.scene.object_ids["mug_1"]
        monkeypatch.setattr(type(sim.backend), "held_body", property(lambda self: mug))
        j.after_command("grasp")                       # holds a valid target, FindObj never reached
        assert not j.metrics.pick and j.metrics.pick_attempts == 1
        j.metrics.find_obj = True
        j.after_command("grasp")
        assert j.metrics.pick
    finally:
        sim.close()


def _mug_on_desk(sim):
    mug = sim.scene.object_ids["mug_1"]
    c = sim.scene.surface_points("desk_1")[0]
    size = sim.world.bodies[mug].extra.get("size", (0.08, 0.08, 0.1))
    sim.world.client.resetBasePositionAndOrientation(mug, [c[0], c[1], c[2] + 0.5 * size[2] + 0.002], [0, 0, 0, 1])
    for _ in range(240):
        sim.world.step()
    return mug


def test_place_needs_findrec_and_the_object_at_rest_for_the_wait_period(monkeypatch):
    """(metrics audit 2026-12-05: Place without FindRec, or without the object at rest through the
    wait period, went unnoticed)"""
    sim = _sim()
    try:
        j = sim.judge
        _mug_on_desk(sim)
        j.metrics.find_obj = j.metrics.pick = True     # FindRec never reached
        m = j.finalize(False)
        assert not m.place and not m.success
    finally:
        sim.close()
    sim = _sim()
    try:
        j = sim.judge
        _mug_on_desk(sim)
        j.metrics.find_obj = j.metrics.pick = j.metrics.find_rec = True
        # on the goal's top but at rest only every other physics step (never 50 in a row)
        monkeypatch.setattr(sim.world, "is_at_rest",
                            lambda b: int(round(sim.world.time / sim.world.timestep)) % 2 == 0)
        m = j.finalize(False)
        assert not m.place and not m.success
    finally:
        sim.close()
    sim = _sim()
    try:                                               # sanity: the same placement, at rest, is a Place
        j = sim.judge
        _mug_on_desk(sim)
        j.metrics.find_obj = j.metrics.pick = j.metrics.find_rec = True
        m = j.finalize(False)
        assert m.place and m.success
    finally:
        sim.close()


def test_rates_count_only_scored_episodes():
    """An episode without metrics (it ended on an exception) is not a failure of every phase."""
    rec = {"metrics": {"find_obj": True, "pick": True, "find_rec": True, "place": True, "success": True,
                       "collisions": 0, "failure_reason": None, "pick_attempts": 1},
           "sim_time": 100.0, "wall_time": 1.0, "episode_id": "val-00000"}
    s = summarize([rec, {"metrics": None, "sim_time": 1.0, "wall_time": 1.0, "episode_id": "val-00001"}])
    assert s["scored"] == 1 and s["SR"]["percent"] == 100.0
