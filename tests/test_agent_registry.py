"""One agent registry (``tasks.registry``) for ``tools trials`` and ``tools spot``: every entry is
described and builds its agent from an ``AgentContext``; unknown names get one error listing the
valid ones, from either command."""

from __future__ import annotations

import pytest

from robots.hal import SE2Pose
from tasks import registry
from tasks.episodes import load_split
from tasks.registry import (AGENTS, DEMO, EPISODE, RUNS_ON, AgentContext, RunContext, UnknownAgentError, agent_names,
                            check_agent, make_agent)
from tasks.runner import SimEpisode
from tasks.trial_config import TrialConfig
from tasks.scripted_demo import DemoHints, ScriptedDemo
from tools.cli import build_parser, main


@pytest.fixture(scope="module")
def sim():
    sim = SimEpisode.create(load_split("smoke")[0])
    yield sim
    sim.close()


def test_every_entry_is_described_and_runs_somewhere():
    for name, entry in AGENTS.items():
        assert isinstance(entry, registry.AgentEntry), name
        assert entry.description.strip(), f"{name} has no description"
        assert entry.runs_on in RUNS_ON, name
    assert sorted(agent_names(EPISODE) + agent_names(DEMO)) == agent_names(None) == sorted(AGENTS)
    assert "helios" in agent_names(EPISODE) and "oracle" in agent_names(EPISODE)
    assert agent_names(DEMO) == ["scripted-demo"]


def test_every_episode_agent_is_built_from_a_context(sim):
    context = RunContext.for_episode(sim, seed=7)
    assert isinstance(context, AgentContext) and context.seed == 7 and context.episode is sim.episode
    for name in agent_names(EPISODE):
        agent = make_agent(name, context)
        assert agent.name == name and callable(agent.reset) and callable(agent.act)


def test_the_context_seed_reaches_simulated_perception(sim, monkeypatch):
    import sim.perception as sim_perception

    seeds = []
    real = sim_perception.make_sim_perception
    monkeypatch.setattr(sim_perception, "make_sim_perception",
                        lambda backend, seed, **kw: seeds.append(seed) or real(backend, seed, **kw))
    make_agent("helios", RunContext.for_episode(sim, seed=12345))
    make_agent("helios-gt", sim)                       # a simulated episode alone: its own seed
    assert seeds == [12345, sim.episode.seed]


def test_the_scripted_demo_is_built_from_the_demo_layout():
    hints = DemoHints.from_layout(SE2Pose(0.0, 0.0, 0.0))
    agent = make_agent("scripted-demo", RunContext(task="Move the mug from the stool to the table", seed=0,
                                                   hints=hints, say=lambda _: None))
    assert isinstance(agent, ScriptedDemo) and agent.hints is hints


def test_unknown_or_misplaced_names_are_one_error_listing_the_valid_ones():
    with pytest.raises(UnknownAgentError, match=r"^unknown agent 'nope'; valid agents: helios, .*oracle"):
        check_agent("nope")
    with pytest.raises(UnknownAgentError, match=r"^unknown agent 'nope'; valid agents: scripted-demo$"):
        check_agent("nope", DEMO)
    with pytest.raises(UnknownAgentError, match="runs on the demo layout, not on task episodes"):
        check_agent("scripted-demo", EPISODE)
    with pytest.raises(UnknownAgentError, match="unknown agent 'nope'; valid agents: .*scripted-demo"):
        make_agent("nope", None)


def test_trials_and_spot_list_and_check_the_same_registry(capsys):
    import tools.spot

    assert not hasattr(tools.spot, "AGENTS")
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices
    helps = {cmd: next(a.help for a in sub[cmd]._actions if a.dest == "agent") for cmd in ("trials", "spot")}
    assert ", ".join(agent_names(EPISODE)) in helps["trials"]
    assert ", ".join(agent_names(DEMO)) in helps["spot"]

    expected = f"error: unknown agent 'nope'; valid agents: {', '.join(agent_names(EPISODE))}"
    assert main(["trials", "--agent", "nope"]) == 2
    assert capsys.readouterr().err.strip() == expected
    assert main(["spot", "--fake", "--episode", "smoke-00001", "--agent", "nope"]) == 2
    assert capsys.readouterr().err.strip() == expected


