"""The run folder: where a batch's results live, and every rule for reading and writing it, so that
a folder is never mixed, lost or half-written whoever writes it (simulated batches, ``tasks.trials``;
hardware trials, ``tasks.hardware``; ``tools spot``) and the report reads it by the same rules.
Layout checks; config.yaml against the records' configuration fingerprints (resume, extend or
refuse); damaged lines of episodes.jsonl moved aside, never deleted; durable writes (atomic
replace, fsynced append); the lock; the log of invocations and the CPU code paths they ran on.

Run folder layout: ``config.yaml`` (resolved trial config, package version, git commit),
``episodes.jsonl`` (one line per episode, in the order episodes finished), ``summary.json``,
``invocations.jsonl`` (one line per command that worked on the folder: workers, executor, host,
commit), ``recordings/<episode_id>.rrd`` (``record=N``), ``episodes/<episode_id>.npz`` (the data of
each episode's pictures in the trial report, ``tasks.episode_trace``), and a ``.lock`` that keeps two batches
from writing the same folder.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np

from helios.runtime import cpu_dispatch, cpu_model
from helios.schema import ConfigError, dump_yaml, finite_number, from_dict, read_text, shorten, yaml_load_text
from tasks.provenance import PROVENANCE_KEYS, differs, git_commit, package_version, provenance
from tasks.trial_config import (FINGERPRINT_FIELD, TrialConfig, config_difference, config_fingerprint, config_text,
                                deterministic_view, is_extension)
from tasks.trial_summary import METRIC_KEYS, PHASE_TIME_KEYS

DAMAGED_FILE = "episodes.damaged.jsonl"      # damaged lines of episodes.jsonl, moved here by a resume
# Files of a run folder (a directory in their place is one clear error, never a traceback).
DIGESTS_FILE = "episode_digests.json"        # episode id -> digest of the episode a record was made from
FOLDER_FILES = ("config.yaml", "episodes.jsonl", "summary.json", "invocations.jsonl", ".lock", DAMAGED_FILE,
                DIGESTS_FILE)


class RunFolderError(ValueError):
    """The run folder holds results of a different configuration, is in use, or is unreadable."""


def write_atomic(path: Path, text: str) -> None:
    """Write a text file so that a reader sees the old or the new whole file, never a part."""
    write_bytes_atomic(path, text.encode())


def read_run_config(out: Path) -> tuple[dict, TrialConfig]:
    """The header (``helios_version``, ``git_commit``) and the trial config saved in a run folder."""
    header, _, config = _read_saved_config(Path(out))
    return header, config


def read_config_body(cfg_path: Path) -> tuple[dict, dict]:
    """A run folder's config.yaml as written: its provenance header and the rest (the body, which
    the fingerprint is taken of); one-line RunFolderError when it is not a YAML mapping."""
    what = f"{cfg_path}"
    saved = yaml_load_text(read_text(cfg_path, what, RunFolderError), what, RunFolderError)
    if saved is None:
        saved = {}
    if not isinstance(saved, dict):
        raise RunFolderError(f"{cfg_path} is damaged: it holds a {type(saved).__name__}, not a trial config")
    header = {k: saved.pop(k, None) for k in PROVENANCE_KEYS}
    return header, saved


def _read_saved_config(out: Path) -> tuple[dict, dict, TrialConfig]:
    """A run folder's config.yaml: header, the body as written (for its fingerprint) and the trial
    config; one-line RunFolderError when it is not a readable trial config."""
    cfg_path = out / "config.yaml"
    header, saved = read_config_body(cfg_path)
    try:
        return header, saved, from_dict(TrialConfig, saved)
    except ConfigError as exc:
        raise RunFolderError(f"{cfg_path} is not a trial config this version can read: {exc}") from None


def check_folder_layout(out: Path, record: int = 0, pictures: bool = False) -> None:
    """One clear RunFolderError when ``out`` cannot be a run folder: a file in its place or in a
    parent's, or a directory where one of its files belongs. Reads only."""
    out = Path(out)
    for parent in [out, *out.parents]:
        if parent.exists() or parent.is_symlink():
            if not parent.is_dir():
                where = "" if parent == out else f" ({str(parent)!r} is a file)"
                raise RunFolderError(f"run folder {shorten(repr(str(out)))} cannot be made: "
                                     f"{'it is a file' if parent == out else 'a parent is not a directory'}{where}")
            break
    if not out.is_dir():
        return
    for name in FOLDER_FILES:
        if (out / name).is_dir():
            raise RunFolderError(f"run folder {str(out)!r} is damaged: {name} is a directory, where a file belongs; "
                                 f"move it away (or use another --out)")
    if record and (out / "recordings").exists() and not (out / "recordings").is_dir():
        raise RunFolderError(f"run folder {str(out)!r}: recordings is a file, where the recordings folder belongs")
    if pictures and (out / "episodes").exists() and not (out / "episodes").is_dir():
        raise RunFolderError(f"run folder {str(out)!r}: episodes is a file, where the folder of the episodes' "
                             f"pictures belongs; move it away (or use --no-pictures)")


