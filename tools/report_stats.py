"""Paired statistics of two runs on the same episodes, for the report: the exact sign test
(McNemar's) on the episodes only one of them passed, the paired table, and the power table (the gap
seen, the smallest gap these episodes could show, about how many episodes the gap would need).
Its own module because it is statistics, not presentation: the time-budget and speed tables use
the same test.
"""

from __future__ import annotations

import math

from tools.report_runs import PHASES, Run


def sign_test_p(wins: int, losses: int) -> float:
    """Exact two-sided sign test (McNemar's exact test) on the discordant episodes: the chance of a
    split at least this uneven if either run were equally likely to win each one."""
    n = wins + losses
    if n == 0:
        return 1.0
    k = min(wins, losses)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2 ** n
    return min(1.0, 2 * tail)


def p_text(p: float) -> str:
    """Two decimals, except below 0.01 (where "p=0.00" would read as impossible) and next to 0.05,
    where two decimals would put a significant p = 0.049 and a p = 0.051 on the same "p=0.05"."""
    if p < 0.005:
        return "p<0.01"
    return f"p={p:.3f}" if 0.045 <= p < 0.055 else f"p={p:.2f}"


def _metrics_by_episode(run: Run) -> dict[str, dict]:
    return {r["episode_id"]: r["metrics"] for r in run.records if r.get("metrics")}


def _discordant(ref: dict[str, dict], mine: dict[str, dict], key: str) -> tuple[int, int, int]:
    """(episodes only ``mine`` passed phase ``key``, only ``ref`` passed, episodes both have)."""
    shared = set(ref) & set(mine)
    wins = sum(bool(mine[e][key]) and not ref[e][key] for e in shared)
    losses = sum(bool(ref[e][key]) and not mine[e][key] for e in shared)
    return wins, losses, len(shared)


def paired_rows(runs: list[Run]) -> tuple[list[str], list[list]]:
    """Each run against the first on the same episodes: per phase, the episodes only this run
    passed / only the first passed, and the sign-test p-value. Ablations that differ by a few
    points are often the same agent on most episodes; this says how many episodes actually differ."""
    from tasks.trial_summary import METRIC_KEYS

    ref = _metrics_by_episode(runs[0])
    headers = ["run", "vs", "episodes"] + list(PHASES)
    rows = []
    for run in runs[1:]:
        mine = _metrics_by_episode(run)
        cells = []
        for key in METRIC_KEYS:        # the order of PHASES
            wins, losses, shared = _discordant(ref, mine, key)
            cells.append(f"+{wins} -{losses} ({p_text(sign_test_p(wins, losses))})")
        rows.append([run.name, runs[0].name, shared] + cells)
    return headers, rows


def _sign_test_p_float(wins: int, losses: int) -> float:
    """:func:`sign_test_p` in floating point (binomial CDF), for counts too large for exact sums."""
    from scipy.stats import binom

    n = wins + losses
    return 1.0 if n == 0 else min(1.0, 2.0 * float(binom.cdf(min(wins, losses), n, 0.5)))


def detectable_gap(discordant: int, alpha: float = 0.05) -> int | None:
    """The smallest net count ``|wins - losses|`` that the exact sign test calls significant
    (p < ``alpha``) when ``discordant`` episodes differ between two runs; None when not even
    a clean sweep would be (fewer than 6 discordant episodes at alpha = 0.05)."""
    for net in range(discordant % 2, discordant + 1, 2):
        wins = (discordant + net) // 2
        if sign_test_p(wins, discordant - wins) < alpha:
            return net
    return None


def episodes_needed(wins: int, losses: int, shared: int, alpha: float = 0.05, limit: int = 100_000) -> int | None:
    """About how many episodes the two runs would need for the gap seen on ``shared`` episodes to
    reach p < ``alpha``, if their wins and losses kept coming at the rates seen. None: no gap
    (wins == losses) or more than ``limit``. The answer a researcher needs before reading an
    ordering into a 3-point difference: the paper's 7-point gaps were measured on 1000 episodes."""
    if wins == losses or shared <= 0:
        return None

    def significant(n: int) -> bool:
        return _sign_test_p_float(round(wins * n / shared), round(losses * n / shared)) < alpha

    if not significant(limit):
        return None
    lo, hi = 1, limit                 # rounding makes p only nearly monotone in n: the first n found
    while lo < hi:
        mid = (lo + hi) // 2
        if significant(mid):
            hi = mid
        else:
            lo = mid + 1
    return lo


POWER_TITLE = ("How many episodes the paired comparisons need (exact sign test, p < 0.05): the gap seen "
               "(percentage points), the smallest gap these episodes could show, and about how many "
               "episodes the gap seen would need at the rates seen")


def power_rows(runs: list[Run], keys: tuple[str, ...] = ("find_obj", "success")) -> tuple[list[str], list[list]]:
    """For each run against the first, per headline phase: the gap in points, the detectable gap
    with this many episodes that differ (:func:`detectable_gap`), and :func:`episodes_needed`."""
    from tasks.trial_summary import METRIC_NAMES

    ref = _metrics_by_episode(runs[0])
    headers = ["run", "vs", "episodes"]
    for key in keys:
        name = METRIC_NAMES[key]
        headers += [f"{name} gap", f"{name} detectable", f"{name} episodes needed"]
    rows = []
    for run in runs[1:]:
        mine = _metrics_by_episode(run)
        row = [run.name, runs[0].name, len(set(ref) & set(mine))]     # shared episodes, whatever the phase
        for key in keys:
            wins, losses, shared = _discordant(ref, mine, key)
            if not shared:
                row += ["n/a"] * 3
                continue
            pts = 100.0 / shared
            gap = detectable_gap(wins + losses)
            need = episodes_needed(wins, losses, shared)
            row += [f"{(wins - losses) * pts:+.1f}",
                    "none" if gap is None else f"{gap * pts:.1f}",
                    "no gap" if wins == losses else (f"> {100_000:,}" if need is None else f"{need:,}")]
        rows.append(row)
    return headers, rows
