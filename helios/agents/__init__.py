"""HELIOS agents: the full method and the paper's ablations as flags on one code path
(:mod:`helios.agents.helios_agent`; named variants in :mod:`helios.agents.variants`)."""

from helios._lazy import lazy_getattr

# imported on first use: the agent pulls in torch and the map, the command line needs only names
_LAZY = {"AgentConfig": "config", "PlaceConfig": "config", "ReachConfig": "config", "ViewConfig": "config",
         "HeliosAgent": "helios_agent", "VARIANTS": "variants"}
__getattr__ = lazy_getattr(__name__, _LAZY)
__all__ = sorted(_LAZY)
