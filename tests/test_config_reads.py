"""What each agent reads while it runs, against what ``tools trials`` refuses it as unread.

A run refuses a setting its agent never reads (``tasks.registry.replaced_settings``'s ignored
sections and ``unread_settings``), so config.yaml never records a setting that changed nothing.
A refusal list written from reading the code could name a setting some branch does read (the
measured arm model leaves ``view.arm_swing_radius`` alone, yet a gaze collision reads
``view.elbow_radius``), and refusing that would be worse than the gap it closes. The guard here
runs real episodes under :class:`tools.config_reads.ReadTracer` for every episode agent in each
mode the refusals depend on, and fails when a refused setting is read.
"""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import pytest

from helios.agents.config import AgentConfig, ViewConfig
from helios.config import HeliosConfig
from helios.schema import with_overrides
from sim.perception import SimPerceptionConfig
from tasks.episodes import load_split
from tasks.registry import agent_names
from tasks.trial_config import TrialConfig
from tools.config_reads import ReadTracer, config_classes, refused_as_unread, traced_run

RADIUS = "agent_config.view.arm_model=radius"
ROLES = "perception.gt_roles=[object,goal_receptacle]"
FRONTIER_TERM = "helios.search.frontier_choice=value_minus_distance"


def _read_view_distance(view: ViewConfig) -> float:
    return view.look_distance


def test_the_tracer_records_uses_by_dotted_key_and_leaves_no_hook_behind():
    agent = AgentConfig()
    with ReadTracer() as tracer:
        checked = AgentConfig(max_revisits=2)                    # __post_init__ checks every value: no use
        grown = replace(agent.planner.footprint, margin=0.5)     # a copy: no use, but its reads count
        assert _read_view_distance(agent.view) == 2.5
        assert grown.margin == 0.5 and checked.max_revisits == 2
        SimPerceptionConfig().p_detect_object
    here = "test_config_reads:test_the_tracer_records_uses_by_dotted_key_and_leaves_no_hook_behind"
    assert dict(tracer.reads) == {
        "agent_config.view": {here},
        "agent_config.view.look_distance": {"test_config_reads:_read_view_distance"},
        "agent_config.planner": {here},
        "agent_config.planner.footprint": {here},
        "agent_config.planner.footprint.margin": {here},      # read on the copy: the setting it came from
        "agent_config.max_revisits": {here},
        "perception.p_detect_object": {here},
    }
    assert tracer.read("agent_config.planner") and tracer.read("agent_config.view.look_distance")
    assert not tracer.read("agent_config.view.look_height") and not tracer.read("helios")
    for cls in config_classes():
        assert "__getattribute__" not in cls.__dict__, f"{cls.__qualname__} kept the tracer's hook"
    agent.view.look_distance                                     # outside the block: not recorded
    assert "agent_config.view.look_distance" in tracer.reads and len(tracer.reads) == 7


def test_every_config_class_sits_at_one_place_in_the_agents_sections():
    classes = config_classes()
    assert classes[AgentConfig] == "agent_config" and classes[HeliosConfig] == "helios"
    assert classes[SimPerceptionConfig] == "perception" and classes[ViewConfig] == "agent_config.view"
    assert len(set(classes.values())) == len(classes)
    twice = SimpleNamespace(agent_config=ViewConfig(), helios=ViewConfig(), perception=SimPerceptionConfig())
    with pytest.raises(ValueError, match="ViewConfig sits at agent_config and at helios"):
        config_classes(twice)


# ------------------------------------------------------------------------------------------------
# The guard: no refused setting is read
# ------------------------------------------------------------------------------------------------
def _modes(agent: str) -> list[str]:
    """The modes the refusals depend on, as overrides: ground-truth or noisy semantics (the
    agent's name), with and without ground-truth roles, the measured and the radius arm model."""
    if agent == "oracle":
        return [""]
    extra = [FRONTIER_TERM] if agent.startswith("trusting") else []     # its frontier term: HIGHEST_VALUE_UNREAD
    if agent.endswith("-gt"):
        return ["", RADIUS, *extra]
    return ["", ROLES, RADIUS, f"{ROLES} {RADIUS}", *extra]


FAST = {"oracle": "", "helios": "", "helios-gt": RADIUS, "helios-no-global": f"{ROLES} {RADIUS}",
        "helios-no-global-gt": "", "helios-5050": RADIUS, "helios-5050-gt": RADIUS, "helios-place": ROLES,
        "helios-place-gt": "", "trusting": "", "trusting-gt": RADIUS}
