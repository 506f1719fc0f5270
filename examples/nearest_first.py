"""An agent of your own for ``tools trials`` (README, "Your own agent"): HELIOS's maps, perception,
decision rule and skills, with HomeRobot's heuristic search order instead of the paper's global
objective. Run it, and rank it against HELIOS on the same episodes::

    python -m tools trials --agent examples/nearest_first.py:make --split val --episodes 200 --workers 2 \\
        --out runs/val/nearest-first
    python -m tools report runs/val/helios runs/val/nearest-first --common

HomeRobot's OVMM heuristic agent goes to the start-receptacle cells it has not yet been close to
and otherwise drives to the nearest frontier; it weighs neither a frontier's semantic value nor
what a look would tell it (its ``reach_object_recep_combination`` and frontier policy, see
``../shared/notes/ovmm_vlfm_reference.md``). Here the same order is the pick phase's search
policy: the nearest open candidate pick location (a start-receptacle candidate HELIOS has not
searched yet), else the nearest frontier, by straight-line distance. Everything else (which
detections are candidates, the gaze points of a local search, when to take another view or
grasp, the place phase) is HELIOS's, so the two runs differ only in where the search goes next.
"""

from __future__ import annotations

import math

import numpy as np

from helios.search.objective import Choice
from tasks.registry import make_agent


class NearestFirst:
    """The pick phase's search policy (``HeliosAgent(search_policy=...)``): made per episode as
    ``NearestFirst(search_config, cell_size, mode)``; ``mode`` is the variant's (``objective``:
    candidates and frontiers, ``frontiers_only``: frontiers only)."""

    def __init__(self, config, cell_size: float, mode: str):
        self.mode = mode
        self.frontiers_chosen = 0

    @property
    def calibrated(self) -> bool:
        """Whether a frontier has been chosen yet: the report's decision counts split the choices
        there (for HELIOS that is when F0 is calibrated; this policy has no F0)."""
        return self.frontiers_chosen > 0

    def note_frontier_chosen(self, frontier) -> None:
        self.frontiers_chosen += 1

    def choose(self, robot_xy, candidates, frontiers) -> Choice | None:
        """The nearest open candidate, else the nearest frontier (None when there is neither); a
        choice's value is minus its distance in metres."""
        def nearest(kind: str, options, xy_of, index_of) -> Choice:
            best = min(options, key=lambda o: (math.dist(robot_xy[:2], xy_of(o)[:2]), index_of(o)))
            xy = np.asarray(xy_of(best), dtype=float)[:2]
            return Choice(kind, index_of(best), xy, -math.dist(robot_xy[:2], xy))

        if candidates and self.mode != "frontiers_only":
            return nearest("candidate", candidates, lambda c: c.centre, lambda c: c.instance_id)
        if frontiers:
            return nearest("frontier", frontiers, lambda f: f.xy, lambda f: f.key)
        return None


def make(context, perception_config=None, **options):
    """The factory ``tools trials --agent examples/nearest_first.py:make`` calls once per episode:
    HELIOS (the registered ``helios`` agent, with the run's settings) searching nearest first;
    with ``perception.mode=gt`` its ground-truth twin ``helios-gt`` (the registered agents take
    the detector's mode from their name, so the factory picks the name)."""
    gt = perception_config is not None and perception_config.mode == "gt"
    return make_agent("helios-gt" if gt else "helios", context, search_policy=NearestFirst,
                      perception_config=perception_config, **options)


make.reads = ("agent_config", "helios", "perception")
"""The run's ``agent_config.*``, ``helios.*`` and ``perception.*`` settings reach HELIOS as options."""
