"""Trial batches: run an agent over episodes, append one JSON line per finished episode (flushed and
fsynced, so a killed batch resumes with nothing lost or duplicated), and summarise the metrics
OVMM-style (percentages with standard errors).

Run folder layout: ``config.yaml`` (resolved trial config, package version, git commit),
``episodes.jsonl`` (one line per episode, in the order episodes finished), ``summary.json``,
``invocations.jsonl`` (one line per command that worked on the folder: workers, executor, host,
commit), ``recordings/<episode_id>.rrd`` (``record=N``), ``episodes/<episode_id>.npz`` (the data of
each episode's pictures in the trial report, ``tasks.episode_trace``), and a ``.lock`` that keeps two batches
from writing the same folder.

Determinism: an episode's numbers depend only on the config and (master seed, episode id)
(:func:`episode_seed`), never on the order, the number of workers, the executor, resumption or
recording. The fields in :data:`NONDETERMINISTIC_FIELDS` (wall-clock time, memory, recording path)
vary between identical runs; everything else in a record is reproduced exactly
(:func:`deterministic_view`).

Workers never write the run folder: the process running :func:`run_batch` collects each result
from its executor (``tasks.executors``: in-process, local processes, Ray) and appends it.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import shutil
import socket
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from helios.agents.config import AgentConfig
from helios.config import HeliosConfig
from helios.runtime import cpu_dispatch
from helios.schema import (ConfigError, dump_yaml, from_dict, load_config, read_config_file, read_text, require,
                           require_range, short_repr, shorten, to_dict, yaml_load_text)
from robots.spot.sim_backend import SimBackendConfig
from sim.perception.config import SimPerceptionConfig
from tasks.executors import WORKER_EPISODES
from tasks.episodes import Episode
from tasks.metrics import FAILURE_REASONS
from tasks.provenance import PROVENANCE_KEYS, differs, git_commit, package_version, provenance
from tasks.registry import RunContext, make_agent
from tasks.runner import RunnerConfig, run_sim_episode

METRIC_KEYS = ("find_obj", "pick", "find_rec", "place", "success")
PHASE_TIME_KEYS = ("find_obj_time", "pick_time", "find_rec_time")   # simulated s to the phase (None: never)
METRIC_NAMES = {"find_obj": "FindObj", "pick": "Pick", "find_rec": "FindRec", "place": "Place", "success": "SR"}
NONDETERMINISTIC_FIELDS = ("wall_time", "memory", "recording")
FINGERPRINT_FIELD = "config_fingerprint"     # in every record: config_fingerprint() of the config that made it
DAMAGED_FILE = "episodes.damaged.jsonl"      # damaged lines of episodes.jsonl, moved here by a resume
# Files of a run folder (a directory in their place is one clear error, never a traceback).
FOLDER_FILES = ("config.yaml", "episodes.jsonl", "summary.json", "invocations.jsonl", ".lock", DAMAGED_FILE)


@dataclass(frozen=True)
class TrialConfig:
    """Everything that determines a batch's numbers (saved as config.yaml in the run folder)."""

    agent: str = "oracle"
    split: str = "smoke"
    episodes_file: str = ""          # overrides ``split`` when set
    episodes: int = 20               # how many episodes of the split (from the start)
    seed: int = 0                    # master seed: each episode's RNG derives from (seed, episode id)
    sim: SimBackendConfig = field(default_factory=lambda: SimBackendConfig(stream_hz=0.0))
    runner: RunnerConfig = RunnerConfig()
    # HELIOS agents only (the oracle ignores them); a variant's own settings (helios.agents.variants)
    # and the "-gt" suffix (perception.mode) take precedence over these.
    agent_config: AgentConfig = field(default_factory=AgentConfig)
    helios: HeliosConfig = field(default_factory=HeliosConfig)
    perception: SimPerceptionConfig = field(default_factory=SimPerceptionConfig)

    def __post_init__(self) -> None:
        require(bool(self.agent.strip()), "agent must be a non-empty name")
        require_range(self, "episodes", 1, 10_000_000)
        require_range(self, "seed", 0, 2 ** 32 - 1)     # numpy seeds are non-negative
        from sim.scenes.catalog import ALL_CATEGORIES

        # A task's classes are categories of the simulator (tasks.spec); HELIOS's map refuses a
        # task class named like its background class (helios.maps.classes.ClassSet.from_task), so
        # such a background name would end every episode that names it on a MapInputError.
        require(self.helios.background_class not in ALL_CATEGORIES,
                f"helios.background_class {short_repr(self.helios.background_class, 40)} is a category of the "
                f"simulator, which clashes with the task classes of the episodes that name it; use a name that "
                f"is not a category (default 'other')")


