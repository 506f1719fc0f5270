"""The ``helios`` / ``python -m tools`` command line.

Each command lives in its own module with ``add_arguments(parser)`` and ``run(args) -> int``;
heavy imports (PyBullet, torch) happen inside ``run`` so ``--help`` stays instant. Errors caused by
the user's input are printed as one line (``error: ...``) with exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import os
import sys
import tempfile
from pathlib import Path

# command name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("tools.demo", "scripted Spot pick-and-place in a small scene; prints the outcome, writes a .rrd"),
    "bench": ("tools.bench", "performance benchmarks printed as tables (sim, ...)"),
    "spot": ("tools.spot", "run an agent on a real Spot via the Spot SDK (--fake: dry run against a simulated Spot)"),
    "trials": ("tools.trials", "run an agent over episodes in simulation; resumable results and a metrics table"),
    "report": ("tools.report", "compare run folders: the paper-style table (text, Markdown) and PNG/HTML plots"),
    "diff": ("tools.diff_runs", "which episodes' records differ between two run folders, field by field "
                                "(exit 1 if any, or if an episode is in one run only; --common: the episodes "
                                "both have): did a change keep every result?"),
    "unchanged": ("tools.unchanged", "run val episodes with a commit's code and with this working tree, here, and "
                                     "compare the records (exit 1 if any differs): the refactor check"),
    "view": ("tools.view", "open a rerun recording (.rrd) in the viewer, or say how to view it elsewhere"),
    "episodes": ("tools.episodes", "generate an episode split from a seed, or check an episode file"),
    "tsdf": ("tools.tsdf", "TSDF-reconstruct what an episode saw; report true-surface coverage, write the mesh"),
    "arm-envelope": ("tools.arm_envelope", "measure where the simulated arm goes when it looks and check the "
                                           "agent's table of it (arm_model=measured); writes a picture"),
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
    from tasks.plugin_agents import PluginAgentError
    from tasks.registry import UnknownAgentError
    from tasks.spec import TaskSpecError
    from tasks.run_folder import RunFolderError

    # HalError covers the Spot SDK backend's errors too (robots.spot.sdk_backend: CredentialsError,
    # SpotConnectError, SpotSdkMissingError and the HAL's RobotFault subclasses).
    return (ConfigError, HalError, UrdfError, CliError, FileNotFoundError, DatasetError, TaskSpecError,
            UnknownAgentError, PluginAgentError, RunFolderError, PerceptionError, ExecutorError)


def is_robot_fault(exc: BaseException) -> bool:
    """A fault of the robot (e-stop, lost lease, power, a command that timed out), not of the input:
    exit status 1, as for a fault mid-run (README, real Spot). Not reaching the robot at all (wrong
    host or port, untrusted certificate, nothing listening: ``SpotConnectError``) stays bad input, 2."""
    from robots.hal import RobotFault

    if not isinstance(exc, RobotFault):
        return False
    from robots.spot.sdk_backend import SpotConnectError      # only for robot faults: no import otherwise

    return not isinstance(exc, SpotConnectError)


class CliError(Exception):
    """A command-line usage problem detected after argument parsing."""


MAX_ERROR_CHARS = 1000       # an error line longer than this is shortened in the middle


def one_line(message: object, limit: int = MAX_ERROR_CHARS) -> str:
    """An error message as one line of at most ``limit`` characters."""
    from helios.schema import shorten

    return shorten(" ".join(str(message).split("\n")).strip(), limit)


def _writable(directory: Path) -> str | None:
    """None when a file can be created in ``directory`` (an existing folder), else why not. Probes
    by making and removing an empty folder (``os.access`` is no help when running as root)."""
    try:
        probe = tempfile.mkdtemp(prefix=".helios-write-test-", dir=directory)
        os.rmdir(probe)
        return None
    except OSError as exc:
        if exc.errno == errno.ENOENT:       # an existing folder that refuses new entries (/proc, /sys)
            return "no file or folder can be made there"
        return exc.strerror or str(exc)


def _nearest_existing(path: Path) -> tuple[Path, Path | None]:
    """The nearest existing ancestor of ``path`` (or itself), and the first non-directory met on the way."""
    for parent in [path, *path.parents]:
        if parent.exists() or parent.is_symlink():
            return parent, (None if parent.is_dir() else parent)
    return Path("."), None


def resolved(path, what: str = "path") -> Path:
    """``Path(path).resolve()``, or one CliError when it cannot be resolved (a symbolic link loop:
    Python raises RuntimeError, which reached ``report`` and ``diff`` users as a traceback)."""
    try:
        return Path(path).resolve()
    except (RuntimeError, OSError) as exc:
        why = "a symbolic link loop" if isinstance(exc, RuntimeError) else exc.strerror or exc
        raise CliError(f"{what} '{shown_path(path)}' cannot be resolved ({why})") from None


def same_folder_twice(paths) -> tuple[str, str] | None:
    """The first of ``paths`` that names an existing folder named before (``./run`` and ``run/``
    alike), with that earlier name; None if none does. A run compared with itself is identical by
    construction (``diff``, ``report``)."""
    seen: dict[Path, str] = {}
    for given in map(str, paths):
        where = resolved(given)
        if where in seen and Path(given).exists():
            return given, seen[where]
        seen.setdefault(where, given)
    return None


def shown_path(path) -> str:
    """A path as text that can always be printed: bytes that are not UTF-8 as ``\\xNN``."""
    return os.fsencode(str(path)).decode("utf-8", "backslashreplace")


def check_text_path(path, what: str) -> None:
    """CliError when ``path`` is not UTF-8 text (a name made of other bytes): run folders are read
    back by ``report`` and ``diff``, which write their paths into UTF-8 pages and tables."""
    try:
        str(path).encode("utf-8")
    except UnicodeEncodeError:
        raise CliError(f"{what} '{shown_path(path)}': its name is not UTF-8 text, which the pages and tables "
                       f"of reports cannot show; rename it to a UTF-8 name") from None


def check_output_dir(path: str | Path, flag: str = "--out") -> Path:
    """``path`` can be (or already is) a folder we can write in; CliError naming ``flag`` otherwise.
    Reads only (a probe folder is made and removed again): call it before any work starts."""
    from helios.schema import short_repr

    p = Path(path)
    if not str(path).strip():
        raise CliError(f"{flag} must not be empty")
    if "\0" in str(path):
        raise CliError(f"{flag} {short_repr(str(path))} contains a NUL character")
    check_text_path(path, flag)
    existing, blocker = _nearest_existing(p)
    if blocker is not None:
        what = "is an existing file" if blocker == p else f"is inside {str(blocker)!r}, which is a file"
        raise CliError(f"{flag} {short_repr(str(p))} {what}; it must name a folder")
    why = _writable(existing)
    if why is not None:
        raise CliError(f"{flag} {short_repr(str(p))}: cannot write in {str(existing)!r} ({why})")
    return p


def check_output_file(path: str | Path, flag: str = "--out") -> Path:
    """``path`` can be written as a file (made or replaced); CliError naming ``flag`` otherwise."""
    from helios.schema import short_repr

    p = Path(path)
    if not str(path).strip():
        raise CliError(f"{flag} must not be empty")
    check_text_path(path, flag)
    if p.is_dir():
        raise CliError(f"{flag} {short_repr(str(p))} is a folder; it must name a file")
    if p.exists() and not p.is_file():      # written by replacing it: /dev/null or a FIFO would be replaced
        raise CliError(f"{flag} {short_repr(str(p))} is a device, FIFO or socket; it must name a regular file")
    if str(path).endswith(("/", os.sep)):
        raise CliError(f"{flag} {short_repr(str(p))} ends with a slash; it must name a file")
    check_output_dir(p.parent if str(p.parent) else Path("."), flag=f"{flag} {short_repr(str(p))}: its folder")
    if p.exists() and _writable(p.parent) is None and not os.access(p, os.W_OK):
        raise CliError(f"{flag} {short_repr(str(p))} exists and cannot be replaced")
    return p


MAX_SEED = 2 ** 32 - 1       # NumPy seeds are 32-bit: every command's seed (trials' TrialConfig.seed too)


def check_seed(value: int, flag: str = "--seed") -> int:
    """A seed within 0..MAX_SEED, else CliError naming ``flag`` (the range ``trials`` and ``demo`` check)."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_SEED:
        raise CliError(f"{flag} must be within 0..{MAX_SEED}, got {value}")
    return value


