"""The one agent registry: agents by name for ``tools trials`` and ``tools spot`` (the simulator, the
fake robot and a real one). Each entry builds a fresh agent for one run from an
:class:`AgentContext`; unknown names get one error listing the valid ones.

Agents of your own run as ``FILE.py:FACTORY`` or ``package.module:FACTORY`` instead of a name
(:mod:`tasks.plugin_agents`): task episodes only, never on a robot.

An entry runs on one kind of run (``runs_on``):

* ``EPISODE``: a task episode (``tools trials``; ``tools spot --fake --episode``). The agent
  implements ``tasks.runner.Agent`` and ``tasks.runner.run_episode`` drives it.
* ``DEMO``: the demo layout with a task in words (``tools spot`` on the fake or a real robot).
  The agent is a one-shot script: ``agent.run(robot) -> tasks.scripted_demo.AgentOutcome``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, NamedTuple, Protocol, runtime_checkable

from helios.schema import short_repr
from tasks.plugin_agents import is_plugin_spec

EPISODE = "episode"
DEMO = "demo"
RUNS_ON = {EPISODE: "task episodes", DEMO: "the demo layout"}


class UnknownAgentError(ValueError):
    """An agent name is not registered (or its agent cannot run here)."""


@runtime_checkable
class AgentContext(Protocol):
    """What an agent factory receives: the one run a fresh agent is made for.

    ``task``: the task in words. ``seed``: seeds the agent's own randomness (simulated perception;
    the episode runner seeds the agent's generator separately).

    A task episode brings the simulator's side of the run (``tasks.runner.SimEpisode``, or the
    fake robot's ``EpisodeFake``): ``episode`` (``tasks.episodes.Episode``), ``world``, ``scene``
    (``sim.scenes.home.HomeScene``; ``scene.layout.rooms`` for the simulated scorer), ``backend``
    and ``judge`` (``tasks.metrics.EpisodeJudge``). This is ground truth, for the oracle and for
    simulated perception: ``backend`` is the simulator's view of the robot (``SimSpotBackend``, or
    the fake's ``FakeSimView``), never the HAL the agent drives, which ``act``/``run`` receive.

    The demo layout brings ``hints`` (``tasks.scripted_demo.DemoHints``) instead, and the
    simulator's side is None (a real robot has none). ``say`` prints an agent's progress lines.
    """

    @property
    def task(self) -> str: ...

    @property
    def seed(self) -> int: ...

    @property
    def episode(self): ...

    @property
    def world(self): ...

    @property
    def scene(self): ...

    @property
    def backend(self): ...

    @property
    def judge(self): ...

    @property
    def hints(self): ...

    @property
    def say(self) -> Callable[[str], None]: ...


@dataclass(frozen=True)
class RunContext:
    """The :class:`AgentContext` of one run (see there for the fields)."""

    task: str
    seed: int
    episode: object = None
    world: object = None
    scene: object = None
    backend: object = None
    judge: object = None
    hints: object = None
    say: Callable[[str], None] = print

    @classmethod
    def for_episode(cls, sim, seed: int | None = None) -> "RunContext":
        """The context of a simulated episode (``SimEpisode`` or ``EpisodeFake``); ``seed``
        defaults to the episode's own seed."""
        ep = sim.episode
        return cls(task=ep.task, seed=ep.seed if seed is None else seed, episode=ep, world=sim.world,
                   scene=sim.scene, backend=sim.backend, judge=sim.judge)


class AgentEntry(NamedTuple):
    factory: Callable           # factory(context: AgentContext, **options) -> agent
    description: str
    runs_on: str = EPISODE
    # Runs on a real robot: needs no ground truth (an EPISODE agent then takes real perception,
    # ``perception=(detector, scorer)``; a DEMO agent takes the layout hints).
    real_robot: bool = False


def _oracle(context: AgentContext, **_options):
    from tasks.oracle import OracleAgent

    return OracleAgent(context)


