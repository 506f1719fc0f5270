"""Trial batches: run an agent over episodes, append one JSON line per finished episode (flushed and
fsynced, so a killed batch resumes with nothing lost or duplicated), and summarise the metrics
OVMM-style (percentages with standard errors).

Run folder layout: ``config.yaml`` (resolved trial config, package version, git commit),
``episodes.jsonl`` (one line per episode, in the order episodes finished), ``summary.json``,
``invocations.jsonl`` (one line per command that worked on the folder: workers, executor, host,
commit), ``recordings/<episode_id>.rrd`` (``record=N``), and a ``.lock`` that keeps two batches
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
from helios.schema import ConfigError, dump_yaml, from_dict, load_config, read_config_file, to_dict
from robots.spot.sim_backend import SimBackendConfig
from sim.perception.config import SimPerceptionConfig
from tasks.episodes import Episode
from tasks.metrics import FAILURE_REASONS
from tasks.provenance import PROVENANCE_KEYS, git_commit, package_version, provenance
from tasks.registry import RunContext, make_agent
from tasks.runner import RunnerConfig, run_sim_episode

METRIC_KEYS = ("find_obj", "pick", "find_rec", "place", "success")
METRIC_NAMES = {"find_obj": "FindObj", "pick": "Pick", "find_rec": "FindRec", "place": "Place", "success": "SR"}
NONDETERMINISTIC_FIELDS = ("wall_time", "memory", "recording")


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


class RunFolderError(ValueError):
    """The run folder holds results of a different configuration, is in use, or is unreadable."""


class EpisodeSetupError(RuntimeError):
    """An episode failed outside the agent (building the scene, making the agent): the batch stops."""


def episode_seed(master_seed: int, episode_id: str) -> int:
    """A stable per-episode seed: independent of order, workers and resumption."""
    state = np.random.SeedSequence([master_seed, *episode_id.encode()]).generate_state(1)[0]
    return int(state % (2 ** 31 - 1))


def deterministic_view(record: dict) -> dict:
    """A record without the fields that vary between identical runs (wall clock, memory, paths)."""
    return {k: v for k, v in record.items() if k not in NONDETERMINISTIC_FIELDS}


def _config_text(config: TrialConfig) -> str:
    return dump_yaml(provenance()) + dump_yaml(config)


def _write_atomic(path: Path, text: str) -> None:
    _write_bytes_atomic(path, text.encode())


def read_run_config(out: Path) -> tuple[dict, TrialConfig]:
    """The header (``helios_version``, ``git_commit``) and the trial config saved in a run folder."""
    import yaml

    cfg_path = Path(out) / "config.yaml"
    try:
        saved = yaml.safe_load(cfg_path.read_text()) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise RunFolderError(f"cannot read {cfg_path}: {exc}") from None
    header = {k: saved.pop(k, None) for k in PROVENANCE_KEYS}
    try:
        return header, from_dict(TrialConfig, saved)
    except ConfigError as exc:
        raise RunFolderError(f"{cfg_path} is not a trial config this version can read: {exc}") from None


def load_trial_config(path: str | Path) -> tuple[dict, TrialConfig]:
    """A scenario file (``configs/*.yaml``) or a run folder's ``config.yaml``: its provenance
    (``helios_version``, ``git_commit``; None where absent, as in a hand-written scenario) and the
    trial config. Any other unknown key is a ConfigError naming the file and the key."""
    data = read_config_file(path)
    header = {k: data.get(k) for k in PROVENANCE_KEYS}
    return header, load_config(TrialConfig, path, ignore=PROVENANCE_KEYS)


def prepare_run_folder(out: Path, config: TrialConfig) -> dict[str, dict]:
    """Create or reopen a run folder; returns the episodes already finished (by id).

    Reopening checks the saved config is the same (results of different configs never mix) and
    drops a torn last line left by a kill in the middle of a write. The one allowed difference is
    a larger ``episodes``: episodes are a prefix of the split and each one's seed depends only on
    (seed, episode id), so a 100-episode run extended to 200 gives exactly the numbers of a fresh
    200-episode run; config.yaml is then rewritten with the new count.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cfg_path = out / "config.yaml"
    if cfg_path.exists():
        _, saved_cfg = read_run_config(out)
        if saved_cfg != config:
            diff = [k for k, v in to_dict(config).items() if to_dict(saved_cfg).get(k) != v]
            if diff == ["episodes"] and config.episodes > saved_cfg.episodes:
                _write_atomic(cfg_path, _config_text(config))
            elif diff == ["episodes"]:
                raise RunFolderError(f"run folder {str(out)!r} holds a run of {saved_cfg.episodes} episodes; "
                                     f"a run can be extended but not shortened (asked for {config.episodes}); "
                                     f"use another --out, or `tools report` to look at part of a run")
            else:
                raise RunFolderError(f"run folder {str(out)!r} holds results of a different configuration "
                                     f"(differs in: {', '.join(diff)}); use another --out to start a new run")
    else:
        _write_atomic(cfg_path, _config_text(config))
    return read_results(out / "episodes.jsonl", repair=True)


def read_results(path: Path, repair: bool = False) -> dict[str, dict]:
    """Finished episodes by id. With ``repair``, a torn last line is cut off the file."""
    done: dict[str, dict] = {}
    path = Path(path)
    if not path.exists():
        return done
    data = path.read_bytes()
    good_end = 0
    for line in data.splitlines(keepends=True):
        if not line.endswith(b"\n"):
            break
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            break
        done.setdefault(record["episode_id"], record)
        good_end += len(line)
    if repair and good_end < len(data):
        with path.open("r+b") as fh:
            fh.truncate(good_end)
            fh.flush()
            os.fsync(fh.fileno())
    return done


def append_result(path: Path, record: dict) -> dict:
    """Append one record as a JSON line (flushed and fsynced); returns it as read back from JSON."""
    text = json.dumps(record, sort_keys=True, default=_json_default)
    with Path(path).open("ab") as fh:
        fh.write((text + "\n").encode())
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
def run_one(config: TrialConfig, episode: Episode, recording: str | Path | None = None) -> dict:
    """Run one episode in simulation and return its JSON record.

    The agent is wrapped for memory sampling (and, with ``recording``, a rerun ``.rrd`` of the
    episode); neither changes its numbers. The agent's context carries the episode's trial seed
    (for agent-side randomness such as simulated perception).
    """
    from tasks.instrument import InstrumentedAgent

    seed = episode_seed(config.seed, episode.episode_id)
    recorder = None
    if recording is not None:
        from tasks.recording import EpisodeRecorder

        recorder = EpisodeRecorder(recording, recording_id=f"{config.agent}-{episode.episode_id}-s{config.seed}")
    holder: dict = {}

    def factory(sim):
        agent = make_agent(config.agent, RunContext.for_episode(sim, seed), agent_config=config.agent_config,
                           method_config=config.helios, perception_config=config.perception)
        state = None
        if recorder is not None:
            _log_scene(recorder, sim, episode)
            spot = sim.backend.spot
            state = lambda: (sim.world.time, spot.T_world_body(), spot.joint_positions())  # noqa: E731
        holder["agent"] = InstrumentedAgent(agent, recorder, state)
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


def run_job(job: EpisodeJob) -> dict:
    """Executor entry point: the record, plus the recording's bytes (``_recording``) when recorded,
    so that workers on other machines need no access to the run folder."""
    if not job.record:
        return run_one(job.config, job.episode)
    tmp = Path(tempfile.mkdtemp(prefix="helios-rec-"))
    try:
        path = tmp / f"{job.episode.episode_id}.rrd"
        record = run_one(job.config, job.episode, recording=path)
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
        self.fh = self.path.open("a+")
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


def run_batch(config: TrialConfig, episodes: list[Episode], out: Path,
              on_episode: Callable[[dict, int, int], None] | None = None, *, workers: int = 1,
              executor: str = "local", address: str = "local", record: int = 0,
              on_tick: Callable[[], None] | None = None, report: BatchReport | None = None) -> list[dict]:
    """Run the episodes not yet in ``out/episodes.jsonl``, appending each as it ends.

    ``workers``/``executor``/``address`` choose where episodes run (``tasks.executors``);
    ``record`` records the first N selected episodes to ``out/recordings/<id>.rrd``. An episode
    whose worker process dies is not written (a re-run retries it) and is listed in ``report``.
    Returns the finished records of ``episodes`` in episode order and writes ``summary.json``.
    """
    from tasks.executors import make_executor

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    report = report if report is not None else BatchReport([])
    with _FolderLock(out):
        saved_commit = None
        if (out / "config.yaml").exists():
            saved_commit = read_run_config(out)[0].get("git_commit")
        done = prepare_run_folder(out, config)
        commit = git_commit()
        if saved_commit and saved_commit != commit and done:
            report.commit_changed = saved_commit
        path = out / "episodes.jsonl"
        records = {e.episode_id: done[e.episode_id] for e in episodes if e.episode_id in done}
        report.skipped = len(records)
        recorded = {e.episode_id for e in episodes[:max(0, record)]}
        jobs = [EpisodeJob(config, e, e.episode_id in recorded) for e in episodes if e.episode_id not in done]
        if jobs:
            _log_invocation(out, workers, executor, address, len(jobs), commit)
            pool = make_executor(executor, min(workers, len(jobs)) if executor == "local" else workers, address)
            try:
                for outcome in pool.map_unordered(run_job, jobs):
                    if outcome is None:
                        if on_tick:
                            on_tick()
                        continue
                    job = jobs[outcome.index]
                    eid = job.episode.episode_id
                    if outcome.status == "error":
                        raise EpisodeSetupError(f"episode {eid} failed outside the agent; the batch stops "
                                                f"(finished episodes are saved):\n{outcome.value.rstrip()}")
                    if outcome.status == "died":
                        report.crashed[eid] = outcome.value
                        continue
                    rec = outcome.value
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
        _write_atomic(out / "summary.json", json.dumps(summary, indent=2, sort_keys=True))
    report.records = ordered
    report.wall_seconds = time.perf_counter() - t0
    return ordered


def _write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write to a temporary file, fsync, rename: a kill leaves the old file or the new one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    tmp.replace(path)


def _log_invocation(out: Path, workers: int, executor: str, address: str, todo: int, commit: str) -> None:
    entry = {"time": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "host": socket.gethostname(), "pid": os.getpid(),
             "argv": sys.argv, "workers": workers, "executor": executor,
             "address": address if executor == "ray" else None, "episodes_to_run": todo,
             "helios_version": package_version(), "git_commit": commit}
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


def metrics_table_rows(name: str, summary: dict) -> list:
    return [name] + [f"{summary[METRIC_NAMES[k]]['percent']:.1f} ± {summary[METRIC_NAMES[k]]['se']:.1f}"
                     for k in METRIC_KEYS]
