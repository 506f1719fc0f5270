"""HELIOS search: information gain of candidate views, the global objective, gaze points and the
pick/place decision rule (names imported on first use)."""

from helios._lazy import lazy_getattr

_LAZY = {
    "PredictedScore": "information", "dirichlet_entropy": "information", "fifty_fifty_information_gain": "information",
    "information_gain": "information", "optimistic_evidence": "information",
    "optimistic_information_gain": "information", "predicted_object_score": "information",
    "views_information_gain": "information",
    "GlobalObjective": "objective", "CandidateLocation": "objective", "FrontierOption": "objective", "Choice": "objective",
    "GazeConfig": "gaze_points", "GazePoint": "gaze_points",
    "Verdict": "decisions", "decide": "decisions",
}
__getattr__ = lazy_getattr(__name__, _LAZY)
__all__ = sorted(_LAZY)
