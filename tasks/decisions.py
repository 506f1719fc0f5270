"""What the search policy decided and where its simulated time went, summed over a run's episodes
(for ``tools report``; the numbers come from each record's ``extra``, see ``tasks.runner``).

Per episode the runner stores, for agents that offer them (HELIOS and its ablations; the oracle
and the scripted demo do not, and their runs read "n/a"):

``extra["decisions"]`` (``HeliosAgent.decision_stats()``)
    ``global_with_candidates``: global decisions (pick phase) taken while at least one candidate
    pick location was open, i.e. where the global objective had to weigh a candidate against the
    frontiers. Each one either chose a candidate (local search) or a frontier (exploration);
    ``chose_candidate_before_f0`` / ``chose_frontier_before_f0`` count them while F0 (the frontier
    calibration) had no chosen frontier to come from yet (a stand-in value, see
    ``helios.search.objective``), ``..._after_f0`` once a frontier had been chosen.
    ``extra_views_object`` / ``extra_views_goal``: extra views of a target-object / goal-receptacle
    candidate taken because the predicted Psi' said one more view was worth it.
    ``gaze_point_visits``: gaze points of local searches visited (walk there and look; a walk
    that fails still counts), so at most the sum of the planned sizes; ``gaze_point_views``: those
    visits that took their view (the walk arrived, the body faced the location and the arm had
    room). Records made before the views were counted lack it; a run with such a record reports
    None for it.
    ``frontiers_given_up``: frontiers marked unreachable because the steps towards them got
    nowhere (``AgentConfig.stall_steps``: the robot ended each where the last one ended and saw no
    new floor); counted since 2026-12-04, None for a run with an older record.
    ``claw_drops``: times the object left the claw between a grasp and the place (it slipped out
    while carried, or fell as the arm stowed; the agent then searches for it again), as the agent
    saw it in the frames after the grasp; counted since 2026-12-06, None for a run with an older
    record.
    ``local_search_sizes``: per candidate pick location searched, the gaze points planned for it.
``extra["start_receptacle"]`` (the runner's ground-truth check, ``EpisodeJudge.start_receptacle_truth``)
    Of the global decisions with open candidates (``decisions``), in how many the start receptacle
    that really holds the object was among the candidates (``offered``), how many chose it
    (``chosen``), of those how many got at least one view from their local search (``viewed``),
    the first decision that offered it (``first_offered``, 1-based; None: never) and when it first
    covered a little of a frame the agent took (``in_view``, simulated s; None: never).
``extra["activity_time"]``
    Simulated seconds per activity (``ACTIVITIES``: start scan, exploration, local search, pick,
    carry, place); they sum to the episode's ``sim_time``.

Reading them: a global objective can only make a difference where there are decisions with open
candidates that chose a frontier. If nearly all such decisions chose a candidate (especially
``chose_candidate_before_f0``), HELIOS behaves as its "w/o global objective" ablation (candidates
always first) and the two runs coincide. Few ``extra_views_*`` mean the Psi' rule rarely asks for
another view, so variants that only change Psi' (e.g. the 50-50 IG reading) cannot differ much.
Large local searches and a large local-search share of the time point at timeouts spent on gaze
points rather than on exploration. The start-receptacle check says why an object was never found:
never offered (never in view: coverage; in view: not recognised as a candidate),
offered and passed over until the end (the objective preferred frontiers or other candidates),
or searched without finding the object: without a single view (every gaze point failed: no
path, a body that could not face the receptacle, no room for the arm) or with views that missed
it (the views or the detector).
"""

from __future__ import annotations

import statistics
from typing import Iterable

from helios.agents.activities import ACTIVITIES, DECISION_COUNTS

COUNTED_LATER = ("gaze_point_views", "frontiers_given_up", "claw_drops")
"""Decision counts that records made before 2026-12-03 / -04 / -06 lack: a run with such a record
totals None for them (unknown), never a 0 that would read as "none"."""

