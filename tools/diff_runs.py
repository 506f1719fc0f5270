"""Which episodes' records differ between two run folders, field by field, with wall time, memory
and recording paths aside: the check that a refactor or an exact speed-up changed no result, and
that a run reproduces another one (the same configuration on another machine or commit). Exit
status 1 when a record differs or an episode is in one run only (``--common``: only the episodes
both runs have count).

    python -m tools diff runs/val/helios runs/new --episodes 30

Exit status 0 when both runs have the same episodes and every record is identical, 1 when any
differs or an episode is in one run only (a run cut short, another episode set: one line names
them, and they count; ``--common`` compares the episodes both runs have and lets the rest
through, as ``tools report --common`` does), 2 for bad input. ``--episodes N`` takes the first N
episodes by id of either run (with ``--common``, of those both have). Fields in ``--ignore``
(dotted paths into a record, e.g. ``config_fingerprint`` when a config key was added, or
``extra.start_receptacle.viewed`` for a field one run does not record yet) are left out; a path
that names nothing in either run is refused (a typo would otherwise hide every difference it was
meant to let through). The two configurations are compared too (the number of episodes aside),
and a difference in the CPU code paths the runs' episodes ran on is said: those alone can move
outcomes (README, "One CPU code path").
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field
from pathlib import Path

MAX_EPISODES_LISTED = 20     # differing episodes named one by one; the rest are counted
MAX_FIELDS_LISTED = 5        # differing fields shown per episode
MAX_IDS_LISTED = 10          # episodes only one run has, named on their line; the rest are counted
VALUE_CHARS = 60             # a value longer than this is shortened in the middle
CONFIG_ASIDE = ("helios_version", "git_commit", "episodes")     # config keys that may differ freely


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_a", metavar="RUN_A", help="run folder (from `python -m tools trials --out`)")
    parser.add_argument("run_b", metavar="RUN_B", help="the run folder to compare it with")
    parser.add_argument("--episodes", type=int, default=None, metavar="N",
                        help="compare only the first N episodes by id (default: all); one of them that only one "
                             "run has counts as a difference, unless --common")
    parser.add_argument("--common", action="store_true",
                        help="compare the episodes both runs have; episodes only one run has are listed but do not "
                             "count (exit 0 when those compared are identical: a run still going, or cut short)")
    parser.add_argument("--ignore", default="", metavar="FIELD[,FIELD...]",
                        help="dotted record fields to leave out (and everything under them), e.g. "
                             "config_fingerprint,extra.start_receptacle.viewed")
    parser.add_argument("--tolerance", type=float, default=0.0, metavar="REL",
                        help="numbers within this relative tolerance count as equal (default 0: exact; e.g. 1e-9 "
                             "to see only what grew past last-bit rounding)")
    parser.add_argument("--show", type=int, default=MAX_EPISODES_LISTED, metavar="K",
                        help=f"differing episodes to list one by one (default {MAX_EPISODES_LISTED})")


# ------------------------------------------------------------------------------------------------
# Field-by-field differences
# ------------------------------------------------------------------------------------------------
_MISSING = object()


def _same_leaf(a, b, tolerance: float = 0.0) -> bool:
    """Equality of two JSON leaves, with NaN equal to NaN and a bool never equal to a number (JSON
    keeps the difference; Python's ``True == 1`` does not); 1 and 1.0 are the same number. Two
    numbers within ``tolerance`` of each other, relative to the larger, count as equal (0: exact)."""
    if isinstance(a, bool) or isinstance(b, bool):
        return type(a) is type(b) and a == b
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    if tolerance > 0 and isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return math.isclose(a, b, rel_tol=tolerance, abs_tol=tolerance * 1e-3)
    return a == b


def differences(a, b, ignore: frozenset[str] = frozenset(), path: str = "",
                tolerance: float = 0.0) -> list[tuple[str, object, object]]:
    """(dotted path, value in a, value in b) for every leaf where two JSON values differ; a key
    present on one side only reads as missing on the other. Lists differ element by element when
    they have the same length, else as a whole. Paths in ``ignore`` are skipped with all below;
    numbers within ``tolerance`` (relative) of each other are the same (see ``_same_leaf``)."""
    if path in ignore:
        return []
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b), key=str):
            sub = f"{path}.{key}" if path else str(key)
            out += differences(a.get(key, _MISSING), b.get(key, _MISSING), ignore, sub, tolerance)
        return out
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        out = []
        for i, (x, y) in enumerate(zip(a, b)):
            out += differences(x, y, ignore, f"{path}[{i}]", tolerance)
        return out
    if a is _MISSING or b is _MISSING or isinstance(a, (dict, list)) or isinstance(b, (dict, list)):
        return [(path, a, b)]          # a side missing, or shapes that differ (dict against list, lengths)
    return [] if _same_leaf(a, b, tolerance) else [(path, a, b)]


def paths_of(value, path: str = "") -> set[str]:
    """Every dotted path in a JSON value (dict keys; list elements as ``[i]``), inner nodes included."""
    out = {path} if path else set()
    if isinstance(value, dict):
        for key, sub in value.items():
            out |= paths_of(sub, f"{path}.{key}" if path else str(key))
    elif isinstance(value, list):
        for i, sub in enumerate(value):
            out |= paths_of(sub, f"{path}[{i}]")
    return out


def show_value(value) -> str:
    """A value as the report prints it: JSON-like, missing fields as ``(missing)``, shortened."""
    import json

    from helios.schema import shorten

    if value is _MISSING:
        return "(missing)"
    try:
        text = json.dumps(value, sort_keys=True)
    except (TypeError, ValueError):
        text = repr(value)
    return shorten(text, VALUE_CHARS)


# ------------------------------------------------------------------------------------------------
# Two runs
# ------------------------------------------------------------------------------------------------
@dataclass
class RunDiff:
    compared: list[str]                                   # episode ids compared, sorted
    differing: dict[str, list[tuple[str, object, object]]]
    only_a: list[str]
    only_b: list[str]
    config: list[tuple[str, object, object]] = field(default_factory=list)
    cpu: tuple[tuple[str, ...], tuple[str, ...]] = ((), ())
    shared: int = 0                                       # episodes both runs have (compared or not)
    tolerance: float = 0.0                                # relative; 0 = exact
    # of the episodes in scope (all, or the first --episodes), those one run lacks: they count as a
    # difference (empty with --common, which compares only what both have)
    one_sided_a: list[str] = field(default_factory=list)
    one_sided_b: list[str] = field(default_factory=list)
    common: bool = False

    @property
    def same(self) -> bool:
        """The verdict (exit status 0): no compared record differs and no episode is missing."""
        return not self.differing and not self.one_sided_a and not self.one_sided_b

    @property
    def identical(self) -> int:
        return len(self.compared) - len(self.differing)


def parse_ignore(text: str) -> frozenset[str]:
    """``--ignore``'s comma-separated dotted paths; CliError for an empty one, stray spaces, or a
    path whose first name (under ``metrics``, first two) no episode record has."""
    from helios.schema import short_repr, shorten
    from tools.cli import CliError

    if not text.strip():
        return frozenset()
    paths = [p.strip() for p in text.split(",")]
    record_fields = _record_fields()
    for p in paths:
        if not p:
            raise CliError(f"--ignore {short_repr(text)} has an empty field name (two commas, or one at an end)")
        if any(c.isspace() for c in p) or p.startswith(".") or p.endswith(".") or ".." in p:
            raise CliError(f"--ignore: {short_repr(p)} is not a dotted field path such as extra.decisions")
    for p in paths:
        top, _, rest = p.partition(".")
        known = record_fields.get(top)
        if known is None or (rest and known and rest.partition(".")[0] not in known):
            where = f"a field of {top}" if known else "a field of an episode record"
            valid = ", ".join(sorted(known) if known else sorted(record_fields))
            raise CliError(f"--ignore {short_repr(p)} names no field: {short_repr(rest or top)} is not {where} "
                           f"({shorten(valid, 300)})")
    return frozenset(paths)


def _record_fields() -> dict[str, frozenset[str]]:
    """The top-level fields of an episode record (``tasks.trials.run_one``, ``tasks.hardware.
    hardware_record``), each with the names it holds where those are fixed (``metrics``), so that a
    misspelt ``--ignore`` is refused before ``tools unchanged`` runs anything."""
    from dataclasses import fields

    from tasks.metrics import EpisodeMetrics
    from tasks.runner import EpisodeResult
    from tasks.trial_config import FINGERPRINT_FIELD, NONDETERMINISTIC_FIELDS

    top = {f.name for f in fields(EpisodeResult)} | {"success", "collision_events", "hardware", FINGERPRINT_FIELD}
    out = {name: frozenset() for name in top | set(NONDETERMINISTIC_FIELDS)}
    out["metrics"] = frozenset(f.name for f in fields(EpisodeMetrics))
    return out


def diff_runs(a, b, episodes: int | None = None, ignore: frozenset[str] = frozenset(),
              tolerance: float = 0.0, common: bool = False) -> RunDiff:
    """Compare two loaded runs (``tools.report_runs.Run``): the records of the episodes both have,
    among all episodes (or the first ``episodes`` by id) of either run; those of them that one run
    lacks are in ``one_sided_a``/``one_sided_b`` and make the runs differ (``RunDiff.same``). With
    ``common``, only the episodes both have (the first ``episodes`` of them) and nothing one-sided
    counts. The records' nondeterministic fields (wall time, memory, recording path:
    ``tasks.trial_config.NONDETERMINISTIC_FIELDS``) are always left out; CliError when the runs
    share no episode or an ``ignore`` path names nothing in either run."""
    from helios.schema import short_repr
    from tasks.trial_config import deterministic_view
    from tools.cli import CliError

    ra = {r["episode_id"]: r for r in a.records}
    rb = {r["episode_id"]: r for r in b.records}
    shared = sorted(set(ra) & set(rb))
    if not shared:
        raise CliError(f"runs {a.name!r} and {b.name!r} share no finished episode ({a.name}: {_span(sorted(ra))}; "
                       f"{b.name}: {_span(sorted(rb))}): nothing to compare")
    scope = shared if common else sorted(set(ra) | set(rb))
    scope = scope if episodes is None else scope[:episodes]
    compared = [eid for eid in scope if eid in ra and eid in rb]
    known = set()
    for eid in compared if ignore else ():
        known |= paths_of(ra[eid]) | paths_of(rb[eid])
    for p in sorted(ignore):
        if p not in known:
            raise CliError(f"--ignore {short_repr(p)} names no field of the compared records (fields look like "
                           f"metrics.find_obj, extra.decisions, config_fingerprint)")
    differing = {}
    for eid in compared:      # the deterministic view: no wall time, memory, recording; an error's first line
        d = differences(deterministic_view(ra[eid]), deterministic_view(rb[eid]), frozenset(ignore),
                        tolerance=tolerance)
        if d:
            differing[eid] = outcomes_first(d)
    cfg_a = {k: v for k, v in a.config.items() if k not in CONFIG_ASIDE}
    cfg_b = {k: v for k, v in b.config.items() if k not in CONFIG_ASIDE}
    config = differences(cfg_a, cfg_b) if a.config and b.config else []
    return RunDiff(compared, differing, sorted(set(ra) - set(rb)), sorted(set(rb) - set(ra)), config, (a.cpu, b.cpu),
                   len(shared), tolerance, [e for e in scope if e not in rb], [e for e in scope if e not in ra],
                   common)


def outcomes_first(diffs: list[tuple[str, object, object]]) -> list[tuple[str, object, object]]:
    """``differences`` in the order a reader wants them: outcomes (metrics, success, simulated
    time, error) first, then the rest of the record, then ``extra``, the configuration's
    fingerprint last; by path within each."""
    return sorted(diffs, key=lambda item: (_rank(item[0]), item[0]))


def _rank(path: str) -> int:
    if path.startswith("metrics.") or path in ("success", "sim_time", "error"):
        return 0
    if path.startswith("extra."):
        return 2
    return 3 if path == "config_fingerprint" else 1


def _span(ids: list[str]) -> str:
    if not ids:
        return "none"
    return f"{len(ids)} episode{'s' if len(ids) != 1 else ''}" + (f", {ids[0]}" if len(ids) == 1 else
                                                                   f", {ids[0]} .. {ids[-1]}")


def _shown_pair(x, y) -> tuple[str, str]:
    """Both values as :func:`show_value` prints them; two long texts that shorten alike (the
    difference in the elided middle) are shown from a little before where they first differ."""
    sx, sy = show_value(x), show_value(y)
    if sx != sy or not (isinstance(x, str) and isinstance(y, str)):
        return sx, sy
    at = next((i for i, (p, q) in enumerate(zip(x, y)) if p != q), min(len(x), len(y)))
    start = max(0, at - 15)
    lead = "..." if start else ""
    return tuple(f"{lead}{show_value(v[start:start + VALUE_CHARS - 10])} (from character {start})" for v in (x, y))


def fields_text(diffs: list[tuple[str, object, object]], limit: int = MAX_FIELDS_LISTED, between: str = " / ") -> str:
    """``path: a / b; ...`` for the first ``limit`` differences, then how many more (``between``:
    what stands between the two values; `tools report`'s settings table writes " -> ")."""
    shown = "; ".join(f"{p}: {between.join(_shown_pair(x, y))}" for p, x, y in diffs[:limit])
    more = f"; and {len(diffs) - limit} more" if len(diffs) > limit else ""
    return shown + more


def describe_run(run) -> str:
    cfg = run.config or {}
    commit = str(cfg.get("git_commit") or "unknown")[:10]
    agent = cfg.get("agent") or (run.records[0].get("agent") if run.records else None) or "unknown"
    cpu = " | ".join(run.cpu) if run.cpu else "not recorded"
    on = f" on {' | '.join(run.cpu_models)}" if run.cpu_models else ""
    return f"{run.path}: {len(run.records)} episodes, agent {agent}, commit {commit}, CPU code paths {cpu}{on}"


def report_lines(a, b, diff: RunDiff, show: int = MAX_EPISODES_LISTED) -> list[str]:
    """The printed report: what was compared, what differs, where to look."""
    lines = [f"A  {describe_run(a)}", f"B  {describe_run(b)}"]
    if not (a.config and b.config):
        lines.append("configurations: not compared (a run folder has no readable config.yaml)")
    elif diff.config:
        lines.append(f"configurations differ in {len(diff.config)} field(s) (A / B): {fields_text(diff.config, 8)}")
    else:
        lines.append("configurations: the same (the number of episodes, version and commit aside)")
    if diff.cpu[0] and diff.cpu[1] and diff.cpu[0] != diff.cpu[1]:
        lines.append("CPU code paths differ between the runs: outcomes can differ for that reason alone "
                     "(README, \"One CPU code path\")")
    elif a.cpu_models and b.cpu_models and set(a.cpu_models) != set(b.cpu_models):
        lines.append("the runs ran on different CPUs (on the same code path): a few records can differ for that "
                     "reason alone (README, \"One CPU code path\"); `python -m tools unchanged` runs both sides on "
                     "one machine")
    n, shared = len(diff.compared), diff.shared
    which = f"the {n} episode{'s' if n != 1 else ''} both runs have" if n == shared else \
        f"the first {n} of the {shared} episodes both runs have"
    span = f" ({diff.compared[0]})" if n == 1 else f" ({diff.compared[0]} .. {diff.compared[-1]})"
    exact = "" if not diff.tolerance else f"; numbers within {diff.tolerance:g} (relative) count as equal"
    lines.append(f"compared: {which}{span}, field by field (wall time, memory and recording paths aside{exact})")
    lines.append(f"identical: {diff.identical} of {len(diff.compared)}")
    if diff.differing:
        lines.append(f"different: {len(diff.differing)} (A / B)")
        for eid in list(diff.differing)[:show]:
            d = diff.differing[eid]
            lines.append(f"  {eid}: {len(d)} field(s) differ: {fields_text(d)}")
        if len(diff.differing) > show:
            lines.append(f"  ... and {len(diff.differing) - show} more episode(s) (--show to list them)")
        counts: dict[str, int] = {}
        for d in diff.differing.values():
            for p in {_top(p) for p, _x, _y in d}:
                counts[p] = counts.get(p, 0) + 1
        lines.append("fields that differ, in how many episodes: "
                     + ", ".join(f"{p} {n}" for p, n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))))
    lines.append(f"only in A: {_span(diff.only_a)}; only in B: {_span(diff.only_b)}")
    missing = len(diff.one_sided_a) + len(diff.one_sided_b)
    if missing:
        sides = "; ".join(f"only in {side}: {_ids(ids)}" for side, ids in (("A", diff.one_sided_a),
                                                                         ("B", diff.one_sided_b)) if ids)
        lines.append(f"not the same episodes: {missing} episode{'s' if missing != 1 else ''} in one run only "
                     f"count{'' if missing != 1 else 's'} as a difference ({sides}); --common compares only the "
                     f"episodes both runs have")
    elif diff.common and (diff.only_a or diff.only_b):
        lines.append("(--common: episodes only one run has do not count)")
    return lines