def stale_results(out: Path, config: TrialConfig, commit: str | None = None) -> str | None:
    """Why the results in run folder ``out`` are not what ``config`` gives at this checkout, or None
    (no folder, no results, or the same configuration at the same commit: a resume).

    Two reasons count: a different configuration (a larger ``episodes`` is an extension, not a
    difference) and results written at another commit (``git_commit`` in config.yaml). Anything
    else wrong with the folder (damage) is left to :func:`prepare_run_folder` to report; a missing
    or unreadable config.yaml counts as a different configuration when the records' fingerprints
    say so (the fingerprint leaves out the episode count: an extension still resumes). ``tools
    trials --replace-stale`` moves a stale folder aside (``make run`` uses it, so the README's
    first command shows this checkout's numbers after a pull instead of refusing the folder or
    resuming another version's results)."""
    out = Path(out)
    if not (out / "episodes.jsonl").is_file():
        return None
    try:
        scan = scan_results(out / "episodes.jsonl")
    except RunFolderError:
        return None
    if not scan.records:
        return None
    known = scan.fingerprints() - {None}
    cfg_path = out / "config.yaml"
    try:
        header, _, saved_cfg = _read_saved_config(out) if cfg_path.is_file() else (None, None, None)
    except RunFolderError:
        header = None
    if header is None:
        # no readable config.yaml: the records' fingerprints still say whether they are this
        # configuration's (then prepare_run_folder rewrites it); another's are moved aside, not refused
        # (reliability audit: --replace-stale refused them, and `make run` with it)
        if known and known != {config_fingerprint(config)}:
            return (f"results of a different configuration (config.yaml "
                    f"{'unreadable' if cfg_path.exists() else 'missing'}; the records' fingerprint is {next(iter(known))})")
        return None
    diff = config_difference(saved_cfg, config)
    if diff and not is_extension(diff, saved_cfg, config):
        return f"results of a different configuration (differs in: {', '.join(diff)})"
    made, now = header.get("git_commit"), commit if commit is not None else git_commit()
    if differs(made, now):
        return f"results of commit {made[:10]} (this checkout is {now[:10]})"
    changed = agent_source_changed(out, config.agent)
    if changed:
        return f"results of other source of agent {config.agent} ({changed}; now {plugin_source(config.agent)})"
    return None


def plugin_source(agent: str) -> str | None:
    """The source digest of a plugin agent (:mod:`tasks.plugin_agents`); None for a registered one."""
    from tasks.plugin_agents import is_plugin_spec, source_digest

    return source_digest(agent) if is_plugin_spec(agent) else None


def agent_source_changed(out: Path, agent: str) -> str | None:
    """The earlier source digests of a plugin agent whose episodes a run folder holds, when they
    are not this source's (a resume would mix two versions of the agent); else None."""
    now = plugin_source(agent)
    if now is None:
        return None
    other = [d for d in run_agent_sources(out) if d != now]
    return ", ".join(other) if other else None


def move_aside(out: Path, stamp: str | None = None) -> Path:
    """Rename run folder ``out`` to ``<out>.<YYYYmmdd-HHMMSS>`` (``.2``, ``.3`` ... if taken), under
    its lock so that a batch still writing there is never moved; returns the new path."""
    out = Path(out)
    stamp = stamp or time.strftime("%Y%m%d-%H%M%S")
    dest, n = out.with_name(f"{out.name}.{stamp}"), 1
    while dest.exists():
        n += 1
        dest = out.with_name(f"{out.name}.{stamp}.{n}")
    with FolderLock(out):
        try:
            out.rename(dest)
        except OSError as exc:
            raise RunFolderError(f"cannot move run folder {str(out)!r} aside to {str(dest)!r}: "
                                 f"{exc.strerror or exc}") from None
    return dest


