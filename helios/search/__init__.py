"""HELIOS search: information gain of candidate views, the global objective, gaze points and the
pick/place decision rule.

The package exports the torch-free parts; information gain (torch) is imported from
``helios.search.information``, so importing the package does not load torch."""

from helios.search.decisions import Verdict, decide
from helios.search.gaze_points import GazeConfig, GazePoint
from helios.search.objective import CandidateLocation, Choice, FrontierOption, GlobalObjective

__all__ = ["CandidateLocation", "Choice", "FrontierOption", "GazeConfig", "GazePoint", "GlobalObjective", "Verdict",
           "decide"]
