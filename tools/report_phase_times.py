"""How fast runs reach each phase, from the simulated seconds to FindObj, Pick and FindRec that the
records keep: the speed table (median time to each phase, who got there first) and the time
budgets (the budgets a run can be scored for, the table of what each run would have scored had it
been stopped at T, its report.json summary and the curve the budget plot draws). Its own module
because both read the same phase times, and the budgets are one question (would a shorter run
have changed the ordering?) apart from the paper's table.
"""

from __future__ import annotations

import math

import numpy as np

from tools.report_runs import Run
from tools.report_stats import p_text, sign_test_p


SPEED_TITLE = ("How fast each run searches: simulated seconds from the start to each phase (median over the "
               "episodes that reached it, how many in brackets), and against the first run, the episodes this run "
               "reached the phase first (+) or the first run did (-; reaching it at all counts as first), exact "
               "sign test; n/a: records made before phase times were kept")
SPEED_PHASES = (("find_obj_time", "FindObj"), ("pick_time", "Pick"), ("find_rec_time", "FindRec"))


def run_phase_times(run: Run, key: str) -> dict[str, float]:
    """Episode id -> seconds to the phase (inf: never reached), for records that keep phase times."""
    out = {}
    for r in run.records:
        m = r.get("metrics")
        if isinstance(m, dict) and key in m:
            out[r["episode_id"]] = math.inf if m[key] is None else float(m[key])
    return out


def speed_rows(runs: list[Run]) -> tuple[list[str], list[list]]:
    """Per run, the median time to FindObj, Pick and FindRec; against the first run, who got to
    FindObj and Pick first, episode by episode. Two policies that find the object in the same
    episodes can still differ in how long they take: this pairs on every episode either one
    completes, where FindObj's yes/no pairs only on those exactly one completes."""
    headers = ["run"] + [f"{name} s" for _, name in SPEED_PHASES] + ["FindObj first", "Pick first"]
    rows = []
    for i, run in enumerate(runs):
        row = [run.name]
        for key, _ in SPEED_PHASES:
            times = run_phase_times(run, key)
            reached = [t for t in times.values() if math.isfinite(t)]
            row.append("n/a" if not times else (f"{np.median(reached):.0f} ({len(reached)})" if reached else "- (0)"))
        for key in ("find_obj_time", "pick_time"):
            if i == 0:
                row.append("-")
                continue
            ref, mine = run_phase_times(runs[0], key), run_phase_times(run, key)
            both = set(ref) & set(mine)
            if not both:
                row.append("n/a")
                continue
            wins = sum(mine[e] < ref[e] for e in both)        # never reached (inf) on both sides: a tie
            losses = sum(ref[e] < mine[e] for e in both)
            row.append(f"+{wins} -{losses} ({p_text(sign_test_p(wins, losses))})")
        rows.append(row)
    return headers, rows


BUDGET_PHASES = (("find_obj_time", "FindObj"), ("pick_time", "Pick"), ("find_rec_time", "FindRec"))
BUDGET_TITLE = ("Search by time budget: % of episodes that reached the phase within T simulated seconds, what the "
                "run would have scored had it been stopped at T (exact for FindObj and FindRec; a grasp that began "
                "before T and ended after it counts for a run stopped at T, not here); against the first run, the "
                "episodes only this run reached within T (+) / only the first run did (-), exact sign test; "
                "n/a: records made before phase times were kept")
BUDGET_FRACTIONS = (0.2, 0.4, 0.6, 0.8, 1.0)
MAX_BUDGETS = 12


def run_time_cap(run: Run) -> float:
    """The simulated-time cap the run's episodes ran under (``runner.max_sim_time`` of its
    config.yaml; the runner's default when the config does not say)."""
    from tasks.runner import RunnerConfig

    runner = run.config.get("runner") if isinstance(run.config, dict) else None
    cap = runner.get("max_sim_time") if isinstance(runner, dict) else None
    return float(cap) if isinstance(cap, (int, float)) and not isinstance(cap, bool) and cap > 0 \
        else RunnerConfig().max_sim_time


def default_budgets(runs: list[Run]) -> tuple[float, ...]:
    """Fifths of the smallest cap among the runs (a run cannot be scored for more time than it had)."""
    cap = min(run_time_cap(r) for r in runs)
    return tuple(round(f * cap, 1) for f in BUDGET_FRACTIONS)


def check_budgets(runs: list[Run], budgets: tuple[float, ...]) -> None:
    """CliError for a budget beyond a run's cap: beyond it the records say nothing about what the
    agent would have done with more time."""
    from tools.cli import CliError

    for r in runs:
        cap = run_time_cap(r)
        over = [t for t in budgets if t > cap + 1e-9]
        if over:
            raise CliError(f"--budgets: {over[0]:g} s is beyond run {r.name!r}'s cap of {cap:g} s "
                           f"(runner.max_sim_time): a run can only be scored for shorter budgets than it had")


def reached_within(times: dict[str, float], budget: float) -> dict[str, bool]:
    """Episode id -> the phase was reached strictly before ``budget`` s (the runner stops an episode
    at the first observation or command that would start at or after its cap)."""
    return {e: t < budget for e, t in times.items()}


def budget_rows(runs: list[Run], budgets: tuple[float, ...]) -> tuple[list[str], list[list]]:
    """Per run and phase (FindObj, Pick, FindRec): the percent of its episodes that reached the
    phase within each budget, and against the first run the paired sign test at that budget. The
    600 s cap is our choice (the paper's benchmark counts steps): an ordering that holds at one
    budget and not another is a statement about the policies' speed, not their reach."""
    headers = ["run", "phase"] + [f"within {t:g} s" for t in budgets]
    rows = []
    for i, run in enumerate(runs):
        for key, name in BUDGET_PHASES:
            times = run_phase_times(run, key)
            if not times:
                rows.append([run.name, name] + ["n/a"] * len(budgets))
                continue
            ref = run_phase_times(runs[0], key) if i else {}
            row = [run.name, name]
            for t in budgets:
                mine = reached_within(times, t)
                cell = f"{100.0 * sum(mine.values()) / len(mine):.1f}"
                if i:
                    theirs = reached_within(ref, t)
                    both = set(mine) & set(theirs)
                    if both:
                        wins = sum(mine[e] and not theirs[e] for e in both)
                        losses = sum(theirs[e] and not mine[e] for e in both)
                        cell += f" +{wins} -{losses} ({p_text(sign_test_p(wins, losses))})"
                    else:
                        cell += " (n/a)"
                row.append(cell)
            rows.append(row)
    return headers, rows


def budget_summary(run: Run, budgets: tuple[float, ...]) -> dict:
    """{budget s: {phase: percent reached within it}} for report.json (phases without times left out)."""
    phase_times = {name: times for key, name in BUDGET_PHASES if (times := run_phase_times(run, key))}
    return {f"{t:g}": {name: 100.0 * sum(reached_within(times, t).values()) / len(times)
                       for name, times in phase_times.items()} for t in budgets}


def budget_curve(times: dict[str, float], grid: np.ndarray) -> np.ndarray:
    """Percent of the episodes in ``times`` that reached the phase strictly before each ``grid`` time."""
    t = np.sort(np.fromiter(times.values(), dtype=float, count=len(times)))
    return 100.0 * np.searchsorted(t, grid, side="left") / max(len(t), 1)