def prepare_run_folder(out: Path, config: TrialConfig, report: "BatchReport | None" = None,
                       dry_run: bool = False, episode_ids: Iterable[str] | None = None,
                       episode_source: str = "the run's episodes",
                       episode_tasks: dict[str, str] | None = None,
                       episode_digests: dict[str, str] | None = None) -> dict[str, dict]:
    """Create or reopen a run folder; returns the episodes already finished (by id).

    Reopening checks that the configuration is the one that made the results (results of
    different configs never mix): config.yaml must equal ``config``, and every record's
    fingerprint must match config.yaml (or, with config.yaml missing or unreadable, ``config``).
    The one allowed difference is a larger ``episodes``: episodes are a prefix of the split and
    each one's seed depends only on (seed, episode id), so a 100-episode run extended to 200 gives
    exactly the numbers of a fresh 200-episode run; config.yaml then records the new count. A
    smaller one is allowed only where every record is among the episodes it selects (given
    ``episode_ids``): an extension stopped before it finished an episode beyond them. A folder
    that holds no results takes the new configuration.

    Damaged lines of episodes.jsonl (a torn last line after a kill, or any line that is not a
    valid record) are moved to ``episodes.damaged.jsonl``, never deleted; their episodes run
    again; so are records of one episode that disagree (a re-run settles which is right) and, given
    ``episode_ids`` (the episodes this configuration selects), records of other episodes (see
    :func:`scan_results`). All checks happen before anything is written. ``report`` (a BatchReport) receives the
    fingerprint new records get, the saved commit and notes on what was repaired. ``dry_run``: only
    the checks (a command line refuses a folder before it creates or locks anything).
    ``episode_tasks`` (episode id -> task, of the episodes about to run): a finished record of one
    of them with another task is refused, since the episodes changed under the same configuration
    (an episode file edited or regenerated, or a relative ``--episodes-file`` that names another
    file from another working directory; the fingerprint holds the file's name, not its contents).
    ``episode_digests`` (episode id -> :func:`episode_digest`) does the same for the rest of an
    episode (its home, start pose, goals: an edit that kept the task once resumed into a mix,
    reliability audit), against ``episode_digests.json``, which a run keeps from its first start
    (folders made before it have none, and only the task is checked).
    """
    out = Path(out)
    check_folder_layout(out)
    if dry_run and not out.is_dir():
        return {}
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RunFolderError(f"cannot create run folder {str(out)!r}: {exc.strerror or exc}") from None
    notes: list[str] = []
    scan = scan_results(out / "episodes.jsonl", episode_ids, episode_source)
    for eid, record in scan.records.items() if episode_tasks else ():
        task, now = record.get("task"), episode_tasks.get(eid)
        if isinstance(task, str) and now is not None and task != now:
            raise RunFolderError(f"run folder {str(out)!r}: episode {eid} was run as {shorten(repr(task), 90)}, but "
                                 f"{episode_source} now give {shorten(repr(now), 90)}: the episodes changed since the run "
                                 f"started (an edited or regenerated episode file, or a relative --episodes-file naming "
                                 f"another file from here); use another --out, or the file the run was made with")
    saved_digests, digests_note = _read_digests(out / DIGESTS_FILE)
    for eid in scan.records if episode_digests else ():
        was, now = saved_digests.get(eid), episode_digests.get(eid)
        if was is not None and now is not None and was != now:
            raise RunFolderError(f"run folder {str(out)!r}: episode {eid} changed since it was run (same task, but "
                                 f"its home, start pose or goals in {episode_source} differ from those the run was made "
                                 f"with: an edited or regenerated episode file); use another --out, or the file the "
                                 f"run was made with")
    fps = {r.get(FINGERPRINT_FIELD) for r in scan.records.values()}
    known = scan.fingerprints() - {None}      # a damaged record of another configuration: a mix, never repaired
    cfg_path = out / "config.yaml"
    current = config_fingerprint(config)
    folder_fp, new_config_text, saved_commit, damaged_config = current, None, None, None
    if len(known) > 1:
        raise RunFolderError(f"run folder {str(out)!r} mixes records of {len(known)} configurations (fingerprints "
                             f"{', '.join(sorted(known))}); use another --out")
    try:
        saved = _read_saved_config(out) if cfg_path.exists() else None
    except RunFolderError as exc:
        if scan.records and (None in fps or known != {current}):
            raise RunFolderError(f"{exc}; the records in episodes.jsonl cannot be matched to this configuration, "
                                 f"so the folder cannot be resumed: restore config.yaml or use another --out") from None
        saved, damaged_config = None, str(exc)
    if saved is not None:
        header, body, saved_cfg = saved
        saved_commit = header.get("git_commit")
        saved_fp = config_fingerprint(body)
        if known and known != {saved_fp}:
            raise RunFolderError(f"run folder {str(out)!r}: config.yaml does not describe the records in episodes.jsonl "
                                 f"(they were made with configuration {next(iter(known))}, config.yaml says {saved_fp}): "
                                 f"it was edited or replaced after they were written; restore it or use another --out")
        # (no difference also when only the spelling of episodes_file differs: the folder keeps its own)
        diff = config_difference(saved_cfg, config)
        if not scan.records:                        # nothing to protect: the folder takes this configuration
            if saved_cfg != config or saved_fp != current:
                new_config_text = config_text(config)
            if diff:
                notes.append("config.yaml of a run without results was replaced by this configuration")
        elif diff:
            # fewer episodes, but every record is one of them: an extension cut short before it
            # finished an episode beyond this count (config.yaml is written when a run starts)
            held = set(scan.records) | {r["episode_id"] for r in scan.unused}
            back_from_extension = diff == ["episodes"] and not is_extension(diff, saved_cfg, config) and \
                episode_ids is not None and held <= set(episode_ids)
            if is_extension(diff, saved_cfg, config) or back_from_extension:
                new_config_text = dump_yaml(provenance()) + dump_yaml({**body, "episodes": config.episodes})
                folder_fp = saved_fp
                if back_from_extension:
                    notes.append(f"config.yaml said {saved_cfg.episodes} episodes, but every finished one is among "
                                 f"the first {config.episodes} (an extension stopped early): it now says "
                                 f"{config.episodes}")
            elif diff == ["episodes"]:
                raise RunFolderError(f"run folder {str(out)!r} holds a run of {saved_cfg.episodes} episodes; "
                                     f"a run can be extended but not shortened (asked for {config.episodes}); "
                                     f"use another --out, or `tools report` to look at part of a run")
            else:
                raise RunFolderError(f"run folder {str(out)!r} holds results of a different configuration "
                                     f"(differs in: {', '.join(diff)}); use another --out to start a new run")
        else:
            folder_fp = saved_fp
    else:
        if scan.records and None in fps:
            raise RunFolderError(f"run folder {str(out)!r}: config.yaml is missing and the records in episodes.jsonl "
                                 f"carry no configuration fingerprint (written by an older version), so nothing "
                                 f"says which configuration made them; restore config.yaml or use another --out")
        if scan.records and known != {current}:
            raise RunFolderError(f"run folder {str(out)!r}: config.yaml is "
                                 f"{'unreadable' if damaged_config else 'missing'} and the records in episodes.jsonl "
                                 f"were made with a different configuration (fingerprint {next(iter(known))}, this "
                                 f"one is {current}); use another --out, or restore config.yaml")
        new_config_text = config_text(config)
        if damaged_config:
            notes.append(f"{damaged_config}; moved it to {cfg_path.name}.damaged and wrote this configuration "
                         f"(the records' fingerprints match it)")
        elif scan.records:
            notes.append("config.yaml was missing; rewrote it (the records' fingerprints match this configuration)")
    # Every check has passed: now write.
    if dry_run:
        return dict(scan.records)
    if scan.damaged:
        quarantine(out / "episodes.jsonl", scan)
        torn = [d for d in scan.damaged if d.torn]
        bad = [d for d in scan.damaged if not d.torn]
        if bad:
            notes.append(f"moved {len(bad)} damaged line(s) of episodes.jsonl to {DAMAGED_FILE} ("
                         + "; ".join(f"line {d.lineno}: {d.reason}" for d in bad[:5])
                         + (f"; and {len(bad) - 5} more" if len(bad) > 5 else "") + "); episodes without a valid record run again")
        if torn:
            notes.append(f"moved the torn last line of episodes.jsonl (an interrupted write) to {DAMAGED_FILE}")
    if new_config_text is not None:
        if damaged_config:
            _move_aside(cfg_path)
        write_atomic(cfg_path, new_config_text)
    if episode_digests:
        if digests_note:
            notes.append(digests_note)
        merged = {**saved_digests, **episode_digests}
        if merged != saved_digests:
            write_atomic(out / DIGESTS_FILE, json.dumps(merged, indent=0, sort_keys=True) + "\n")
    if report is not None:
        report.fingerprint = folder_fp
        report.saved_commit = saved_commit
        report.notes.extend(notes)
    return dict(scan.records)


