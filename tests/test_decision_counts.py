"""Decision instrumentation: the runner's simulated time per activity and decision counts, their
aggregation (``tasks.decisions``) and the "Decisions" / "Simulated time per phase" report tables."""

from __future__ import annotations

import json
from collections import Counter
from types import SimpleNamespace

import numpy as np
import pytest

from helios.agents import helios_agent
from helios.agents.config import AgentConfig
from helios.agents.helios_agent import HeliosAgent, _LocalSearch
from helios.config import HeliosConfig
from helios.maps.instances import Instance
from helios.schema import with_overrides
from helios.search.decisions import Verdict
from helios.search.objective import FrontierOption, GlobalObjective
from tasks.decisions import (ACTIVITIES, DECISION_COUNTS, summarize_activity_time, summarize_decisions,
                             summarize_start_receptacle, summarize_timeouts)
from tasks.episodes import load_split
from tasks.run_folder import append_result, prepare_run_folder, read_results
from tasks.runner import RunnerConfig, run_episode
from tasks.trial_config import TrialConfig
from tasks.trials import run_batch, run_one
from tools.report import make_report


def test_the_report_keys_match_the_agent():
    from helios.agents import helios_agent

    assert ACTIVITIES == helios_agent.ACTIVITIES and DECISION_COUNTS == helios_agent.DECISION_COUNTS


# ------------------------------------------------------------------------------------------------
# The runner
# ------------------------------------------------------------------------------------------------
class _Standing:
    """A robot whose only command, ``stand``, takes 1.5 simulated seconds."""

    def stand(self):
        return SimpleNamespace(duration=1.5)


class _Phased:
    """Two stands per act, naming a different activity each act; its third act is cut short by the
    command budget after one stand."""

    name = "phased"

    def reset(self, task, rng):
        self.n = 0

    def act(self, robot):
        self.activity = ("start_scan", "exploration", "local_search")[min(self.n, 2)]
        self.n += 1
        robot.stand()
        robot.stand()
        return False

    def decision_stats(self):
        return {"gaze_point_visits": self.n}


def test_the_runner_times_each_activity_including_an_act_cut_short():
    ep = load_split("smoke")[0]
    result = run_episode(_Phased(), _Standing(), ep, RunnerConfig(max_commands=5))
    assert result.limit_hit and result.commands == 5 and result.sim_time == pytest.approx(7.5)
    assert result.extra["activity_time"] == {"start_scan": 3.0, "exploration": 3.0, "local_search": 1.5}
    assert result.extra["decisions"] == {"gaze_point_visits": 3}


class _Choosing(_Phased):
    """Reports its global decisions with candidates, as HELIOS does."""

    def decision_stats(self):
        return {"gaze_point_visits": self.n, "global_choices": [{"chosen": None, "candidates": [[3, 1.0, 2.0]]}]}


class _Judge:
    """Stands in for the sim judge: no metrics, and a truth check that echoes what it was given."""

    def __init__(self):
        self.given = None

    def after_command(self, name, result=None):
        pass

    def finalize(self, limit_hit):
        return None

    def start_receptacle_truth(self, choices):
        self.given = choices
        return {"decisions": len(choices), "offered": 1, "chosen": 0, "first_offered": 1}


def test_the_runner_checks_the_global_choices_with_the_judge_and_keeps_only_the_result():
    ep = load_split("smoke")[0]
    judge = _Judge()
    result = run_episode(_Choosing(), _Standing(), ep, RunnerConfig(max_commands=2), judge)
    assert judge.given == [{"chosen": None, "candidates": [[3, 1.0, 2.0]]}]
    assert result.extra["start_receptacle"] == {"decisions": 1, "offered": 1, "chosen": 0, "first_offered": 1}
    assert result.extra["decisions"] == {"gaze_point_visits": 2}          # the raw choices are not stored
    bare = run_episode(_Choosing(), _Standing(), ep, RunnerConfig(max_commands=2))     # no judge (a real robot)
    assert "start_receptacle" not in bare.extra and bare.extra["decisions"] == {"gaze_point_visits": 2}