def check_finite(value: float, flag: str, positive: bool = False) -> float:
    """A finite number (and > 0 with ``positive``), else CliError naming ``flag``."""
    import math

    if not math.isfinite(value) or (positive and value <= 0):
        raise CliError(f"{flag} must be a {'positive ' if positive else ''}finite number, got {value}")
    return value


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one ``error:`` line (exit status 2) like every other error,
    and no flag may be shortened: ``--ou X`` beside ``--out Y`` once ran in X, past the check
    for a flag given twice (sub-parsers, made by this class, inherit both)."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message: str):  # noqa: D401 - argparse's hook
        self.exit(2, f"error: {one_line(self.prog + ': ' + message)} (see: {self.prog} --help)\n")


def _summary(doc: str) -> str:
    """A module docstring's first paragraph as one line (a sentence can wrap over lines)."""
    return " ".join(doc.strip().split("\n\n")[0].split())


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="helios", description="HELIOS testbed command line.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, (module, help_) in COMMANDS.items():
        mod = importlib.import_module(module)
        p = sub.add_parser(name, help=help_, description=_summary(mod.__doc__ or help_))
        mod.add_arguments(p)
        p.set_defaults(_module=module)
    return parser


def _refuse_repeated_flags(parser: argparse.ArgumentParser, argv: list[str]) -> None:
    """A flag that takes one value (or a fixed number of them), given twice, is a usage error:
    argparse keeps the last one silently (``make run ARGS="--out X"`` once ran in X and reported the
    Makefile's folder)."""
    single = {opt: action for action in parser._actions if type(action) is argparse._StoreAction
              and (action.nargs in (None, "?") or isinstance(action.nargs, int)) for opt in action.option_strings}
    seen: dict[argparse.Action, str] = {}
    for i, token in enumerate(argv):
        if token == "--":
            break
        flag = token.split("=", 1)[0] if token.startswith("--") else token
        action = single.get(flag)
        if action is None:
            continue
        n = action.nargs if isinstance(action.nargs, int) else 1
        given = token if "=" in token else " ".join(argv[i:i + 1 + n])
        if action in seen:
            parser.error(f"{flag} is given twice ({seen[action]!r} and {given!r}); give it once")
        seen[action] = given