def episode_digest(episode) -> str:
    """A short digest of everything that defines an episode (its JSON line)."""
    import hashlib

    return hashlib.sha256(episode.to_json().encode()).hexdigest()[:16]


def _read_digests(path: Path) -> tuple[dict[str, str], str | None]:
    """The saved episode digests ({} when none) and a note when the file was unreadable (it is then
    rewritten from the episodes about to run, as config.yaml is)."""
    if not path.exists():
        return {}, None
    try:
        data = json.loads(path.read_text(encoding="utf-8")) if path.is_file() else None
    except (OSError, ValueError, RecursionError):
        data = None
    if isinstance(data, dict) and all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
        return data, None
    return {}, f"{path.name} was unreadable; rewrote it (the episodes' tasks were still checked)"


def _move_aside(path: Path) -> None:
    target = path.with_name(path.name + ".damaged")
    n = 1
    while target.exists():
        n += 1
        target = path.with_name(f"{path.name}.damaged{n}")
    path.replace(target)


@dataclass
class DamagedLine:
    """A line of episodes.jsonl that is not a valid record (1-based line number, why, raw bytes)."""

    lineno: int
    reason: str
    data: bytes
    torn: bool = False              # the last line, without its newline: an interrupted write


@dataclass
class ResultsScan:
    """episodes.jsonl read line by line: the first valid record per episode, the damaged lines."""

    records: dict[str, dict]
    damaged: list[DamagedLine]
    good_lines: list[bytes]         # the valid lines as written, in order (duplicates included)
    legacy: int = 0                 # valid records without a configuration fingerprint
    unused: list[dict] = field(default_factory=list)    # records among the damaged lines (disagreeing
    # with another record of their episode, or of an episode not the run's): their fingerprints still
    # say whether the folder mixes configurations
    repeated_runs: dict[str, int] = field(default_factory=dict)   # robot runs (``tools spot``) of one
    # episode id: how many; the first is in :attr:`records`

    def fingerprints(self) -> set:
        """The configuration fingerprints of every record in the file, damaged ones included (None:
        a record without one); the records used are :attr:`records`."""
        return {r.get(FINGERPRINT_FIELD) for r in [*self.records.values(), *self.unused]}


