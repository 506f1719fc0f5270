"""Trial batches: run an agent over episodes, append one JSON line per finished episode (flushed and
fsynced, so a killed batch resumes with nothing lost or duplicated), and summarise the metrics
OVMM-style (percentages with standard errors) into ``summary.json``.

What a batch runs is its configuration (``tasks.trial_config``, which also says what is
deterministic); where its results go and by which rules, the run folder (``tasks.run_folder``);
how they are summarised, ``tasks.trial_summary``.

Workers never write the run folder: the process running :func:`run_batch` collects each result
from its executor (``tasks.executors``: in-process, local processes, Ray) and appends it.
"""

from __future__ import annotations

import json
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from helios.schema import shorten
from tasks.executors import WORKER_EPISODES
from tasks.episodes import Episode
from tasks.provenance import git_commit
from tasks.registry import RunContext, make_agent
from tasks.run_folder import (FolderLock, RunFolderError, agent_source_changed, append_result, check_folder_layout,
                              cpu_paths_now, episode_digest, log_invocation, plugin_source, prepare_run_folder,
                              run_cpu_paths, write_atomic, write_bytes_atomic)
from tasks.runner import run_sim_episode
from tasks.trial_config import FINGERPRINT_FIELD, TrialConfig, episode_seed, run_episode_ids
from tasks.trial_summary import METRIC_KEYS, METRIC_NAMES, summarize


class EpisodeSetupError(RuntimeError):
    """An episode failed outside the agent (building the scene, making the agent): the batch stops.
    The message is one line; ``trace`` holds the worker's traceback."""

    def __init__(self, message: str, trace: str = ""):
        super().__init__(message)
        self.trace = trace


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
    agent_source_changed: str | None = None   # a plugin agent's earlier source digests, when not this one's
    fingerprint: str = ""            # config_fingerprint stamped on the records this call writes
    saved_commit: str | None = None  # git commit in the folder's config.yaml before this call
    notes: list[str] = field(default_factory=list)   # what opening the folder repaired


def run_folder_episodes(config: TrialConfig, episodes: list[Episode]) -> dict:
    """What :func:`tasks.run_folder.prepare_run_folder` checks a folder's records against, for
    ``config`` about to run ``episodes``: the episodes the configuration selects (records of others
    are set aside), where they come from (for messages), and each one's task (a record of another
    task means the episode file changed). ``tools trials`` passes the same to its dry run."""
    ids, source = run_episode_ids(config) or (None, "")
    return {"episode_ids": None if ids is None else [*ids, *(e.episode_id for e in episodes)],
            "episode_source": source, "episode_tasks": {e.episode_id: e.task for e in episodes},
            "episode_digests": {e.episode_id: episode_digest(e) for e in episodes}}


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
    with FolderLock(out):
        done = prepare_run_folder(out, config, report, **run_folder_episodes(config, episodes))
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
                report.agent_source_changed = agent_source_changed(out, config.agent)
            log_invocation(out, workers, executor, address, len(jobs), commit, plugin_source(config.agent))
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

                        write_bytes_atomic(trace_path(out, eid), trace)
                    blob = rec.pop("_recording", None)
                    if blob is not None:
                        rel = Path("recordings") / f"{eid}.rrd"
                        write_bytes_atomic(out / rel, blob)
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