def test_gt_roles_give_the_agent_exact_detections_of_those_roles_classes(sim):
    from sim.perception import PartlyTrueDetector, SimDetector, SimImageTextScorer, SimPerceptionConfig

    ep = sim.episode
    agent = make_agent("helios", RunContext.for_episode(sim, seed=3),
                       perception_config=SimPerceptionConfig(gt_roles=("goal_receptacle", "object")))
    assert isinstance(agent.detector, PartlyTrueDetector) and isinstance(agent.detector.noisy, SimDetector)
    assert agent.detector.true_classes == {ep.goal_receptacle_category, ep.object_category}
    assert isinstance(agent.scorer, SimImageTextScorer)                 # the value maps stay noisy
    trusting = make_agent("trusting", RunContext.for_episode(sim, seed=3),
                          perception_config=SimPerceptionConfig(gt_roles=("start_receptacle",)))
    assert trusting.detector.true_classes == {ep.start_receptacle_category}
    assert isinstance(make_agent("helios", RunContext.for_episode(sim, seed=3)).detector, SimDetector)


def test_replaced_settings_name_what_each_agent_forces_or_never_reads():
    from helios.agents.variants import VARIANTS
    from tasks.registry import IGNORED, replaced_settings

    assert replaced_settings("oracle") == {"agent_config": IGNORED, "helios": IGNORED, "perception": IGNORED}
    assert replaced_settings("helios") == {"perception.mode": "noisy"}
    assert replaced_settings("helios-gt") == {"perception.mode": "gt"}
    assert replaced_settings("helios-5050") == {"helios.search.information_gain": "fifty_fifty", "perception.mode": "noisy"}
    assert replaced_settings("helios-place-gt") == {"agent_config.place.mode": "improved", "perception.mode": "gt"}
    assert replaced_settings("trusting") == {"agent_config.variant": "trusting", "perception.mode": "noisy"}
    assert replaced_settings("no-such-agent") == {}
    for variant in VARIANTS:      # each forced key exists in TrialConfig (a renamed field would slip past)
        for key in replaced_settings(variant + "-gt"):
            section, _, name = key.rpartition(".")
            cfg = TrialConfig()
            for part in section.split("."):
                cfg = getattr(cfg, part)
            assert hasattr(cfg, name), f"{variant}: TrialConfig has no {key}"


def test_check_agent_settings_refuses_what_would_change_nothing_and_allows_the_rest():
    from helios.schema import ConfigError, with_overrides
    from tasks.registry import check_agent_settings

    def check(agent, *overrides, explicit=True):
        cfg = with_overrides(TrialConfig(agent=agent), list(overrides))
        check_agent_settings(cfg, [o.partition("=")[0] for o in overrides] if explicit else ())

    check("oracle", "runner.max_sim_time=100", "sim.camera.width=160")       # the oracle's robot and budget
    check("helios-gt", "perception.mode=gt")                  # what the agent forces anyway: harmless
    check("helios-5050", "helios.search.information_gain=fifty_fifty", "helios.search.cs_start_receptacle=0.4")
    check("helios", "agent_config.variant=trusting", "perception.mode=noisy")  # helios reads them
    # the name sets the detector's mode: `helios perception.mode=gt` once ran the noisy detector while
    # config.yaml said gt (audit 2026-12-06); the -gt twin is the run asked for
    with pytest.raises(ConfigError, match="which sets perception.mode='noisy' itself; leave it out, or run agent "
                                          "'helios-gt'"):
        check("helios", "perception.mode=gt")
    with pytest.raises(ConfigError, match="run agent 'trusting-gt'"):
        check("trusting", "perception.mode=gt", explicit=False)              # from a scenario file
    with pytest.raises(ConfigError, match=r"agent_config.max_pick_attempts: agent 'oracle' reads no agent_config"):
        check("oracle", "agent_config.max_pick_attempts=3")     # even at its default: it was asked for
    with pytest.raises(ConfigError, match=r"perception.\*: agent 'oracle' reads no perception"):
        check("oracle", "perception.mask_morph_px=3", explicit=False)          # from a scenario file
    with pytest.raises(ConfigError, match="which sets perception.mode='gt' itself; leave it out, or run agent 'trusting'"):
        check("trusting-gt", "perception.mode=noisy")
    with pytest.raises(ConfigError, match="sets agent_config.variant='no_global' itself"):
        check("helios-no-global-gt", "agent_config.variant=trusting", explicit=False)