def record_problem(record) -> str | None:
    """Why a parsed line of episodes.jsonl is not a usable record, or None when it is. Besides the
    numbers the tables use, the fields that name files (``episode_id``: the report's episode pages,
    picture data, recordings) and those the episode pages draw (``collision_events``,
    ``extra.decisions``, ``extra.activity_time``) must have their shapes."""
    from helios.agents.activities import DECISION_COUNTS
    from tasks.episodes import is_episode_id

    if not isinstance(record, dict):
        return f"a JSON {type(record).__name__}, not an episode record"
    eid = record.get("episode_id")
    if not isinstance(eid, str) or not eid:
        return "no episode_id"
    if not is_episode_id(eid):
        return (f"episode_id {shorten(repr(eid), 60)} is not an episode id (1-100 letters, digits, '-', '_' or '.'; "
                f"it names files)")

    def number(v) -> bool:
        return finite_number(v) and v >= 0

    m = record.get("metrics")
    if m is not None:
        if not isinstance(m, dict):
            return "metrics is not an object"
        for key in METRIC_KEYS:
            if not isinstance(m.get(key), bool):
                return f"metrics.{key} is not true/false"
        if m.get("failure_reason") is not None and not isinstance(m.get("failure_reason"), str):
            return "metrics.failure_reason is not a string"
        if "failure_reason" not in m:
            return "metrics.failure_reason is missing"
        if not (number(m.get("collisions")) and float(m["collisions"]).is_integer()):
            return "metrics.collisions is not a count"
        for key in PHASE_TIME_KEYS:
            if m.get(key) is not None and not number(m[key]):
                return f"metrics.{key} is not a non-negative number"
    for key in ("sim_time", "wall_time"):
        if not number(record.get(key)):
            return f"{key} is not a non-negative number"
    if "success" in record and not isinstance(record["success"], bool):
        return "success is not true/false"
    if record.get(FINGERPRINT_FIELD) is not None and not isinstance(record[FINGERPRINT_FIELD], str):
        return f"{FINGERPRINT_FIELD} is not a string"
    events = record.get("collision_events")
    if events is not None:
        if not isinstance(events, list) or not all(isinstance(c, dict) for c in events):
            return "collision_events is not a list of objects"
        if not all(c.get("time") is None or number(c["time"]) for c in events):
            return "collision_events: a time is not a non-negative number"
    extra = record.get("extra")
    if extra is not None and not isinstance(extra, dict):
        return "extra is not an object"
    decisions = (extra or {}).get("decisions")
    if decisions is not None:
        if not isinstance(decisions, dict):
            return "extra.decisions is not an object"
        for key in DECISION_COUNTS:
            if decisions.get(key) is not None and not (number(decisions[key]) and float(decisions[key]).is_integer()):
                return f"extra.decisions.{key} is not a count"
        sizes = decisions.get("local_search_sizes")
        if sizes is not None and not (isinstance(sizes, list) and all(number(v) for v in sizes)):
            return "extra.decisions.local_search_sizes is not a list of counts"
    activity = (extra or {}).get("activity_time")
    if activity is not None and not (isinstance(activity, dict) and all(v is None or number(v)
                                                                          for v in activity.values())):
        return "extra.activity_time is not an object of non-negative seconds"
    mem = record.get("memory")
    if mem is not None:
        if not isinstance(mem, dict):
            return "memory is not an object"
        for key in ("peak_rss_mb", "map_mb_peak", "gpu_allocated_mb_peak", "gpu_reserved_mb_peak"):
            if mem.get(key) is not None and not number(mem[key]):
                return f"memory.{key} is not a number"
        series = mem.get("series")
        if series is not None:
            if not isinstance(series, dict) or not isinstance(series.get("t", []), list):
                return "memory.series is malformed"
            n = len(series.get("t", []))
            for key, vals in series.items():
                if not isinstance(vals, list) or len(vals) != n or not all(
                        v is None or finite_number(v)
                        for v in vals):
                    return f"memory.series.{key} is malformed"
    return None