def test_agents_without_the_hooks_get_no_fields():
    class Bare:
        name = "bare"

        def reset(self, task, rng):
            pass

        def act(self, robot):
            robot.stand()
            return True

    result = run_episode(Bare(), _Standing(), load_split("smoke")[0])
    assert "activity_time" not in result.extra and "decisions" not in result.extra


@pytest.fixture(scope="module")
def real_runs(tmp_path_factory):
    """One short HELIOS episode (40 commands: start scan, an extra view, a pick cut short) and one
    short oracle episode, as run folders."""
    tmp = tmp_path_factory.mktemp("runs")
    ep = next(e for e in load_split("smoke") if e.episode_id == "smoke-00001")
    cfg = with_overrides(TrialConfig(agent="helios", split="smoke", episodes=2), ["runner.max_commands=40"])
    helios = tmp / "helios"
    prepare_run_folder(helios, cfg)
    append_result(helios / "episodes.jsonl", run_one(cfg, ep))
    oracle = tmp / "oracle"
    run_batch(with_overrides(TrialConfig(episodes=1), ["runner.max_sim_time=20"]), load_split("smoke")[:1], oracle)
    return helios, oracle


def test_helios_records_carry_activity_time_and_decisions(real_runs):
    helios, oracle = real_runs
    record = read_results(helios / "episodes.jsonl")["smoke-00001"]
    times, decisions = record["extra"]["activity_time"], record["extra"]["decisions"]
    assert sum(times.values()) == pytest.approx(record["sim_time"], abs=1e-9)
    assert set(times) <= set(ACTIVITIES) and times["start_scan"] > 0 and len(times) >= 2
    assert set(decisions) == set(DECISION_COUNTS) | {"local_search_sizes"}
    assert all(isinstance(decisions[k], int) for k in DECISION_COUNTS)
    truth = record["extra"]["start_receptacle"]         # checked against the scene, every decision
    assert truth["decisions"] == decisions["global_with_candidates"]
    assert truth["in_view"] is None or 0.0 <= truth["in_view"] <= record["sim_time"]
    assert 0 <= truth["chosen"] <= truth["offered"] <= truth["decisions"]
    assert truth["viewed"] is not None and 0 <= truth["viewed"] <= truth["chosen"]
    other = read_results(oracle / "episodes.jsonl")["smoke-00000"]
    assert "activity_time" not in other["extra"] and "decisions" not in other["extra"]


def test_report_on_real_runs_shows_helios_numbers_and_oracle_na(real_runs, tmp_path):
    helios, oracle = real_runs
    result = make_report([helios, oracle], tmp_path / "rep")
    lines = result["text"].splitlines()
    row = lambda title, name: next(line for line in lines[next(i for i, x in enumerate(lines)  # noqa: E731
                                                                if x.startswith(title)):] if line.startswith(name))
    assert "n/a" not in row("Decisions", "helios") and row("Decisions", "oracle").count("n/a") == 15
    assert "start_scan" in result["text"] and row("Simulated time per phase", "oracle").count("n/a") == 7
    report = json.loads((tmp_path / "rep" / "report.json").read_text())
    assert report["oracle"]["decisions"] is None and report["helios"]["activity_time"]["episodes"] == 1


# ------------------------------------------------------------------------------------------------
# The agent's counters (no simulator: the agent is built bare and its map replaced)
# ------------------------------------------------------------------------------------------------
def _table(iid: int, class_name: str, score: float) -> Instance:
    return Instance(id=iid, class_name=class_name, class_scores={"table": score, "other": 1 - score},
                    uncertainties={}, psi={}, centre=np.array([1.0, 0.0, 0.5]), footprint_xy=np.zeros((1, 2)),
                    max_height=0.7, n_gaussians=10, gaussian_indices=np.arange(10))


def _bare_agent() -> HeliosAgent:
    agent = HeliosAgent.__new__(HeliosAgent)
    agent.config, agent.method, agent.stats = AgentConfig(), HeliosConfig(), Counter()
    agent.visited, agent.log = set(), []
    agent.start_class, agent.choices = "table", []
    return agent


