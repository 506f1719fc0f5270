"""Measure the simulated detector on random views of train scenes: per-class precision/recall at
the paper's thresholds, recall against distance, and how often one view's top label is wrong while
the majority over 5 views is right. Prints tables, the receptacle targets against the measured
numbers (``sim.perception.config.RECEPTACLE_TARGETS``), writes calibration.json and
calibration.png.

    python -m tools calibrate-perception                      # 1500 views of 8 train scenes (~1 min)
    python -m tools calibrate-perception --views 200 --out runs/pc bad_view_object=0.2
    python -m tools calibrate-perception --baseline runs/old/calibration.json   # before/after lines

Tune on ``train`` (the default); ``--split val`` measures the evaluation homes.

Trailing ``key=value`` arguments override ``sim.perception.config.SimPerceptionConfig`` fields.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from tools.cli import CliError, check_output_dir, check_output_file, check_seed
from tools.tables import format_table


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--views", type=int, default=1500, help="views rendered in all (default 1500)")
    parser.add_argument("--group", type=int, default=5, help="views per target for the majority vote (default 5)")
    parser.add_argument("--scenes", type=int, default=8, help="distinct scenes of the split to use (default 8)")
    parser.add_argument("--split", default="train",
                        help="episode split whose scenes are viewed (default train: tune there, not on val)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the view sampling (default 0)")
    parser.add_argument("--min-pixels", type=int, default=50,
                        help="an instance counts for recall when at least this many pixels show (default 50)")
    parser.add_argument("--out", default="runs/perception_calibration",
                        help="output folder for the JSON and the plot (default: %(default)s)")
    parser.add_argument("--baseline", metavar="JSON", default=None,
                        help="a calibration.json of an earlier run: print its receptacle numbers as 'before'")
    parser.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="SimPerceptionConfig overrides")


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.1f}"


def tables(result: dict) -> str:
    from sim.scenes.catalog import OBJECT_CATEGORIES

    thr = result["thresholds"]
    rows = []
    for cat, r in result["per_class"].items():
        group = "object" if cat in OBJECT_CATEGORIES else "receptacle"
        t = thr["od_object"] if group == "object" else thr["od_start_receptacle"]
        rows.append((cat, group, t, _pct(r["precision"]), _pct(r["recall"]), r["tp"], r["fp"], r["instances"]))
    for name, r in result["pooled"].items():
        rows.append((f"ALL {name}", "", "", _pct(r["precision"]), _pct(r["recall"]), r["tp"], r["fp"], r["instances"]))
    out = [format_table(["class", "group", "threshold", "precision %", "recall %", "TP", "FP", "instances"], rows,
                        title=f"Single-view detection, full-vocabulary query ({result['views']} views)")]
    rows = [(role, _pct(r["precision"]), _pct(r["recall"]), r["tp"], r["fp"], r["instances"])
            for role, r in result["task_query"].items()]
    out.append(format_table(["role", "precision %", "recall %", "TP", "FP", "instances"], rows,
                            title="Task-like queries (3 classes; od_g=%.2f od_a=%.2f od_b=%.2f)" % (
                                thr["od_object"], thr["od_start_receptacle"], thr["od_goal_receptacle"])))
    rd = result["recall_by_distance"]
    edges = [0.0] + rd["edges_m"] + [math.inf]
    rows = [(f"{edges[i]:.1f}-{edges[i + 1]:.1f}", _pct(f / n if n else None), n)
            for i, (f, n) in enumerate(zip(rd["found"], rd["instances"]))]
    out.append(format_table(["distance m", "recall %", "instances"], rows, title="Small-object recall by distance"))
    rows = []
    for name, c in result["consistency"].items():
        rows.append((name, c["targets"], c["views_with_detection"], _pct(c["single_view_label_accuracy"]),
                     _pct(c["majority_label_accuracy"]), _pct(c["single_wrong_majority_right"])))
    g = result["settings"]["group"]
    out.append(format_table(["targets", "n", "views with a detection", "single-view label right %",
                             f"{g}-view majority right %", "single wrong but majority right %"], rows,
                            title=f"Multi-view consistency (top label of the target per view, majority over {g} views)"))
    return "\n\n".join(out)


# The rows receptacle_lines prints, of a result and of a --baseline file: (section, key, row name), each
# with RATE_FIELDS and COUNT_FIELDS. load_baseline checks a baseline has them all before the calibration runs.
RECEPTACLE_ROWS = (("task_query", "start receptacle", "start receptacle"),
                   ("task_query", "goal receptacle", "goal receptacle"),
                   ("pooled", "receptacles", "all receptacles (full vocabulary)"))
RATE_FIELDS, COUNT_FIELDS = ("precision", "recall"), ("tp", "fp", "instances")


def _baseline_problem(doc) -> str | None:
    """The first key of a baseline's ``RECEPTACLE_ROWS`` that is missing or of the wrong type (a
    rate: null or a number within 0..1; a count: a whole number >= 0), in words; None if all are fine."""
    from helios.schema import finite

    if not isinstance(doc, dict):
        return f"it holds a {type(doc).__name__}, not an object"
    for section, key, _ in RECEPTACLE_ROWS:
        row, where = doc, ""
        for k in (section, key):
            where += f"[{k!r}]"
            if k not in row:
                return f"{where} is missing"
            row = row[k]
            if not isinstance(row, dict):
                return f"{where} is {_short(row)}, not an object"
        for field in RATE_FIELDS + COUNT_FIELDS:
            where = f"[{section!r}][{key!r}][{field!r}]"
            if field not in row:
                return f"{where} is missing"
            v = row[field]
            if field in RATE_FIELDS and not (v is None or (finite(v) and 0 <= v <= 1)):
                return f"{where} is {_short(v)}, not null or a number within 0..1"
            if field in COUNT_FIELDS and not (isinstance(v, int) and not isinstance(v, bool) and v >= 0):
                return f"{where} is {_short(v)}, not a whole number >= 0"
    return None


def _short(value) -> str:
    """A JSON value as the file writes it, shortened."""
    from helios.schema import shorten

    return shorten(json.dumps(value), 40)


def load_baseline(path: str) -> dict:
    """The ``--baseline`` calibration.json, with everything :func:`receptacle_lines` reads of it
    checked: a CliError naming the file and the first bad key, before the calibration runs (a
    parseable but wrong file once failed with a traceback after it)."""
    from helios.schema import short_repr

    if not path.strip():
        raise CliError("--baseline must not be empty")
    name = short_repr(path, 100)
    if Path(path).exists() and not Path(path).is_file():      # a FIFO would be waited on for ever
        raise CliError(f"--baseline {name} is not a regular file")
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, ValueError, RecursionError) as exc:
        raise CliError(f"--baseline {name}: not a calibration.json of this tool ({short_repr(str(exc), 100)})") from None
    problem = _baseline_problem(doc)
    if problem is not None:
        raise CliError(f"--baseline {name}: not a calibration.json of this tool: {problem}")
    return doc


def receptacle_lines(result: dict, baseline: dict | None = None) -> str:
    """Targets vs measured for the targeted receptacle role, plus before/after rows when given a
    baseline result (the same settings on other code or parameters)."""
    from sim.perception.config import RECEPTACLE_TARGET_ROLE, RECEPTACLE_TARGETS

    t = RECEPTACLE_TARGETS
    tol = t["tolerance"]
    r = result["task_query"][RECEPTACLE_TARGET_ROLE]
    verdicts = []
    for key in ("precision", "recall"):
        v = r[key]
        ok = v is not None and abs(v - t[key]) <= tol + 1e-9
        verdicts.append(f"{key} {_pct(v)} % (target {100 * t[key]:.0f} +- {100 * tol:.0f}: {'met' if ok else 'NOT met'})")
    lines = [f"Receptacle targets ({RECEPTACLE_TARGET_ROLE}, single view, od_a="
             f"{result['thresholds']['od_start_receptacle']:.2f}): " + "; ".join(verdicts)]
    rows = []
    for label, res in (("before", baseline), ("after" if baseline else "measured", result)):
        if res is None:
            continue
        for section, key, name in RECEPTACLE_ROWS:
            x = res[section][key]
            rows.append((label, name, _pct(x["precision"]), _pct(x["recall"]), x["tp"], x["fp"], x["instances"]))
    lines.append(format_table(["run", "receptacles", "precision %", "recall %", "TP", "FP", "instances"], rows,
                              title="Receptacles, single view" + (" (before / after)" if baseline else "")))
    return "\n".join(lines)


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sim.scenes.catalog import OBJECT_CATEGORIES

    fig, axes = plt.subplots(1, 3, figsize=(17, 5.2), gridspec_kw={"width_ratios": [3.2, 1.2, 1.2]})
    cats = [c for c, r in result["per_class"].items() if r["instances"] or r["tp"] + r["fp"]]
    x = range(len(cats))
    prec = [result["per_class"][c]["precision"] for c in cats]
    rec = [result["per_class"][c]["recall"] for c in cats]
    ax = axes[0]
    ax.bar([i - 0.2 for i in x], [v or 0 for v in prec], 0.4, label="precision", color="#3b75af")
    ax.bar([i + 0.2 for i in x], [v or 0 for v in rec], 0.4, label="recall", color="#ef8636")
    # 0 % and "no data" both drew no bar (pictures audit): say which, at the foot of each bar
    for i, (p, r) in enumerate(zip(prec, rec)):
        for dx, v in ((-0.2, p), (0.2, r)):
            if not v:
                ax.text(i + dx, 0.01, "n/a" if v is None else "0", ha="center", va="bottom", fontsize=6,
                        rotation=90, color="0.3")
    ax.set_xticks(list(x))
    ax.set_xticklabels(cats, rotation=70, fontsize=8)
    for i, c in enumerate(cats):
        if c not in OBJECT_CATEGORIES:
            ax.axvspan(i - 0.5, i + 0.5, color="0.92", zorder=0)
    # the legends sit in a band above 1.0 that no bar reaches (they covered the first bars)
    ax.set_ylim(0, 1.22)
    ax.set_yticks([0, 0.2, 0.4, 0.6, 0.8, 1.0])
    ax.set_ylabel("single-view precision / recall")
    ax.set_title("Single view, per class (grey: furniture)")
    ax.legend(loc="upper center", ncol=2, frameon=False)
    rd = result["recall_by_distance"]
    edges = [0.0] + rd["edges_m"] + [rd["edges_m"][-1] + 2.0]
    mids = [(a + b) / 2 for a, b in zip(edges[:-1], edges[1:])]
    vals = [f / n if n else float("nan") for f, n in zip(rd["found"], rd["instances"])]
    axes[1].plot(mids, vals, "o-", color="#3b75af")
    for m, v, n in zip(mids, vals, rd["instances"]):       # how many instances each point stands on
        if n:
            axes[1].annotate(f"n={n}", (m, v), textcoords="offset points", xytext=(0, 6), ha="center", fontsize=7)
    axes[1].set_xlabel("camera distance (m)")
    axes[1].set_ylabel("recall")
    axes[1].set_ylim(0, 1.05)
    axes[1].set_title("Small-object recall vs distance")
    cons = result["consistency"]
    names = [n for n in ("small objects", "receptacles") if cons[n]["targets"]]
    single = [cons[n]["single_view_label_accuracy"] or 0 for n in names]
    maj = [cons[n]["majority_label_accuracy"] or 0 for n in names]
    xi = range(len(names))
    axes[2].bar([i - 0.2 for i in xi], single, 0.4, label="single view", color="#999999")
    axes[2].bar([i + 0.2 for i in xi], maj, 0.4, label=f"{result['settings']['group']}-view majority", color="#2a9d55")
    axes[2].set_xticks(list(xi))
    axes[2].set_xticklabels(names)
    axes[2].set_ylim(0, 1.22)
    axes[2].set_yticks([0, 0.2, 0.4, 0.6, 0.8, 1.0])
    axes[2].set_ylabel("share of targets labelled right")
    axes[2].set_title("Label accuracy of the target")
    axes[2].legend(loc="upper center", ncol=2, frameon=False)
    fig.suptitle(f"Simulated detector calibration: {result['views']} views of {result['settings']['scenes']} "
                 f"{result['settings']['split']} scenes")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    from helios.schema import with_overrides
    from tasks.perception_calibration import CalibrationSettings, calibrate, scene_count
    from sim.perception.config import SimPerceptionConfig

    if args.views < args.group or args.group < 1:
        raise CliError(f"--views ({args.views}) must be at least --group ({args.group}), and --group >= 1")
    if args.scenes < 1:
        raise CliError("--scenes must be >= 1")
    if args.views > 1_000_000 or args.scenes > 10_000:
        raise CliError(f"--views ({args.views}) must be at most 1000000 and --scenes ({args.scenes}) at most 10000")
    check_seed(args.seed)
    if args.min_pixels < 1:
        raise CliError(f"--min-pixels must be >= 1, got {args.min_pixels}")
    baseline = None if args.baseline is None else load_baseline(args.baseline)
    config = with_overrides(SimPerceptionConfig(), args.overrides)
    if config.mode != "noisy":
        raise CliError("calibration measures the noisy simulated detector; mode=gt is perfect by construction")
    from tasks.episodes import split_path

    split_path(args.split)                     # an unknown split is one clear error before any work
    available = scene_count(args.split)
    if args.scenes > available:                # one line here, not calibrate()'s ValueError
        raise CliError(f"--scenes {args.scenes} is more than the {available} distinct scenes of split {args.split!r}")
    out = check_output_dir(args.out)
    for name in ("calibration.json", "calibration.png"):
        check_output_file(out / name, "--out")
    out.mkdir(parents=True, exist_ok=True)
    # the views are shared out over the scenes: with fewer views than scenes only that many scenes
    # are viewed, and the first line and calibration.json say so (never a scene recorded but unseen)
    scenes = min(args.scenes, args.views)
    settings = CalibrationSettings(split=args.split, views=args.views, group=args.group, scenes=scenes,
                                   seed=args.seed, min_pixels=args.min_pixels)
    fewer = f" (fewer views than --scenes {args.scenes})" if scenes < args.scenes else ""
    print(f"calibrating the simulated detector on {args.views} views of {scenes} {args.split} scenes{fewer} ...",
          flush=True)
    result = calibrate(settings, config, progress=lambda line: print(line, flush=True))
    print()
    print(tables(result))
    print()
    print(receptacle_lines(result, baseline))
    (out / "calibration.json").write_text(json.dumps(result, indent=1, default=str))
    plot(result, out / "calibration.png")
    print(f"\nwrote {out / 'calibration.json'} and {out / 'calibration.png'} ({result['seconds']:.0f} s)")
    return 0