def scan_results(path: Path, episode_ids: Iterable[str] | None = None,
                 episode_source: str = "the run's episodes") -> ResultsScan:
    """Read episodes.jsonl without changing it: every line is a valid record or a damaged line
    (with its line number and why). RunFolderError when the file itself cannot be read.

    Besides lines that are not records (:func:`record_problem`), damaged are: records of the same
    episode that disagree (their deterministic fields differ: nothing says which is right, so every
    record of that episode is damaged; identical copies are kept and the first one used), and,
    given ``episode_ids`` (the episodes the run's configuration selects, ``episode_source`` says
    which), records of other episodes."""
    path = Path(path)
    scan = ResultsScan({}, [], [])
    if path.is_dir():
        raise RunFolderError(f"{path} is a directory, where the results file belongs; move it away")
    if not path.exists():
        return scan
    if not path.is_file():                 # a FIFO: reading it would wait for a writer for ever
        raise RunFolderError(f"{path} is not a regular file (a FIFO, device or socket), where the results file "
                             f"belongs; move it away")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise RunFolderError(f"cannot read {path}: {exc.strerror or exc}") from None
    valid: list[tuple[int, bytes, dict]] = []
    for lineno, line in enumerate(_lines_of(data), 1):
        if not line.endswith(b"\n"):
            scan.damaged.append(DamagedLine(lineno, "torn last line (an interrupted write)", line, torn=True))
            break
        if not line.strip():
            scan.damaged.append(DamagedLine(lineno, "empty line", line))
            continue
        try:
            record = json.loads(line.decode("utf-8"))
        except UnicodeDecodeError:
            scan.damaged.append(DamagedLine(lineno, "not UTF-8 text", line))
            continue
        except (json.JSONDecodeError, RecursionError) as exc:
            scan.damaged.append(DamagedLine(lineno, f"not valid JSON ({getattr(exc, 'msg', 'too deeply nested')})",
                                            line))
            continue
        except ValueError as exc:                 # an integer of over 4,300 digits
            scan.damaged.append(DamagedLine(lineno, f"not valid JSON ({shorten(exc, 80)})", line))
            continue
        problem = record_problem(record)
        if problem:
            scan.damaged.append(DamagedLine(lineno, problem, line))
            continue
        valid.append((lineno, line, record))
    by_episode: dict[str, list[tuple[int, dict]]] = {}
    for lineno, _line, record in valid:
        by_episode.setdefault(record["episode_id"], []).append((lineno, record))
    # Robot runs (records with a ``hardware`` section: `tools spot`) are not replays: two runs of one
    # episode differ by nature (robot clock, operator's answers), so they never "disagree"; the first
    # is used, as for simulated duplicates, and ``repeated_runs`` says how many there were.
    robot = {eid for eid, entries in by_episode.items() if any("hardware" in r for _, r in entries)}
    scan.repeated_runs = {eid: len(by_episode[eid]) for eid in sorted(robot) if len(by_episode[eid]) > 1}
    conflicts = {eid: _conflict(entries) for eid, entries in by_episode.items() if len(entries) > 1 and eid not in robot}
    conflicts = {eid: fields for eid, fields in conflicts.items() if fields}
    allowed = None if episode_ids is None else set(episode_ids)
    for lineno, line, record in valid:
        eid = record["episode_id"]
        if eid in conflicts:
            others = ", ".join(str(n) for n, _ in by_episode[eid] if n != lineno)
            scan.damaged.append(DamagedLine(lineno, f"episode {eid} has records that disagree (this one and line(s) "
                                                    f"{others}, in {conflicts[eid]}); none of them is used", line))
            scan.unused.append(record)
            continue
        if allowed is not None and eid not in allowed:
            scan.damaged.append(DamagedLine(lineno, f"episode {eid} is not one of {episode_source}", line))
            scan.unused.append(record)
            continue
        scan.good_lines.append(line)
        if eid not in scan.records:
            scan.records[eid] = record
            scan.legacy += record.get(FINGERPRINT_FIELD) is None
    scan.damaged.sort(key=lambda d: d.lineno)
    return scan


def _lines_of(data: bytes) -> list[bytes]:
    """The file's lines, each ending in its newline (the last may be torn): split at b"\\n" only.
    ``bytes.splitlines`` also splits at a lone CR (and \\v, \\f, \\x1c..\\x1e): one CR byte in a
    middle record read as a torn last line, every record after it was dropped, and a resume
    rewrote the file without them (reliability audit)."""
    parts = data.split(b"\n")
    return [part + b"\n" for part in parts[:-1]] + ([parts[-1]] if parts[-1] else [])