def _choosing_agent(monkeypatch, instances: list[Instance]) -> HeliosAgent:
    """An agent whose global choice weighs ``instances`` (each with one gaze point worth IG 100)
    against one frontier 3 m away."""
    agent = _bare_agent()
    agent.body = SimpleNamespace(body_height=0.6, xy=lambda: np.zeros(2))
    agent.observer = SimpleNamespace(last_obs=SimpleNamespace(intrinsics=None), map=SimpleNamespace(objects=None),
                                     instances=lambda: instances)
    agent.pick_objective = GlobalObjective(agent.method.search, 0.025, "objective")
    monkeypatch.setattr(agent, "_gaze_points_of", lambda iid: ["g"], raising=False)
    monkeypatch.setattr(agent, "_frontier_options", lambda layer: [FrontierOption(np.array([0.0, 3.0]), 0.5, 0)],
                        raising=False)
    monkeypatch.setattr(helios_agent, "gaze_cameras", lambda views, h, v: views)
    monkeypatch.setattr(helios_agent, "views_information_gain", lambda *a, **k: 100.0)
    return agent


def test_global_decisions_are_counted_before_and_after_f0_and_only_with_candidates(monkeypatch):
    """``global_with_candidates`` counts the global decisions with an open candidate, each also
    counted once as ``chose_<kind>_before_f0`` or ``_after_f0`` (F0 calibrated by a chosen
    frontier); a decision with no candidate counts nowhere and records no choice."""
    agent = _choosing_agent(monkeypatch, [_table(1, "table", 0.8)])
    first, _ = agent._global_choice()
    assert agent.stats["global_with_candidates"] == 1 and agent.stats[f"chose_{first.kind}_before_f0"] == 1
    agent.pick_objective.note_frontier_chosen(FrontierOption(np.array([0.0, 3.0]), 0.5, 0))
    second, _ = agent._global_choice()
    assert agent.stats["global_with_candidates"] == 2 and agent.stats[f"chose_{second.kind}_after_f0"] == 1
    assert sum(agent.stats[f"chose_{k}_{w}_f0"] for k in ("candidate", "frontier") for w in ("before", "after")) == 2
    other = _choosing_agent(monkeypatch, [_table(1, "other", 0.35)])          # not a table candidate (mode is other)
    other._global_choice()
    assert other.stats["global_with_candidates"] == 0 and other.choices == []


def test_every_gaze_point_visit_counts_and_only_those_with_a_view_count_as_views():
    """``gaze_point_visits`` counts every gaze point a local search went to, ``gaze_point_views``
    (and the deciding choice's ``views``) only those where the view was taken."""
    agent = _bare_agent()
    answers = iter([False, True])                           # the first view fails, the second is taken
    agent.body = SimpleNamespace(view_from=lambda robot, g: next(answers))
    choice = {"views": 0}
    agent.local = _LocalSearch(3, ["g1", "g2"], choice)
    agent._continue_local_search(None)
    agent._continue_local_search(None)
    assert (agent.stats["gaze_point_visits"], agent.stats["gaze_point_views"], choice["views"]) == (2, 1, 1)
    assert agent.local is None and 3 in agent.visited


def test_extra_views_are_counted_for_the_phase_that_asked_for_them(monkeypatch):
    """An extra view the Psi' rule asks for counts as ``extra_views_object`` while picking and as
    ``extra_views_goal`` while placing."""
    agent = _bare_agent()
    agent.pick_attempts, agent.object_class, agent.goal_class, agent.local = 0, "mug", "bed", None
    agent.observer = SimpleNamespace(last_obs=None)      # no frame since the grasp's
    agent.grasp_frame = None
    monkeypatch.setattr(agent, "_judge_targets", lambda cls: ("t", Verdict.LOOK, "v"), raising=False)
    monkeypatch.setattr(agent, "_take_view", lambda robot, t, v: None, raising=False)
    agent._pick_step(None)
    assert (agent.stats["extra_views_object"], agent.stats["extra_views_goal"]) == (1, 0)
    agent._place_step(None)
    assert (agent.stats["extra_views_object"], agent.stats["extra_views_goal"]) == (1, 1)