def _helios_factory(variant: str, ground_truth: bool) -> Callable:
    """Factory of one HELIOS variant with simulated (noisy or ground-truth) perception."""

    def factory(context: AgentContext, agent_config=None, method_config=None, perception_config=None,
                perception=None, search_policy=None):
        """``perception``: a (detector, scorer) pair (e.g. ``tasks.hardware.load_robot_perception``:
        OWLv2 and CLIP from local weights) used instead of the simulated detector; the only way
        to run on a real robot. ``search_policy``: the pick phase's choice between candidates and
        frontiers (``HeliosAgent``; None: the paper's objective), for agents of your own."""
        from dataclasses import replace

        from helios.agents.config import AgentConfig
        from helios.agents.helios_agent import HeliosAgent
        from helios.agents.variants import VARIANTS
        from helios.config import HeliosConfig
        from sim.perception import SimPerceptionConfig, make_sim_perception, role_classes_of

        agent_fields, search_fields, _ = VARIANTS[variant]
        policy = {"search_policy": search_policy} if search_policy is not None else {}
        agent_config = agent_config or AgentConfig()
        agent_fields = {k: replace(getattr(agent_config, k), **v) if isinstance(v, dict) else v
                        for k, v in agent_fields.items()}
        agent_config = replace(agent_config, **agent_fields)
        method_config = method_config or HeliosConfig()
        if search_fields:
            method_config = replace(method_config, search=replace(method_config.search, **search_fields))
        name = variant + ("-gt" if ground_truth else "")
        if perception is not None:
            if ground_truth:
                raise UnknownAgentError(f"{name} uses ground-truth semantics; with real perception run {variant}")
            detector, scorer = perception
            return HeliosAgent(detector, scorer, agent_config, method_config, name=name, **policy)
        if context.backend is None or context.scene is None:
            raise UnknownAgentError(f"{name} with simulated perception needs the simulator (a task episode); on a "
                                    f"real robot give it real perception")
        perception_config = replace(perception_config or SimPerceptionConfig(), mode="gt" if ground_truth else "noisy")
        roles = role_classes_of(context.episode) if context.episode is not None else None   # for gt_roles
        detector, scorer = make_sim_perception(context.backend, seed=context.seed, config=perception_config,
                                               rooms=context.scene.layout.rooms, role_classes=roles)
        return HeliosAgent(detector, scorer, agent_config, method_config, name=name, **policy)

    return factory


def _scripted_demo(context: AgentContext, **_options):
    from tasks.scripted_demo import ScriptedDemo

    if context.hints is None:
        raise ValueError("scripted-demo runs on the demo layout: its context needs the layout's hints")
    return ScriptedDemo(context.hints, say=context.say)


def _helios_agents() -> dict[str, AgentEntry]:
    from helios.agents.variants import VARIANTS

    out = {}
    for variant, (_, _, text) in VARIANTS.items():
        out[variant] = AgentEntry(_helios_factory(variant, False), text + " (simulated detector, or real "
                                                                          "perception on a robot)", real_robot=True)
        out[variant + "-gt"] = AgentEntry(_helios_factory(variant, True), text + " (ground-truth semantics)")
    return out


# name -> AgentEntry
AGENTS: dict[str, AgentEntry] = {
    **_helios_agents(),
    "oracle": AgentEntry(_oracle, "scripted ground-truth agent: knows where everything is, acts through the HAL "
                                  "(the ceiling)"),
    "scripted-demo": AgentEntry(_scripted_demo, "scripted pick-and-place in the demo layout (tools demo's sequence)",
                                DEMO, real_robot=True),
}


def agent_names(runs_on: str | None = EPISODE) -> list[str]:
    """Registered names, sorted: those that run on ``runs_on`` (``None``: all)."""
    return sorted(name for name, entry in AGENTS.items() if runs_on is None or entry.runs_on == runs_on)


