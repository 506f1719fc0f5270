"""HELIOS search: information gain of candidate views (and, later, the global objective)."""

from helios.search.information import (PredictedScore, dirichlet_entropy, fifty_fifty_information_gain,
                                       information_gain, optimistic_evidence, optimistic_information_gain,
                                       predicted_object_score)

__all__ = ["PredictedScore", "dirichlet_entropy", "fifty_fifty_information_gain", "information_gain",
           "optimistic_evidence", "optimistic_information_gain", "predicted_object_score"]
