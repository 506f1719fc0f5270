"""Summaries of a batch's records, OVMM-style: phase rates in percent with standard errors, failure
reasons, collisions, time and memory (``summary.json`` and the tables), and the paper's
pick-attempt limit rows. Functions of records alone, apart from running episodes, so that the
report scores saved runs without the batch runner.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Iterable

import numpy as np

from tasks.metrics import FAILURE_REASONS

METRIC_KEYS = ("find_obj", "pick", "find_rec", "place", "success")
PHASE_TIME_KEYS = ("find_obj_time", "pick_time", "find_rec_time")   # simulated s to the phase (None: never)
METRIC_NAMES = {"find_obj": "FindObj", "pick": "Pick", "find_rec": "FindRec", "place": "Place", "success": "SR"}


def summarize(records: Iterable[dict]) -> dict:
    """Phase rates in percent with standard errors, collisions, failure reasons, time and memory.

    Rates are over the scored episodes (those with metrics); episodes that ended on an agent or
    robot exception are scored like any other (the judge still ran) and also counted in ``errors``.
    """
    records = list(records)
    n = len(records)
    out: dict = {"episodes": n}
    scored = [r for r in records if r.get("metrics")]
    m = len(scored)
    out["scored"] = m
    for key in METRIC_KEYS:
        hits = sum(bool(r["metrics"][key]) for r in scored)
        p = hits / m if m else 0.0
        out[METRIC_NAMES[key]] = {"percent": 100.0 * p, "se": 100.0 * math.sqrt(p * (1 - p) / m) if m else 0.0,
                                  "count": hits}
    reasons = Counter(r["metrics"]["failure_reason"] for r in scored if r["metrics"]["failure_reason"])
    out["failure_reasons"] = {k: reasons.get(k, 0) for k in FAILURE_REASONS}
    out["collisions_per_episode"] = float(np.mean([r["metrics"]["collisions"] for r in scored])) if m else 0.0
    out["episodes_with_collisions"] = sum(r["metrics"]["collisions"] > 0 for r in scored)
    out["errors"] = sum(bool(r.get("error")) for r in records)
    out["sim_seconds_per_episode"] = float(np.mean([r["sim_time"] for r in records])) if n else 0.0
    out["wall_seconds_per_episode"] = float(np.mean([r["wall_time"] for r in records])) if n else 0.0
    out["memory"] = _memory_summary(records)
    return out


def _memory_summary(records: list[dict]) -> dict:
    def peaks(key: str) -> list[float]:
        return [r["memory"][key] for r in records if r.get("memory") and r["memory"].get(key) is not None]

    out = {}
    for key in ("peak_rss_mb", "map_mb_peak", "gpu_allocated_mb_peak", "gpu_reserved_mb_peak"):
        vals = peaks(key)
        out[key] = {"max": max(vals), "mean": float(np.mean(vals))} if vals else None
    return out


MAX_PICK_LIMIT = 1000


def limit_pick_attempts(records: Iterable[dict], limit: int) -> list[dict]:
    """The records scored as the paper's "N picks" rows: "With limited attempts, if the agent
    exceeds the limit, we set all metrics for that episode to 0" (paper, Pick Attempts). An
    episode with more than ``limit`` grasp attempts keeps its record (failure reason, times,
    decisions) but fails every phase (FindObj, Pick, FindRec, Place, SR); the others are
    unchanged. The agent ran without a limit, which is what the paper's wording describes: the
    limit scores a run, it does not stop the agent (``agent_config.max_pick_attempts`` does that).
    Records are copied, never changed in place; unscored records (no metrics) stay unscored."""
    if not is_pick_limit(limit):
        raise ValueError(f"a pick-attempt limit must be an integer in [1, {MAX_PICK_LIMIT}], got {limit!r}")
    return [{**r, "metrics": {**r["metrics"], **{k: False for k in METRIC_KEYS}}} if exceeds_pick_limit(r, limit)
            else r for r in records]


def is_pick_limit(limit) -> bool:
    """Whether ``limit`` is a whole number of grasp attempts in [1, MAX_PICK_LIMIT]."""
    return isinstance(limit, int) and not isinstance(limit, bool) and 1 <= limit <= MAX_PICK_LIMIT


def exceeds_pick_limit(record: dict, limit: int) -> bool:
    """A scored record that made more than ``limit`` grasp attempts (its phases score 0 under it)."""
    m = record.get("metrics")
    return bool(m) and int(m.get("pick_attempts", 0)) > limit


def metrics_table_rows(name: str, summary: dict) -> list:
    return [name] + [f"{summary[METRIC_NAMES[k]]['percent']:.1f} ± {summary[METRIC_NAMES[k]]['se']:.1f}"
                     for k in METRIC_KEYS]