# ACTIVITIES: table order; activities not in it follow in the order they appear.


def _extra(record: dict, key: str):
    extra = record.get("extra")
    value = extra.get(key) if isinstance(extra, dict) else None
    return value if isinstance(value, dict) else None


def summarize_decisions(records: Iterable[dict]) -> dict | None:
    """Decision counts summed over the records that have them; None when none has (a run of an
    agent without ``decision_stats`` or one made before the runner stored them).

    Returns ``episodes`` (records with decisions), ``of`` (all records), ``totals`` (each of
    ``DECISION_COUNTS`` summed), ``per_episode`` (the same divided by ``episodes``),
    ``local_searches`` (candidate pick locations searched) and ``gaze_points_planned``
    (``mean``, ``median``, ``max`` over those searches; None when there was none).
    """
    records = list(records)
    stats = [d for d in (_extra(r, "decisions") for r in records) if d is not None]
    if not stats:
        return None
    n = len(stats)
    totals = {k: int(sum(int(d.get(k, 0) or 0) for d in stats)) for k in DECISION_COUNTS}
    for key in COUNTED_LATER:
        if any(key not in d for d in stats):
            totals[key] = None
    sizes = [int(s) for d in stats for s in (d.get("local_search_sizes") or [])]
    planned = ({"mean": float(statistics.fmean(sizes)), "median": float(statistics.median(sizes)),
                "max": max(sizes)} if sizes else None)
    return {"episodes": n, "of": len(records), "totals": totals,
            "per_episode": {k: (None if v is None else v / n) for k, v in totals.items()},
            "local_searches": len(sizes), "local_searches_per_episode": len(sizes) / n,
            "gaze_points_planned": planned}


def summarize_activity_time(records: Iterable[dict]) -> dict | None:
    """Simulated time per activity over the records that have it; None when none has.

    Returns ``episodes``, ``of``, ``activities`` (``ACTIVITIES`` first, then any other seen),
    ``seconds`` (summed), ``share_percent`` (of the summed time of all activities: a time-weighted
    share, so long episodes weigh more) and ``seconds_per_episode`` (mean over ``episodes``).
    """
    records = list(records)
    times = [t for t in (_extra(r, "activity_time") for r in records) if t is not None]
    if not times:
        return None
    n = len(times)
    seen = [a for t in times for a in t]
    activities = list(ACTIVITIES) + list(dict.fromkeys(a for a in seen if a not in ACTIVITIES))
    seconds = {a: float(sum(float(t.get(a, 0.0) or 0.0) for t in times)) for a in activities}
    total = sum(seconds.values())
    return {"episodes": n, "of": len(records), "activities": activities, "seconds": seconds,
            "share_percent": {a: (100.0 * s / total if total > 0 else 0.0) for a, s in seconds.items()},
            "seconds_per_episode": {a: s / n for a, s in seconds.items()}}


