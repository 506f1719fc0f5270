"""HELIOS search: information gain of candidate views, the global objective, gaze points and the
pick/place decision rule (names imported on first use)."""

_LAZY = {
    "PredictedScore": "information", "dirichlet_entropy": "information", "fifty_fifty_information_gain": "information",
    "information_gain": "information", "optimistic_evidence": "information",
    "optimistic_information_gain": "information", "predicted_object_score": "information",
    "views_information_gain": "information",
    "GlobalObjective": "objective", "CandidateLocation": "objective", "FrontierOption": "objective", "Choice": "objective",
    "GazeConfig": "gaze_points", "GazePoint": "gaze_points",
    "Verdict": "decisions", "decide": "decisions",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"helios.search.{_LAZY[name]}"), name)
    raise AttributeError(name)


__all__ = sorted(_LAZY)