def check_devices(config: TrialConfig) -> None:
    """ConfigError, before any work, when ``config`` asks for a torch device this machine lacks:
    ``helios.device=cuda`` for a HELIOS agent (the oracle ignores ``helios``) without a CUDA
    device. Its episodes would otherwise each end on that ConfigError, counted as failures."""
    from helios.agents.variants import VARIANTS

    if config.helios.device != "cuda" or config.agent.removesuffix("-gt") not in VARIANTS:
        return
    from helios.maps.hierarchical import resolve_device

    try:
        resolve_device("cuda")
    except ConfigError as exc:
        raise ConfigError(f"helios.device=cuda: {exc}") from None


class RunFolderError(ValueError):
    """The run folder holds results of a different configuration, is in use, or is unreadable."""


class EpisodeSetupError(RuntimeError):
    """An episode failed outside the agent (building the scene, making the agent): the batch stops.
    The message is one line; ``trace`` holds the worker's traceback."""

    def __init__(self, message: str, trace: str = ""):
        super().__init__(message)
        self.trace = trace


def episode_seed(master_seed: int, episode_id: str) -> int:
    """A stable per-episode seed: independent of order, workers and resumption."""
    state = np.random.SeedSequence([master_seed, *episode_id.encode()]).generate_state(1)[0]
    return int(state % (2 ** 31 - 1))


def deterministic_view(record: dict) -> dict:
    """A record without the fields that vary between identical runs (wall clock, memory, paths)."""
    return {k: v for k, v in record.items() if k not in NONDETERMINISTIC_FIELDS}


def config_text(config: TrialConfig | dict) -> str:
    """A run folder's config.yaml: the provenance header, then the configuration."""
    return dump_yaml(provenance()) + dump_yaml(config)