def _command_parser(parser: argparse.ArgumentParser, args: argparse.Namespace) -> argparse.ArgumentParser:
    """The innermost sub-parser the arguments chose (``episodes generate``), so that its usage errors
    name it (``helios trials: ...``) and its flags are the ones checked for repeats."""
    while True:
        chosen = next((action.choices.get(getattr(args, action.dest, None)) for action in parser._actions
                       if isinstance(action, argparse._SubParsersAction)), None)
        if chosen is None:
            return parser
        parser = chosen


def parse_arguments(parser: argparse.ArgumentParser, argv: list[str] | None) -> argparse.Namespace:
    """``parser.parse_args``, except that ``KEY=VALUE`` overrides may stand anywhere among the flags
    (argparse gives a positional list only its first run: ``trials a=1 --out X b=2`` would refuse
    ``b=2``). Later runs are appended in command-line order, so a later override still wins."""
    args, extras = parser.parse_known_args(argv)
    command = _command_parser(parser, args)      # usage errors name it: "helios trials: ..."
    _refuse_repeated_flags(command, sys.argv[1:] if argv is None else argv)
    if extras:
        overrides = getattr(args, "overrides", None)
        if args.command == "spot" or not isinstance(overrides, list) or \
                not all("=" in e and not e.startswith("-") for e in extras):
            command.error(f"unrecognized arguments: {' '.join(extras)}")
        args.overrides = [*overrides, *extras]
    return args


def main(argv: list[str] | None = None) -> int:
    from helios.runtime import check_cpu_choice, configure_threads

    try:
        check_cpu_choice(os.environ)      # HELIOS_CPU (read when `tools` was imported, before NumPy)
    except ValueError as exc:
        print(f"error: {one_line(exc)}", file=sys.stderr)
        return 2
    configure_threads(1)  # see helios.runtime: one native thread per process is fastest here
    try:
        parser = build_parser()          # imports every command's module: a Ctrl-C may land here too
        args = parse_arguments(parser, argv)
        return int(importlib.import_module(args._module).run(args) or 0)
    except KeyboardInterrupt as exc:       # Ctrl-C; SIGTERM/SIGHUP where a command turns them into one
        print(f"interrupted ({exc})" if str(exc) else "interrupted", file=sys.stderr)
        return 130
    except user_error_types() as exc:
        print(f"error: {one_line(exc)}", file=sys.stderr)
        return 1 if is_robot_fault(exc) else 2
    except (OSError, UnicodeError) as exc:
        # The environment refused something (a file or folder that cannot be written, a full disk,
        # a file that is not text): one line, like bad input. HELIOS_DEBUG=1 shows the traceback.
        if os.environ.get("HELIOS_DEBUG"):
            raise
        where = f": {exc.filename}" if getattr(exc, "filename", None) else ""
        print(f"error: {one_line((getattr(exc, 'strerror', None) or exc) if where else exc)}{one_line(where, 300)}",
              file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
