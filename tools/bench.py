"""Performance benchmarks, printed as tables with ratios measured side by side in one run.

Usage: ``python -m tools bench SUITE [SUITE ...]``. Timings never live in tests; they live here.
"""

from __future__ import annotations

import argparse
import importlib
import os
from pathlib import Path

from tools.cli import CliError, check_seed

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
    parser.add_argument("--quick", action="store_true",
                        help="fewer repetitions (smoke-test the benchmark); an explicit --agent-episodes, "
                             "--agent-replans or --trials-episodes still wins")
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
    check_seed(args.seed)
    for flag, lo in (("agent_episodes", 1), ("agent_replans", 1), ("trials_episodes", 1), ("maps_threads", 1)):
        value = getattr(args, flag, None)
        if value is not None and not lo <= value <= 100_000:
            raise CliError(f"--{flag.replace('_', '-')} must be within {lo}..100000, got {value}")
    from helios.schema import short_repr

    twice = _first_repeat(args.suites)
    if twice is not None:
        raise CliError(f"suite {short_repr(twice, 40)} is given twice")
    _check_unselected(args)
    flag_recording = getattr(args, "maps_recording", None)
    if getattr(args, "maps_synthetic", False) and (flag_recording or os.environ.get("HELIOS_MAPS_RECORDING")):
        given = "--maps-recording" if flag_recording else "HELIOS_MAPS_RECORDING"     # the recording won, silently
        raise CliError(f"--maps-synthetic and {given} both choose what the maps suite replays; give one")
    seeded = "agent" in args.suites or ("maps" in args.suites and getattr(args, "maps_synthetic", False))
    if args.seed != 0 and not seeded:          # read by the agent suite and the synthetic maps replay only
        raise CliError(f"--seed is read by the agent suite and by maps --maps-synthetic only; the selected suite(s) "
                       f"({', '.join(args.suites)}) would ignore it")
    workers = getattr(args, "trials_workers", None)
    if workers is not None:
        try:
            counts = [int(w) for w in workers.split(",")]
        except ValueError:
            counts = []
        if not counts or not all(1 <= c <= 1024 for c in counts):
            raise CliError(f"--trials-workers must be comma-separated worker counts within 1..1024, "
                           f"got {short_repr(workers, 60)}")
        if _first_repeat(counts) is not None:
            raise CliError(f"--trials-workers: {_first_repeat(counts)} is given twice")
    _check_agents(args)
    if "trials" in args.suites:
        from tasks.episodes import load_split
        from tools.bench_trials import episode_count

        n = episode_count(args)
        available = len(load_split(args.trials_split))        # an unknown split is one line too
        if n > available:
            raise CliError(f"--trials-episodes must be in 1..{available} (split {args.trials_split!r}), got {n}")
    recording = getattr(args, "maps_recording", None)
    if recording and not Path(recording).is_file():
        raise CliError(f"--maps-recording {short_repr(recording)} is not a file")
    if "maps" in args.suites:
        from tools.bench_maps import check_inputs

        check_inputs(args)
    if "agent" in args.suites:
        from tools.bench_agent import check_inputs as check_agent_inputs

        check_agent_inputs(args)         # repeats, seed, --agent-set, --agent-save, --agent-baseline


def suite_options() -> dict[str, tuple[str, object]]:
    """Each suite's own option (its ``add_arguments``: ``agent_repeats``, ``maps_device``, ...) ->
    (that suite, the option's default)."""
    owned: dict[str, tuple[str, object]] = {}
    for suite, module in SUITES.items():
        mod = importlib.import_module(module)
        if hasattr(mod, "add_arguments"):
            parser = argparse.ArgumentParser(add_help=False)
            mod.add_arguments(parser)
            owned.update((dest, (suite, default)) for dest, default in vars(parser.parse_args([])).items())
    return owned


def _check_unselected(args: argparse.Namespace) -> None:
    """A suite's option given (other than its default) while that suite is not selected would be
    ignored: refused instead (``bench scenes --agent-repeats 0`` once ran scenes and exited 0)."""
    for dest, (suite, default) in suite_options().items():
        if suite not in args.suites and getattr(args, dest, default) != default:
            raise CliError(f"--{dest.replace('_', '-')} applies to the {suite!r} suite, which is not selected")


def _first_repeat(values):
    """The first value that occurs twice in ``values``, else None."""
    seen = set()
    for v in values:
        if v in seen:
            return v
        seen.add(v)
    return None


def _check_agents(args: argparse.Namespace) -> None:
    """The agents the trials and agent suites would run are registered episode agents."""
    from tasks.plugin_agents import is_plugin_spec
    from tasks.registry import UnknownAgentError, check_agent

    for flag in ("trials_agent", "agent_name"):
        name = getattr(args, flag, None)
        if name is not None and is_plugin_spec(name):       # `tools trials` only
            raise CliError(f"--{flag.replace('_', '-')} {name!r}: the benchmarks time registered agents (the "
                           f"baseline side runs a commit's tree, without your file); time your own agent with "
                           f"`tools trials --agent FILE.py:FACTORY` (wall s per episode in its summary)")
        if name is not None:
            try:
                check_agent(name)
            except UnknownAgentError as exc:
                raise CliError(f"--{flag.replace('_', '-')}: {exc}") from None