def config_fingerprint(config: TrialConfig | dict) -> str:
    """A short hash of a trial configuration (a TrialConfig, or a run folder's config.yaml as
    loaded), without its provenance (version, commit) and without ``episodes`` (extending a run
    keeps its fingerprint). Every record carries the fingerprint of the configuration that made
    it, so a folder whose records disagree with its config.yaml (edited, replaced or deleted) is
    recognised."""
    d = dict(to_dict(config)) if not isinstance(config, dict) else dict(config)
    for key in (*PROVENANCE_KEYS, "episodes"):
        d.pop(key, None)
    text = json.dumps(d, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def write_atomic(path: Path, text: str) -> None:
    """Write a text file so that a reader sees the old or the new whole file, never a part."""
    _write_bytes_atomic(path, text.encode())


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


def load_trial_config(path: str | Path) -> tuple[dict, TrialConfig]:
    """A scenario file (``configs/*.yaml``) or a run folder's ``config.yaml``: its provenance
    (``helios_version``, ``git_commit``; None where absent, as in a hand-written scenario) and the
    trial config. Any other unknown key is a ConfigError naming the file and the key."""
    data = read_config_file(path)
    header = {k: data.get(k) for k in PROVENANCE_KEYS}
    return header, load_config(TrialConfig, path, ignore=PROVENANCE_KEYS)


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
    else wrong with the folder (damage, a missing config.yaml) is left to :func:`prepare_run_folder`
    to report. ``tools trials --replace-stale`` moves a stale folder aside (``make run`` uses it, so
    the README's first command shows this checkout's numbers after a pull instead of refusing the
    folder or resuming another version's results)."""
    out = Path(out)
    if not (out / "episodes.jsonl").is_file() or not (out / "config.yaml").is_file():
        return None
    try:
        if not scan_results(out / "episodes.jsonl").records:
            return None
        header, _, saved_cfg = _read_saved_config(out)
    except RunFolderError:
        return None
    diff = config_difference(saved_cfg, config)
    if diff and not is_extension(diff, saved_cfg, config):
        return f"results of a different configuration (differs in: {', '.join(diff)})"
    made, now = header.get("git_commit"), commit if commit is not None else git_commit()
    if differs(made, now):
        return f"results of commit {made[:10]} (this checkout is {now[:10]})"
    return None


def config_difference(saved: TrialConfig, config: TrialConfig) -> list[str]:
    """The top-level keys where ``config`` differs from a run folder's ``saved`` configuration."""
    if saved == config:
        return []
    old = to_dict(saved)
    return [k for k, v in to_dict(config).items() if old.get(k) != v]


def is_extension(diff: list[str], saved: TrialConfig, config: TrialConfig) -> bool:
    """Whether the only difference is more episodes: a run may be extended, never shortened."""
    return diff == ["episodes"] and config.episodes > saved.episodes


def move_aside(out: Path, stamp: str | None = None) -> Path:
    """Rename run folder ``out`` to ``<out>.<YYYYmmdd-HHMMSS>`` (``.2``, ``.3`` ... if taken), under
    its lock so that a batch still writing there is never moved; returns the new path."""
    out = Path(out)
    stamp = stamp or time.strftime("%Y%m%d-%H%M%S")
    dest, n = out.with_name(f"{out.name}.{stamp}"), 1
    while dest.exists():
        n += 1
        dest = out.with_name(f"{out.name}.{stamp}.{n}")
    with _FolderLock(out):
        try:
            out.rename(dest)
        except OSError as exc:
            raise RunFolderError(f"cannot move run folder {str(out)!r} aside to {str(dest)!r}: "
                                 f"{exc.strerror or exc}") from None
    return dest


def prepare_run_folder(out: Path, config: TrialConfig, report: "BatchReport | None" = None,
                       dry_run: bool = False, episode_ids: Iterable[str] | None = None,
                       episode_source: str = "the run's episodes") -> dict[str, dict]:
    """Create or reopen a run folder; returns the episodes already finished (by id).

    Reopening checks that the configuration is the one that made the results (results of
    different configs never mix): config.yaml must equal ``config``, and every record's
    fingerprint must match config.yaml (or, with config.yaml missing or unreadable, ``config``).
    The one allowed difference is a larger ``episodes``: episodes are a prefix of the split and
    each one's seed depends only on (seed, episode id), so a 100-episode run extended to 200 gives
    exactly the numbers of a fresh 200-episode run; config.yaml then records the new count. A
    folder that holds no results takes the new configuration.

    Damaged lines of episodes.jsonl (a torn last line after a kill, or any line that is not a
    valid record) are moved to ``episodes.damaged.jsonl``, never deleted; their episodes run
    again; so are records of one episode that disagree (a re-run settles which is right) and, given
    ``episode_ids`` (the episodes this configuration selects), records of other episodes (see
    :func:`scan_results`). All checks happen before anything is written. ``report`` (a BatchReport) receives the
    fingerprint new records get, the saved commit and notes on what was repaired. ``dry_run``: only
    the checks (a command line refuses a folder before it creates or locks anything).
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
        if not scan.records:                        # nothing to protect: the folder takes this configuration
            if saved_cfg != config or saved_fp != current:
                new_config_text = config_text(config)
            if saved_cfg != config:
                notes.append("config.yaml of a run without results was replaced by this configuration")
        elif saved_cfg != config:
            diff = config_difference(saved_cfg, config)
            if is_extension(diff, saved_cfg, config):
                new_config_text = dump_yaml(provenance()) + dump_yaml({**body, "episodes": config.episodes})
                folder_fp = saved_fp
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
    if report is not None:
        report.fingerprint = folder_fp
        report.saved_commit = saved_commit
        report.notes.extend(notes)
    return dict(scan.records)


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
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0

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
                        v is None or (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v))
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
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise RunFolderError(f"cannot read {path}: {exc.strerror or exc}") from None
    valid: list[tuple[int, bytes, dict]] = []
    for lineno, line in enumerate(data.splitlines(keepends=True), 1):
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


def run_episode_ids(config: "TrialConfig | dict") -> tuple[list[str], str] | None:
    """The episodes a run folder of trial configuration ``config`` (a TrialConfig, or its
    config.yaml as loaded) holds records of: the first ``episodes`` of its split or episode file,
    and a description of them; None when that cannot be told (not a trial configuration, e.g. a
    hardware run's; an episode file that cannot be read)."""
    from tasks.episodes import DatasetError, load_episodes, load_split

    d = to_dict(config) if isinstance(config, TrialConfig) else config
    if not isinstance(d, dict):
        return None
    split, source, count = d.get("split"), d.get("episodes_file") or "", d.get("episodes")
    if not isinstance(count, int) or isinstance(count, bool) or count < 1 or not isinstance(source, str) or \
            (not source and not isinstance(split, str)):
        return None
    try:
        episodes = load_episodes(source) if source else load_split(split)
    except (DatasetError, OSError, ValueError):
        return None
    where = f"episode file {source}" if source else f"split {split}"
    return [e.episode_id for e in episodes[:count]], f"the run's {min(count, len(episodes))} episodes ({where}, " \
                                                     f"config.yaml)"


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
    _write_bytes_atomic(Path(path), b"".join(scan.good_lines))


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


# ------------------------------------------------------------------------------------------------
# One episode
# ------------------------------------------------------------------------------------------------
def run_one(config: TrialConfig, episode: Episode, recording: str | Path | None = None,
            pictures: bool = False) -> dict:
    """Run one episode in simulation and return its JSON record.

    The agent is wrapped for memory sampling (and, with ``recording``, a rerun ``.rrd`` of the
    episode; with ``pictures``, the data of its pictures in the trial report as ``.npz`` bytes
    under ``_trace``, see ``tasks.episode_trace``); none of it changes its numbers. The agent's
    context carries the episode's trial seed (for agent-side randomness such as simulated perception).
    """
    from tasks.instrument import InstrumentedAgent

    seed = episode_seed(config.seed, episode.episode_id)
    recorder = None
    if recording is not None:
        from tasks.recording import EpisodeRecorder

        recorder = EpisodeRecorder(recording, recording_id=f"{config.agent}-{episode.episode_id}-s{config.seed}")
    tracer = None
    if pictures:
        from tasks.episode_trace import EpisodeTracer

        tracer = EpisodeTracer()
    holder: dict = {}

    def factory(sim):
        agent = make_agent(config.agent, RunContext.for_episode(sim, seed), agent_config=config.agent_config,
                           method_config=config.helios, perception_config=config.perception)
        state = None
        if recorder is not None:
            _log_scene(recorder, sim, episode)
            spot = sim.backend.spot
            state = lambda: (sim.world.time, spot.T_world_body(), spot.joint_positions())  # noqa: E731
        if tracer is not None:
            try:
                tracer.bind_sim(sim, episode)
            except Exception as exc:  # noqa: BLE001 - pictures never change the episode
                tracer.failed(f"ground truth: {type(exc).__name__}: {exc}")
        holder["agent"] = InstrumentedAgent(agent, recorder, state, tracer)
        return holder["agent"]

    try:
        result = run_sim_episode(factory, episode, config.runner, config.sim, seed=seed)
    except Exception:
        if recorder is not None:
            recorder.close()
        raise
    record = result.as_dict()
    record["collision_events"] = record["extra"].pop("collision_events", [])
    agent = holder.get("agent")
    record["memory"] = agent.probe.summary() if agent is not None else None
    if recorder is not None:
        _log_outcome(recorder, record)
        recorder.close()
        record["recording"] = {"path": str(recording), "errors": list(agent.hook_errors) if agent else []}
    if tracer is not None:
        try:
            record["_trace"] = tracer.finish(agent, record)
        except Exception as exc:  # noqa: BLE001 - an episode without its picture, never a lost episode
            print(f"[trials] warning: no pictures for episode {episode.episode_id}: {type(exc).__name__}: {exc}",
                  file=sys.stderr, flush=True)
    return record


def _log_scene(recorder, sim, episode: Episode) -> None:
    """Static context for recordings: walls, furniture and objects as boxes (the ground truth the
    judge uses; never shown to the agent), with the target and the goal receptacles highlighted."""
    world = sim.world
    goals = set(episode.goal_receptacles)
    recorder.log_text(f"{episode.episode_id}: {episode.task} (target {episode.target_object} on "
                      f"{episode.start_receptacle}; goals {', '.join(episode.goal_receptacles)})")
    groups: dict[str, list] = {}
    for b in world.bodies.values():
        if b.kind not in ("structure", "furniture", "object"):
            continue
        lo, hi = world.aabb(b.body_id)
        if b.name == episode.target_object:
            group, color = "target", (255, 60, 60)
        elif b.name in goals:
            group, color = "goal_receptacles", (60, 220, 90)
        else:
            group, color = {"structure": ("walls", (150, 150, 150)), "furniture": ("furniture", (170, 130, 90)),
                            "object": ("objects", (90, 150, 230))}[b.kind]
        g = groups.setdefault(group, [[], [], [], color])
        g[0].append((lo + hi) / 2)
        g[1].append((hi - lo) / 2)
        g[2].append(b.name if b.kind != "structure" else "")
    for group, (centers, halves, labels, color) in groups.items():
        recorder.log_boxes(group, centers, halves, labels=labels if any(labels) else None,
                           colors=[color] * len(centers), static=True)


def _log_outcome(recorder, record: dict) -> None:
    m = record.get("metrics") or {}
    for key in METRIC_KEYS:
        if key in m:
            recorder.log_scalar(f"outcome/{METRIC_NAMES[key]}", float(bool(m[key])))
    status = "success" if record.get("success") else f"failed: {m.get('failure_reason')}"
    recorder.log_text(f"episode {record['episode_id']} {status}; {record['commands']} commands, "
                      f"{record['sim_time']:.1f} s simulated" + (f"; error: {record['error']}" if record.get("error") else ""),
                      level="INFO" if record.get("success") else "WARN")


@dataclass(frozen=True)
class EpisodeJob:
    """One episode for an executor: picklable, self-contained."""

    config: TrialConfig
    episode: Episode
    record: bool = False
    pictures: bool = False


def run_job(job: EpisodeJob) -> dict:
    """Executor entry point: the record, plus the recording's bytes (``_recording``) when recorded
    and the pictures' data (``_trace``) when asked for, so that workers on other machines need no
    access to the run folder."""
    if not job.record:
        return run_one(job.config, job.episode, pictures=job.pictures)
    tmp = Path(tempfile.mkdtemp(prefix="helios-rec-"))
    try:
        path = tmp / f"{job.episode.episode_id}.rrd"
        record = run_one(job.config, job.episode, recording=path, pictures=job.pictures)
        record["_recording"] = path.read_bytes()
        return record
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


# ------------------------------------------------------------------------------------------------
# Batches
# ------------------------------------------------------------------------------------------------
class _FolderLock:
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
            raise RunFolderError(f"run folder {str(self.path.parent)!r} is in use by {owner}; "
                                 f"wait for it to finish or use another --out") from None
        self.fh.seek(0)
        self.fh.truncate()
        self.fh.write(f"pid {os.getpid()} on {socket.gethostname()}")
        self.fh.flush()
        return self

    def __exit__(self, *exc):
        if self.fh is not None:
            try:                         # leave the folder as it was: an empty lock file
                self.fh.seek(0)
                self.fh.truncate()
            except OSError:
                pass
            self.fh.close()


@dataclass
class BatchReport:
    """What one :func:`run_batch` call did (records of all selected, finished episodes in episode order)."""

    records: list[dict]
    ran: int = 0                     # episodes run by this call
    skipped: int = 0                 # already in the run folder
    crashed: dict[str, str] = field(default_factory=dict)   # episode id -> why its worker died
    wall_seconds: float = 0.0
    commit_changed: str | None = None
    cpu_changed: str | None = None   # the other CPU code paths earlier episodes of the folder ran on
    fingerprint: str = ""            # config_fingerprint stamped on the records this call writes
    saved_commit: str | None = None  # git commit in the folder's config.yaml before this call
    notes: list[str] = field(default_factory=list)   # what opening the folder repaired


def run_batch(config: TrialConfig, episodes: list[Episode], out: Path,
              on_episode: Callable[[dict, int, int], None] | None = None, *, workers: int = 1,
              executor: str = "local", address: str = "local", record: int = 0,
              on_tick: Callable[[], None] | None = None, report: BatchReport | None = None,
              pictures: bool = True, worker_episodes: int = WORKER_EPISODES) -> list[dict]:
    """Run the episodes not yet in ``out/episodes.jsonl``, appending each as it ends.

    ``workers``/``executor``/``address`` choose where episodes run (``tasks.executors``); a
    local worker process is replaced by a fresh one after ``worker_episodes`` episodes (0 = never;
    a batch of more than that with one worker then runs in one such process, not in this one)
    because PyBullet leaks the Python objects of every mesh it is given (see
    ``tasks.executors.ProcessExecutor``);
    ``record`` records the first N selected episodes to ``out/recordings/<id>.rrd``; ``pictures``
    keeps every episode's picture data in ``out/episodes/<id>.npz`` (``tasks.episode_trace``,
    written before the episode's record, so a record always has its trace). An episode
    whose worker process dies is not written (a re-run retries it) and is listed in ``report``.
    Returns the finished records of ``episodes`` in episode order and writes ``summary.json``.
    """
    from tasks.executors import make_executor

    out = Path(out)
    check_folder_layout(out, record, pictures)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RunFolderError(f"cannot create run folder {str(out)!r}: {exc.strerror or exc}") from None
    t0 = time.perf_counter()
    report = report if report is not None else BatchReport([])
    with _FolderLock(out):
        ids, source = run_episode_ids(config) or (None, "")
        done = prepare_run_folder(out, config, report, episode_ids=None if ids is None else
                                  [*ids, *(e.episode_id for e in episodes)], episode_source=source)
        saved_commit = report.saved_commit
        commit = git_commit()
        if saved_commit and saved_commit != commit and done:
            report.commit_changed = saved_commit
        path = out / "episodes.jsonl"
        records = {e.episode_id: done[e.episode_id] for e in episodes if e.episode_id in done}
        report.skipped = len(records)
        recorded = {e.episode_id for e in episodes[:max(0, record)]}
        jobs = [EpisodeJob(config, e, e.episode_id in recorded, pictures)
                for e in episodes if e.episode_id not in done]
        if jobs:
            if done:
                now = cpu_paths_now()
                other = [p for p in run_cpu_paths(out) if p != now]
                report.cpu_changed = "; ".join(other) if other else None
            _log_invocation(out, workers, executor, address, len(jobs), commit)
            pool = make_executor(executor, min(workers, len(jobs)) if executor == "local" else workers, address,
                                 jobs=len(jobs), jobs_per_worker=worker_episodes)
            try:
                for outcome in pool.map_unordered(run_job, jobs):
                    if outcome is None:
                        if on_tick:
                            on_tick()
                        continue
                    job = jobs[outcome.index]
                    eid = job.episode.episode_id
                    if outcome.status == "error":
                        trace = outcome.value.rstrip()
                        raise EpisodeSetupError(f"episode {eid} failed outside the agent ("
                                                f"{shorten(trace.splitlines()[-1] if trace else 'no message', 300)}); "
                                                f"the batch stops (finished episodes are saved)", trace)
                    if outcome.status == "died":
                        report.crashed[eid] = outcome.value
                        continue
                    rec = outcome.value
                    rec[FINGERPRINT_FIELD] = report.fingerprint
                    trace = rec.pop("_trace", None)
                    if trace is not None:
                        from tasks.episode_trace import trace_path

                        _write_bytes_atomic(trace_path(out, eid), trace)
                    blob = rec.pop("_recording", None)
                    if blob is not None:
                        rel = Path("recordings") / f"{eid}.rrd"
                        _write_bytes_atomic(out / rel, blob)
                        rec["recording"]["path"] = str(rel)
                    rec = append_result(path, rec)
                    records[eid] = rec
                    report.ran += 1
                    if on_episode:
                        on_episode(rec, len(records), len(episodes))
            finally:
                pool.close()
        order = {e.episode_id: i for i, e in enumerate(episodes)}
        ordered = sorted(records.values(), key=lambda r: order[r["episode_id"]])
        summary = summarize(ordered)
        summary["selected"] = len(episodes)
        summary["complete"] = len(ordered) == len(episodes)
        write_atomic(out / "summary.json", json.dumps(summary, indent=2, sort_keys=True))
    report.records = ordered
    report.wall_seconds = time.perf_counter() - t0
    return ordered


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


def _write_bytes_atomic(path: Path, data: bytes) -> None:
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
    seen: list[str] = []
    for entry in read_invocations(out)[0]:
        if entry.get("episodes_to_run"):
            paths = invocation_cpu(entry)
            if paths not in seen:
                seen.append(paths)
    return seen


def _log_invocation(out: Path, workers: int, executor: str, address: str, todo: int, commit: str) -> None:
    entry = {"time": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "host": socket.gethostname(), "pid": os.getpid(),
             "argv": sys.argv, "workers": workers, "executor": executor,
             "address": address if executor == "ray" else None, "episodes_to_run": todo,
             "helios_version": package_version(), "git_commit": commit, "cpu": cpu_dispatch()}
    append_result(out / "invocations.jsonl", entry)


# ------------------------------------------------------------------------------------------------
# Summaries
# ------------------------------------------------------------------------------------------------
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
