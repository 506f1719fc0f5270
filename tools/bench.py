"""Performance benchmarks, printed as tables with ratios measured side by side in one run.

Usage: ``python -m tools bench SUITE [SUITE ...]``. Timings never live in tests; they live here.
"""

from __future__ import annotations

import argparse
import importlib
from pathlib import Path

from tools.cli import CliError

# suite name -> module exposing ``add_arguments(parser)`` (optional) and ``run(args) -> str``
SUITES: dict[str, str] = {
    "sim": "tools.bench_sim",
    "maps": "tools.bench_maps",
    "scenes": "tools.bench_scenes",
    "perception": "tools.bench_perception",
    "trials": "tools.bench_trials",
    "agent": "tools.bench_agent",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("suites", nargs="+", metavar="SUITE", help=f"one or more of: {', '.join(SUITES)}")
    parser.add_argument("--quick", action="store_true", help="fewer repetitions (smoke-test the benchmark)")
    parser.add_argument("--seed", type=int, default=0, help="seed for scenes and trajectories")
    for module in SUITES.values():   # suite-specific options (e.g. --maps-recording)
        suite = importlib.import_module(module)
        if hasattr(suite, "add_arguments"):
            suite.add_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from helios.schema import short_repr

    unknown = [s for s in args.suites if s not in SUITES]
    if unknown:
        raise CliError(f"unknown benchmark suite(s) {', '.join(short_repr(u, 40) for u in unknown[:5])}; "
                       f"valid: {', '.join(SUITES)}")
    _check_options(args)
    for name in args.suites:
        print(importlib.import_module(SUITES[name]).run(args))
        print()
    return 0


def _check_options(args: argparse.Namespace) -> None:
    """Every suite's numeric options, before any suite starts (so a typo costs no benchmark time)."""
    if args.seed < 0:
        raise CliError(f"--seed must be >= 0, got {args.seed}")
    for flag, lo in (("agent_episodes", 1), ("agent_replans", 1), ("trials_episodes", 1), ("maps_threads", 1)):
        value = getattr(args, flag, None)
        if value is not None and not lo <= value <= 100_000:
            raise CliError(f"--{flag.replace('_', '-')} must be within {lo}..100000, got {value}")
    workers = getattr(args, "trials_workers", None)
    if workers is not None:
        try:
            counts = [int(w) for w in workers.split(",")]
        except ValueError:
            counts = []
        if not counts or not all(1 <= c <= 1024 for c in counts):
            from helios.schema import short_repr

            raise CliError(f"--trials-workers must be comma-separated worker counts within 1..1024, "
                           f"got {short_repr(workers, 60)}")
    if "maps" in args.suites:
        from tools.bench_maps import check_device

        check_device(getattr(args, "maps_device", "cpu") or "cpu")
    recording = getattr(args, "maps_recording", None)
    if recording and not Path(recording).is_file():
        raise CliError(f"--maps-recording {recording!r} is not a file")