# ------------------------------------------------------------------------------------------------
# Aggregation and the report on hand-written records
# ------------------------------------------------------------------------------------------------
def _record(i: int, extra: dict) -> dict:
    return {"episode_id": f"val-{i:05d}", "agent": "helios", "task": "Move the cup from the stool to the chair",
            "seed": i, "success": False, "error": None, "commands": 50, "limit_hit": False, "extra": extra,
            "collision_events": [], "sim_time": 100.0, "wall_time": 3.0,
            "metrics": {"find_obj": True, "pick": False, "find_rec": False, "place": False, "success": False,
                        "collisions": 0, "failure_reason": "pick_failed"}, "memory": None}


def _decisions(**counts) -> dict:
    sizes = counts.pop("sizes", [])
    return {**{k: 0 for k in DECISION_COUNTS}, **counts, "local_search_sizes": sizes}


NEW = [
    _record(0, {"activity_time": {"start_scan": 40.0, "local_search": 50.0, "pick": 10.0},
                "decisions": _decisions(global_with_candidates=3, chose_candidate_before_f0=2,
                                        chose_frontier_after_f0=1, extra_views_object=1, gaze_point_visits=14,
                                        gaze_point_views=9, frontiers_given_up=1, claw_drops=1, sizes=[8, 10])}),
    _record(1, {"activity_time": {"start_scan": 40.0, "exploration": 60.0},
                "decisions": _decisions(global_with_candidates=1, chose_candidate_after_f0=1, extra_views_goal=2,
                                        gaze_point_visits=3, gaze_point_views=3, sizes=[12])}),
]
OLD = _record(2, {})


def test_aggregation_of_hand_written_records():
    d = summarize_decisions(NEW + [OLD])
    assert d["episodes"] == 2 and d["of"] == 3
    assert d["totals"] == {"global_with_candidates": 4, "chose_candidate_before_f0": 2, "chose_frontier_before_f0": 0,
                           "chose_candidate_after_f0": 1, "chose_frontier_after_f0": 1, "extra_views_object": 1,
                           "extra_views_goal": 2, "gaze_point_visits": 17, "gaze_point_views": 12,
                           "frontiers_given_up": 1, "claw_drops": 1}
    assert d["per_episode"]["global_with_candidates"] == 2.0 and d["per_episode"]["gaze_point_visits"] == 8.5
    assert d["per_episode"]["gaze_point_views"] == 6.0 and d["per_episode"]["frontiers_given_up"] == 0.5
    assert d["local_searches"] == 3 and d["local_searches_per_episode"] == 1.5
    assert d["gaze_points_planned"] == {"mean": 10.0, "median": 10.0, "max": 12}
    t = summarize_activity_time(NEW + [OLD])
    assert t["episodes"] == 2 and t["activities"] == list(ACTIVITIES)
    assert t["seconds"] == {"start_scan": 80.0, "exploration": 60.0, "local_search": 50.0, "pick": 10.0,
                            "carry": 0.0, "place": 0.0}
    assert t["share_percent"]["start_scan"] == 40.0 and t["share_percent"]["exploration"] == 30.0
    assert t["seconds_per_episode"]["local_search"] == 25.0
    assert summarize_decisions([OLD]) is None and summarize_activity_time([OLD, {"episode_id": "x"}]) is None
    # no local search at all: no sizes, no crash
    assert summarize_decisions([_record(3, {"decisions": _decisions()})])["gaze_points_planned"] is None