def test_settings_the_agents_mode_never_reads_are_refused():
    """Audit 2026-12-05 (session 35): `helios-gt perception.p_detect_object=0.01` ran and recorded
    the setting, with records identical to 0.95 (ground truth reads none of the detector's noise);
    so did `perception.gt_min_pixels` without gt roles and the radius arm model's sizes under the
    measured model."""
    from helios.schema import ConfigError, with_overrides
    from tasks.registry import check_agent_settings

    def check(agent, *overrides, explicit=True):
        cfg = with_overrides(TrialConfig(agent=agent), list(overrides))
        check_agent_settings(cfg, [o.partition("=")[0] for o in overrides] if explicit else ())

    for agent, setting in (("helios-gt", "perception.p_detect_object=0.01"),
                           ("trusting-gt", "perception.bad_view_object=0.9"),
                           ("helios-no-global-gt", "perception.score_logit_std=2")):
        with pytest.raises(ConfigError, match=r"would change nothing .* ground-truth semantics"):
            check(agent, *setting.split())
    with pytest.raises(ConfigError, match=r"perception.p_detect_object \(set in the scenario file\) would change"):
        check("helios-gt", "perception.p_detect_object=0.5", explicit=False)
    with pytest.raises(ConfigError, match="applies only with perception.gt_roles"):
        check("helios", "perception.gt_min_pixels=50")
    with pytest.raises(ConfigError, match="measured arm model"):
        check("helios", "agent_config.view.arm_swing_height=0.9")
    # what those modes do read is allowed
    check("helios-gt", "perception.gt_min_pixels=50", "perception.scorer_saturation_receptacle=0.1")
    check("helios", "perception.gt_roles=[object]", "perception.gt_min_pixels=50", "perception.p_detect_object=0.9")
    check("helios", "agent_config.view.arm_model=radius", "agent_config.view.arm_swing_height=0.9")
    with pytest.raises(ConfigError, match="would change nothing"):
        check("helios-gt", "perception.p_detect_object=0.95")   # even at its default: it was asked for


def test_the_trusting_variant_is_refused_the_object_maps_settings():
    """Session of 2026-12-06: `trusting helios.decision.tau_object=0.7` ran and recorded the
    setting, which it never reads (no object map: it acts on the first detection it trusts).
    What it never reaches is refused; what it reads is not (tests/test_config_reads.py runs it)."""
    from helios.schema import ConfigError, with_overrides
    from tasks.registry import HIGHEST_VALUE_UNREAD, OBJECT_MAP_ONLY, check_agent_settings, unread_settings

    def check(agent, *overrides, explicit=True):
        cfg = with_overrides(TrialConfig(agent=agent), list(overrides))
        check_agent_settings(cfg, [o.partition("=")[0] for o in overrides] if explicit else ())

    for agent, setting in (("trusting", "helios.decision.tau_object=0.7"),
                           ("trusting-gt", "agent_config.gaze.spacing=0.4"),
                           ("trusting", "helios.search.information_gain=fifty_fifty"),
                           ("helios", "agent_config.variant=trusting agent_config.max_looks_per_candidate=2")):
        key = setting.split()[-1].partition("=")[0]
        with pytest.raises(ConfigError, match=rf"^{key} would change nothing with agent '{agent}': the trusting "
                                              r"variant \(agent_config.variant=trusting\) keeps no object map; "
                                              r".*; leave it out$"):
            check(agent, *setting.split())
    with pytest.raises(ConfigError, match=r"local_search_views \(set in the scenario file\) would change nothing"):
        check("trusting", "agent_config.local_search_views=all", explicit=False)      # not the default
    with pytest.raises(ConfigError, match=r"alpha_d would change nothing .* goes to the highest-value frontier"):
        check("trusting", "helios.search.alpha_d=0.01")
    check("trusting", "helios.search.frontier_choice=value_minus_distance", "helios.search.alpha_d=0.01",
          "helios.search.initial_frontier_ratio=2")                   # then its frontier term reads them
    # what the trusting agent reads, and what the object map's agents read, stays allowed
    check("trusting", "agent_config.max_failures_per_candidate=3", "agent_config.place.drop_height=0.2",
          "helios.detection.od_object=0.4", "helios.gaussians.full_scene=true", "agent_config.gaze_goal_radius=0.2",
          "agent_config.view.elbow_radius=0.5", "helios.search.distance_unit=metres")
    check("helios", "helios.decision.tau_object=0.7", "agent_config.gaze.spacing=0.4", "helios.search.alpha_d=0.01")
    check("helios-no-global-gt", "helios.search.min_frontier_value=0.01", "agent_config.fresh_view_distance=0.3")
    assert set(OBJECT_MAP_ONLY) | set(HIGHEST_VALUE_UNREAD) <= set(unread_settings(TrialConfig(agent="trusting")))
    informative = with_overrides(TrialConfig(agent="helios-gt"), ["agent_config.local_search_views=informative"])
    assert not set(OBJECT_MAP_ONLY) & set(unread_settings(informative))     # local_search_min_gain: ONLY_WITH


