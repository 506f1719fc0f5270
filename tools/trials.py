"""Run a trial batch: an agent over episodes of a split (or your own episode file), with resumable
results, a printed OVMM-style table and ``summary.json``.

    python -m tools trials --agent oracle --split smoke --episodes 20 --seed 0 --out runs/NAME
    python -m tools trials --agent oracle --episodes-file my_eval.jsonl --out runs/mine runner.max_sim_time=300

Re-running the same command continues an interrupted batch (finished episodes are skipped).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from tasks.episodes import SPLITS
    from tasks.registry import agent_names

    parser.add_argument("--agent", default="oracle", help=f"agent: {', '.join(agent_names())}")
    parser.add_argument("--split", default="smoke", help=f"episode split: {', '.join(SPLITS)}")
    parser.add_argument("--episodes-file", default="", help="JSONL episode file (overrides --split)")
    parser.add_argument("--episodes", type=int, default=20, help="number of episodes (from the start of the split)")
    parser.add_argument("--seed", type=int, default=0, help="master seed (per-episode seeds derive from it)")
    parser.add_argument("--out", default="", help="run folder (default: runs/<agent>_<split>_s<seed>)")
    parser.add_argument("overrides", nargs="*", metavar="KEY=VALUE",
                        help="config overrides, e.g. runner.max_sim_time=300 sim.camera.width=640")


def resolve_config(args: argparse.Namespace):
    from helios.configuration import with_overrides
    from tasks.trials import TrialConfig

    base = TrialConfig(agent=args.agent, split=args.split, episodes_file=args.episodes_file,
                       episodes=args.episodes, seed=args.seed)
    return with_overrides(base, list(args.overrides))


def select_episodes(config):
    from tasks.episodes import DatasetError, load_episodes, load_split

    episodes = load_episodes(config.episodes_file) if config.episodes_file else load_split(config.split)
    if config.episodes <= 0:
        raise DatasetError(f"--episodes must be positive, got {config.episodes}")
    if config.episodes > len(episodes):
        source = config.episodes_file or f"split {config.split!r}"
        raise DatasetError(f"{source} has {len(episodes)} episodes, fewer than the {config.episodes} requested")
    return episodes[:config.episodes]


def run(args: argparse.Namespace) -> int:
    from tasks.registry import agent_names
    from tasks.trials import METRIC_NAMES, metrics_table_rows, run_batch, summarize
    from tools.cli import CliError
    from tools.tables import format_markdown, format_table

    config = resolve_config(args)
    if config.agent not in agent_names():
        raise CliError(f"unknown agent {config.agent!r}; valid agents: {', '.join(agent_names())}")
    episodes = select_episodes(config)
    out = Path(args.out or f"runs/{config.agent}_{Path(config.episodes_file).stem if config.episodes_file else config.split}_s{config.seed}")
    t0 = time.perf_counter()
    print(f"[trials] {config.agent} on {len(episodes)} episode(s) "
          f"({config.episodes_file or 'split ' + config.split}), seed {config.seed}, results in {out}/", flush=True)

    def progress(record: dict, done: int, total: int) -> None:
        m = record["metrics"] or {}
        status = "success" if m.get("success") else f"failed: {m.get('failure_reason')}"
        elapsed = time.perf_counter() - t0
        print(f"[trials] {done}/{total} {record['episode_id']} {status}  "
              f"(sim {record['sim_time']:.0f} s, wall {record['wall_time']:.1f} s; elapsed {elapsed:.0f} s)",
              flush=True)

    records = run_batch(config, episodes, out, on_episode=progress)
    summary = summarize(records)
    headers = ["run"] + list(METRIC_NAMES.values())
    rows = [metrics_table_rows(out.name, summary)]
    print()
    print(format_table(headers, rows, title=f"{len(records)} episodes, percent ± standard error"))
    reasons = ", ".join(f"{k} {v}" for k, v in summary["failure_reasons"].items() if v) or "none"
    print(f"failure reasons: {reasons}; collisions per episode {summary['collisions_per_episode']:.2f}; "
          f"{summary['sim_seconds_per_episode']:.0f} s simulated, {summary['wall_seconds_per_episode']:.1f} s wall per episode")
    print()
    print(format_markdown(headers, rows))
    print(f"\nsummary: {out / 'summary.json'}   episodes: {out / 'episodes.jsonl'}")
    if summary["errors"]:
        print(f"warning: {summary['errors']} episode(s) ended on an exception; see 'error' in episodes.jsonl",
              file=sys.stderr)
    return 0