def robot_agent_names() -> list[str]:
    """Agents that can run on a real robot (sorted)."""
    return sorted(name for name, entry in AGENTS.items() if entry.real_robot)


def check_robot_agent(name: str) -> AgentEntry:
    """The entry of ``name`` if it can run on a real robot; UnknownAgentError listing those that can."""
    valid = ", ".join(robot_agent_names())
    if name not in AGENTS:
        raise UnknownAgentError(f"unknown agent {short_repr(name, 80)}; valid agents: {valid}")
    entry = AGENTS[name]
    if not entry.real_robot:
        raise UnknownAgentError(f"agent {name!r} needs the simulator's ground truth and cannot run on a real robot; "
                                f"agents for a robot: {valid}")
    return entry


def check_agent(name: str, runs_on: str | None = EPISODE) -> AgentEntry:
    """The entry of ``name``; an :class:`UnknownAgentError` listing the valid names unless it is
    registered and runs on ``runs_on`` (``None``: anywhere). A plugin (``FILE.py:FACTORY``,
    :mod:`tasks.plugin_agents`) is imported and checked here, and runs on task episodes."""
    valid = ", ".join(agent_names(runs_on))
    if is_plugin_spec(name):
        from tasks.plugin_agents import make_plugin_factory

        if runs_on not in (None, EPISODE):
            raise UnknownAgentError(f"agent {short_repr(name, 80)}: agents of your own run on task episodes, not on "
                                    f"{RUNS_ON[runs_on]}; valid agents: {valid}")
        return AgentEntry(make_plugin_factory(name), f"your own agent ({short_repr(name, 80)})")
    if name not in AGENTS:
        raise UnknownAgentError(f"unknown agent {short_repr(name, 80)}; valid agents: {valid}")
    entry = AGENTS[name]
    if runs_on is not None and entry.runs_on != runs_on:
        raise UnknownAgentError(f"agent {short_repr(name, 80)} runs on {RUNS_ON[entry.runs_on]}, not on {RUNS_ON[runs_on]}; "
                                f"valid agents: {valid}")
    return entry


def make_agent(name: str, context, **options):
    """A fresh agent for one run. ``context``: an :class:`AgentContext`; a simulated episode
    (``SimEpisode``, ``EpisodeFake``) stands for ``RunContext.for_episode(sim)`` (the episode's own
    seed). ``options`` (agent_config, method_config, perception_config) configure the HELIOS
    agents and are ignored by the others: a factory is called as ``factory(context, **options)``,
    so it must accept (and may ignore) them."""
    entry = check_agent(name, runs_on=None)
    if not isinstance(context, AgentContext):
        context = RunContext.for_episode(context)
    return entry.factory(context, **options)


IGNORED = "ignored"
"""``replaced_settings``: a whole section the agent never reads."""

# sections of TrialConfig the oracle never reads: it acts on ground truth, with no map or detector
_ORACLE_IGNORES = ("agent_config", "helios", "perception")


def replaced_settings(name: str) -> dict[str, object]:
    """TrialConfig settings (dotted keys, or whole sections) that agent ``name`` does not take from
    the run's config: the value its factory forces (a HELIOS variant's fields, ``perception.mode``:
    ``gt`` for a ``-gt`` agent, ``noisy`` otherwise), or :data:`IGNORED` for a section it never
    reads (the oracle's; a plugin's that its ``reads`` does not name). A run setting one of them
    otherwise would record in config.yaml a setting that changed nothing."""
    if name == "oracle":
        return {section: IGNORED for section in _ORACLE_IGNORES}
    if is_plugin_spec(name):
        from tasks.plugin_agents import SECTION_OPTIONS, plugin_reads

        reads = plugin_reads(name)
        return {section: IGNORED for section in SECTION_OPTIONS if section not in reads}
    from helios.agents.variants import VARIANTS

    variant = name.removesuffix("-gt")
    if variant not in VARIANTS:
        return {}
    agent_fields, search_fields, _ = VARIANTS[variant]
    out: dict[str, object] = {}
    for key, value in agent_fields.items():
        if isinstance(value, dict):
            out.update({f"agent_config.{key}.{sub}": v for sub, v in value.items()})
        else:
            out[f"agent_config.{key}"] = value
    out.update({f"helios.search.{key}": value for key, value in search_fields.items()})
    # the factory sets the detector's mode from the name (_helios_factory): `helios perception.mode=gt`
    # once ran the noisy detector while config.yaml said gt (audit 2026-12-06)
    out["perception.mode"] = "gt" if name.endswith("-gt") else "noisy"
    return out