def test_settings_only_a_switched_off_part_of_the_agent_reads_are_refused():
    """Audit 2026-12-07: `helios agent_config.stall_steps=0 agent_config.stall_radius=0.8` ran and
    recorded a radius no code read (no stall watch without stall_steps), as did the improved
    place's sizes with the default drop, `local_search_min_gain` with every gaze point visited,
    the revisits' spacing with `max_revisits=0` and the extra views' settings with
    `max_looks_per_candidate=0`. Refused now, naming the switch and its value; with the switch
    on, or the agent's variant turning it on, they are allowed."""
    from helios.schema import ConfigError, with_overrides
    from tasks.registry import ONLY_WITH, check_agent_settings, unread_settings

    def check(agent, *overrides, explicit=True):
        cfg = with_overrides(TrialConfig(agent=agent), list(overrides))
        check_agent_settings(cfg, [o.partition("=")[0] for o in overrides] if explicit else ())

    with pytest.raises(ConfigError, match=r"^agent_config.stall_radius would change nothing with agent 'helios': "
                                          r"exploration stall detection, which alone reads it, is off "
                                          r"\(agent_config.stall_steps=0; a count above 0 turns it on\); leave it out$"):
        check("helios", "agent_config.stall_steps=0", "agent_config.stall_radius=0.8")
    for agent, setting, switch in (
            ("helios", "agent_config.stall_new_area=1", "agent_config.stall_steps=0"),
            ("helios-gt", "agent_config.place.improved_height=0.05", "agent_config.place.mode=drop"),
            ("trusting", "agent_config.place.top_band=0.05", "agent_config.place.mode=drop"),
            ("helios-5050", "agent_config.place.surface_cell=0.05", "agent_config.place.mode=drop"),
            ("helios-no-global", "agent_config.local_search_min_gain=0.2", "agent_config.local_search_views=all"),
            ("trusting-gt", "agent_config.revisit_spacing=2", "agent_config.max_revisits=0"),
            ("helios", "agent_config.revisit_candidates=3", "agent_config.max_revisits=0"),
            ("helios", "agent_config.fresh_view_distance=0.3", "agent_config.max_looks_per_candidate=0"),
            ("helios-place-gt", "helios.decision.tau_increase=0.1", "agent_config.max_looks_per_candidate=0"),
            ("helios", "helios.decision.view_prediction=optimistic", "agent_config.max_looks_per_candidate=0"),
            ("helios", "helios.decision.view_prediction_poses=all", "agent_config.max_looks_per_candidate=0")):
        key = setting.partition("=")[0]
        overrides = [setting] if switch.endswith("=drop") else [switch, setting]   # drop is the default
        with pytest.raises(ConfigError, match=rf"^{key} would change nothing with agent '{agent}': .*, which alone "
                                              rf"reads it, is off \({switch}; .* turns it on\); leave it out$"):
            check(agent, *overrides)
        with pytest.raises(ConfigError, match=rf"^{key} \(set in the scenario file\) would change nothing"):
            check(agent, *overrides, explicit=False)
    with pytest.raises(ConfigError, match=r"the improved place, which alone reads it, is off "
                                          r"\(agent_config.place.mode=drop; improved turns it on\)"):
        check("helios", "agent_config.place.improved_height=0.02")     # even at its default: it was asked for
    # with the switch on (given, by default, or by the agent's variant) they are read, so allowed
    check("helios", "agent_config.stall_steps=3", "agent_config.stall_radius=0.8", "agent_config.stall_new_area=1")
    check("helios", "agent_config.stall_radius=0.8", "agent_config.revisit_spacing=2")     # stall_steps=6, 4 revisits
    check("helios", "agent_config.place.mode=improved", "agent_config.place.improved_height=0.05",
          "agent_config.place.top_band=0.05", "agent_config.place.surface_cell=0.05")
    check("helios-place", "agent_config.place.improved_height=0.05", "agent_config.place.top_band=0.05")
    check("helios-place-gt", "agent_config.place.surface_cell=0.05", explicit=False)
    check("helios", "agent_config.local_search_views=informative", "agent_config.local_search_min_gain=0.2")
    check("helios", "agent_config.max_looks_per_candidate=2", "agent_config.fresh_view_distance=0.3",
          "helios.decision.tau_increase=0.1", "helios.decision.view_prediction_poses=all")
    check("helios", "agent_config.max_revisits=1", "agent_config.revisit_candidates=3")
    # the switches themselves are read in either state
    check("helios", "agent_config.stall_steps=0", "agent_config.max_revisits=0", "agent_config.place.mode=drop",
          "agent_config.max_looks_per_candidate=0", "agent_config.local_search_views=all")
    # each place mode reads its own height only: the other's is refused, whichever way round
    check("helios", "agent_config.place.drop_height=0.01")
    with pytest.raises(ConfigError, match=r"agent_config.place.drop_height would change nothing with agent "
                                          r"'helios-place': the paper's drop, which alone reads it, is off "
                                          r"\(agent_config.place.mode=improved; drop turns it on\)"):
        check("helios-place", "agent_config.place.drop_height=0.2")
    with pytest.raises(ConfigError, match=r"improved_height would change nothing with agent 'helios'"):
        check("helios", "agent_config.place.drop_height=0.01", "agent_config.place.improved_height=0.01")
    check("helios", "agent_config.place.mode=improved", "agent_config.place.improved_height=0.3")
    # the trusting variant reaches no local search or extra views at all: that refusal says so
    with pytest.raises(ConfigError, match=r"local_search_min_gain would change nothing .* the trusting variant"):
        check("trusting", "agent_config.local_search_min_gain=0.2")
    with pytest.raises(ConfigError, match=r"tau_increase would change nothing .* the trusting variant"):
        check("trusting", "agent_config.max_looks_per_candidate=0", "helios.decision.tau_increase=0.1")
    # the oracle reads none of them: its refusal is the whole section's
    with pytest.raises(ConfigError, match=r"agent 'oracle' reads no agent_config"):
        check("oracle", "agent_config.stall_radius=0.8")
    assert not unread_settings(TrialConfig(agent="oracle"))
    defaults = unread_settings(TrialConfig(agent="helios"))
    assert "agent_config.place.improved_height" in defaults
    assert not {"agent_config.stall_radius", "agent_config.revisit_spacing", "helios.decision.tau_increase",
                "agent_config.local_search_min_gain"} & set(defaults)          # informative views by default
    assert "agent_config.local_search_min_gain" in unread_settings(
        with_overrides(TrialConfig(agent="helios"), ["agent_config.local_search_views=all"]))
    for switch, off, *_ in ONLY_WITH:      # each switch's off value is a value the setting takes
        with_overrides(TrialConfig(agent="helios"), [f"{switch}={off}"])


