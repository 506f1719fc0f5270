"""Navigation on the agent's own occupancy map: fast-marching-squared paths turned into Spot-sized,
footprint-checked rotate/forward actions (HELIOS appendix "Path Planner")."""

from helios.planning.fmm import Action, FMMPlanner, PlannerConfig, PlanResult
from helios.planning.footprint import FootprintChecker, FootprintConfig

__all__ = ["Action", "FMMPlanner", "PlannerConfig", "PlanResult", "FootprintChecker", "FootprintConfig"]
