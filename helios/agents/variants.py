"""The agents of the paper's tables as named settings of one code path (no heavy imports: the
command line lists these names without loading torch)."""

from __future__ import annotations

VARIANTS: dict[str, tuple[dict, dict, str]] = {
    # name: (AgentConfig fields, SearchConfig fields, description); nested configs as dicts
    "helios": ({}, {}, "HELIOS: hierarchical map, global search objective, gaze points, Psi decisions"),
    "helios-no-global": ({"variant": "no_global"}, {}, "HELIOS w/o global search objective (candidates before frontiers)"),
    "trusting": ({"variant": "trusting"}, {}, "2D maps only; highest-value frontier; trusts the first detection"),
    "helios-5050": ({}, {"information_gain": "fifty_fifty"}, "HELIOS with the 50-50 information-gain assumption"),
    "helios-place": ({"place": {"mode": "improved"}}, {}, "HELIOS with the improved place skill"),
}
"""Each also exists with ground-truth semantics (name suffix ``-gt``)."""