def reads_section(name: str, section: str) -> bool:
    """Whether agent ``name`` reads TrialConfig section ``section`` at all (the oracle reads no
    ``helios``, ``agent_config`` or ``perception``: :func:`replaced_settings`)."""
    return replaced_settings(name).get(section) is not IGNORED


OBJECT_MAP_ONLY = (
    # candidates and their support (helios.agents.candidates), the Psi decision rule and its extra
    # views (HeliosAgent._judge_targets, _best_view)
    *(f"helios.decision.{name}" for name in ("tau_object", "tau_goal_receptacle", "tau_increase", "cs_object",
                                             "cs_goal_receptacle", "candidate_class", "view_prediction",
                                             "view_prediction_poses")),
    "agent_config.max_looks_per_candidate", "agent_config.fresh_view_distance", "agent_config.require_start_support",
    "agent_config.support_radius",
    # gaze points, the cameras they predict, local search (HeliosAgent._gaze_points_of, Body.view_from)
    *(f"agent_config.gaze.{name}" for name in ("standoffs", "outer_rings", "spacing", "min_points", "los_margin",
                                               "own_margin", "min_look_height", "arm_room")),
    "agent_config.view.camera_in_body", "agent_config.gaze_hop", "agent_config.local_search_views",
    "agent_config.local_search_min_gain", "agent_config.end_local_search_on_doubt",
    # the global objective's candidates: with none (GlobalObjective's frontiers_only mode) it never
    # scores or calibrates against them
    "helios.search.cs_start_receptacle", "helios.search.information_gain", "helios.search.candidate_gain",
    "helios.search.initial_frontier_calibration", "helios.search.frontier_calibration",
    "helios.search.min_frontier_value",
)
"""Settings only an agent with the object map (``VariantFlags.object_map``) reads: the trusting
variant never reaches them (it keeps 2D maps and acts on the first detection it trusts), so a
trusting run refuses them. The Gaussian layer's own settings (``helios.gaussians``, ``instances``,
``scoring``) are not here: the trusting agent updates that layer too, empty (with
``gaussians.full_scene`` it fills it). Checked against what runs read by tests/test_config_reads.py;
traced over the 20 smoke and first 40 val episodes of trusting and of trusting-gt when the list
was made, none was read."""

HIGHEST_VALUE_UNREAD = ("helios.search.alpha_d", "helios.search.initial_frontier_ratio")
"""The objective's frontier term: an agent with no candidates to weigh (the trusting variant)
computes it only with ``helios.search.frontier_choice=value_minus_distance``."""

NO_AGENT_READS = ("perception.scorer_saturation_object",)
"""Settings no HELIOS agent reads in a task episode: the agents ask the image-text scorer only
about their value maps' classes, the start and goal receptacles (``tasks.spec`` requires
receptacle categories there), and this one sets its evidence for small objects."""


