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

The command lives here (its arguments, the tables put together, the files written); its parts have
modules of their own: ``tools.report_runs`` (loading a run folder), ``tools.report_stats`` (the
paired sign tests and the power table), ``tools.report_phase_times`` (the speed and time-budget
tables) and ``tools.report_plots`` (the PNG figures).
"""

from __future__ import annotations

import argparse
import base64
import functools
import html
import json
import math
from pathlib import Path

from tools.cli import check_text_path, resolved
from tools.report_phase_times import (BUDGET_TITLE, MAX_BUDGETS, SPEED_TITLE, budget_rows, budget_summary,
                                      check_budgets, default_budgets, speed_rows)
from tools.report_plots import _pyplot, _quiet_plots, plot_budgets, plot_failures, plot_memory, plot_subtasks
from tools.report_runs import MAX_LISTED_DAMAGE, PHASES, Run, check_names, load_run
from tools.report_stats import POWER_TITLE, paired_rows, power_rows

FIGURES = ("subtasks.png", "failures.png", "memory.png", "budgets.png")
FIGURE_TITLES = {"subtasks.png": "Subtasks: share of episodes reaching each phase",
                 "failures.png": "How episodes ended (share of all episodes)",
                 "memory.png": "Memory over an episode's time",
                 "budgets.png": "Phases reached within each time budget"}


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


# ------------------------------------------------------------------------------------------------
# Tables
# ------------------------------------------------------------------------------------------------
def metrics_rows(runs: list[Run]) -> tuple[list[str], list[list]]:
    from tasks.trial_summary import metrics_table_rows

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


SETTINGS_TITLE = ("Settings each run changes against the first run (config.yaml; commit, version and episode count "
                  "aside): setting: first run's value -> this run's")
MAX_SETTINGS_LISTED = 8       # changed settings named per run; the rest are counted


def settings_rows(runs: list[Run]) -> tuple[list[str], list[list]]:
    """Per run, the settings in which its configuration differs from the first run's, read from the
    run folders: an ablation or a sensitivity sweep (``make sensitivity``) labels its rows by what
    was changed, and a row that differs in more than was meant (another detector setting, another
    split) shows it before its numbers are read. An agent name stands for its preset (the
    settings it implies are not in config.yaml)."""
    from tools.diff_runs import CONFIG_ASIDE, differences, fields_text

    def settings(r: Run) -> dict:
        return {k: v for k, v in r.config.items() if k not in CONFIG_ASIDE}

    first = runs[0]
    rows = []
    for i, r in enumerate(runs):
        agent = r.config.get("agent") or (r.records[0].get("agent") if r.records else None) or "?"
        if i == 0:
            cell = "(the first run: the others are read against it)"
        elif not (first.config and r.config):
            cell = "unknown (a run folder without a readable config.yaml)"
        else:
            changed = differences(settings(first), settings(r))
            cell = fields_text(changed, MAX_SETTINGS_LISTED, " -> ") or "nothing (the same configuration)"
        rows.append([r.name, agent, cell])
    return ["run", "agent", "settings changed"], rows


def failure_rows(runs: list[Run]) -> tuple[list[str], list[list]]:
    """Counts of success and each failure reason per run, and of the unscored episodes (an episode
    that ended on an exception has no metrics) when there are any: the row adds up to the run's
    episodes, as failures.png does."""
    from tasks.metrics import FAILURE_REASONS

    used = [k for k in FAILURE_REASONS if any(r.summary["failure_reasons"][k] for r in runs)]
    unscored = [r.summary["episodes"] - r.summary["scored"] for r in runs]
    headers = ["run", "success"] + used + (["unscored"] if any(unscored) else [])
    rows = [[r.name, r.summary["SR"]["count"]] + [r.summary["failure_reasons"][k] for k in used]
            + ([u] if any(unscored) else []) for r, u in zip(runs, unscored)]
    return headers, rows


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
               "gaze pts/search mean", "median", "max", "gaze pt visits", "with a view", "frontiers given up",
               "claw drops"]
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
# Output
# ------------------------------------------------------------------------------------------------
def _html_table(headers, rows) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def write_html(path: Path, runs: list[Run], tables: list[tuple[str, list, list]], figures: list[Path],
               episodes: list[tuple[Run, list]] = (), warnings: list[str] = ()) -> None:
    """index.html: the warnings (as the terminal printed them), the tables, the plots (embedded),
    and per run a failure gallery and the per-episode table, whose rows and thumbnails link to the
    episode pages (relative links)."""
    from tools.episode_pages import episode_table_html, failure_gallery_html

    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>HELIOS trial report</title><style>",
             "body{font-family:sans-serif;margin:2em;max-width:1100px}table{border-collapse:collapse;margin:1em 0}"
             "td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}td:first-child,th:first-child{text-align:left}"
             "img{max-width:100%;margin:1em 0}code{background:#f4f4f4}"
             "table.episodes td,table.episodes th{text-align:left}figure{display:inline-block;margin:4px;vertical-align:top}"
             "figure img{margin:0;border:1px solid #ccc}figcaption{font-size:85%}"
             ".warnings{background:#fff4e5;border:1px solid #f0b429;padding:0.5em 1em}",
             "</style></head><body><h1>HELIOS trial report</h1>"]
    for r in runs:
        cfg = r.config
        parts.append(f"<p><b>{html.escape(r.name)}</b>: <code>{html.escape(str(r.path))}</code>, agent "
                     f"{html.escape(str(cfg.get('agent', '?')))}, {html.escape(str(cfg.get('episodes_file') or 'split ' + str(cfg.get('split', '?'))))}, "
                     f"seed {html.escape(str(cfg.get('seed', '?')))}, commit {html.escape(str(cfg.get('git_commit', '?'))[:10])}</p>")
    if warnings:
        items = "".join(f"<li>{html.escape(w)}</li>" for w in warnings)
        parts.append(f"<div class='warnings'><b>Warnings</b><ul>{items}</ul></div>")
    for title, headers, rows in tables:
        parts.append(f"<h2>{html.escape(title)}</h2>" + _html_table(headers, rows))
    for fig in figures:
        data = base64.b64encode(fig.read_bytes()).decode()
        title = FIGURE_TITLES.get(fig.name, fig.stem)
        parts.append(f"<h2>{html.escape(title)}</h2><img alt='{html.escape(title)}' src='data:image/png;base64,{data}'>")
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
    from tasks.trial_summary import summarize
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


def parse_pick_limits(text: str) -> tuple[int, ...]:
    """``--pick-limits`` "1,5" -> (1, 5); CliError for anything but distinct integers in range."""
    from tasks.trial_summary import MAX_PICK_LIMIT
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
    (:func:`tasks.trial_summary.limit_pick_attempts`, the paper's "N picks" rows)."""
    import dataclasses

    from tasks.trial_summary import limit_pick_attempts, summarize

    out = []
    for r in runs:
        records = limit_pick_attempts(r.records, limit)
        out.append(dataclasses.replace(r, records=records, summary=summarize(records)))
    return out


