"""HELIOS's global search objective: visit a candidate pick location or explore a frontier?

Paper Sec. "Global search objective" (Eqs. frontier score, F0 and the objective):

- candidates a_i (instances whose class score for the start receptacle is >= cs_a) are worth
  ``V(a_i) = S(a_i) IG(a_i) - alpha_d dist(a_i)``;
- frontiers f_i are worth ``V(f_i) = F(f_i) F0 - alpha_d dist(f_i)``, where F is the value-map
  score near the frontier and F0 converts value-map scores into the candidates' units:
  ``F0 = mean over previously chosen frontiers f' of V0(f') / F0(f')`` with
  ``V0(f') = max_a (S0(a) IG0(a) - alpha_d dist(a, f'))`` built from every candidate's *initial*
  score, information gain and centre (stored the first time it is seen) and ``F0(f')`` the value
  the frontier had when it was chosen.

Distances are measured in occupancy-grid cells (2.5 cm by default), not metres. The paper gives
alpha_d = 0.001 without a unit; HELIOS plans on the 2.5 cm grid and home-robot's planner measures
distances in cells, so cells is the reading that gives the distance term any weight at all: with
IG summed over an instance's Gaussians (hundreds of nats), 0.001 per *metre* would make distance
irrelevant, while 0.001 per cell costs 0.4 per 10 m. ``SearchConfig.distance_unit`` switches.

Which candidates V0 maximises over is a reading of the paper's A: by default every candidate ever
seen (its S0, IG0 are stored "the first time each a_i is detected"); ``frontier_calibration =
"open_candidates"`` uses only those not yet searched. Because IG is summed over an instance's
Gaussians, S0 IG0 spans orders of magnitude (a whole table ~9000, a fragment seen from afar ~30),
and under the default the largest instance ever seen fixes F0 for the rest of the episode: on
val-00004 F0 ~ 35000 made every frontier worth ~5000-25000 against open candidates of 33 and 222.
On 30 train episodes the two readings gave the same FindObj (17 of 30 each) and SR 5 vs 4.

Before any frontier has been chosen F' is empty and the paper does not define F0. Our reading
(``initial_frontier_calibration = "current_frontiers"``): the frontiers on offer stand in for F',
i.e. F0 = mean over them of V0(f) / F(f), so the first decisions already weigh candidates against
frontiers on the candidates' scale. The earlier reading (``"fixed_ratio"``) used
``initial_frontier_ratio`` = 1, raw value-map scores: every candidate with positive information
gain then outranked every frontier, and HELIOS searched everything seen during and soon after the
start scan exactly as the w/o-global ablation does (36 of 36 such decisions chose a candidate).

With no candidate to weigh (``mode = "frontiers_only"``: the trusting agent and every agent's
place phase) the paper goes to "the frontier with the highest value": ``frontier_choice =
"highest_value"`` (ties to the nearest); ``"value_minus_distance"`` keeps the objective's frontier
term with F0 = 1, about 0.04 per metre of distance penalty (our earlier reading).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, Sequence

import numpy as np

from helios.config import SearchConfig


@dataclass(frozen=True)
class CandidateLocation:
    """A detected candidate pick location (an instance) as the objective sees it now."""

    instance_id: int
    centre: np.ndarray          # (2,) or (3,) world metres
    class_score: float          # S_a
    info_gain: float            # IG_a from the instance's gaze points (optimistic or 50-50)


@dataclass(frozen=True)
class FrontierOption:
    """A frontier as the objective sees it: centre and value-map score for the current target."""

    xy: np.ndarray
    value: float                # F(f)
    key: int = -1               # caller's index (e.g. into the frontier list)


@dataclass(frozen=True)
class Choice:
    kind: Literal["candidate", "frontier"]
    index: int                  # instance id for candidates, FrontierOption.key for frontiers
    xy: np.ndarray
    value: float                # V(r)


@dataclass
class _Initial:
    score: float
    info_gain: float
    centre: np.ndarray


@dataclass
class GlobalObjective:
    """Scores candidates and frontiers with the paper's objective; remembers what it needs to
    (initial candidate scores, chosen frontiers). One instance per search target and episode.

    ``mode``: ``"objective"`` (HELIOS), ``"prefer_candidates"`` (the "w/o global search
    objective" ablation: any candidate beats every frontier) or ``"frontiers_only"``.
    """

    config: SearchConfig
    cell_size: float
    mode: Literal["objective", "prefer_candidates", "frontiers_only"] = "objective"
    initial: dict[int, _Initial] = field(default_factory=dict)
    chosen_frontiers: list[tuple[np.ndarray, float]] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.mode not in ("objective", "prefer_candidates", "frontiers_only"):
            raise ValueError(f"unknown objective mode {self.mode!r}")
        if self.cell_size <= 0:
            raise ValueError("cell_size must be > 0")

    # ------------------------------------------------------------------ units
    def distance(self, a, b) -> float:
        """Euclidean ground distance in the objective's unit (cells or metres)."""
        d = math.dist(np.asarray(a, dtype=float)[:2], np.asarray(b, dtype=float)[:2])
        return d / self.cell_size if self.config.distance_unit == "cells" else d

    # ------------------------------------------------------------------ memory
    def remember(self, candidates: Sequence[CandidateLocation]) -> None:
        """Store S0, IG0 and the centre of candidates seen for the first time."""
        for c in candidates:
            if c.instance_id not in self.initial:
                self.initial[c.instance_id] = _Initial(float(c.class_score), float(c.info_gain),
                                                       np.asarray(c.centre, dtype=float)[:2].copy())

    def note_frontier_chosen(self, frontier: FrontierOption) -> None:
        self.chosen_frontiers.append((np.asarray(frontier.xy, dtype=float)[:2].copy(), float(frontier.value)))

    @property
    def calibrated(self) -> bool:
        """Whether F0 comes from chosen frontiers (the paper's formula) rather than a stand-in."""
        return bool(self.chosen_frontiers)

    def frontier_ratio(self, open_ids: Sequence[int] = (), current: Sequence[FrontierOption] = ()) -> float:
        """F0: mean of V0(f') / F0(f') over previously chosen frontiers (see module doc).
        ``open_ids``: the candidates still in A, used for V0 under ``frontier_calibration =
        "open_candidates"``. ``current``: the frontiers on offer, which stand in for F' before any
        frontier has been chosen (``initial_frontier_calibration = "current_frontiers"``)."""
        if not self.initial:
            return self.config.initial_frontier_ratio
        pool = list(self.initial.values())
        if self.config.frontier_calibration == "open_candidates":
            pool = [self.initial[i] for i in open_ids if i in self.initial] or pool
        reference = self.chosen_frontiers
        if not reference and self.config.initial_frontier_calibration == "current_frontiers":
            reference = [(np.asarray(f.xy, dtype=float)[:2], float(f.value)) for f in current]
        ratios = []
        for xy, f0 in reference:
            if f0 <= self.config.min_frontier_value:
                continue      # a zero-valued frontier says nothing about the scale
            v0 = max(i.score * i.info_gain - self.config.alpha_d * self.distance(i.centre, xy) for i in pool)
            ratios.append(v0 / f0)
        return float(np.mean(ratios)) if ratios else self.config.initial_frontier_ratio

    # ------------------------------------------------------------------ scoring
    def candidate_value(self, c: CandidateLocation, robot_xy) -> float:
        return float(c.class_score * c.info_gain - self.config.alpha_d * self.distance(c.centre, robot_xy))

    def frontier_value(self, f: FrontierOption, robot_xy, ratio: float | None = None) -> float:
        ratio = self.frontier_ratio() if ratio is None else ratio
        return float(f.value * ratio - self.config.alpha_d * self.distance(f.xy, robot_xy))

    def choose(self, robot_xy, candidates: Sequence[CandidateLocation],
               frontiers: Sequence[FrontierOption]) -> Choice | None:
        """The best candidate or frontier (None when there is neither). Candidates are
        remembered (S0, IG0, centre) on first sight."""
        self.remember(candidates)
        if self.mode == "frontiers_only" and self.config.frontier_choice == "highest_value":
            if not frontiers:
                return None
            best = max(frontiers, key=lambda f: (f.value, -self.distance(f.xy, robot_xy)))
            return Choice("frontier", best.key, np.asarray(best.xy, dtype=float)[:2], float(best.value))
        options: list[Choice] = []
        if self.mode != "frontiers_only":
            options += [Choice("candidate", c.instance_id, np.asarray(c.centre, dtype=float)[:2],
                               self.candidate_value(c, robot_xy)) for c in candidates]
        if self.mode == "prefer_candidates" and options:
            return max(options, key=lambda o: o.value)
        ratio = self.frontier_ratio([c.instance_id for c in candidates], frontiers)
        options += [Choice("frontier", f.key, np.asarray(f.xy, dtype=float)[:2], self.frontier_value(f, robot_xy, ratio))
                    for f in frontiers]
        if not options:
            return None
        return max(options, key=lambda o: o.value)
