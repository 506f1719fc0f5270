"""Which instances count as candidates, and how the searches without candidates pick frontiers."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from helios.agents.candidates import is_candidate
from helios.agents.config import AgentConfig, VariantFlags
from helios.config import DecisionConfig, HeliosConfig
from helios.maps.instances import Instance


def instance(class_name: str, scores: dict[str, float]) -> Instance:
    return Instance(id=1, class_name=class_name, class_scores=scores, uncertainties={k: 0.1 for k in scores},
                    psi={k: v - 0.1 for k, v in scores.items()}, centre=np.zeros(3),
                    footprint_xy=np.zeros((1, 2)), max_height=0.7, n_gaussians=10, gaussian_indices=np.arange(10))


def test_a_candidate_must_be_most_likely_its_class_and_score_at_least_cs():
    """The paper's A ("objects whose class is that of the pick location") with cs_a = 0.3: a chair
    that is 35 % table is not a table candidate; the earlier reading (score only) took it."""
    paper = HeliosConfig()
    score_only = replace(paper, decision=replace(paper.decision, candidate_class="score_only"))
    chair = instance("chair", {"table": 0.35, "chair": 0.5, "other": 0.15})
    table = instance("table", {"table": 0.45, "chair": 0.3, "other": 0.25})
    faint_table = instance("table", {"table": 0.28, "chair": 0.27, "other": 0.27})
    assert paper.decision.candidate_class == "most_likely"
    assert not is_candidate(chair, "table", 0.3, paper)
    assert is_candidate(chair, "table", 0.3, score_only)
    assert is_candidate(table, "table", 0.3, paper) and is_candidate(table, "table", 0.3, score_only)
    assert not is_candidate(faint_table, "table", 0.3, paper)          # most likely, but below cs
    assert not is_candidate(faint_table, "table", 0.3, score_only)
    with pytest.raises(ValueError, match="candidate_class"):
        DecisionConfig(candidate_class="vote")


def test_searches_without_candidates_use_the_frontiers_only_objective():
    """The trusting agent's pick phase and every agent's place phase choose frontiers by value
    alone (helios.search.objective, frontier_choice = highest_value)."""
    from helios.agents.helios_agent import HeliosAgent
    from helios.config import SearchConfig
    from tasks.spec import parse_task

    assert VariantFlags.of("trusting") == VariantFlags(object_map=False, pick_objective="frontiers_only")
    assert VariantFlags.of("helios").pick_objective == "objective"
    assert VariantFlags.of("no_global").pick_objective == "prefer_candidates"
    assert SearchConfig().frontier_choice == "highest_value"
    task = parse_task("Move the mug from the stool to the table")
    for variant, pick_mode in (("helios", "objective"), ("trusting", "frontiers_only")):
        agent = HeliosAgent(detector=None, scorer=None, config=AgentConfig(variant=variant))
        agent.reset(task, np.random.default_rng(0))
        assert agent.pick_objective.mode == pick_mode
        assert agent.place_objective.mode == "frontiers_only"