def test_report_prints_the_sections_with_na_for_old_runs(tmp_path):
    runs = {}
    for name, records in (("new", NEW + [OLD]), ("old", [OLD])):
        runs[name] = tmp_path / name
        prepare_run_folder(runs[name], TrialConfig(agent="helios", split="val", episodes=50))
        for r in records:
            append_result(runs[name] / "episodes.jsonl", r)
    result = make_report([runs["new"], runs["old"]], tmp_path / "rep")
    text, md, page = result["text"], result["markdown"], result["html"].read_text()
    assert "Decisions: totals over the episodes shown" in text and "Simulated time per phase" in text
    assert ("| new | 2/3 | 4 (2.0) | 2 (1.0) | 0 (0.0) | 1 (0.5) | 1 (0.5) | 1 (0.5) | 2 (1.0) | 3 (1.5) "
            "| 10.0 | 10 | 12 | 17 (8.5) | 12 (6.0) | 1 (0.5) | 1 (0.5) |") in md
    assert "| old | 0/1 | n/a | n/a |" in md
    assert ("| new | 2/3 | 100 | 40.0 (40 s) | 30.0 (30 s) | 25.0 (25 s) | 5.0 (5 s) | 0.0 (0 s) | 0.0 (0 s) |"
            in md)
    assert "**Decisions: totals" in md and "**Simulated time per phase" in md
    assert "<h2>Decisions: totals" in page and "<h2>Simulated time per phase" in page
    # n/a: decisions 15 + phase times 7, and the search-speed table's 3 + 5 (these records keep no phase times)
    assert "<td>40.0 (40 s)</td>" in page and page.count("<td>n/a</td>") == 15 + 7 + 8 + 2 * 3 * 5   # + the budget table: no phase times


def test_the_phase_share_is_weighted_by_time_not_averaged_over_episodes():
    """``share_percent`` is each phase's share of the summed time: the 300 s episode weighs twice
    the 100 s one (start scan 80 of 300 s, not the mean of 40 % and 20 %)."""
    t = summarize_activity_time([_record(0, {"activity_time": {"start_scan": 40.0, "local_search": 60.0}}),
                                 _record(1, {"activity_time": {"start_scan": 40.0, "exploration": 160.0}})])
    assert t["share_percent"]["start_scan"] == pytest.approx(80 / 300 * 100)
    assert t["share_percent"]["exploration"] == pytest.approx(160 / 300 * 100)


def test_report_decisions_row_puts_each_count_in_its_own_column(tmp_path):
    """Every decision count differs, so a column shown under another's header shows."""
    run = tmp_path / "distinct"
    prepare_run_folder(run, TrialConfig(agent="helios", split="val", episodes=1))
    append_result(run / "episodes.jsonl", _record(0, {"decisions": _decisions(
        global_with_candidates=28, chose_candidate_before_f0=1, chose_frontier_before_f0=2,
        chose_candidate_after_f0=3, chose_frontier_after_f0=4, extra_views_object=5, extra_views_goal=6,
        gaze_point_visits=7, gaze_point_views=8, frontiers_given_up=9, claw_drops=10)}))
    md = make_report([run], tmp_path / "rep", episode_pages=False)["markdown"].splitlines()
    assert ("| distinct | 1/1 | 28 (28.0) | 1 (1.0) | 2 (2.0) | 3 (3.0) | 4 (4.0) | 5 (5.0) | 6 (6.0) | 0 (0.0) "
            "| - | - | - | 7 (7.0) | 8 (8.0) | 9 (9.0) | 10 (10.0) |") in md


def test_gaze_point_views_unknown_when_a_record_predates_them(tmp_path):
    """Records made before views were counted lack ``gaze_point_views``: the run's total is None and
    the report's cell '-', never a 0 that would read as 'no visit took a view'."""
    before = _record(4, {"decisions": {k: v for k, v in _decisions(gaze_point_visits=5).items()
                                       if k != "gaze_point_views"}})
    d = summarize_decisions(NEW + [before])
    assert d["totals"]["gaze_point_views"] is None and d["per_episode"]["gaze_point_views"] is None
    assert d["totals"]["gaze_point_visits"] == 22
    run = tmp_path / "mixed"
    prepare_run_folder(run, TrialConfig(agent="helios", split="val", episodes=20))
    for r in NEW + [before]:
        append_result(run / "episodes.jsonl", r)
    md = make_report([run], tmp_path / "rep")["markdown"]
    assert "| 22 (7.3) | - | 1 (0.3) | 1 (0.3) |" in md


@pytest.mark.parametrize("key", ["frontiers_given_up", "claw_drops"])
def test_counts_added_later_are_unknown_when_a_record_predates_them(key):
    """``frontiers_given_up`` (``AgentConfig.stall_steps``) is counted since 2026-12-04 and
    ``claw_drops`` since 2026-12-06: a run with an older record reports None for them, not 0."""
    before = _record(5, {"decisions": {k: v for k, v in _decisions().items() if k != key}})
    d = summarize_decisions(NEW + [before])
    assert d["totals"][key] is None and d["per_episode"][key] is None
    assert summarize_decisions(NEW)["totals"][key] == 1


