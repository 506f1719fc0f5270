"""Global search objective (paper Sec. "Global search objective"): candidates versus frontiers, F0."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from helios.config import SearchConfig
from helios.search.objective import CandidateLocation, Choice, FrontierOption, GlobalObjective

CELL = 0.025


def cand(i, xy, score, ig):
    return CandidateLocation(i, np.array(xy, dtype=float), score, ig)


def front(xy, value, key=0):
    return FrontierOption(np.array(xy, dtype=float), value, key)


def objective(mode="objective", **cfg) -> GlobalObjective:
    return GlobalObjective(SearchConfig(**cfg), CELL, mode)


def calibrated(ratio_target_xy=(0.0, 0.0)) -> GlobalObjective:
    """An objective whose F0 is exactly 100: one candidate (S0 IG0 = 0.8 * 50 = 40) at the origin,
    one chosen frontier at its centre with value 0.4 -> V0 = 40, F0 = 40 / 0.4."""
    obj = objective()
    obj.remember([cand(1, (0.0, 0.0, 0.7), 0.8, 50.0)])
    obj.note_frontier_chosen(front(ratio_target_xy, 0.4))
    assert obj.frontier_ratio() == pytest.approx(100.0)
    return obj


def test_distances_are_in_cells_by_default_and_metres_on_request():
    assert SearchConfig().distance_unit == "cells"
    assert objective().distance((0, 0), (3.0, 4.0)) == pytest.approx(5.0 / CELL)
    assert objective(distance_unit="metres").distance((0, 0, 9.0), (3.0, 4.0, -1.0)) == pytest.approx(5.0)


def test_candidate_and_frontier_values_follow_the_paper():
    obj = calibrated()
    robot = (2.0, 0.0)
    c = cand(7, (2.0, 3.0), 0.6, 20.0)          # 3 m = 120 cells away
    assert obj.candidate_value(c, robot) == pytest.approx(0.6 * 20.0 - 0.001 * 120)
    f = front((-2.0, 3.0), 0.3)                  # 5 m = 200 cells away
    assert obj.frontier_value(f, robot) == pytest.approx(0.3 * 100.0 - 0.001 * 200)
    assert obj.frontier_value(f, robot, ratio=2.0) == pytest.approx(0.3 * 2.0 - 0.001 * 200)


def test_prefers_a_near_high_ig_candidate_over_a_far_frontier():
    obj = calibrated()
    robot = np.array([0.0, 0.0])
    c = cand(3, (1.0, 0.0), 0.8, 50.0)                 # 40 - 0.001 * 40 cells = 39.96
    far = front((20.0, 0.0), 0.405, key=11)             # 40.5 - 0.001 * 800 cells = 39.70
    choice = obj.choose(robot, [c], [far])
    assert isinstance(choice, Choice)
    assert choice.kind == "candidate" and choice.index == 3
    assert choice.value == pytest.approx(39.96)
    np.testing.assert_allclose(choice.xy, [1.0, 0.0])
    # the same frontier 1 m away is worth more than the candidate: distance decided it
    near = front((1.0, 0.0), 0.405, key=12)             # 40.5 - 0.04 = 40.46
    choice = obj.choose(robot, [c], [near])
    assert choice.kind == "frontier" and choice.index == 12
    assert choice.value == pytest.approx(40.46)


def test_prefers_a_frontier_over_a_saturated_candidate():
    obj = calibrated()
    robot = (0.0, 0.0)
    saturated = cand(5, (0.5, 0.0), 0.9, 0.0)           # IG 0: nothing left to learn there
    f = front((6.0, 0.0), 0.05, key=2)                   # 5 - 0.24 = 4.76
    choice = obj.choose(robot, [saturated], [f])
    assert choice.kind == "frontier" and choice.index == 2
    assert choice.value == pytest.approx(0.05 * 100 - 0.001 * 240)
    # under the earlier reading of F0 before any frontier (a fixed ratio of 1), too
    fresh = objective(initial_frontier_calibration="fixed_ratio")
    choice = fresh.choose(robot, [cand(5, (0.5, 0.0), 0.9, 0.0)], [front((6.0, 0.0), 0.5, key=2)])
    assert choice.kind == "frontier"


def test_prefer_candidates_mode_picks_any_candidate_over_frontiers():
    obj = GlobalObjective(SearchConfig(), CELL, "prefer_candidates")
    robot = (0.0, 0.0)
    weak = cand(9, (10.0, 0.0), 0.31, 0.0)               # zero IG, 10 m away: value -0.4
    strong_frontier = front((1.0, 0.0), 1.0, key=4)
    choice = obj.choose(robot, [weak], [strong_frontier])
    assert choice.kind == "candidate" and choice.index == 9
    assert choice.value == pytest.approx(-0.4)
    # the best of several candidates
    choice = obj.choose(robot, [weak, cand(8, (1.0, 0.0), 0.5, 4.0)], [strong_frontier])
    assert choice.kind == "candidate" and choice.index == 8
    # with no candidates it explores
    choice = obj.choose(robot, [], [strong_frontier])
    assert choice.kind == "frontier" and choice.index == 4
    # the objective mode on the same inputs explores
    assert objective().choose(robot, [weak], [strong_frontier]).kind == "frontier"


def test_frontiers_only_mode_and_empty_inputs():
    obj = objective("frontiers_only")
    choice = obj.choose((0, 0), [cand(1, (1.0, 0.0), 1.0, 1000.0)], [front((5.0, 0.0), 0.01, key=3)])
    assert choice.kind == "frontier" and choice.index == 3
    assert obj.choose((0, 0), [cand(1, (1.0, 0.0), 1.0, 1000.0)], []) is None
    assert objective().choose((0, 0), [], []) is None
    with pytest.raises(ValueError):
        GlobalObjective(SearchConfig(), CELL, "greedy")
    with pytest.raises(ValueError):
        GlobalObjective(SearchConfig(), 0.0)


def test_frontier_ratio_matches_the_paper_formula_by_hand():
    """F0 = mean over chosen frontiers f' of V0(f') / F0(f'),
    V0(f') = max_a S0(a) IG0(a) - alpha_d dist(a, f') with *initial* S0, IG0 and centres.

    A: S0 IG0 = 0.8 * 100 = 80 at (0, 0);  B: 0.5 * 40 = 20 at (4, 0). alpha_d = 0.001 per cell.
    f1 = (1, 0), F0(f1) = 0.5: V0 = max(80 - 0.001 * 40, 20 - 0.001 * 120) = 79.96 -> 159.92
    f2 = (4, 3), F0(f2) = 0.2: V0 = max(80 - 0.001 * 200, 20 - 0.001 * 120) = 79.80 -> 399.00
    f3 = (9, 9), F0(f3) = 0.0: below min_frontier_value, left out (no scale information).
    F0 = (159.92 + 399.00) / 2 = 279.46
    """
    obj = objective()
    assert obj.frontier_ratio() == pytest.approx(1.0)             # nothing to calibrate with yet
    a, b = cand(1, (0.0, 0.0, 0.8), 0.8, 100.0), cand(2, (4.0, 0.0), 0.5, 40.0)
    obj.choose((0.0, 0.0), [a, b], [])                            # first sight stores S0, IG0, centre
    assert obj.frontier_ratio() == pytest.approx(1.0)             # ... but no frontier chosen yet
    obj.note_frontier_chosen(front((1.0, 0.0), 0.5))
    obj.note_frontier_chosen(front((4.0, 3.0), 0.2))
    obj.note_frontier_chosen(front((9.0, 9.0), 0.0))
    expected = ((80 - 0.001 * 40) / 0.5 + (80 - 0.001 * 200) / 0.2) / 2
    assert expected == pytest.approx(279.46)
    assert obj.frontier_ratio() == pytest.approx(expected, rel=1e-12)

    # later sightings with other scores, IG and centres do not change the stored initial values
    obj.choose((0.0, 0.0), [cand(1, (3.0, 3.0), 0.1, 1.0), cand(2, (1.0, 0.0), 1.0, 500.0)], [])
    assert obj.frontier_ratio() == pytest.approx(expected, rel=1e-12)
    # a new candidate joins V0 with its own first values: C: 1.0 * 300 = 300 at (4, 3)
    obj.remember([cand(3, (4.0, 3.0), 1.0, 300.0)])
    v0_f1 = max(79.96, 300 - 0.001 * (3 * math.sqrt(2)) / CELL)    # |(4,3)-(1,0)| = 3 sqrt(2) m
    v0_f2 = 300.0
    assert obj.frontier_ratio() == pytest.approx((v0_f1 / 0.5 + v0_f2 / 0.2) / 2, rel=1e-12)

    # the frontier value uses it: F * F0 - alpha_d * dist
    f = front((0.0, 2.0), 0.1)
    assert obj.frontier_value(f, (0.0, 0.0)) == pytest.approx(0.1 * obj.frontier_ratio() - 0.001 * 80)


def test_frontier_ratio_in_metres():
    obj = objective(distance_unit="metres", alpha_d=0.5)
    obj.remember([cand(1, (0.0, 0.0), 1.0, 10.0)])
    obj.note_frontier_chosen(front((2.0, 0.0), 0.25))
    assert obj.frontier_ratio() == pytest.approx((10.0 - 0.5 * 2.0) / 0.25)


def test_initial_frontier_ratio_is_used_until_calibrated():
    obj = objective(initial_frontier_ratio=7.0, initial_frontier_calibration="fixed_ratio")
    assert obj.frontier_ratio() == pytest.approx(7.0)
    obj.remember([cand(1, (0.0, 0.0), 1.0, 10.0)])
    assert obj.frontier_ratio() == pytest.approx(7.0)
    obj.note_frontier_chosen(front((0.0, 0.0), 0.0))          # zero-valued: ignored
    assert obj.frontier_ratio() == pytest.approx(7.0)


def test_search_config_validation():
    for bad in (dict(alpha_d=-1.0), dict(cs_start_receptacle=1.5), dict(distance_unit="feet"),
                dict(initial_frontier_ratio=0.0), dict(information_gain="pessimistic")):
        with pytest.raises(ValueError):
            SearchConfig(**bad)
    assert dataclasses.replace(SearchConfig(), alpha_d=0.0).alpha_d == 0.0


def test_open_candidates_calibration_scales_frontiers_to_the_candidates_still_in_A():
    """A big searched candidate (S0 IG0 = 1 * 9000) no longer sets F0 once it has left A: with
    one small open candidate (S0 IG0 = 1 * 200) and a chosen frontier of value 0.25 at both
    centres, F0 = 9000 / 0.25 = 36000 over all candidates but 200 / 0.25 = 800 over the open
    one, and a 0.2 frontier then loses to the open candidate (160 < 200) instead of beating it
    7200 to 200."""
    big, small = cand(1, (0.0, 0.0), 1.0, 9000.0), cand(2, (0.0, 0.0), 1.0, 200.0)
    frontier = front((0.0, 0.0), 0.2, key=7)
    results = {}
    for mode in ("all_candidates", "open_candidates"):
        obj = objective(frontier_calibration=mode)
        obj.remember([big, small])
        obj.note_frontier_chosen(front((0.0, 0.0), 0.25))
        results[mode] = (obj.frontier_ratio([2]), obj.choose((0.0, 0.0), [small], [frontier]).kind)
        assert obj.frontier_ratio([]) == pytest.approx(36000.0)     # no open candidate: all of them
    assert results["all_candidates"] == (pytest.approx(36000.0), "frontier")
    assert results["open_candidates"] == (pytest.approx(800.0), "candidate")
    with pytest.raises(Exception, match="frontier_calibration"):
        SearchConfig(frontier_calibration="latest")


def test_before_the_first_frontier_the_frontiers_on_offer_calibrate_f0():
    """F' is empty before any frontier has been chosen. Our reading: the frontiers on offer stand
    in for it. A: S0 IG0 = 0.8 * 100 = 80 at the origin; frontiers f1 = (1, 0) value 0.5 and
    f2 = (0, 2) value 0.25 (40 and 80 cells away):
    F0 = ((80 - 0.04) / 0.5 + (80 - 0.08) / 0.25) / 2 = 479.76."""
    a = cand(1, (0.0, 0.0), 0.8, 100.0)
    f1, f2 = front((1.0, 0.0), 0.5, key=1), front((0.0, 2.0), 0.25, key=2)
    obj = objective()
    expected = ((80 - 0.001 * 40) / 0.5 + (80 - 0.001 * 80) / 0.25) / 2
    obj.remember([a])
    assert not obj.calibrated
    assert obj.frontier_ratio([1], [f1, f2]) == pytest.approx(expected, rel=1e-12)
    # the frontier 1 m away is now worth 0.5 * 479.76 - 0.04 = 239.84, more than the candidate
    # (80 - 0.001 * 40 = 79.96 from (1, 0)): HELIOS may explore before searching what it saw
    choice = obj.choose((1.0, 0.0), [a], [f1, f2])
    assert choice.kind == "frontier" and choice.index == 1
    assert choice.value == pytest.approx(0.5 * expected - 0.0, rel=1e-9)
    # the earlier reading (F0 = 1 until a frontier is chosen) searches the candidate instead,
    # exactly as the w/o-global ablation does
    old = objective(initial_frontier_calibration="fixed_ratio")
    assert old.choose((1.0, 0.0), [a], [f1, f2]).kind == "candidate"
    assert GlobalObjective(SearchConfig(), CELL, "prefer_candidates").choose((1.0, 0.0), [a], [f1, f2]).kind == "candidate"
    # once a frontier is chosen, the paper's formula takes over (the chosen one, not those on offer)
    obj.note_frontier_chosen(f2)
    assert obj.calibrated
    assert obj.frontier_ratio([1], [f1, f2]) == pytest.approx((80 - 0.001 * 80) / 0.25, rel=1e-12)


def test_frontiers_only_takes_the_highest_value_frontier():
    """The trusting agent and the place phase: "the frontier with the highest value" (paper),
    however far; ties go to the nearest. The earlier reading subtracted a distance penalty."""
    near = front((1.0, 0.0), 0.30, key=1)
    far = front((40.0, 0.0), 0.31, key=2)        # 39 m farther: -1.56 under the old penalty
    tie = front((3.0, 0.0), 0.31, key=3)
    obj = objective("frontiers_only")
    choice = obj.choose((0.0, 0.0), [], [near, far])
    assert choice.kind == "frontier" and choice.index == 2 and choice.value == pytest.approx(0.31)
    assert obj.choose((0.0, 0.0), [], [near, far, tie]).index == 3
    assert obj.choose((0.0, 0.0), [cand(1, (0.5, 0.0), 1.0, 1e6)], [near]).kind == "frontier"
    assert obj.choose((0.0, 0.0), [], []) is None
    old = objective("frontiers_only", frontier_choice="value_minus_distance")
    assert old.choose((0.0, 0.0), [], [near, far]).index == 1