def _conflict(entries: list[tuple[int, dict]]) -> str:
    """The top-level fields in which records of one episode differ (wall time, memory and
    recording path aside: :func:`deterministic_view`), as text; "" when they agree."""
    def canon(v) -> str:
        return json.dumps(v, sort_keys=True)

    first = deterministic_view(entries[0][1])
    fields: set[str] = set()
    for _, record in entries[1:]:
        view = deterministic_view(record)
        fields |= {k for k in set(first) | set(view) if canon(first.get(k)) != canon(view.get(k)) or
                   (k in first) != (k in view)}
    shown = sorted(fields)
    return ", ".join(shown[:4]) + (f" and {len(shown) - 4} more field(s)" if len(shown) > 4 else "")


def quarantine(path: Path, scan: ResultsScan) -> None:
    """Move the damaged lines of ``path`` to ``episodes.damaged.jsonl`` next to it (appended, with
    their bytes unchanged; fsynced first) and rewrite ``path`` with the valid lines in order.

    A repair killed between the two steps left the lines in both files; the next one finds the
    side file already ending with exactly these lines and does not append them again (QA
    2026-12-04: three kills at the rename left one damaged line three times)."""
    if not scan.damaged:
        return
    side = Path(path).with_name(DAMAGED_FILE)
    block = b"".join(d.data if d.data.endswith(b"\n") else d.data + b"\n" for d in scan.damaged)
    kept = side.read_bytes() if side.is_file() else b""
    if not (kept.endswith(block) and (len(kept) == len(block) or kept[-len(block) - 1:-len(block)] == b"\n")):
        with naming_the_file(side), side.open("ab") as fh:
            fh.write((b"" if not kept or kept.endswith(b"\n") else b"\n") + block)
            fh.flush()
            os.fsync(fh.fileno())
    write_bytes_atomic(Path(path), b"".join(scan.good_lines))


def read_results(path: Path, repair: bool = False) -> dict[str, dict]:
    """Finished episodes by id (the first valid record of each); damaged lines are skipped (see
    :func:`scan_results`). With ``repair``, they are moved to ``episodes.damaged.jsonl``."""
    scan = scan_results(path)
    if repair:
        quarantine(path, scan)
    return dict(scan.records)


def append_result(path: Path, record: dict) -> dict:
    """Append one record as a JSON line (flushed and fsynced); returns it as read back from JSON.
    After a torn last line (a kill mid-write) the record starts a line of its own, so the torn one
    stays the only damaged line instead of swallowing this record too."""
    text = json.dumps(record, sort_keys=True, default=_json_default)
    with naming_the_file(path), Path(path).open("ab+") as fh:
        lead = b""
        if fh.seek(0, os.SEEK_END) > 0:
            fh.seek(-1, os.SEEK_END)
            lead = b"" if fh.read(1) == b"\n" else b"\n"
        fh.write(lead + (text + "\n").encode())
        fh.flush()
        os.fsync(fh.fileno())
    return json.loads(text)


def _json_default(o):
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"cannot serialise {type(o).__name__}")