def pick_limit_tables(runs: list[Run], limits: tuple[int, ...]) -> list[tuple[str, list, list]]:
    """Per limit: the percent table and (several runs) the paired sign tests against the first run."""
    from tasks.trial_summary import exceeds_pick_limit

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
    from tasks.run_folder import FOLDER_FILES
    from tasks.trial_summary import MAX_PICK_LIMIT, is_pick_limit
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
        run_dir, target = resolved(p, "run folder"), resolved(out, "--out")
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
    finished = {id(r): len(r.records) for r in runs}      # before --common trims them to the shared episodes
    note = []
    if common:
        n = restrict_to_common(runs)
        note.append(f"compared on the {n} episode(s) all runs finished")
    elif len(runs) > 1 and not set.intersection(*({r["episode_id"] for r in run.records} for run in runs)):
        note.append("the runs share no episode (different splits or episode files?): each row stands alone, "
                    "and the paired comparisons have no episode to pair")
    elif len(counts) > 1:
        note.append(f"the runs cover different numbers of episodes ({', '.join(map(str, counts))}); "
                    f"--common compares them on the episodes they share")
    for r in runs:          # a run still going (or stopped): its rates are of the episodes done so far
        planned = (r.config or {}).get("episodes")
        if isinstance(planned, int) and finished[id(r)] < planned:
            note.append(f"{r.name}: {finished[id(r)]} of its {planned} episodes finished (a run in progress, "
                        f"or stopped; the same command resumes it)")
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
    tables += [("Runs", d_headers, d_rows)]
    if len(runs) > 1:
        tables.append((SETTINGS_TITLE, *settings_rows(runs)))
    tables.append(("How episodes ended (counts)", f_headers, f_rows))
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
    # what the terminal printed as warnings goes into the files too: a report read later (or in a
    # browser) showed run8 over 4 episodes with --common and did not say so (pictures audit)
    (out / "table.txt").write_text(text + "".join(f"\n\nwarning: {w}" for w in warnings) + "\n")
    (out / "table.md").write_text(markdown + ("\n\n**Warnings**\n\n" + "\n".join(f"- {w}" for w in warnings)
                                              if warnings else "") + "\n")
    write_html(out / "index.html", runs, tables, figures, episodes, warnings)
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

    from tools.cli import CliError, same_folder_twice

    twice = same_folder_twice(args.runs)      # it would be paired with itself ("R (2)")
    if twice:
        raise CliError(f"run folder {twice[0]!r} is given twice (also as {twice[1]!r}); each run once")
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
