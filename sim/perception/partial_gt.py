"""Ground truth for some of a task's roles, the simulated detector for the rest
(``SimPerceptionConfig.gt_roles``).

The paper's "with gt" rows replace every detection by ground truth at once, which says how much
perception costs in all but not where. Making one role exact (the target object, the start
receptacle or the goal receptacle) while the others keep the noisy detector splits that cost by
role: on the first 100 train episodes HELIOS timed out in 32, and in 19 with an exact start
receptacle, 21 with an exact object, 25 with an exact goal receptacle (README, "Where the
timeouts come from"). The image-text scorer (the value maps) stays noisy either way.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from helios.perception.detection import Detection
from helios.schema import require

GT_ROLES = ("object", "start_receptacle", "goal_receptacle")
"""The roles of a task whose class ``gt_roles`` may name."""


class PartlyTrueDetector:
    """The noisy detector's detections, except those labelled with one of ``true_classes``, plus
    the ground-truth detections of those classes (exact masks, score 1).

    The noisy detector is still asked for every queried class, so what it says about the other
    classes (its look-alike confusions depend on what is queried) is what it says without this
    wrapper; a look-alike it labels with a true class is dropped, a true-class object it labels
    with another queried class keeps that wrong label.
    """

    def __init__(self, noisy, truth, true_classes: Sequence[str]):
        require(bool(true_classes), "PartlyTrueDetector needs at least one class to take from ground truth")
        self.noisy, self.truth = noisy, truth
        self.true_classes = frozenset(true_classes)
        self.known_classes = getattr(noisy, "known_classes", None)

    def __call__(self, rgb: np.ndarray, depth: np.ndarray, class_names: Sequence[str]) -> list[Detection]:
        out = [d for d in self.noisy(rgb, depth, class_names) if d.class_name not in self.true_classes]
        exact = [c for c in dict.fromkeys(class_names) if c in self.true_classes]
        if exact:
            out += self.truth(rgb, depth, exact)
        return out


def role_classes_of(episode) -> dict[str, str]:
    """Role -> class of a task episode (``tasks.episodes.Episode``)."""
    return {"object": episode.object_category, "start_receptacle": episode.start_receptacle_category,
            "goal_receptacle": episode.goal_receptacle_category}


def true_classes(gt_roles: Sequence[str], role_classes: Mapping[str, str] | None) -> list[str]:
    """The classes of ``gt_roles`` in this task; a one-line error when the task's roles are unknown."""
    require(role_classes is not None, f"perception.gt_roles={list(gt_roles)} needs the task's classes by role "
                                      f"(a task episode); none were given")
    missing = [r for r in gt_roles if r not in role_classes]
    require(not missing, f"perception.gt_roles: no class for role(s) {missing} in this task")
    return [role_classes[r] for r in gt_roles]
