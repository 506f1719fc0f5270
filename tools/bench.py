"""Performance benchmarks, printed as tables with ratios measured side by side in one run.

Usage: ``python -m tools bench SUITE [SUITE ...]``. Timings never live in tests; they live here.
"""

from __future__ import annotations

import argparse
import importlib

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
    unknown = [s for s in args.suites if s not in SUITES]
    if unknown:
        raise CliError(f"unknown benchmark suite(s) {', '.join(unknown)}; valid: {', '.join(SUITES)}")
    for name in args.suites:
        print(importlib.import_module(SUITES[name]).run(args))
        print()
    return 0