def test_no_agent_is_asked_for_the_scorers_object_evidence():
    """The value maps' prompts name the start and goal receptacles only (tasks.spec requires
    receptacle categories there), so `perception.scorer_saturation_object` changes nothing in any
    mode; the ground-truth refusal no longer names it among what that mode reads."""
    from helios.schema import ConfigError, with_overrides
    from tasks.registry import check_agent_settings

    for agent in ("helios", "helios-gt", "trusting", "helios-place-gt"):
        cfg = with_overrides(TrialConfig(agent=agent), ["perception.scorer_saturation_object=0.01"])
        with pytest.raises(ConfigError, match=r"^perception.scorer_saturation_object would change nothing with agent "
                                              r".*: the agents ask the image-text scorer only about receptacles"):
            check_agent_settings(cfg, ["perception.scorer_saturation_object"])
    cfg = with_overrides(TrialConfig(agent="helios-gt"), ["perception.p_detect_object=0.5"])
    with pytest.raises(ConfigError, match=r"read only gt_min_pixels, mode, scorer_saturation_receptacle; "
                                          r"leave it out$"):
        check_agent_settings(cfg, ["perception.p_detect_object"])


def test_every_setting_a_run_may_refuse_as_unread_names_a_setting():
    """A refusal of a renamed or misspelt key would refuse nothing and let the setting through."""
    from tasks.registry import unread_settings

    def exists(key):
        cfg = TrialConfig()
        for part in key.split("."):
            if not hasattr(cfg, part):
                return False
            cfg = getattr(cfg, part)
        return True

    from helios.schema import with_overrides

    modes = ([], ["perception.gt_roles=[object]"], ["agent_config.view.arm_model=radius"])
    keys = {key for agent in agent_names() for mode in modes if not (mode and agent.endswith("-gt"))
            for key in unread_settings(with_overrides(TrialConfig(agent=agent), mode))}
    assert {"helios.decision.tau_object", "perception.p_detect_object", "agent_config.view.arm_swing_radius",
            "perception.gt_min_pixels", "perception.scorer_saturation_object"} <= keys
    assert [key for key in sorted(keys) if not exists(key)] == []
