"""Trial batches: run an agent over episodes, append one JSON line per finished episode (flushed and
fsynced, so a killed batch resumes with nothing lost or duplicated), and summarise the metrics
OVMM-style (percentages with standard errors).

Run folder layout: ``config.yaml`` (resolved trial config, package version, git commit),
``episodes.jsonl`` (one line per episode), ``summary.json``.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from helios.configuration import ConfigError, dump_yaml, from_dict, to_dict
from robots.spot.sim_backend import SimBackendConfig
from tasks.episodes import Episode
from tasks.metrics import FAILURE_REASONS
from tasks.registry import make_agent
from tasks.runner import RunnerConfig, run_sim_episode

METRIC_KEYS = ("find_obj", "pick", "find_rec", "place", "success")
METRIC_NAMES = {"find_obj": "FindObj", "pick": "Pick", "find_rec": "FindRec", "place": "Place", "success": "SR"}


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


class RunFolderError(ValueError):
    """The run folder holds results of a different configuration (or is unreadable)."""


def episode_seed(master_seed: int, episode_id: str) -> int:
    """A stable per-episode seed: independent of order, workers and resumption."""
    state = np.random.SeedSequence([master_seed, *episode_id.encode()]).generate_state(1)[0]
    return int(state % (2 ** 31 - 1))


def git_commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5,
                             cwd=Path(__file__).resolve().parent)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def _config_text(config: TrialConfig) -> str:
    from helios import __version__

    header = {"helios_version": __version__, "git_commit": git_commit()}
    return dump_yaml(header) + dump_yaml(config)


def prepare_run_folder(out: Path, config: TrialConfig) -> dict[str, dict]:
    """Create or reopen a run folder; returns the episodes already finished (by id).

    Reopening checks the saved config is the same (results of different configs never mix) and
    drops a torn last line left by a kill in the middle of a write.
    """
    out.mkdir(parents=True, exist_ok=True)
    cfg_path = out / "config.yaml"
    import yaml

    if cfg_path.exists():
        saved = yaml.safe_load(cfg_path.read_text()) or {}
        saved.pop("helios_version", None)
        saved.pop("git_commit", None)
        try:
            saved_cfg = from_dict(TrialConfig, saved)
        except ConfigError as exc:
            raise RunFolderError(f"{cfg_path} is not a trial config this version can read: {exc}") from None
        if saved_cfg != config:
            diff = [k for k, v in to_dict(config).items() if to_dict(saved_cfg).get(k) != v]
            raise RunFolderError(f"run folder {str(out)!r} holds results of a different configuration "
                                 f"(differs in: {', '.join(diff)}); use another --out to start a new run")
    else:
        tmp = cfg_path.with_suffix(".yaml.tmp")
        tmp.write_text(_config_text(config))
        tmp.replace(cfg_path)
    return read_results(out / "episodes.jsonl", repair=True)


def read_results(path: Path, repair: bool = False) -> dict[str, dict]:
    """Finished episodes by id. With ``repair``, a torn last line is cut off the file."""
    done: dict[str, dict] = {}
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
    return done


def append_result(path: Path, record: dict) -> None:
    line = (json.dumps(record, sort_keys=True, default=_json_default) + "\n").encode()
    with path.open("ab") as fh:
        fh.write(line)
        fh.flush()
        os.fsync(fh.fileno())


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"cannot serialise {type(o).__name__}")


def run_one(config: TrialConfig, episode: Episode) -> dict:
    """Run one episode in simulation and return its JSON record."""
    seed = episode_seed(config.seed, episode.episode_id)
    result = run_sim_episode(lambda sim: make_agent(config.agent, sim), episode, config.runner, config.sim, seed=seed)
    record = result.as_dict()
    record["collision_events"] = record["extra"].pop("collision_events", [])
    return record


def run_batch(config: TrialConfig, episodes: list[Episode], out: Path,
              on_episode: Callable[[dict, int, int], None] | None = None) -> list[dict]:
    """Run the episodes not yet in ``out/episodes.jsonl``, appending each as it ends."""
    done = prepare_run_folder(out, config)
    path = out / "episodes.jsonl"
    records = [done[e.episode_id] for e in episodes if e.episode_id in done]
    todo = [e for e in episodes if e.episode_id not in done]
    for episode in todo:
        record = run_one(config, episode)
        append_result(path, record)
        records.append(record)
        if on_episode:
            on_episode(record, len(records), len(episodes))
    order = {e.episode_id: i for i, e in enumerate(episodes)}
    records.sort(key=lambda r: order[r["episode_id"]])
    summary = summarize(records)
    tmp = out / "summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=2, sort_keys=True))
    tmp.replace(out / "summary.json")
    return records


def summarize(records: Iterable[dict]) -> dict:
    """Phase rates in percent with standard errors, collisions, failure reasons and timings."""
    records = list(records)
    n = len(records)
    out: dict = {"episodes": n}
    scored = [r for r in records if r.get("metrics")]
    m = len(scored)
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
    return out


def metrics_table_rows(name: str, summary: dict) -> list:
    return [name] + [f"{summary[METRIC_NAMES[k]]['percent']:.1f} ± {summary[METRIC_NAMES[k]]['se']:.1f}"
                     for k in METRIC_KEYS]