def _timed_out(i: int, reached: tuple[str, ...], extra: dict) -> dict:
    r = _record(i, extra)
    r["metrics"] = {**r["metrics"], **{k: k in reached for k in ("find_obj", "pick", "find_rec", "place")},
                    "failure_reason": "timeout"}
    r["sim_time"] = 600.0
    return r


TIMEOUTS = [
    _timed_out(10, (), {"activity_time": {"start_scan": 40.0, "exploration": 300.0, "local_search": 260.0},
                        "decisions": _decisions(gaze_point_visits=20, extra_views_object=1, sizes=[9, 11])}),
    _timed_out(11, (), {"activity_time": {"start_scan": 40.0, "exploration": 500.0, "local_search": 60.0},
                        "decisions": _decisions(gaze_point_visits=6, sizes=[6])}),
    _timed_out(12, ("find_obj",), {"activity_time": {"start_scan": 40.0, "exploration": 200.0,
                                                     "local_search": 360.0},
                                   "decisions": _decisions(gaze_point_visits=10, extra_views_object=6, sizes=[10])}),
    _timed_out(13, ("find_obj", "pick", "find_rec"), {"activity_time": {"start_scan": 40.0, "pick": 20.0,
                                                                         "carry": 540.0},
                                                      "decisions": _decisions(extra_views_goal=5)}),
]


def test_timeouts_are_split_by_the_stage_they_ran_out_in():
    t = summarize_timeouts(NEW + [OLD] + TIMEOUTS)
    assert t["scored"] == 7 and t["timeouts"] == 4 and abs(t["percent"] - 400 / 7) < 1e-9
    assert t["stages"] == {"before_find_obj": 2, "found_not_picked": 1, "picked_goal_not_found": 0,
                           "at_goal_not_placed": 1}
    per = t["activity_seconds_per_episode"]           # over the 4 timeouts only
    assert per["exploration"] == 250.0 and per["local_search"] == 170.0 and per["carry"] == 135.0
    assert t["gaze_point_visits_per_episode"] == 9.0 and t["extra_views_per_episode"] == 3.0
    none = summarize_timeouts(NEW)                     # scored, no timeout: zeros, nothing to average
    assert none["timeouts"] == 0 and none["percent"] == 0.0 and set(none["stages"].values()) == {0}
    assert none["activity_seconds_per_episode"] is None and none["gaze_point_visits_per_episode"] is None
    assert summarize_timeouts([{"episode_id": "x", "metrics": None}]) is None


def test_report_has_the_timeouts_table(tmp_path):
    runs = {}
    for name, records in (("with", NEW + TIMEOUTS), ("without", NEW)):
        runs[name] = tmp_path / name
        prepare_run_folder(runs[name], TrialConfig(agent="helios", split="val", episodes=50))
        for r in records:
            append_result(runs[name] / "episodes.jsonl", r)
    result = make_report([runs["with"], runs["without"]], tmp_path / "rep", episode_pages=False)
    md = result["markdown"]
    assert "**Timeouts: where the time ran out" in md
    assert ("| with | 4/6 (66.7 %) | 2 | 1 | 0 | 1 | 40 | 250 | 170 | 5 | 135 | 0 | 9.0 | 3.0 |") in md
    assert "| without | 0/2 (0.0 %) | 0 | 0 | 0 | 0 | - | - | - | - | - | - | - | - |" in md
    report = json.loads((tmp_path / "rep" / "report.json").read_text())
    assert report["with"]["timeouts"]["stages"]["before_find_obj"] == 2


def _checked(i: int, found: bool, offered: int, chosen: int, **in_view) -> dict:
    r = _record(i, {"start_receptacle": {"decisions": 9, "offered": offered, "chosen": chosen,
                                         "first_offered": 2 if offered else None, **in_view}})
    r["metrics"] = {**r["metrics"], "find_obj": found, "failure_reason": "pick_failed" if found else "not_found"}
    return r


