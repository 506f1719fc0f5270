"""HELIOS agents: the full method and the paper's ablations as flags on one code path
(:mod:`helios.agents.helios_agent`; named variants in :mod:`helios.agents.variants`)."""

_LAZY = {"AgentConfig": "helios.agents.config", "PlaceConfig": "helios.agents.config",
         "ReachConfig": "helios.agents.config", "ViewConfig": "helios.agents.config",
         "HeliosAgent": "helios.agents.helios_agent", "VARIANTS": "helios.agents.variants"}


def __getattr__(name: str):
    """Imported on first use: the agent pulls in torch and the map, the command line needs only names."""
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(name)


__all__ = sorted(_LAZY)
