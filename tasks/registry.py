"""Agents by name, for the command line and trial batches. Each entry builds a fresh agent for one
simulated episode (``tasks.runner.SimEpisode``); unknown names get one error listing the valid ones."""

from __future__ import annotations

from typing import Callable


class UnknownAgentError(ValueError):
    """An agent name is not registered."""


def _oracle(sim):
    from tasks.oracle import OracleAgent

    return OracleAgent(sim)


AGENTS: dict[str, tuple[Callable, str]] = {
    "oracle": (_oracle, "scripted ground-truth agent: knows where everything is, acts through the HAL (the ceiling)"),
}


def agent_names() -> list[str]:
    return sorted(AGENTS)


def make_agent(name: str, sim):
    try:
        factory, _ = AGENTS[name]
    except KeyError:
        raise UnknownAgentError(f"unknown agent {name!r}; valid agents: {', '.join(agent_names())}") from None
    return factory(sim)