"""The fast suite's one run per agent: every mode of :func:`_modes` for some variants, with and
without the object map (``test_slow_*`` runs every agent in every mode, on more episodes)."""
SHORT = 20
"""HAL commands of a fast run: the start scan's looks, walks and map updates (under 1 s)."""
THROUGH_PLACE = {"trusting": 15, "trusting-gt": 9}
"""Smoke episodes (index) the trusting agents pick and place in within ~45 commands (seed 0):
their refusals are about the decisions they make on detections, so their runs go that far."""


def check_reads(agent: str, mode: str, episodes, max_commands: int) -> ReadTracer:
    """Run ``episodes`` traced; fail naming each setting the run refuses as unread but read."""
    config = with_overrides(TrialConfig(agent=agent), [*mode.split(), f"runner.max_commands={max_commands}"])
    refused = refused_as_unread(config)
    tracer = traced_run(config, episodes)
    read = sorted(key for key in refused if tracer.read(key))

    def readers(key: str) -> list[str]:
        return sorted({r for s, by in tracer.reads.items() if s == key or s.startswith(key + ".") for r in by})

    assert not read, (f"{agent} {mode or '(defaults)'} read settings its run refuses as unread: "
                      + "; ".join(f"{k} (by {', '.join(readers(k))})" for k in read))
    if agent == "oracle":
        assert not tracer.reads, "the oracle reads no agent_config, helios or perception setting"
        return tracer
    for section in ("agent_config", "helios", "perception"):
        assert tracer.read(section), f"{agent} {mode}: nothing of {section} read: the tracer saw nothing"
    # positive controls: what this mode reads is what another mode's run refuses
    if not agent.endswith("-gt"):
        assert tracer.read("perception.p_detect_object")            # refused with ground-truth semantics
    if RADIUS in mode:
        assert tracer.read("agent_config.view.arm_swing_radius")    # refused with the measured model
    if ROLES in mode:
        assert tracer.read("perception.gt_min_pixels")              # refused without gt roles
    if FRONTIER_TERM in mode:
        assert tracer.read("helios.search.alpha_d")                 # refused a trusting run with highest_value
    return tracer


@pytest.mark.parametrize("agent", agent_names())
def test_no_setting_a_run_refuses_as_unread_is_read(agent):
    smoke = load_split("smoke")
    through = THROUGH_PLACE.get(agent)
    tracer = check_reads(agent, FAST[agent], [smoke[2 if through is None else through]], 60 if through else SHORT)
    if through is not None:          # the run got as far as it is meant to
        assert tracer.read("agent_config.place.drop_height") and tracer.read("agent_config.reach.grasp_lift")


def test_the_fast_guard_runs_every_agent_and_every_mode():
    assert sorted(FAST) == agent_names()
    for agent, mode in FAST.items():
        assert mode in _modes(agent), (agent, mode)
    for noisy in (True, False):
        modes = {mode for agent, mode in FAST.items() if agent != "oracle" and agent.endswith("-gt") != noisy}
        assert modes == set(_modes("helios" if noisy else "helios-gt")), noisy     # FRONTIER_TERM: slow only
    for trusting in (True, False):      # with and without the object map, both semantics
        gt = {a.endswith("-gt") for a in FAST if a.startswith("trusting") == trusting and a != "oracle"}
        assert gt == {True, False}, trusting


def test_every_run_of_the_guard_has_refusals_to_check():
    """The guard is not vacuous: in each mode it runs, a run of each agent refuses something
    (but with gt roles and the radius arm model, where a HELIOS agent reads every setting)."""
    for agent in agent_names():
        for mode in _modes(agent):
            config = with_overrides(TrialConfig(agent=agent), mode.split())
            assert refused_as_unread(config) or mode == f"{ROLES} {RADIUS}", (agent, mode)


@pytest.mark.slow
@pytest.mark.parametrize("agent", agent_names())
def test_slow_no_setting_refused_as_unread_is_read_in_any_mode(agent):
    """Every agent in every mode, longer: the trusting agents to the end of three smoke episodes
    (picks, places and a failed place among them), the others for 60 HAL commands of one
    (about 2.5 min of CPU for all of them, under 1.5 min on two workers, on the 2-core machine)."""
    smoke = load_split("smoke")
    for mode in _modes(agent):
        if agent.startswith("trusting"):
            check_reads(agent, mode, smoke[:3], 600)
        else:
            check_reads(agent, mode, smoke[2:3], 60)