def _ids(ids: list[str], limit: int = MAX_IDS_LISTED) -> str:
    """Episode ids, the first ``limit`` of them by name, then how many more."""
    more = f" and {len(ids) - limit} more" if len(ids) > limit else ""
    return ", ".join(ids[:limit]) + more


def _top(path: str) -> str:
    """A field path cut to its first two levels (``extra.decisions.gaze_point_visits`` ->
    ``extra.decisions``), so the summary counts groups of fields."""
    parts = path.split("[")[0].split(".")
    return ".".join(parts[:2])


def run(args: argparse.Namespace) -> int:
    import sys

    from tools.cli import CliError, same_folder_twice
    from tools.report_runs import load_run

    if args.episodes is not None and args.episodes <= 0:
        raise CliError(f"--episodes must be a positive number of episodes, got {args.episodes}")
    if args.show < 0:
        raise CliError(f"--show must be 0 or more, got {args.show}")
    if not (math.isfinite(args.tolerance) and 0.0 <= args.tolerance < 1.0):
        raise CliError(f"--tolerance must be a relative tolerance in [0, 1), got {args.tolerance}")
    ignore = parse_ignore(args.ignore)
    if same_folder_twice([args.run_a, args.run_b]):     # a pasted-twice path would pass the check
        raise CliError(f"RUN_A and RUN_B are the same folder ({str(Path(args.run_a).resolve())!r}); "
                       f"compare two different runs")
    warnings: list[str] = []
    a = load_run(args.run_a, warnings=warnings)
    b = load_run(args.run_b, warnings=warnings)
    diff = diff_runs(a, b, args.episodes, ignore, args.tolerance, common=args.common)
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
    print("\n".join(report_lines(a, b, diff, args.show)))
    return 0 if diff.same else 1
