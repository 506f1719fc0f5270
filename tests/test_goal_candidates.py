"""Goal-receptacle candidates and the receptacle the held object was taken from
(``AgentConfig.goal_not_pick_site``): with a detector that confuses look-alikes, the cabinet an apple
was just taken from is also labelled "filing cabinet", and without the option it is the first goal
candidate the place phase looks at."""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import torch

from helios.agents import helios_agent
from helios.agents.candidates import candidate_targets, is_pick_site
from helios.agents.config import AgentConfig
from helios.agents.helios_agent import HeliosAgent, Phase
from helios.agents.skill import SkillOutcome
from helios.agents.target import Target
from helios.config import HeliosConfig
from helios.maps.instances import Instance
from helios.search.decisions import Verdict


def _instance(iid: int, cls: str, x0: float, x1: float, psi: float = 0.45) -> Instance:
    """A 0.5 m deep receptacle spanning x0..x1 at y 0..0.5, labelled ``cls``."""
    xs, ys = np.meshgrid(np.arange(x0, x1 + 1e-9, 0.1), np.arange(0.0, 0.51, 0.1))
    foot = np.stack([xs.ravel(), ys.ravel()], axis=1)
    scores = {cls: 0.6}
    return Instance(iid, cls, scores, {cls: 0.15}, {cls: psi}, np.array([(x0 + x1) / 2, 0.25, 0.4]),
                    foot, 0.8, len(foot), np.arange(len(foot)))


def _observer(instances, picked_from=None):
    n = max(i.n_gaussians for i in instances)
    return SimpleNamespace(
        object_class="apple", goal_class="filing cabinet", start_class="cabinet", picked_from=picked_from,
        instances=lambda: instances, map=SimpleNamespace(objects=SimpleNamespace(means=torch.zeros(n, 3))))


# the apple was grasped at (0.3, 0.25), on the cabinet spanning x 0..1; a real filing cabinet at x 3..3.5
UNDER_THE_HAND = _instance(22, "filing cabinet", 0.0, 1.0)
ELSEWHERE = _instance(36, "filing cabinet", 3.0, 3.5, psi=0.40)


def test_the_receptacle_the_object_came_from_is_no_goal_candidate_with_the_option():
    method, picked = HeliosConfig(), np.array([0.3, 0.25])
    on = replace(AgentConfig(), goal_not_pick_site=True)
    observer = _observer([UNDER_THE_HAND, ELSEWHERE], picked)
    assert is_pick_site(observer, UNDER_THE_HAND, on) and not is_pick_site(observer, ELSEWHERE, on)
    keys = [t.key for t in candidate_targets(observer, "filing cabinet", on, method, Counter())]
    assert keys == [("instance", 36)]
    # the paper's rule (default): both, best Psi first, so the pick site is judged first
    assert AgentConfig().goal_not_pick_site is False
    keys = [t.key for t in candidate_targets(observer, "filing cabinet", AgentConfig(), method, Counter())]
    assert keys == [("instance", 22), ("instance", 36)]
    # before any grasp nothing is left out
    keys = [t.key for t in candidate_targets(_observer([UNDER_THE_HAND, ELSEWHERE]), "filing cabinet", on, method,
                                             Counter())]
    assert keys == [("instance", 22), ("instance", 36)]


def test_the_pick_site_reaches_as_far_as_the_support_radius():
    near = _instance(5, "filing cabinet", 0.6, 1.2)          # its edge 0.3 m from the grasp point
    far = _instance(6, "filing cabinet", 0.7, 1.2)           # 0.4 m
    observer = _observer([near, far], np.array([0.3, 0.25]))
    config = replace(AgentConfig(), goal_not_pick_site=True, support_radius=0.35)
    assert is_pick_site(observer, near, config) and not is_pick_site(observer, far, config)
    assert not is_pick_site(observer, near, replace(config, support_radius=0.25))


def test_the_object_candidates_are_never_filtered_by_the_pick_site():
    apple = _instance(9, "apple", 0.2, 0.4, psi=0.6)
    observer = _observer([apple], np.array([0.3, 0.25]))
    config = replace(AgentConfig(), goal_not_pick_site=True, require_start_support=False)
    assert [t.key for t in candidate_targets(observer, "apple", config, HeliosConfig(), Counter())] == [("instance", 9)]


def test_a_successful_grasp_records_where_the_object_was_taken_from(monkeypatch):
    agent = HeliosAgent.__new__(HeliosAgent)
    agent.config, agent.method, agent.phase = AgentConfig(), HeliosConfig(), Phase.PICK
    agent.pick_attempts, agent.object_class, agent.body, agent.log = 0, "apple", None, []
    agent.observer = SimpleNamespace(picked_from=None)
    target = Target(("instance", 9), np.array([2.0, 3.0, 0.7]), np.zeros((1, 2)), 0.8, 0.7, None, 9)
    monkeypatch.setattr(agent, "_judge_targets", lambda cls: (target, Verdict.ACT, None), raising=False)
    monkeypatch.setattr(helios_agent, "pick", lambda *a: SkillOutcome(False, "slipped", attempted=True))
    agent.failures = Counter()
    agent._pick_step(None)
    assert agent.phase is Phase.PICK and agent.observer.picked_from is None
    monkeypatch.setattr(helios_agent, "pick", lambda *a: SkillOutcome(True, attempted=True))
    agent._pick_step(None)
    assert agent.phase is Phase.PLACE
    np.testing.assert_allclose(agent.observer.picked_from, [2.0, 3.0])
