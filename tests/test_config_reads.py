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
SWITCHED = ("agent_config.stall_steps=0 agent_config.max_revisits=0 agent_config.max_looks_per_candidate=0 "
            "agent_config.place.mode=improved agent_config.local_search_views=informative "
            "agent_config.view.near_look_distance=0")
"""Every switch of ``tasks.registry.ONLY_WITH`` the other way round from its default: the settings
the defaults refuse (the improved place's, informative local search's) are then allowed, and those
of the parts it turns off are refused."""


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
    agent's name), with and without ground-truth roles, the measured and the radius arm model,
    the switches of ``ONLY_WITH`` as by default and each the other way (:data:`SWITCHED`)."""
    if agent == "oracle":
        return [""]
    extra = [FRONTIER_TERM] if agent.startswith("trusting") else []     # its frontier term: HIGHEST_VALUE_UNREAD
    if agent.endswith("-gt"):
        return ["", RADIUS, SWITCHED, *extra]
    return ["", ROLES, RADIUS, f"{ROLES} {RADIUS}", SWITCHED, *extra]


FAST = {"oracle": "", "helios": SWITCHED, "helios-gt": RADIUS, "helios-no-global": f"{ROLES} {RADIUS}",
        "helios-no-global-gt": "", "helios-5050": RADIUS, "helios-5050-gt": SWITCHED, "helios-place": ROLES,
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
    """The guard is not vacuous: in each mode it runs, a run of each agent refuses something (with
    gt roles and the radius arm model a HELIOS agent still refuses what ``ONLY_WITH``'s switches
    turn off: the improved place's settings, or informative local search's)."""
    for agent in agent_names():
        for mode in _modes(agent):
            config = with_overrides(TrialConfig(agent=agent), mode.split())
            assert refused_as_unread(config), (agent, mode)


SWITCHED_ON = (
    # (agent, overrides that turn the parts on (stall detection and revisits are on by default), smoke episode,
    #  HAL commands, what the run reads)
    ("helios", "agent_config.local_search_views=informative", 0, 60,
     ("agent_config.local_search_min_gain", "agent_config.fresh_view_distance", "helios.decision.tau_increase",
      "helios.decision.view_prediction", "helios.decision.view_prediction_poses",
      "agent_config.view.start_near_yaws_deg")),
    ("trusting", "agent_config.place.mode=improved", 15, 60,
     ("agent_config.place.improved_height", "agent_config.place.top_band", "agent_config.place.surface_cell")),
    ("trusting", "", 1, 200, ("agent_config.stall_radius", "agent_config.stall_new_area",
                              "agent_config.revisit_spacing", "agent_config.revisit_candidates")),
    ("trusting", "", 15, 60, ("agent_config.place.drop_height",)),
)
"""Runs (seed 0) that reach every part of the agent ``ONLY_WITH`` can turn off, with it on."""


@pytest.mark.parametrize("case", SWITCHED_ON, ids=[c[0] + (" " + c[1] if c[1] else "") for c in SWITCHED_ON])
def test_the_guard_would_catch_a_switched_off_setting_refused_while_its_part_is_on(case):
    """Each setting of ``tasks.registry.ONLY_WITH`` is read by a run with its part of the agent on
    (positive controls: the tracer sees those reads), and refused by a run with that part off; so
    a refusal that also fired with the part on would be read, and fail the guard."""
    from tasks.registry import ONLY_WITH

    agent, mode, episode, max_commands, keys = case
    tracer = check_reads(agent, mode, [load_split("smoke")[episode]], max_commands)
    assert [key for key in keys if not tracer.read(key)] == []
    off = {key: f"{switch}={value}" for switch, value, _, _, names in ONLY_WITH for key in names}
    for key in keys:
        config = with_overrides(TrialConfig(agent=agent), [*mode.split(), off[key]])
        assert key in refused_as_unread(config), (key, off[key])


def test_the_runs_with_the_switches_on_cover_every_setting_only_a_switch_reads():
    from tasks.registry import ONLY_WITH

    assert sorted(key for *_, names in ONLY_WITH for key in names) == sorted(k for *_, ks in SWITCHED_ON for k in ks)


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
