"""The ``helios`` / ``python -m tools`` command line.

Each command lives in its own module with ``add_arguments(parser)`` and ``run(args) -> int``;
heavy imports (PyBullet, torch) happen inside ``run`` so ``--help`` stays instant. Errors caused by
the user's input are printed as one line (``error: ...``) with exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# command name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("tools.demo", "scripted Spot pick-and-place in a small scene; prints the outcome, writes a .rrd"),
    "bench": ("tools.bench", "performance benchmarks printed as tables (sim, ...)"),
    "spot": ("tools.spot", "run an agent on a real Spot via the Spot SDK (--fake: dry run against a simulated Spot)"),
    "trials": ("tools.trials", "run an agent over episodes in simulation; resumable results and a metrics table"),
    "report": ("tools.report", "compare run folders: the paper-style table (text, Markdown) and PNG/HTML plots"),
    "view": ("tools.view", "open a rerun recording (.rrd) in the viewer, or say how to view it elsewhere"),
    "episodes": ("tools.episodes", "generate an episode split from a seed, or check an episode file"),
    "tsdf": ("tools.tsdf", "TSDF-reconstruct what an episode saw; report true-surface coverage, write the mesh"),
    "calibrate-perception": ("tools.calibrate_perception",
                             "measure the simulated detector: per-class precision/recall, 5-view majority; plot"),
}


def user_error_types() -> tuple[type[BaseException], ...]:
    """Exception classes that mean 'bad input', reported without a traceback."""
    from helios.schema import ConfigError
    from helios.perception.errors import PerceptionError
    from robots.hal import HalError
    from robots.spot.urdf import UrdfError
    from tasks.episodes import DatasetError
    from tasks.executors import ExecutorError
    from tasks.registry import UnknownAgentError
    from tasks.spec import TaskSpecError
    from tasks.trials import RunFolderError

    # HalError covers the Spot SDK backend's errors too (robots.spot.sdk_backend: CredentialsError,
    # SpotConnectError, SpotSdkMissingError and the HAL's RobotFault subclasses).
    return (ConfigError, HalError, UrdfError, CliError, FileNotFoundError, DatasetError, TaskSpecError,
            UnknownAgentError, RunFolderError, PerceptionError, ExecutorError)


class CliError(Exception):
    """A command-line usage problem detected after argument parsing."""


def _summary(doc: str) -> str:
    """A module docstring's first paragraph as one line (a sentence can wrap over lines)."""
    return " ".join(doc.strip().split("\n\n")[0].split())


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="helios", description="HELIOS testbed command line.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, (module, help_) in COMMANDS.items():
        mod = importlib.import_module(module)
        p = sub.add_parser(name, help=help_, description=_summary(mod.__doc__ or help_))
        mod.add_arguments(p)
        p.set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    from helios.runtime import configure_threads

    configure_threads(1)  # see helios.runtime: one native thread per process is fastest here
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(importlib.import_module(args._module).run(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except user_error_types() as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
