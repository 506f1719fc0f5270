"""Ground truth for some roles of a task (``perception.gt_roles``, ``sim.perception.partial_gt``):
the detections of those roles' classes are exact, every other one is the noisy detector's own,
and bad settings are one clear error before any work."""

from __future__ import annotations

import numpy as np
import pytest

from helios.perception import Detection
from helios.schema import ConfigError, with_overrides
from sim.perception.partial_gt import PartlyTrueDetector, role_classes_of, true_classes
from tasks.episodes import load_split
from tasks.trial_config import TrialConfig


def _mask(i: int) -> np.ndarray:
    m = np.zeros((4, 4), dtype=bool)
    m.flat[i] = True
    return m


class _Fake:
    def __init__(self, dets):
        self.dets, self.asked = dets, []

    def __call__(self, rgb, depth, class_names):
        self.asked.append(list(class_names))
        return [d for d in self.dets if d.class_name in class_names]


def test_true_classes_come_from_ground_truth_and_the_rest_from_the_noisy_detector():
    noisy = _Fake([Detection(_mask(0), "table", 0.6),          # a desk taken for a table: dropped
                   Detection(_mask(1), "mug", 0.4), Detection(_mask(2), "counter", 0.5)])
    truth = _Fake([Detection(_mask(3), "table", 1.0), Detection(_mask(4), "counter", 1.0)])
    detector = PartlyTrueDetector(noisy, truth, ["table"])
    out = detector(None, None, ["mug", "table", "counter"])
    assert [(d.class_name, d.score, int(np.flatnonzero(d.mask)[0])) for d in out] == \
        [("mug", 0.4, 1), ("counter", 0.5, 2), ("table", 1.0, 3)]
    assert noisy.asked == [["mug", "table", "counter"]]      # the noisy detector sees the whole query
    assert truth.asked == [["table"]]                         # the truth only for the true classes
    assert [d.class_name for d in detector(None, None, ["mug"])] == ["mug"] and truth.asked == [["table"]]


def test_roles_map_to_the_episode_classes():
    ep = load_split("smoke")[0]
    roles = role_classes_of(ep)
    assert roles == {"object": ep.object_category, "start_receptacle": ep.start_receptacle_category,
                     "goal_receptacle": ep.goal_receptacle_category}
    assert true_classes(("goal_receptacle", "object"), roles) == [ep.goal_receptacle_category, ep.object_category]
    with pytest.raises(ConfigError, match="needs the task's classes by role"):
        true_classes(("object",), None)


@pytest.mark.parametrize("agent, overrides, message", [
    ("helios", ["perception.gt_roles=[goal]"], "'goal' is not one of"),
    ("helios", ["perception.gt_roles=[object,object]"], "distinct roles"),
    ("helios", ["perception.gt_roles=[object]", "perception.mode=gt"], "needs mode=noisy"),
    ("helios-gt", ["perception.gt_roles=[object]"], "use 'helios'"),
])
def test_bad_gt_roles_are_one_clear_error(agent, overrides, message):
    with pytest.raises(ConfigError, match=message):
        with_overrides(TrialConfig(agent=agent), overrides)
    assert with_overrides(TrialConfig(agent="helios"), ["perception.gt_roles=[goal_receptacle]"]) \
        .perception.gt_roles == ("goal_receptacle",)
