"""Agents by name, for the command line and trial batches. Each entry builds a fresh agent for one
simulated episode (``tasks.runner.SimEpisode``); unknown names get one error listing the valid ones."""

from __future__ import annotations

from typing import Callable


class UnknownAgentError(ValueError):
    """An agent name is not registered."""


def _oracle(sim, **_options):
    from tasks.oracle import OracleAgent

    return OracleAgent(sim)


def _helios_factory(variant: str, ground_truth: bool) -> Callable:
    """Factory of one HELIOS variant with simulated (noisy or ground-truth) perception."""

    def factory(sim, agent_config=None, method_config=None, perception_config=None):
        from dataclasses import replace

        from helios.agents import AgentConfig, HeliosAgent
        from helios.agents.variants import VARIANTS
        from helios.config import HeliosConfig
        from sim.perception import SimPerceptionConfig, make_sim_perception

        agent_fields, search_fields, _ = VARIANTS[variant]
        agent_config = agent_config or AgentConfig()
        agent_fields = {k: replace(getattr(agent_config, k), **v) if isinstance(v, dict) else v
                        for k, v in agent_fields.items()}
        agent_config = replace(agent_config, **agent_fields)
        method_config = method_config or HeliosConfig()
        if search_fields:
            method_config = replace(method_config, search=replace(method_config.search, **search_fields))
        perception_config = replace(perception_config or SimPerceptionConfig(), mode="gt" if ground_truth else "noisy")
        detector, scorer = make_sim_perception(sim.backend, seed=getattr(sim, "seed", sim.episode.seed),
                                               config=perception_config,
                                               rooms=sim.scene.layout.rooms)
        name = variant + ("-gt" if ground_truth else "")
        return HeliosAgent(detector, scorer, agent_config, method_config, name=name)

    return factory


def _helios_agents() -> dict[str, tuple[Callable, str]]:
    from helios.agents.variants import VARIANTS

    out = {}
    for variant, (_, _, text) in VARIANTS.items():
        out[variant] = (_helios_factory(variant, False), text + " (simulated detector)")
        out[variant + "-gt"] = (_helios_factory(variant, True), text + " (ground-truth semantics)")
    return out


AGENTS: dict[str, tuple[Callable, str]] = {
    **_helios_agents(),
    "oracle": (_oracle, "scripted ground-truth agent: knows where everything is, acts through the HAL (the ceiling)"),
}


def agent_names() -> list[str]:
    return sorted(AGENTS)


def make_agent(name: str, sim, **options):
    """A fresh agent for one simulated episode; ``options`` (agent_config, method_config,
    perception_config) configure the HELIOS agents and are ignored by the oracle. A registered
    factory is called as ``factory(sim, **options)``, so it must accept (and may ignore) them."""
    try:
        factory, _ = AGENTS[name]
    except KeyError:
        raise UnknownAgentError(f"unknown agent {name!r}; valid agents: {', '.join(agent_names())}") from None
    return factory(sim, **options)
