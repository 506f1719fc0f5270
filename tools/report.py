"""Compare trial runs: the paper-style table (rows = runs; FindObj, Pick, FindRec, Place, SR in
percent ± standard error) as text and Markdown, what the search policy decided and where its
simulated time went (the "Decisions" and "Simulated time per phase" tables, see
``tasks.decisions``), how each run would score with a shorter time budget, PNG plots (subtask
success as the paper's stacked bars, failure modes, memory over episode time, phases reached by
each budget), one HTML page with all of it, and one page per episode (its top-down
picture, hand-camera frames and numbers; ``tools.episode_pages``) with a failure gallery.

    python -m tools report runs/helios runs/trusting --out runs/report

Numbers are recomputed from each run's ``episodes.jsonl`` (so a run that is still going or was
interrupted is reported as it stands; its row says how many episodes it has).
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import functools
import html
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tools.cli import check_text_path, shown_path

PHASES = ("FindObj", "Pick", "FindRec", "Place", "SR")
PHASE_COLORS = ("#c6dbef", "#9ecae1", "#6baed6", "#3182bd", "#08519c")
MEMORY_SERIES = (("rss_mb", "resident memory (RSS)"), ("map_mb", "agent map"),
                 ("gpu_allocated_mb", "GPU allocated"), ("gpu_reserved_mb", "GPU reserved"))
FIGURES = ("subtasks.png", "failures.png", "memory.png", "budgets.png")


@dataclass
class Run:
    name: str
    path: Path
    records: list[dict]
    summary: dict
    config: dict
    legacy: int = 0             # records without a configuration fingerprint (written before they existed)
    cpu: tuple[str, ...] = ()   # the CPU code paths its invocations ran on (tasks.trials.run_cpu_paths)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("runs", nargs="+", metavar="RUN", help="run folders (from `python -m tools trials --out`)")
    parser.add_argument("--out", default="runs/report", help="folder for the table, PNGs and index.html")
    parser.add_argument("--names", default="", help="comma-separated row names (default: the folder names)")
    parser.add_argument("--common", action="store_true",
                        help="compare on the episodes every run has finished (runs of different lengths)")
    parser.add_argument("--no-episode-pages", action="store_true",
                        help="skip the per-episode pages and the failure gallery (pictures of every episode)")
    parser.add_argument("--pick-limits", default="", metavar="N[,N...]",
                        help="also score the runs as the paper's 'N picks' rows (e.g. 1,5): an episode with more "
                             "than N grasp attempts fails every phase; a table and paired tests per limit")
    parser.add_argument("--budgets", default="", metavar="S[,S...]",
                        help="simulated-second budgets for the 'search by time budget' table (default: fifths of "
                             "the runs' cap, runner.max_sim_time): each run scored as if stopped there")


MAX_LISTED_DAMAGE = 10     # damaged lines named one by one (FILE:LINE) per run folder; the rest are counted
MAX_NAME_CHARS = 100       # a --names name (row labels, file and folder names of the episode pages)


def check_names(names: list[str]) -> None:
    """CliError for a --names name that is empty, too long or holds control characters (names are
    row labels and become folder names of the episode pages)."""
    from helios.schema import short_repr
    from tools.cli import CliError

    for n in names:
        if not n:
            raise CliError("--names has an empty name")
        if len(n) > MAX_NAME_CHARS:
            raise CliError(f"--names: the name {short_repr(n)} has {len(n)} characters, at most {MAX_NAME_CHARS}")
        if not n.isprintable():
            raise CliError(f"--names: the name {short_repr(n)} holds a control character")
        check_text_path(n, "--names: the name")


def invocations_problem(run_path: Path) -> str | None:
    """What is wrong with a run folder's invocations.jsonl (a directory in its place, damaged
    lines), or None. It only says which code paths the episodes ran on: the report and diff read
    the records without it, but say so (a resume refuses a directory; it appends after damaged
    lines, which ``tasks.trials.read_invocations`` names and the rest skips)."""
    from tasks.trials import read_invocations

    path = run_path / "invocations.jsonl"
    if path.is_dir():
        return (f"{path} is a directory, where the log of the run's invocations belongs: the CPU code paths of its "
                f"episodes are unknown (a resume refuses the folder until it is moved away)")
    try:
        bad = read_invocations(run_path)[1]
    except OSError as exc:
        return f"{path} cannot be read ({exc.strerror or exc}): the CPU code paths of its episodes are unknown"
    if bad:
        shown = ", ".join(f"{path}:{n}" for n in bad[:5]) + (f" and {len(bad) - 5} more" if len(bad) > 5 else "")
        return (f"{shown}: damaged line{'s' if len(bad) > 1 else ''} of the run's invocation log (torn by a kill, "
                f"or edited), skipped: the CPU code paths shown come from the other lines")
    return None


def load_run(path: str | Path, name: str | None = None, warnings: list[str] | None = None) -> Run:
    """A run folder's finished episodes and summary; CliError when it is missing, unreadable or
    empty. Damaged lines of episodes.jsonl are skipped, each named as FILE:LINE in ``warnings``
    (also records of one episode that disagree, and records of episodes that are not the run's:
    ``tasks.trials.scan_results``); so are an unreadable config.yaml, records that disagree with it
    and a damaged invocations.jsonl."""
    from helios.schema import read_text, short_repr, yaml_load_text
    from tasks.trials import (FINGERPRINT_FIELD, RunFolderError, config_fingerprint, run_cpu_paths, run_episode_ids,
                              scan_results, summarize)
    from tools.cli import CliError

    warnings = warnings if warnings is not None else []
    p = Path(path)
    check_text_path(p, "run folder")
    if not p.exists():
        raise CliError(f"run folder {short_repr(str(p))} does not exist")
    if not p.is_dir():
        raise CliError(f"run folder {short_repr(str(p))} is a file, not a run folder")
    results = p / "episodes.jsonl"
    config: dict = {}
    config_warnings: list[str] = []
    cfg_path = p / "config.yaml"
    if cfg_path.exists():
        try:
            loaded = yaml_load_text(read_text(cfg_path, str(cfg_path), CliError), str(cfg_path), CliError)
            if loaded is not None and not isinstance(loaded, dict):
                raise CliError(f"{cfg_path} holds a {type(loaded).__name__}, not a trial config")
            config = loaded or {}
        except CliError as exc:
            config_warnings.append(f"{exc}; the run's configuration is shown as unknown")
    selected = run_episode_ids(config) if config else None      # the episodes its records may be of
    try:
        scan = scan_results(results, *(selected or (None,)))
    except RunFolderError as exc:
        raise CliError(str(exc)) from None
    for d in scan.damaged[:MAX_LISTED_DAMAGE]:
        warnings.append(f"{results}:{d.lineno}: {d.reason}; skipped this line")
    if len(scan.damaged) > MAX_LISTED_DAMAGE:
        warnings.append(f"{results}: {len(scan.damaged) - MAX_LISTED_DAMAGE} more damaged line(s) skipped")
    if scan.repeated_runs:
        shown = ", ".join(f"{eid} ({n} runs)" for eid, n in list(scan.repeated_runs.items())[:5])
        more = f" and {len(scan.repeated_runs) - 5} more" if len(scan.repeated_runs) > 5 else ""
        warnings.append(f"{results}: robot runs repeated under one episode id, the first of each is in the tables: "
                        f"{shown}{more} (on a robot, --trial-id gives each run its own id)")
    records = list(scan.records.values())
    if not records:
        what = "only damaged lines" if scan.damaged else "missing or empty"
        raise CliError(f"run folder {str(p)!r} has no finished episodes (episodes.jsonl {what}); "
                       f"run `python -m tools trials --out {p}` (or `tools spot`) first")
    records.sort(key=lambda r: r["episode_id"])
    warnings.extend(config_warnings)
    invocations = invocations_problem(p)
    if invocations:
        warnings.append(invocations)
    fps = scan.fingerprints() - {None}
    if len(fps) > 1:
        warnings.append(f"{results}: the records were made with {len(fps)} different configurations "
                        f"(fingerprints {', '.join(sorted(fps))}); they are reported together")
    elif fps and config:
        try:
            written = config_fingerprint(config)
        except (TypeError, ValueError):
            written = None
        if written not in fps:
            warnings.append(f"{cfg_path} does not describe the records in {results} (they were made with "
                            f"configuration {next(iter(fps))}, config.yaml says {written}): it was edited or "
                            f"replaced; the table shows the records")
    cpu = tuple(run_cpu_paths(p))
    if len(cpu) > 1:
        warnings.append(f"{p}: its episodes ran on {len(cpu)} different CPU code paths ({' | '.join(cpu)}); "
                        f"they can differ in outcome (README, \"One CPU code path\")")
    return Run(name or p.resolve().name, p, records, summarize(records), config, legacy=scan.legacy, cpu=cpu)


# ------------------------------------------------------------------------------------------------
# Tables
# ------------------------------------------------------------------------------------------------
def metrics_rows(runs: list[Run]) -> tuple[list[str], list[list]]:
    from tasks.trials import metrics_table_rows

    headers = ["run"] + list(PHASES)
    return headers, [metrics_table_rows(r.name, r.summary) for r in runs]


def detail_rows(runs: list[Run]) -> tuple[list[str], list[list]]:
    headers = ["run", "agent", "episodes", "collisions/ep", "errors", "sim s/ep", "wall s/ep", "peak RSS MB",
               "map MB", "GPU alloc MB", "GPU reserved MB", "CPU code paths"]
    rows = []
    for r in runs:
        s, mem = r.summary, r.summary["memory"]

        def peak(key: str) -> str:
            return f"{mem[key]['max']:.1f}" if mem.get(key) else "-"

        rows.append([r.name, r.config.get("agent", r.records[0].get("agent", "?")), s["episodes"],
                     f"{s['collisions_per_episode']:.2f}", s["errors"], f"{s['sim_seconds_per_episode']:.0f}",
                     f"{s['wall_seconds_per_episode']:.1f}", peak("peak_rss_mb"), peak("map_mb_peak"),
                     peak("gpu_allocated_mb_peak"), peak("gpu_reserved_mb_peak"),
                     " | ".join(r.cpu) if r.cpu else "-"])
    return headers, rows


def failure_rows(runs: list[Run]) -> tuple[list[str], list[list]]:
    from tasks.metrics import FAILURE_REASONS

    used = [k for k in FAILURE_REASONS if any(r.summary["failure_reasons"][k] for r in runs)]
    headers = ["run", "success"] + used
    rows = [[r.name, r.summary["SR"]["count"]] + [r.summary["failure_reasons"][k] for k in used] for r in runs]
    return headers, rows


def sign_test_p(wins: int, losses: int) -> float:
    """Exact two-sided sign test (McNemar's exact test) on the discordant episodes: the chance of a
    split at least this uneven if either run were equally likely to win each one."""
    n = wins + losses
    if n == 0:
        return 1.0
    k = min(wins, losses)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2 ** n
    return min(1.0, 2 * tail)


def _p_text(p: float) -> str:
    """Two decimals, except below 0.01 (where "p=0.00" would read as impossible)."""
    return "p<0.01" if p < 0.005 else f"p={p:.2f}"


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
    from tasks.trials import METRIC_KEYS

    ref = _metrics_by_episode(runs[0])
    headers = ["run", "vs", "episodes"] + list(PHASES)
    rows = []
    for run in runs[1:]:
        mine = _metrics_by_episode(run)
        cells = []
        for key in METRIC_KEYS:        # the order of PHASES
            wins, losses, shared = _discordant(ref, mine, key)
            cells.append(f"+{wins} -{losses} ({_p_text(sign_test_p(wins, losses))})")
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
    from tasks.trials import METRIC_NAMES

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


SPEED_TITLE = ("How fast each run searches: simulated seconds from the start to each phase (median over the "
               "episodes that reached it, how many in brackets), and against the first run, the episodes this run "
               "reached the phase first (+) or the first run did (-; reaching it at all counts as first), exact "
               "sign test; n/a: records made before phase times were kept")
SPEED_PHASES = (("find_obj_time", "FindObj"), ("pick_time", "Pick"), ("find_rec_time", "FindRec"))


def _phase_times(run: Run, key: str) -> dict[str, float]:
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
            times = _phase_times(run, key)
            reached = [t for t in times.values() if math.isfinite(t)]
            row.append("n/a" if not times else (f"{np.median(reached):.0f} ({len(reached)})" if reached else "- (0)"))
        for key in ("find_obj_time", "pick_time"):
            if i == 0:
                row.append("-")
                continue
            ref, mine = _phase_times(runs[0], key), _phase_times(run, key)
            both = set(ref) & set(mine)
            if not both:
                row.append("n/a")
                continue
            wins = sum(mine[e] < ref[e] for e in both)        # never reached (inf) on both sides: a tie
            losses = sum(ref[e] < mine[e] for e in both)
            row.append(f"+{wins} -{losses} ({_p_text(sign_test_p(wins, losses))})")
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


def parse_budgets(text: str) -> tuple[float, ...]:
    """``--budgets`` "120,300" -> (120.0, 300.0); CliError for anything but distinct positive seconds."""
    from tools.cli import CliError

    def one(part: str) -> float:
        try:
            t = float(part)
        except ValueError:
            raise CliError(f"--budgets: {part!r} is not a number of seconds (expected e.g. 120,300,600)") from None
        if not math.isfinite(t) or t <= 0:
            raise CliError(f"--budgets: {part} is not a positive number of simulated seconds")
        return t

    budgets = _parse_list(text, "--budgets", one)
    if len(budgets) > MAX_BUDGETS:
        raise CliError(f"--budgets: {len(budgets)} budgets given, at most {MAX_BUDGETS}")
    return budgets


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
            times = _phase_times(run, key)
            if not times:
                rows.append([run.name, name] + ["n/a"] * len(budgets))
                continue
            ref = _phase_times(runs[0], key) if i else {}
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
                        cell += f" +{wins} -{losses} ({_p_text(sign_test_p(wins, losses))})"
                    else:
                        cell += " (n/a)"
                row.append(cell)
            rows.append(row)
    return headers, rows


def budget_summary(run: Run, budgets: tuple[float, ...]) -> dict:
    """{budget s: {phase: percent reached within it}} for report.json (phases without times left out)."""
    phase_times = {name: times for key, name in BUDGET_PHASES if (times := _phase_times(run, key))}
    return {f"{t:g}": {name: 100.0 * sum(reached_within(times, t).values()) / len(times)
                       for name, times in phase_times.items()} for t in budgets}


def budget_curve(times: dict[str, float], grid: np.ndarray) -> np.ndarray:
    """Percent of the episodes in ``times`` that reached the phase strictly before each ``grid`` time."""
    t = np.sort(np.fromiter(times.values(), dtype=float, count=len(times)))
    return 100.0 * np.searchsorted(t, grid, side="left") / max(len(t), 1)


DECISIONS_TITLE = ("Decisions: totals over the episodes shown (per-episode mean in brackets); "
                   "n/a: the agent or the run has no decision counts")
TIME_TITLE = ("Simulated time per phase: % of the run's simulated time (mean s per episode in brackets); "
              "n/a: no phase times")


def decision_rows(runs: list[Run]) -> tuple[list[str], list[list]]:
    """Per run, what the search policy decided (``tasks.decisions`` says what each number means):
    global decisions with open candidates and their choice before / after F0 calibration, extra
    views the Psi' rule asked for, local searches with their planned gaze points and the visits."""
    from tasks.decisions import COUNTED_LATER, summarize_decisions

    keys = ("global_with_candidates", "chose_candidate_before_f0", "chose_frontier_before_f0",
            "chose_candidate_after_f0", "chose_frontier_after_f0", "extra_views_object", "extra_views_goal")
    headers = ["run", "episodes", "with candidates", "cand. before F0", "frontier before F0", "cand. after F0",
               "frontier after F0", "extra views obj", "extra views goal", "local searches",
               "gaze pts/search mean", "median", "max", "gaze pt visits", "with a view", "frontiers given up"]
    rows = []
    for r in runs:
        d = summarize_decisions(r.records)
        if d is None:
            rows.append([r.name, f"0/{len(r.records)}"] + ["n/a"] * (len(headers) - 2))
            continue

        def cell(total: float, mean: float) -> str:
            return f"{total} ({mean:.1f})"

        tot, per = d["totals"], d["per_episode"]
        planned = d["gaze_points_planned"]
        rows.append([r.name, f"{d['episodes']}/{d['of']}"] + [cell(tot[k], per[k]) for k in keys]
                    + [cell(d["local_searches"], d["local_searches_per_episode"])]
                    + ([f"{planned['mean']:.1f}", f"{planned['median']:g}", str(planned["max"])] if planned
                       else ["-", "-", "-"])
                    + [cell(tot["gaze_point_visits"], per["gaze_point_visits"])]
                    + ["-" if tot[k] is None else cell(tot[k], per[k]) for k in COUNTED_LATER])
    return headers, rows


def _activity_columns(per_run) -> list[str]:
    """Table columns for phases: ``ACTIVITIES`` in their order, then any other a run has, in the
    order first seen (``per_run``: each run's activity names)."""
    from tasks.decisions import ACTIVITIES

    columns = list(ACTIVITIES)
    for names in per_run:
        columns += [a for a in names if a not in columns]
    return columns


def activity_rows(runs: list[Run]) -> tuple[list[str], list[list]]:
    """Per run, the share of simulated time spent in each phase (time-weighted over the episodes)
    and the mean seconds per episode (``tasks.decisions.summarize_activity_time``)."""
    from tasks.decisions import summarize_activity_time

    summaries = [summarize_activity_time(r.records) for r in runs]
    activities = _activity_columns(s["activities"] if s else () for s in summaries)
    headers = ["run", "episodes", "sim s/ep"] + activities
    rows = []
    for r, s in zip(runs, summaries):
        if s is None:
            rows.append([r.name, f"0/{len(r.records)}"] + ["n/a"] * (len(headers) - 2))
            continue
        per = s["seconds_per_episode"]
        rows.append([r.name, f"{s['episodes']}/{s['of']}", f"{sum(per.values()):.0f}"]
                    + [f"{s['share_percent'].get(a, 0.0):.1f} ({per.get(a, 0.0):.0f} s)" for a in activities])
    return headers, rows


TIMEOUTS_TITLE = ("Timeouts: where the time ran out (stage = the first phase never reached; then the mean "
                  "simulated s per phase and gaze point visits in those episodes); n/a: no phase times or decisions")


def timeout_rows(runs: list[Run]) -> tuple[list[str], list[list]]:
    """Per run, the episodes that ran out of time, by the stage they ran out in, and what they
    spent that time on (``tasks.decisions.summarize_timeouts``): a high timeout share with most
    of them before FindObj and much local search points at search cost, one with most of them
    found-not-picked at the Psi' rule."""
    from tasks.decisions import summarize_timeouts

    summaries = [summarize_timeouts(r.records) for r in runs]
    activities = _activity_columns(((s or {}).get("activity_seconds_per_episode") or ()) for s in summaries)
    headers = (["run", "timeouts", "before FindObj", "found, not picked", "picked, goal not found",
                "at goal, not placed"] + [f"{a} s" for a in activities] + ["gaze pt visits", "extra views"])
    rows = []
    for r, s in zip(runs, summaries):
        if s is None:
            rows.append([r.name, "0 scored"] + ["-"] * (len(headers) - 2))
            continue
        row = [r.name, f"{s['timeouts']}/{s['scored']} ({s['percent']:.1f} %)"] + [str(v) for v in s["stages"].values()]
        per = s["activity_seconds_per_episode"]
        if not s["timeouts"]:
            row += ["-"] * (len(activities) + 2)
        else:
            row += [f"{per.get(a, 0.0):.0f}" if per is not None else "n/a" for a in activities]
            row += [f"{s[k]:.1f}" if s[k] is not None else "n/a"
                    for k in ("gaze_point_visits_per_episode", "extra_views_per_episode")]
        rows.append(row)
    return headers, rows


START_REC_TITLE = ("The start receptacle that holds the object, checked against the true scene: episodes in "
                   "which the search offered it as a candidate, chose it, or passed it over until the end "
                   "(decisions that chose something else while it was open, mean per offered episode); "
                   "then the episodes that never reached FindObj by why, never offered split into never in "
                   "view / in view of the agent's camera; n/a: no check in the records")


def start_receptacle_rows(runs: list[Run]) -> tuple[list[str], list[list]] | None:
    """Per run, how the global search treated the receptacle the object really rests on
    (``tasks.decisions.summarize_start_receptacle``): a policy that loses on FindObj with its
    misses mostly "never offered" and never in view explores too little or in the wrong places,
    in view but never offered does not recognise the receptacle, and with most "offered, not
    searched" its objective passes over the right candidate. None when no run
    has the check (the table is left out)."""
    from tasks.decisions import summarize_start_receptacle

    summaries = [summarize_start_receptacle(r.records) for r in runs]
    if all(s is None for s in summaries):
        return None
    headers = ["run", "episodes", "offered", "searched", "offered, never searched", "passed over",
               "no FindObj", "never offered (not in view / in view)", "offered, not searched",
               "searched, not found (no view / viewed)"]
    rows = []
    for r, s in zip(runs, summaries):
        if s is None:
            rows.append([r.name, f"0/{len(r.records)}"] + ["n/a"] * (len(headers) - 2))
            continue
        n = s["episodes"]
        miss = s["not_found"]
        passed = s["passed_over_per_offered"]
        rows.append([r.name, f"{n}/{s['of']}"]
                    + [f"{s[k]} ({100.0 * s[k] / n:.0f} %)" for k in ("offered", "searched", "never_searched")]
                    + [f"{passed:.1f}" if passed is not None else "-", str(miss["episodes"])]
                    + [str(miss["never_offered"]) + (f" ({miss['never_in_view']} / {miss['in_view']})"
                                                     if miss["never_in_view"] is not None else "")]
                    + [str(miss["offered_not_searched"])]
                    + [str(miss["searched"]) + (f" ({miss['searched_no_view']} / {miss['searched_viewed']})"
                                                if miss["searched_no_view"] is not None else "")])
    return headers, rows


# ------------------------------------------------------------------------------------------------
# Plots
# ------------------------------------------------------------------------------------------------
@contextlib.contextmanager
def _quiet_plots():
    """Drawing never writes to stderr: matplotlib's warnings (a tight layout that does not fit long
    labels, a glyph missing from the font) and its log messages are left out; what matters about
    the figures is in the tables."""
    import logging
    import warnings

    logger = logging.getLogger("matplotlib")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        logger.setLevel(level)


def _pyplot():
    try:
        import matplotlib
    except ImportError:
        return None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_subtasks(runs: list[Run], path: Path, plt) -> None:
    """The paper's hardware-results style: per run one column of overlaid bars, FindObj (tallest,
    lightest) down to SR (lowest, darkest), each labelled with its percentage ± SE."""
    fig, ax = plt.subplots(figsize=(max(5.0, 2.2 * len(runs) + 2.0), 4.2))
    x = np.arange(len(runs))
    for phase, color in zip(PHASES, PHASE_COLORS):
        vals = [r.summary[phase]["percent"] for r in runs]
        ax.bar(x, vals, width=0.6, color=color, edgecolor="white", linewidth=0.6, label=phase)
    for i, r in enumerate(runs):
        groups: list[tuple[float, list[str], float]] = []       # equal levels share one label
        for phase in PHASES:
            v, se = r.summary[phase]["percent"], r.summary[phase]["se"]
            if groups and abs(groups[-1][0] - v) < 1e-9:
                groups[-1][1].append(phase)
            else:
                groups.append((v, [phase], se))
        y_prev = -10.0
        for v, names, se in sorted(groups, key=lambda g: g[0]):
            y = max(v, y_prev + 4.5)                            # keep close labels apart
            ax.text(i + 0.32, y, f"{'='.join(names)} {v:.0f}±{se:.0f}", va="center", ha="left", fontsize=7)
            y_prev = y
    ax.set_xticks(x, [f"{r.name}\n(n={r.summary['episodes']})" for r in runs], fontsize=8)
    ax.set_xlim(-0.6, len(runs) - 0.4 + 0.9)
    ax.set_ylim(0, 105)
    ax.set_ylabel("episodes (%)")
    # a figure title from the left edge: an axes title is centred on the (narrow) axes and its
    # ends were cut off at the figure's edges with one or two runs
    fig.suptitle("Subtask success\n(each bar: episodes reaching that phase)", fontsize=10, x=0.02, ha="left")
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8, frameon=False)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_failures(runs: list[Run], path: Path, plt) -> None:
    """How episodes ended, per run: success and each failure reason, as shares of the scored episodes."""
    from tasks.metrics import FAILURE_REASONS

    cmap = plt.get_cmap("tab10")
    fig, ax = plt.subplots(figsize=(8.0, max(2.2, 0.55 * len(runs) + 1.4)))
    y = np.arange(len(runs))
    left = np.zeros(len(runs))
    parts = [("success", "#2ca02c", [r.summary["SR"]["count"] for r in runs])]
    for i, k in enumerate(FAILURE_REASONS):
        parts.append((k, cmap((i + 3) % 10), [r.summary["failure_reasons"][k] for r in runs]))
    crashed = [r.summary["episodes"] - r.summary["scored"] for r in runs]
    if any(crashed):
        parts.append(("unscored", "#7f7f7f", crashed))
    for label, color, counts in parts:
        share = np.array([100.0 * c / max(1, r.summary["episodes"]) for c, r in zip(counts, runs)])
        if not share.any():
            continue
        ax.barh(y, share, left=left, color=color, label=label, edgecolor="white", linewidth=0.6)
        for yi, (l0, w) in enumerate(zip(left, share)):
            if w >= 6:
                ax.text(l0 + w / 2, yi, f"{w:.0f}", ha="center", va="center", fontsize=7, color="white")
        left += share
    ax.set_yticks(y, [r.name for r in runs], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlim(0, 100)
    ax.set_xlabel("episodes (%)")
    ax.set_title("How episodes ended")
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8, frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def memory_curve(records: list[dict], key: str, bins: int = 30) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Mean and max over episodes of ``key`` against episode time (each episode holds its last sample
    until it ends; episodes that have ended drop out)."""
    series = [r["memory"]["series"] for r in records
              if r.get("memory") and key in (r["memory"].get("series") or {})]
    series = [(np.asarray(s["t"], dtype=float), np.array([np.nan if v is None else v for v in s[key]], dtype=float))
              for s in series if s.get("t")]
    if not series:
        return None
    t_end = max(t[-1] for t, _ in series)
    grid = np.linspace(0.0, max(t_end, 1e-6), bins)
    vals = np.full((len(series), bins), np.nan)
    for i, (t, v) in enumerate(series):
        idx = np.searchsorted(t, grid, side="right") - 1
        ok = (grid <= t[-1])
        vals[i, ok] = v[np.clip(idx[ok], 0, len(v) - 1)]
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return grid, np.nanmean(vals, axis=0), np.nanmax(vals, axis=0)


def plot_memory(runs: list[Run], path: Path, plt) -> None:
    """Memory against episode time (simulated s), averaged over each run's episodes (solid) with the
    maximum (dashed): RSS, the agent's map, and GPU allocated/reserved where recorded."""
    panels = [(k, label) for k, label in MEMORY_SERIES if any(memory_curve(r.records, k) for r in runs)]
    if not panels:
        panels = [MEMORY_SERIES[0]]
    cols = min(2, len(panels))
    nrows = (len(panels) + cols - 1) // cols
    fig, axes = plt.subplots(nrows, cols, figsize=(5.0 * cols + 2.2, 3.2 * nrows + 0.4), squeeze=False)
    cmap = plt.get_cmap("tab10")
    legend: dict[str, object] = {}
    for ax, (key, label) in zip(axes.flat, panels):
        for i, r in enumerate(runs):
            curve = memory_curve(r.records, key)
            if curve is None:
                continue
            t, mean, mx = curve
            legend[f"{r.name} mean"], = ax.plot(t, mean, color=cmap(i % 10))
            legend[f"{r.name} max"], = ax.plot(t, mx, color=cmap(i % 10), linestyle="--", linewidth=0.8)
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("episode time (simulated s)", fontsize=8)
        ax.set_ylabel("MB", fontsize=8)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(panels):]:
        ax.set_visible(False)
    fig.legend(list(legend.values()), list(legend), fontsize=7, loc="upper right", frameon=False)
    fig.suptitle("Memory over episode time (mean over episodes; dashed: max)", fontsize=10, x=0.02, ha="left")
    fig.tight_layout(rect=(0, 0, 1.0 - 1.6 / (5.0 * cols + 2.2), 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_budgets(runs: list[Run], path: Path, plt, budgets: tuple[float, ...] = ()) -> None:
    """One panel per phase (FindObj, Pick, FindRec): the percent of each run's episodes that had
    reached it by each simulated second, up to the smallest cap; dotted lines at the table's budgets."""
    cap = min(run_time_cap(r) for r in runs)
    grid = np.linspace(0.0, cap, 601)
    fig, axes = plt.subplots(1, len(BUDGET_PHASES), figsize=(4.0 * len(BUDGET_PHASES) + 2.0, 3.6), squeeze=False)
    cmap = plt.get_cmap("tab10")
    handles: dict[str, object] = {}
    for ax, (key, name) in zip(axes.flat, BUDGET_PHASES):
        for i, r in enumerate(runs):
            times = _phase_times(r, key)
            if not times:
                continue
            handles[r.name], = ax.step(grid, budget_curve(times, grid), where="post", color=cmap(i % 10),
                                        linewidth=1.4)
        for t in budgets:
            ax.axvline(t, color="0.6", linestyle=":", linewidth=0.8)
        ax.set_xlim(0, cap)
        ax.set_ylim(0, 100)
        ax.set_title(f"{name} within the budget", fontsize=9)
        ax.set_xlabel("budget (simulated s)", fontsize=8)
        ax.set_ylabel("episodes (%)", fontsize=8)
        ax.grid(alpha=0.3)
    if handles:
        fig.legend(list(handles.values()), list(handles), fontsize=7, loc="upper right", frameon=False)
    else:
        axes.flat[0].text(0.5, 0.5, "no phase times in these records", transform=axes.flat[0].transAxes,
                          ha="center", va="center", fontsize=8)
    fig.suptitle("Search by time budget (episodes that reached each phase by then)", fontsize=10, x=0.02, ha="left")
    fig.tight_layout(rect=(0, 0, 1.0 - 1.8 / (4.0 * len(BUDGET_PHASES) + 2.0), 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ------------------------------------------------------------------------------------------------
# Output
# ------------------------------------------------------------------------------------------------
def _html_table(headers, rows) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def write_html(path: Path, runs: list[Run], tables: list[tuple[str, list, list]], figures: list[Path],
               episodes: list[tuple[Run, list]] = ()) -> None:
    """index.html: the tables, the plots (embedded), and per run a failure gallery and the
    per-episode table, whose rows and thumbnails link to the episode pages (relative links)."""
    from tools.episode_pages import episode_table_html, failure_gallery_html

    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>HELIOS trial report</title><style>",
             "body{font-family:sans-serif;margin:2em;max-width:1100px}table{border-collapse:collapse;margin:1em 0}"
             "td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}td:first-child,th:first-child{text-align:left}"
             "img{max-width:100%;margin:1em 0}code{background:#f4f4f4}"
             "table.episodes td,table.episodes th{text-align:left}figure{display:inline-block;margin:4px;vertical-align:top}"
             "figure img{margin:0;border:1px solid #ccc}figcaption{font-size:85%}",
             "</style></head><body><h1>HELIOS trial report</h1>"]
    for r in runs:
        cfg = r.config
        parts.append(f"<p><b>{html.escape(r.name)}</b>: <code>{html.escape(str(r.path))}</code>, agent "
                     f"{html.escape(str(cfg.get('agent', '?')))}, {html.escape(str(cfg.get('episodes_file') or 'split ' + str(cfg.get('split', '?'))))}, "
                     f"seed {html.escape(str(cfg.get('seed', '?')))}, commit {html.escape(str(cfg.get('git_commit', '?'))[:10])}</p>")
    for title, headers, rows in tables:
        parts.append(f"<h2>{html.escape(title)}</h2>" + _html_table(headers, rows))
    for fig in figures:
        data = base64.b64encode(fig.read_bytes()).decode()
        parts.append(f"<h2>{html.escape(fig.stem)}</h2><img alt='{html.escape(fig.stem)}' src='data:image/png;base64,{data}'>")
    for run, pages in episodes:
        parts.append(f"<h2 id='gallery-{html.escape(run.name)}'>Failure gallery: {html.escape(run.name)}</h2>"
                     + failure_gallery_html(pages))
    for run, pages in episodes:
        parts.append(f"<h2 id='episodes-{html.escape(run.name)}'>Episodes: {html.escape(run.name)}</h2>"
                     + episode_table_html(run, pages))
    parts.append("</body></html>")
    path.write_text("\n".join(parts))


def restrict_to_common(runs: list[Run]) -> int:
    """Keep only the episodes every run has finished (a fair comparison of runs of different
    lengths or of unfinished runs); returns how many that is."""
    from tasks.trials import summarize
    from tools.cli import CliError

    common = set.intersection(*({r["episode_id"] for r in run.records} for run in runs))
    if not common:
        raise CliError("--common: the runs share no finished episode")
    for run in runs:
        run.records = [r for r in run.records if r["episode_id"] in common]
        run.summary = summarize(run.records)
    return len(common)


def _parse_list(text: str, option: str, one) -> tuple:
    """A comma-separated option value -> its sorted values, each read by ``one(part)`` (which raises
    CliError for a bad one); empty text -> (); CliError for a value given twice."""
    from tools.cli import CliError

    if not text.strip():
        return ()
    values: list = []
    for part in text.split(","):
        part = part.strip()
        value = one(part)
        if value in values:
            raise CliError(f"{option}: {part} is given twice")
        values.append(value)
    return tuple(sorted(values))


def parse_pick_limits(text: str) -> tuple[int, ...]:
    """``--pick-limits`` "1,5" -> (1, 5); CliError for anything but distinct integers in range."""
    from tasks.trials import MAX_PICK_LIMIT
    from tools.cli import CliError

    def one(part: str) -> int:
        try:
            n = int(part)
        except ValueError:
            raise CliError(f"--pick-limits: {part!r} is not a whole number (expected e.g. 1,5)") from None
        if not 1 <= n <= MAX_PICK_LIMIT:
            raise CliError(f"--pick-limits: {n} is outside [1, {MAX_PICK_LIMIT}] grasp attempts")
        return n

    return _parse_list(text, "--pick-limits", one)


def pick_limited_runs(runs: list[Run], limit: int) -> list[Run]:
    """Copies of ``runs`` scored with at most ``limit`` grasp attempts per episode
    (:func:`tasks.trials.limit_pick_attempts`, the paper's "N picks" rows)."""
    import dataclasses

    from tasks.trials import limit_pick_attempts, summarize

    out = []
    for r in runs:
        records = limit_pick_attempts(r.records, limit)
        out.append(dataclasses.replace(r, records=records, summary=summarize(records)))
    return out


def pick_limit_tables(runs: list[Run], limits: tuple[int, ...]) -> list[tuple[str, list, list]]:
    """Per limit: the percent table and (several runs) the paired sign tests against the first run."""
    from tasks.trials import exceeds_pick_limit

    tables = []
    for n in limits:
        limited = pick_limited_runs(runs, n)
        over = ", ".join(f"{r.name} {sum(exceeds_pick_limit(x, n) for x in r.records)}" for r in runs)
        noun = "attempt" if n == 1 else "attempts"
        tables.append((f"{n} pick{'s' if n > 1 else ''} (the paper's protocol: an episode with more than {n} grasp "
                       f"{noun} scores 0 in every phase; such episodes: {over}): percent ± standard error",
                       *metrics_rows(limited)))
        if len(runs) > 1:
            p_headers, p_rows = paired_rows(limited)
            tables.append((f"{n} pick{'s' if n > 1 else ''}, paired with {runs[0].name}: episodes only this run "
                           f"passed (+) / only {runs[0].name} passed (-), exact sign test", p_headers, p_rows))
    return tables


def _paired_table(runs: list[Run], qualifier: str = "") -> tuple[str, list, list]:
    return (f"Paired with {runs[0].name}{qualifier}: episodes only this run passed (+) / only "
            f"{runs[0].name} passed (-), exact sign test", *paired_rows(runs))


def make_report(run_paths: list[str | Path], out: str | Path, names: list[str] | None = None,
                common: bool = False, episode_pages: bool = True, pick_limits: tuple[int, ...] = (),
                budgets: tuple[float, ...] = ()) -> dict:
    """Load the runs, write table.txt, table.md, the PNGs, index.html and (``episode_pages``) one
    page per episode under ``out/episodes/`` (``tools.episode_pages``); return what was written
    (``text``, ``markdown``, ``figures``, ``html``, ``warnings``, ``pages``: run name -> its
    ``EpisodePage`` list). ``common``: compare on the episodes all runs have finished.
    ``pick_limits``: also the paper's "N picks" tables (:func:`pick_limit_tables`). ``budgets``:
    the simulated seconds of the time-budget table (:func:`budget_rows`; default fifths of the cap)."""
    from tasks.episode_trace import trace_path
    from tasks.trials import FOLDER_FILES, MAX_PICK_LIMIT, is_pick_limit
    from tools.cli import CliError, check_output_dir, check_output_file

    RUN_FOLDER_PARTS = {*FOLDER_FILES, "episodes", "recordings", "config.yaml.damaged"}
    from tools.tables import format_markdown, format_table

    pick_limits = tuple(pick_limits)
    if not all(map(is_pick_limit, pick_limits)) or len(set(pick_limits)) != len(pick_limits):
        raise CliError(f"pick limits must be distinct integers in [1, {MAX_PICK_LIMIT}], got {pick_limits}")
    if names and len(names) != len(run_paths):
        raise CliError(f"--names has {len(names)} name(s) for {len(run_paths)} run(s)")
    if names:
        check_names(names)
    out = Path(out)
    check_text_path(out, "--out")
    for p in run_paths:
        check_text_path(p, "run folder")
    for p in run_paths:
        if not Path(p).is_dir():
            continue
        run_dir, target = Path(p).resolve(), out.resolve()
        if target == run_dir:
            raise CliError(f"--out {str(out)!r} is a run folder given to report; write the report elsewhere "
                           f"(e.g. --out {Path(p).parent / (Path(p).name + '-report')})")
        # A report folder of its own inside the run folder (README: runs/smoke/report) is fine;
        # one that is, or lies in, a part of the run folder (its picture data, recordings, files) is not.
        if target.is_relative_to(run_dir) and target.relative_to(run_dir).parts[0] in RUN_FOLDER_PARTS:
            raise CliError(f"--out {str(out)!r} is inside run folder {str(p)!r}'s own "
                           f"{target.relative_to(run_dir).parts[0]!r}, which report reads; write the report "
                           f"elsewhere (e.g. --out {Path(p) / 'report'})")
    check_output_dir(out)
    for fname in ("table.txt", "table.md", "index.html", "report.json", *FIGURES):
        check_output_file(out / fname, "--out")
    check_output_dir(out / "episodes", "--out (its episodes folder)")
    load_warnings: list[str] = []
    runs = [load_run(p, names[i] if names else None, load_warnings) for i, p in enumerate(run_paths)]
    budgets = tuple(sorted(budgets)) or default_budgets(runs)
    if any(not (isinstance(t, (int, float)) and math.isfinite(t) and t > 0) for t in budgets):
        raise CliError(f"budgets must be positive numbers of simulated seconds, got {budgets}")
    check_budgets(runs, budgets)
    legacy = [r for r in runs if r.legacy]
    if legacy:
        load_warnings.append("record(s) without a configuration fingerprint (written before fingerprints existed) "
                             "in " + ", ".join(f"{r.path} ({r.legacy})" for r in legacy)
                             + ": their configuration is taken as unknown")
    if len({r.cpu for r in runs if len(r.cpu) == 1}) > 1:
        load_warnings.append("the runs compared ran on different CPU code paths (" + "; ".join(
            f"{r.name}: {r.cpu[0]}" for r in runs if len(r.cpu) == 1) + "): paired differences include the "
            "bit-level differences those paths make (README, \"One CPU code path\")")
    counts = sorted({len(r.records) for r in runs})
    note = []
    if common:
        n = restrict_to_common(runs)
        note.append(f"compared on the {n} episode(s) all runs finished")
    elif len(counts) > 1:
        note.append(f"the runs cover different numbers of episodes ({', '.join(map(str, counts))}); "
                    f"--common compares them on the episodes they share")
    seen: dict[str, int] = {}
    for r in runs:                                   # two folders with the same name: keep rows apart
        seen[r.name] = seen.get(r.name, 0) + 1
        if seen[r.name] > 1:
            r.name = f"{r.name} ({seen[r.name]})"
    out.mkdir(parents=True, exist_ok=True)
    headers, rows = metrics_rows(runs)
    d_headers, d_rows = detail_rows(runs)
    f_headers, f_rows = failure_rows(runs)
    unlimited = " (unlimited pick attempts)" if pick_limits else ""
    tables = [(f"Percent of episodes ± standard error{unlimited}", headers, rows)]
    if len(runs) > 1 and pick_limits:       # the unlimited comparison next to its table, then the limits
        tables.append(_paired_table(runs, unlimited))
    tables += pick_limit_tables(runs, pick_limits)
    tables += [("Runs", d_headers, d_rows), ("How episodes ended (counts)", f_headers, f_rows)]
    if len(runs) > 1:
        if not pick_limits:
            tables.append(_paired_table(runs, unlimited))
        tables.append((POWER_TITLE, *power_rows(runs)))
    tables.append((SPEED_TITLE, *speed_rows(runs)))
    tables.append((BUDGET_TITLE, *budget_rows(runs, budgets)))
    tables.append((DECISIONS_TITLE, *decision_rows(runs)))
    tables.append((TIME_TITLE, *activity_rows(runs)))
    tables.append((TIMEOUTS_TITLE, *timeout_rows(runs)))
    start_rec = start_receptacle_rows(runs)
    if start_rec is not None:
        tables.append((START_REC_TITLE, *start_rec))
    text = "\n\n".join(format_table(h, r, title=t) for t, h, r in tables)
    markdown = "\n\n".join(f"**{t}**\n\n" + format_markdown(h, r) for t, h, r in tables)
    (out / "table.txt").write_text(text + "\n")
    (out / "table.md").write_text(markdown + "\n")
    warnings = load_warnings + list(note)
    figures: list[Path] = []
    plt = _pyplot()
    if plt is None:
        warnings.append("plots need matplotlib (pip install -e '.[viz]'); wrote the tables only")
    else:
        with _quiet_plots():
            for fname, fn in zip(FIGURES, (plot_subtasks, plot_failures, plot_memory,
                                           functools.partial(plot_budgets, budgets=budgets))):
                fn(runs, out / fname, plt)
                figures.append(out / fname)
    episodes: list[tuple[Run, list]] = []
    if episode_pages:
        from tools.episode_pages import write_episode_pages

        try:
            with _quiet_plots():
                episodes = [(r, write_episode_pages(out, i, r)) for i, r in enumerate(runs)]
        except ImportError as exc:
            warnings.append(f"episode pages need Pillow (pip install -e '.[viz]'): {exc}; wrote the tables only")
        for r, pages in episodes:
            damaged = [pg for pg in pages if pg.damaged]
            for pg in damaged[:MAX_LISTED_DAMAGE]:
                warnings.append(f"{trace_path(r.path, pg.episode_id)}: the picture data {pg.damaged}; its episode "
                                f"page says so and shows no pictures")
            if len(damaged) > MAX_LISTED_DAMAGE:
                warnings.append(f"{r.path}: {len(damaged) - MAX_LISTED_DAMAGE} more episode(s) with damaged "
                                f"picture data")
    write_html(out / "index.html", runs, tables, figures, episodes)
    from tasks.decisions import (summarize_activity_time, summarize_decisions, summarize_start_receptacle,
                                 summarize_timeouts)

    (out / "report.json").write_text(json.dumps({r.name: {"path": str(r.path), "summary": r.summary,
                                                          "decisions": summarize_decisions(r.records),
                                                          "activity_time": summarize_activity_time(r.records),
                                                          "timeouts": summarize_timeouts(r.records),
                                                          "start_receptacle": summarize_start_receptacle(r.records),
                                                          "pick_limits": {str(n): lr.summary for n in pick_limits
                                                                          for lr in pick_limited_runs([r], n)},
                                                          "time_budgets": budget_summary(r, budgets)}
                                                 for r in runs}, indent=2, sort_keys=True))
    return {"text": text, "markdown": markdown, "figures": figures, "html": out / "index.html", "warnings": warnings,
            "pages": {r.name: pages for r, pages in episodes}}


def run(args: argparse.Namespace) -> int:
    import sys

    names = [n.strip() for n in args.names.split(",")] if args.names else None
    limits = parse_pick_limits(args.pick_limits)
    budgets = parse_budgets(args.budgets)
    result = make_report(args.runs, args.out, names, common=args.common, episode_pages=not args.no_episode_pages,
                         pick_limits=limits, budgets=budgets)
    print(result["text"])
    print()
    print(result["markdown"])
    print()
    for w in result["warnings"]:
        print(f"warning: {w}", file=sys.stderr)
    for f in result["figures"]:
        print(f"plot: {f}")
    pages = sum(len(p) for p in result["pages"].values())
    if pages:
        print(f"episode pages: {pages} in {Path(args.out) / 'episodes'}/ (linked from the report)")
    print(f"report: {result['html']}")
    return 0