ONLY_WITH: tuple[tuple[str, object, str, str, tuple[str, ...]], ...] = (
    # (the setting that turns a part of the agent on or off, its value for off, that part, what
    #  turns it on, the settings only that part reads)
    ("agent_config.place.mode", "drop", "the improved place", "improved",
     ("agent_config.place.improved_height", "agent_config.place.top_band", "agent_config.place.surface_cell")),
    ("agent_config.place.mode", "improved", "the paper's drop", "drop", ("agent_config.place.drop_height",)),
    ("agent_config.local_search_views", "all", "local search's choice of informative gaze points", "informative",
     ("agent_config.local_search_min_gain",)),
    ("agent_config.stall_steps", 0, "exploration stall detection", "a count above 0",
     ("agent_config.stall_radius", "agent_config.stall_new_area")),
    ("agent_config.max_revisits", 0, "revisiting the most promising seen places", "a count above 0",
     ("agent_config.revisit_spacing", "agent_config.revisit_candidates")),
    ("agent_config.max_looks_per_candidate", 0, "taking extra views of a candidate", "a count above 0",
     ("agent_config.fresh_view_distance", *(f"helios.decision.{name}" for name in
                                            ("tau_increase", "view_prediction", "view_prediction_poses")))),
    ("agent_config.view.near_look_distance", 0.0, "the views of the near floor", "a distance above 0",
     ("agent_config.view.start_near_yaws_deg",)),
)
"""Settings only one part of a HELIOS agent reads, and the setting that turns that part off: with
it off, they change nothing. The place skill's ``improved`` branch (helios.agents.place:
``choose_place_point`` past its ``drop`` return, and the ``mode != "drop"`` fallback of ``place``);
``informative_views``, called only with ``local_search_views=informative``
(``HeliosAgent._start_local_search``); ``frontier_goals.StallWatch``, which the agent makes only
with ``stall_steps`` above 0 (``HeliosAgent.reset``); ``revisit_goals``, called only below
``max_revisits`` revisits (``HeliosAgent._revisit``); ``HeliosAgent._best_view`` and the Psi' rule's
``decide``, reached only for a candidate with fewer than ``max_looks_per_candidate`` extra views
(``_judge_targets``); ``Body.look``'s near-floor views, none with ``near_look_distance`` 0
(``Body.look_all_around`` then passes no directions); and the other way round, the paper's drop
height, which the improved place never reads (``place`` and ``choose_place_point`` read the height
of their mode only). A variant's forced value counts (``helios-place`` places ``improved``).
Checked against what runs read by tests/test_config_reads.py, in both states of each switch."""


def _value_at(cfg, key: str):
    for part in key.split("."):
        cfg = getattr(cfg, part)
    return cfg


def _only_with_unread(config) -> dict[str, str]:
    """:data:`ONLY_WITH`'s settings whose part of the agent ``config`` turns off -> why."""
    forced = replaced_settings(config.agent)
    out: dict[str, str] = {}
    for switch, off, part, on, keys in ONLY_WITH:
        value = forced.get(switch, _value_at(config, switch))
        if value == off:
            out.update({key: f"{part}, which alone reads it, is off ({switch}={value}; {on} turns it on)"
                        for key in keys})
    return out