class FolderLock:
    """An exclusive advisory lock on ``out/.lock`` (released by the kernel even on SIGKILL)."""

    def __init__(self, out: Path):
        self.path = out / ".lock"
        self.fh = None

    def __enter__(self):
        try:
            import fcntl
        except ImportError:  # pragma: no cover - Windows: no lock
            return self
        if self.path.is_dir():
            raise RunFolderError(f"run folder {str(self.path.parent)!r} is damaged: .lock is a directory, where the "
                                 f"lock file belongs; move it away (or use another --out)")
        try:
            self.fh = self.path.open("a+")
        except OSError as exc:
            raise RunFolderError(f"cannot lock run folder {str(self.path.parent)!r}: {exc.strerror or exc}") from None
        try:
            fcntl.flock(self.fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self.fh.seek(0)
            owner = self.fh.read().strip() or "another process"
            self.fh.close()
            raise self._in_use(owner) from None
        self.fh.seek(0)
        self.fh.truncate()
        self.fh.write(f"pid {os.getpid()} on {socket.gethostname()}")
        self.fh.flush()
        return self

    def _in_use(self, owner: str) -> RunFolderError:
        return RunFolderError(f"run folder {str(self.path.parent)!r} is in use by {owner}; "
                              f"wait for it to finish or use another --out")

    def check_free(self) -> None:
        """RunFolderError when another process holds the lock now; takes nothing and writes nothing
        (a command checks before it prints or starts anything; ``with FolderLock`` still decides)."""
        try:
            import fcntl
        except ImportError:  # pragma: no cover - Windows: no lock
            return
        if not self.path.is_file():
            return
        try:
            with self.path.open("r") as fh:
                try:
                    fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError:
                    raise self._in_use(fh.read().strip() or "another process") from None
                fcntl.flock(fh.fileno(), fcntl.LOCK_UN)
        except OSError:
            return                       # unreadable: `with FolderLock` reports it

    def __exit__(self, *exc):
        if self.fh is not None:
            try:                         # leave the folder as it was: an empty lock file
                self.fh.seek(0)
                self.fh.truncate()
            except OSError:
                pass
            self.fh.close()


@contextlib.contextmanager
def naming_the_file(path: Path):
    """An OSError from writing to an open file (a full disk, an I/O error) carries no file name,
    so the one error line said only "[Errno 28] No space left on device" (QA 2026-12-04): name it."""
    try:
        yield
    except OSError as exc:
        if exc.filename is not None or exc.errno is None:
            raise
        raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from exc


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write to a temporary file, fsync, rename: a kill leaves the old file or the new one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with naming_the_file(tmp), tmp.open("wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    tmp.replace(path)


def invocation_cpu(entry: dict) -> str:
    """The CPU code paths one line of ``invocations.jsonl`` ran under, as one short string:
    the pin (``helios.runtime``) and NumPy's and torch's kernels where recorded; ``not recorded``
    for lines written before 2026-12-03, when runs did not say (and nothing was pinned)."""
    cpu = entry.get("cpu") if isinstance(entry, dict) else None
    if not isinstance(cpu, dict):
        return "not recorded"
    return ", ".join([str(cpu.get("pin", "?"))] + [f"{k} {cpu[k]}" for k in ("numpy", "torch") if k in cpu])


def cpu_paths_now() -> str:
    """:func:`invocation_cpu` of this process (and of the workers, which inherit its environment)."""
    return invocation_cpu({"cpu": cpu_dispatch()})


def read_invocations(out: Path) -> tuple[list[dict], list[int]]:
    """The entries of a run folder's ``invocations.jsonl``, and the line numbers (1-based) of its
    damaged lines: not JSON (a torn last line after a kill, an edit) or not an object. Both empty
    without the file. The log is informative, never a reason to fail: the report names the damaged
    lines, the rest skip them."""
    path = Path(out) / "invocations.jsonl"
    if not path.is_file():
        return [], []
    entries, bad = [], []
    for number, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        if not line.strip():
            continue
        try:
            entry = json.loads(line)
        except ValueError:
            entry = None
        if isinstance(entry, dict):
            entries.append(entry)
        else:
            bad.append(number)
    return entries, bad


def run_cpu_paths(out: Path) -> list[str]:
    """The distinct CPU code paths (:func:`invocation_cpu`) of the invocations that ran episodes
    in a run folder, in the order first seen; empty when it has no ``invocations.jsonl``.
    Episodes run on different code paths can differ in outcome (README, "One CPU code path")."""
    return _distinct(invocation_cpu(entry) for entry in _episode_invocations(out))


def run_cpu_models(out: Path) -> list[str]:
    """The distinct CPU models (``model name`` of /proc/cpuinfo) of the invocations that ran
    episodes in a run folder, in the order first seen; invocations written before 2026-12-05 did
    not record it and are left out. The same code on the same pinned code path can still give
    other records on another CPU (README, "One CPU code path")."""
    return _distinct(e["cpu_model"] for e in _episode_invocations(out) if isinstance(e.get("cpu_model"), str))


def _episode_invocations(out: Path) -> list[dict]:
    """The entries of ``invocations.jsonl`` that ran episodes."""
    return [entry for entry in read_invocations(out)[0] if entry.get("episodes_to_run")]


def _distinct(values) -> list[str]:
    """``values`` without repeats, in the order first seen."""
    return list(dict.fromkeys(values))


def run_agent_sources(out: Path) -> list[str]:
    """The distinct source digests of a plugin agent (``agent_source``, :mod:`tasks.plugin_agents`)
    that the invocations which ran episodes in a run folder logged, in the order first seen; empty
    for a registered agent (its code is the commit's)."""
    return _distinct(e["agent_source"] for e in _episode_invocations(out) if isinstance(e.get("agent_source"), str))


def log_invocation(out: Path, workers: int, executor: str, address: str, todo: int, commit: str,
                   agent_source: str | None = None) -> None:
    """One line of ``invocations.jsonl``: who ran how many episodes where, with which code (the
    commit, the CPU code paths, and a plugin agent's source digest, ``agent_source``)."""
    entry = {"time": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "host": socket.gethostname(), "pid": os.getpid(),
             "argv": sys.argv, "workers": workers, "executor": executor,
             "address": address if executor == "ray" else None, "episodes_to_run": todo,
             "helios_version": package_version(), "git_commit": commit, "cpu": cpu_dispatch(),
             "cpu_model": cpu_model()}
    if agent_source is not None:
        entry["agent_source"] = agent_source
    append_result(out / "invocations.jsonl", entry)
