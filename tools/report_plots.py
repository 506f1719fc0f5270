"""The report's PNG figures (matplotlib, Agg): subtask success as the paper's stacked bars, how
episodes ended, memory over episode time and phases reached by each time budget; also
``_pyplot`` (None without matplotlib) and ``_quiet_plots`` (drawing writes nothing to stderr).
Its own module because drawing is the one part of the report that needs matplotlib, and the tables
say everything the figures show.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np

from tools.report_phase_times import BUDGET_PHASES, budget_curve, run_phase_times, run_time_cap
from tools.report_runs import PHASES, Run


PHASE_COLORS = ("#c6dbef", "#9ecae1", "#6baed6", "#3182bd", "#08519c")
MEMORY_SERIES = (("rss_mb", "resident memory (RSS)"), ("map_mb", "agent map"),
                 ("gpu_allocated_mb", "GPU allocated"), ("gpu_reserved_mb", "GPU reserved"))


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
            # equal phases are consecutive: "FindObj..SR", not a label running into the next bar or
            # off the axes (pictures audit)
            which = "=".join(names) if len(names) <= 2 else f"{names[0]}..{names[-1]}"
            ax.text(i + 0.32, y, f"{which} {v:.0f}±{se:.0f}", va="center", ha="left", fontsize=7)
            y_prev = y
    ax.set_xticks(x, [f"{r.name}\n(n={r.summary['scored']}" + (f" scored of {r.summary['episodes']})"
                                                             if r.summary["scored"] != r.summary["episodes"] else ")")
                      for r in runs], fontsize=8)
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
    """How episodes ended, per run: success, each failure reason and (when any) the unscored
    episodes, as shares of all the run's episodes (so a bar adds up to 100 %; the tables' rates are
    over the scored ones)."""
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
        parts.append(("unscored", "#1a1a1a", crashed))        # not tab10's grey (receptacle_not_found)
    for label, color, counts in parts:
        share = np.array([100.0 * c / max(1, r.summary["episodes"]) for c, r in zip(counts, runs)])
        if not share.any():
            continue
        ax.barh(y, share, left=left, color=color, label=label, edgecolor="white", linewidth=0.6)
        for yi, (l0, w) in enumerate(zip(left, share)):
            if w >= 6:
                ax.text(l0 + w / 2, yi, f"{w:.1f}".rstrip("0").rstrip("."), ha="center", va="center", fontsize=7,
                        color="white")
        left += share
    ax.set_yticks(y, [r.name for r in runs], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlim(0, 100)
    ax.set_xlabel("episodes (% of all, unscored included)")
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
    fig.suptitle("Memory over episode time (mean over the episodes still running; dashed: max)", fontsize=10,
                 x=0.02, ha="left")
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
            times = run_phase_times(r, key)
            if not times:
                continue
            handles[r.name], = ax.step(grid, budget_curve(times, grid), where="post", color=cmap(i % 10),
                                        linewidth=1.4)
        for t in budgets:
            ax.axvline(t, color="0.6", linestyle=":", linewidth=0.8)
        ax.set_xlim(0, cap)
        ax.set_ylim(-3, 103)            # a curve at 0 % or 100 % was hidden under the frame
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