def summarize_start_receptacle(records: Iterable[dict]) -> dict | None:
    """How the runs' searches treated the start receptacle that holds the object (each record's
    ``extra["start_receptacle"]``); None when no record has the check (an agent without a global
    objective's candidates, or records made before the runner kept it).

    Returns ``episodes`` (records with the check), ``of`` (all records), ``offered`` (episodes in
    which it was ever an open candidate), ``searched`` (episodes in which a decision chose it),
    ``never_searched`` (offered, never chosen), ``passed_over_per_offered`` (mean over the offered
    episodes of the decisions that chose something else while it was open; None when none was
    offered) and ``not_found``: the checked episodes that never reached FindObj, split into
    ``never_offered``, ``offered_not_searched`` and ``searched``, and the never-offered ones into
    ``never_in_view`` and ``in_view`` (both None when no such record says, e.g. made before the
    check kept ``in_view``), and the searched ones into ``searched_no_view`` (no decision that
    chose it got a view from its local search: every gaze point failed) and ``searched_viewed``
    (both None when no such record says: made before the check kept ``viewed``).
    """
    records = list(records)
    checked = [(r, t) for r in records if (t := _extra(r, "start_receptacle")) is not None]
    if not checked:
        return None
    kinds = [_search_kind(t) for _r, t in checked]
    offered = [t for (_r, t), k in zip(checked, kinds) if k != "never_offered"]
    missed = [(t, k) for (r, t), k in zip(checked, kinds) if not (r.get("metrics") or {}).get("find_obj")]
    not_found = {"episodes": len(missed)}
    not_found.update({kind: sum(1 for _t, k in missed if k == kind)
                      for kind in ("never_offered", "offered_not_searched", "searched")})
    unoffered = [t for t, k in missed if k == "never_offered" and "in_view" in t]
    not_found["never_in_view"] = sum(1 for t in unoffered if t["in_view"] is None) if unoffered else None
    not_found["in_view"] = sum(1 for t in unoffered if t["in_view"] is not None) if unoffered else None
    looked = [t for t, k in missed if k == "searched" and t.get("viewed") is not None]
    not_found["searched_no_view"] = sum(1 for t in looked if not t["viewed"]) if looked else None
    not_found["searched_viewed"] = sum(1 for t in looked if t["viewed"]) if looked else None
    searched = kinds.count("searched")
    return {"episodes": len(checked), "of": len(records), "offered": len(offered), "searched": searched,
            "never_searched": len(offered) - searched,
            "passed_over_per_offered": (statistics.fmean(t["offered"] - t.get("chosen", 0) for t in offered)
                                        if offered else None),
            "not_found": not_found}


def _search_kind(check: dict) -> str:
    """How one episode's search treated the right start receptacle: ``never_offered``,
    ``offered_not_searched`` (passed over until the end) or ``searched`` (a decision chose it)."""
    if not check.get("offered"):
        return "never_offered"
    return "searched" if check.get("chosen") else "offered_not_searched"


# How far a timed-out episode got: the first phase it never reached names the stage it ran out in.
TIMEOUT_STAGES = (("before_find_obj", "find_obj"), ("found_not_picked", "pick"),
                  ("picked_goal_not_found", "find_rec"), ("at_goal_not_placed", "place"))


def summarize_timeouts(records: Iterable[dict]) -> dict | None:
    """Where the time ran out: the scored episodes that ended in ``timeout``, split by the stage
    they ran out in (``TIMEOUT_STAGES``: never found the object; found it, never picked it;
    picked it, never found the goal receptacle; reached the goal receptacle, never placed), and
    what those episodes spent their simulated time on. None when no record is scored.

    Returns ``scored``, ``timeouts``, ``percent`` (of ``scored``), ``stages`` (stage -> count),
    ``activity_seconds_per_episode`` (mean over the timeouts with activity times; None when none
    has them) and ``gaze_point_visits_per_episode`` / ``extra_views_per_episode`` (mean over the
    timeouts with decision counts; None when none has them).
    """
    scored = [r for r in records if isinstance(r.get("metrics"), dict)]
    if not scored:
        return None
    timeouts = [r for r in scored if r["metrics"].get("failure_reason") == "timeout"]
    stages = {stage: 0 for stage, _ in TIMEOUT_STAGES}
    for r in timeouts:
        stage = next((s for s, key in TIMEOUT_STAGES if not r["metrics"].get(key)), TIMEOUT_STAGES[-1][0])
        stages[stage] += 1
    activity = summarize_activity_time(timeouts) if timeouts else None
    decisions = summarize_decisions(timeouts) if timeouts else None
    per = decisions["per_episode"] if decisions else None
    return {"scored": len(scored), "timeouts": len(timeouts), "percent": 100.0 * len(timeouts) / len(scored),
            "stages": stages,
            "activity_seconds_per_episode": activity["seconds_per_episode"] if activity else None,
            "gaze_point_visits_per_episode": per["gaze_point_visits"] if per else None,
            "extra_views_per_episode": (per["extra_views_object"] + per["extra_views_goal"]) if per else None}
