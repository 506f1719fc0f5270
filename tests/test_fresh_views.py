"""Where an extra view of a candidate comes from (``AgentConfig.fresh_view_distance``): the gaze
point with the best predicted Psi', or with the option the best one away from where earlier
views of that candidate were taken (no simulator: a fixed table of promised Psi' replaces the
prediction)."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from helios.agents import helios_agent
from helios.agents.config import AgentConfig
from helios.agents.geometry import fresh_views
from helios.agents.helios_agent import HeliosAgent
from helios.agents.target import Target
from helios.config import HeliosConfig
from helios.search import information
from helios.search.gaze_points import GazePoint
from robots.hal import SE2Pose

# three gaze points round an object at the origin; the first promises the best view
VIEWS = [GazePoint(SE2Pose(x, y, 0.0), np.array([0.0, 0.0, 0.5])) for x, y in ((0.9, 0.0), (0.0, 0.9), (-0.9, 0.0))]
PROMISED = {(0.9, 0.0): 0.8, (0.0, 0.9): 0.7, (-0.9, 0.0): 0.6}


def test_fresh_views_keeps_the_gaze_points_away_from_earlier_views_or_all_when_none_is():
    assert fresh_views(VIEWS, [], 0.3) == VIEWS
    assert fresh_views(VIEWS, [(0.9, 0.0)], 0.0) == VIEWS                       # off
    assert fresh_views(VIEWS, [(0.85, 0.05)], 0.3) == VIEWS[1:]
    assert fresh_views(VIEWS, [(0.9, 0.0), (0.0, 0.9)], 0.3) == VIEWS[2:]
    assert fresh_views(VIEWS, [(0.9, 0.0), (0.0, 0.9), (-0.9, 0.0)], 0.3) == VIEWS   # all used: any will do
    assert fresh_views([], [(0.9, 0.0)], 0.3) == []


def _agent(config: AgentConfig, monkeypatch) -> HeliosAgent:
    agent = HeliosAgent.__new__(HeliosAgent)
    agent.config, agent.method = config, HeliosConfig()
    agent.viewed = defaultdict(list)
    agent.body = SimpleNamespace(body_height=0.6)
    agent.observer = SimpleNamespace(last_obs=SimpleNamespace(intrinsics=None), map=SimpleNamespace(objects=None))
    monkeypatch.setattr(agent, "_gaze_points_of", lambda instance_id: list(VIEWS), raising=False)
    monkeypatch.setattr(helios_agent, "gaze_cameras", lambda views, h, v: [(g.pose.x, g.pose.y) for g in views])
    monkeypatch.setattr(information, "predicted_object_score",
                        lambda gmap, iid, cls, intr, T, assumption: SimpleNamespace(predicted_psi=PROMISED[T]))
    return agent


def test_an_extra_view_comes_from_a_new_spot_only_with_the_option(monkeypatch):
    target = Target(("instance", 7), np.zeros(3), np.zeros((1, 2)), 0.5, 0.4, None, 7)
    # the paper's rule read literally (default): the best promised view, however often it was taken
    agent = _agent(AgentConfig(), monkeypatch)
    assert AgentConfig().fresh_view_distance == 0.0
    agent.viewed[target.key] = [(0.9, 0.0), (0.9, 0.0)]
    view, psi = agent._best_view(target, "mug")
    assert (view.pose.x, view.pose.y) == (0.9, 0.0) and psi == 0.8
    # with the option: the best promised view among the spots not looked from yet
    agent = _agent(replace(AgentConfig(), fresh_view_distance=0.3), monkeypatch)
    view, psi = agent._best_view(target, "mug")
    assert (view.pose.x, view.pose.y) == (0.9, 0.0) and psi == 0.8             # nothing taken yet
    agent.viewed[target.key] = [(0.9, 0.0)]
    view, psi = agent._best_view(target, "mug")
    assert (view.pose.x, view.pose.y) == (0.0, 0.9) and psi == 0.7
    agent.viewed[target.key] = [(0.9, 0.0), (0.0, 0.9), (-0.9, 0.0)]            # every spot used: the best again
    view, psi = agent._best_view(target, "mug")
    assert (view.pose.x, view.pose.y) == (0.9, 0.0)


def test_the_look_decision_can_weigh_one_view_from_every_gaze_point(monkeypatch):
    """``DecisionConfig.view_prediction_poses``: with ``best`` (default) the Psi' of the best single
    view decides; with ``all`` the Psi' of one view from every gaze point together decides, and the
    view taken is still the best single one. Psi 0.40, tau 0.5, tau_inc 0.05: a view must promise
    0.45. No single view does (0.44 at best); all three together do (0.47)."""
    from helios.search.decisions import Verdict

    promised = {(0.9, 0.0): 0.44, (0.0, 0.9): 0.43, (-0.9, 0.0): 0.42}
    target = Target(("instance", 7), np.zeros(3), np.zeros((1, 2)), 0.45, 0.40, None, 7)
    seen_cams = []

    def of_views(gmap, iid, cls, intr, cams, assumption):
        seen_cams.append(list(cams))
        return SimpleNamespace(predicted_psi=0.40 + 0.07 * len(cams) / 3)

    for poses, verdict in (("best", Verdict.IGNORE), ("all", Verdict.LOOK)):
        agent = _agent(AgentConfig(), monkeypatch)
        agent.method = replace(agent.method, decision=replace(agent.method.decision, view_prediction_poses=poses))
        agent.object_class, agent.failures = "mug", {}
        monkeypatch.setattr(information, "predicted_object_score",
                            lambda gmap, iid, cls, intr, T, assumption: SimpleNamespace(predicted_psi=promised[T]))
        monkeypatch.setattr(information, "predicted_object_score_of_views", of_views)
        monkeypatch.setattr(helios_agent, "candidate_targets", lambda *a, **k: [target])
        chosen, got, view = agent._judge_targets("mug")
        assert got is verdict, poses
        if verdict is Verdict.LOOK:
            assert chosen is target and (view.pose.x, view.pose.y) == (0.9, 0.0)     # still the best single view
    assert seen_cams == [[(0.9, 0.0), (0.0, 0.9), (-0.9, 0.0)]]                      # asked once, with every view
    assert HeliosConfig().decision.view_prediction_poses == "best"


@pytest.mark.parametrize("information_gain, view_prediction, expected", [
    ("optimistic", "follow_information_gain", "optimistic"),
    ("fifty_fifty", "follow_information_gain", "fifty_fifty"),
    ("fifty_fifty", "optimistic", "optimistic"),
])
def test_the_predicted_psi_of_a_view_takes_its_assumption_from_view_prediction(information_gain, view_prediction,
                                                                              expected, monkeypatch):
    """``DecisionConfig.view_prediction``: Psi' is predicted under the IG's measurement assumption
    (``follow_information_gain``, the default) or always optimistic; the 50-50 ablation must
    reach the decision rule, not only the start-receptacle IG."""
    agent = _agent(AgentConfig(), monkeypatch)
    m = agent.method
    agent.method = replace(m, search=replace(m.search, information_gain=information_gain),
                           decision=replace(m.decision, view_prediction=view_prediction))
    seen = []
    monkeypatch.setattr(information, "predicted_object_score",
                        lambda gmap, iid, cls, intr, T, assumption: seen.append(assumption)
                        or SimpleNamespace(predicted_psi=PROMISED[T]))
    agent._best_view(Target(("instance", 7), np.zeros(3), np.zeros((1, 2)), 0.5, 0.4, None, 7), "mug")
    assert seen == [expected] * len(VIEWS)               # one prediction per gaze point, all alike
