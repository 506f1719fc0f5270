"""Trial throughput: episodes per hour with 1 and 2 local workers on the same episodes, side by side.

Each configuration runs the same episodes into a fresh temporary run folder, timed from the call to
``run_batch`` to its return (worker start-up included: spawning, imports, first scene), and the
runs must give identical numbers. "Steady" rates count the episodes finished after every worker has
finished its first one, which is what a long batch (hundreds of episodes) sees once its workers are up. The load average
before and after is printed: on a shared 2-core machine other work steals cores and lowers the
scaling ratio.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

DEFAULT_EPISODES, QUICK_EPISODES = 12, 3


def add_arguments(parser: argparse.ArgumentParser) -> None:
    # default None, so that an explicit value is known and wins over --quick (see episode_count)
    parser.add_argument("--trials-episodes", type=int, default=None,
                        help=f"trials suite: episodes per configuration (default {DEFAULT_EPISODES}; "
                             f"--quick: {QUICK_EPISODES})")
    parser.add_argument("--trials-agent", default="oracle", help="trials suite: agent")
    parser.add_argument("--trials-split", default="smoke", help="trials suite: split")
    parser.add_argument("--trials-workers", default="1,2", help="trials suite: worker counts to compare")


def episode_count(args: argparse.Namespace) -> int:
    """Episodes per configuration. ``--quick`` only changes the default: an explicit
    ``--trials-episodes`` wins (``--quick`` once replaced it silently)."""
    if args.trials_episodes is not None:
        return args.trials_episodes
    return QUICK_EPISODES if getattr(args, "quick", False) else DEFAULT_EPISODES


def spin(n: int) -> float:
    """A pure-Python CPU loop (no memory traffic); returns its duration."""
    t = time.perf_counter()
    s = 0
    for i in range(n):
        s += i * i
    return time.perf_counter() - t


def cpu_scaling(workers: int = 2, n: int = 4_000_000) -> float:
    """What this machine gives right now: throughput of ``workers`` processes spinning at once
    relative to one (2.0 on two idle cores; less when other work shares them)."""
    from tasks.executors import ProcessExecutor

    ex = ProcessExecutor(workers)
    try:
        list(ex.map_unordered(spin, [1000] * workers))          # start the workers
        single = spin(n)
        t0 = time.perf_counter()
        list(ex.map_unordered(spin, [n] * workers))
        return workers * single / (time.perf_counter() - t0)
    finally:
        ex.close()


def _load() -> str:
    try:
        return "/".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "n/a"


def run(args: argparse.Namespace) -> str:
    from tasks.episodes import load_split
    from tasks.trial_config import TrialConfig, deterministic_view
    from tasks.trials import run_batch
    from tools.cli import CliError
    from tools.tables import format_table

    n = episode_count(args)
    episodes = load_split(args.trials_split)
    if n < 1 or n > len(episodes):
        raise CliError(f"--trials-episodes must be in 1..{len(episodes)}, got {n}")
    try:
        counts = [int(w) for w in args.trials_workers.split(",")]
    except ValueError:
        raise CliError(f"--trials-workers must be comma-separated integers, got {args.trials_workers!r}") from None
    episodes = episodes[:n]
    config = TrialConfig(agent=args.trials_agent, split=args.trials_split, episodes=n, seed=args.seed)
    rows, results = [], {}
    load_before = _load()
    cpu_before = cpu_scaling(max(counts)) if max(counts) > 1 else 1.0
    for workers in counts:
        marks: list[float] = []
        with tempfile.TemporaryDirectory(prefix="bench-trials-") as tmp:
            t0 = time.perf_counter()
            records = run_batch(config, episodes, Path(tmp) / "run", workers=workers,
                                on_episode=lambda r, d, t: marks.append(time.perf_counter() - t0))
            wall = time.perf_counter() - t0
        results[workers] = [deterministic_view(r) for r in records]
        k = min(workers, n) - 1          # from the moment every worker has finished one episode
        steady = 3600.0 * (n - 1 - k) / (marks[-1] - marks[k]) if n - 1 > k and marks[-1] > marks[k] else float("nan")
        sr = 100.0 * sum(r["success"] for r in records) / n
        # "-": no steady rate when no episode finishes after every worker's first (episodes <= workers)
        rows.append([workers, n, round(wall, 1), round(3600.0 * n / wall), "-" if steady != steady else round(steady),
                     f"{sr:.0f}%", f"{sum(r['wall_time'] for r in records) / n:.2f}"])
    base, base_steady = rows[0][3], rows[0][4]
    for row in rows:
        steady_ok = isinstance(row[4], int) and isinstance(base_steady, int) and base_steady > 0
        row += [f"{row[3] / base:.2f}x", f"{row[4] / base_steady:.2f}x" if steady_ok else "-"]
    same = all(results[w] == results[counts[0]] for w in counts)
    title = (f"Trial throughput: {args.trials_agent} on {n} {args.trials_split} episodes, seed {args.seed}, "
             f"{os.cpu_count()} cores; load average before {load_before}, after {_load()}")
    table = format_table(["workers", "episodes", "wall s", "episodes/hour", "steady episodes/hour", "SR",
                          "wall s/episode", "scaling", "steady scaling"], rows, title=title)
    cpu_after = cpu_scaling(max(counts)) if max(counts) > 1 else 1.0
    return (table + f"\nidentical records across worker counts: {'yes' if same else 'NO'}"
            + f"\nmachine control (pure-Python spin, {max(counts)} processes vs 1): {cpu_before:.2f}x before, "
              f"{cpu_after:.2f}x after (the most any {max(counts)}-worker scaling can reach right now)")