CHECKED = [_checked(20, True, 3, 1), _checked(21, False, 0, 0), _checked(22, False, 5, 0),
           _checked(23, False, 2, 1), _checked(24, False, 0, 0)]


def test_the_start_receptacle_check_is_summed_and_split_by_why_the_object_was_missed():
    s = summarize_start_receptacle(CHECKED + [OLD])
    assert (s["episodes"], s["of"], s["offered"], s["searched"], s["never_searched"]) == (5, 6, 3, 2, 1)
    assert s["passed_over_per_offered"] == (2 + 5 + 1) / 3
    assert s["not_found"] == {"episodes": 4, "never_offered": 2, "offered_not_searched": 1, "searched": 1,
                              "never_in_view": None, "in_view": None, "searched_no_view": None,
                              "searched_viewed": None}
    assert summarize_start_receptacle([OLD]) is None
    nothing = summarize_start_receptacle([_checked(25, False, 0, 0)])
    assert nothing["passed_over_per_offered"] is None and nothing["not_found"]["never_offered"] == 1
    assert nothing["not_found"]["never_in_view"] is None          # records that do not say
    viewed = summarize_start_receptacle(VIEWED)
    assert viewed["not_found"] == {"episodes": 4, "never_offered": 3, "offered_not_searched": 1, "searched": 0,
                                   "never_in_view": 1, "in_view": 2, "searched_no_view": None, "searched_viewed": None}
    looked = summarize_start_receptacle(LOOKED)["not_found"]
    assert (looked["searched"], looked["searched_no_view"], looked["searched_viewed"]) == (3, 2, 1)


VIEWED = [_checked(30, False, 0, 0, in_view=None), _checked(31, False, 0, 0, in_view=80.5),
          _checked(32, False, 0, 0, in_view=12.0), _checked(33, False, 4, 0, in_view=30.0),
          _checked(34, True, 0, 0, in_view=None)]
# searched without FindObj: twice without a single view (every gaze point failed), once with views;
# a found one with no view does not count, nor one made before views were kept
LOOKED = [_checked(40, False, 2, 1, in_view=20.0, viewed=0), _checked(41, False, 3, 2, in_view=20.0, viewed=0),
          _checked(42, False, 1, 1, in_view=20.0, viewed=1), _checked(43, True, 1, 1, in_view=20.0, viewed=0),
          _checked(44, False, 0, 0, in_view=None, viewed=0)]


def test_report_has_the_start_receptacle_table_only_when_a_run_has_the_check(tmp_path):
    runs = {}
    for name, records in (("checked", CHECKED), ("viewed", VIEWED), ("looked", LOOKED), ("old", [OLD])):
        runs[name] = tmp_path / name
        prepare_run_folder(runs[name], TrialConfig(agent="helios", split="val", episodes=50))
        for r in records:
            append_result(runs[name] / "episodes.jsonl", r)
    md = make_report([runs["checked"], runs["viewed"], runs["looked"], runs["old"]], tmp_path / "rep",
                     episode_pages=False)["markdown"]
    assert "**The start receptacle that holds the object" in md
    assert "| checked | 5/5 | 3 (60 %) | 2 (40 %) | 1 (20 %) | 2.7 | 4 | 2 | 1 | 1 |" in md
    assert "| viewed | 5/5 | 1 (20 %) | 0 (0 %) | 1 (20 %) | 4.0 | 4 | 3 (1 / 2) | 1 | 0 |" in md
    assert "| looked | 5/5 | 4 (80 %) | 4 (80 %) | 0 (0 %) | 0.5 | 4 | 1 (1 / 0) | 0 | 3 (2 / 1) |" in md
    assert "| old | 0/1 | n/a | n/a | n/a | n/a | n/a | n/a | n/a | n/a |" in md
    report = json.loads((tmp_path / "rep" / "report.json").read_text())
    assert report["checked"]["start_receptacle"]["offered"] == 3 and report["old"]["start_receptacle"] is None
    alone = make_report([runs["old"]], tmp_path / "rep2", episode_pages=False)["markdown"]
    assert "start receptacle that holds" not in alone