def unread_settings(config) -> dict[str, str]:
    """Settings (dotted keys) that ``config``'s agent would not read in the mode the config puts it
    in -> why: the simulated detector's noise with ground-truth semantics, the exact detector's
    smallest mask without ground-truth roles, the radius arm model's sizes with the measured one,
    the object map's settings with the trusting variant (:data:`OBJECT_MAP_ONLY`), the scorer's
    evidence for objects, which no agent asks for (:data:`NO_AGENT_READS`), and the settings of a
    part of the agent that its switch turns off (:data:`ONLY_WITH`)."""
    import dataclasses

    from helios.agents.config import VariantFlags
    from sim.perception.config import GT_MODE_READS, NOISY_ONLY_WITH_ROLES, SimPerceptionConfig

    out: dict[str, str] = {}
    if not reads_section(config.agent, "perception") or is_plugin_spec(config.agent):
        return out            # replaced_settings refuses the whole section; what a plugin reads, it knows
    perception = [f.name for f in dataclasses.fields(SimPerceptionConfig)]
    never = {key.removeprefix("perception.") for key in NO_AGENT_READS}
    if config.agent.endswith("-gt") or config.perception.mode == "gt":
        why = "ground-truth semantics (perception.mode=gt) read only " + ", ".join(sorted(GT_MODE_READS - never))
        out.update({f"perception.{name}": why for name in perception if name not in GT_MODE_READS})
    elif not config.perception.gt_roles:
        out.update({f"perception.{name}": "it applies only with perception.gt_roles (the exact detector of "
                                          "those roles)" for name in NOISY_ONLY_WITH_ROLES})
    out.update({key: "the agents ask the image-text scorer only about receptacles (their value maps' start and "
                     "goal receptacles), and this sets its evidence for small objects" for key in NO_AGENT_READS})
    if config.agent_config.view.arm_model == "measured":
        out.update({f"agent_config.view.{name}": "the measured arm model (agent_config.view.arm_model, the "
                                                 "default) does not read it; the radius model does"
                    for name in ("arm_swing_radius", "arm_swing_height")})
    out.update(_only_with_unread(config))           # before the variant's: no object map says more
    variant = replaced_settings(config.agent).get("agent_config.variant", config.agent_config.variant)
    if not VariantFlags.of(variant).object_map:
        variant = f"the {variant} variant (agent_config.variant={variant})"
        out.update({key: f"{variant} keeps no object map; it acts on the first detection it trusts, with no "
                         f"candidates, Psi decisions, gaze points or local search" for key in OBJECT_MAP_ONLY})
        if config.helios.search.frontier_choice == "highest_value":
            out.update({key: f"{variant} has no candidates to weigh frontiers against and goes to the "
                             f"highest-value frontier (helios.search.frontier_choice=highest_value)"
                        for key in HIGHEST_VALUE_UNREAD})
    return out


def check_agent_settings(config, explicit: Iterable[str] = ()) -> None:
    """ConfigError, before any work, when a TrialConfig sets what its agent replaces or never reads
    (:func:`replaced_settings`): ``explicit`` (the KEY of each KEY=VALUE given on the command line)
    names such a setting, or the config's value there differs from the default (a scenario file's
    setting), and it is not the value the agent forces anyway."""
    from helios.schema import ConfigError
    from tasks.trial_config import TrialConfig

    default = TrialConfig(agent=config.agent)
    named = {key.strip() for key in explicit}
    for key, forced in replaced_settings(config.agent).items():
        given = sorted(k for k in named if k == key or k.startswith(key + "."))
        value = _value_at(config, key)
        if not given and value == _value_at(default, key):
            continue
        agent = short_repr(config.agent, 40)
        if forced is IGNORED:
            where = given[0] if given else f"{key}.*"
            if is_plugin_spec(config.agent):
                raise ConfigError(f"{where}: agent {agent} reads no {key}.* settings (its factory's reads does not "
                                  f"name {key!r}), so this would change nothing; leave it out, or add {key!r} to "
                                  f"its reads and take the option it brings")
            raise ConfigError(f"{where}: agent {agent} reads no {key}.* settings (it acts on ground truth, with no map "
                              f"or detector), so this would change nothing; leave it out or run a HELIOS agent")
        if value != forced:
            if key == "perception.mode":
                other = config.agent.removesuffix("-gt") if config.agent.endswith("-gt") else config.agent + "-gt"
            else:
                other = "helios"
            raise ConfigError(f"{key}={value!r} with agent {agent}, which sets {key}={forced!r} itself; leave it out, "
                              f"or run agent {short_repr(other, 40)} with it")
    for key, why in unread_settings(config).items():
        given = key in named
        if given or _value_at(config, key) != _value_at(default, key):
            raise ConfigError(f"{key}{' (set in the scenario file)' if not given else ''} would change nothing with "
                              f"agent {short_repr(config.agent, 40)}: {why}; leave it out")
