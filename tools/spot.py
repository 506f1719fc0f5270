"""Run an agent on a real Spot through the Spot SDK (--fake: a dry run against a simulated Spot).

``--fake`` starts a local fake Spot backed by the simulator and runs the same code path end to
end (unmodified bosdyn client, TLS, gRPC): a hardware dry run.

    BOSDYN_CLIENT_USERNAME=... BOSDYN_CLIENT_PASSWORD=... \\
        python -m tools spot 192.168.80.3 --task "Move the mug from the stool to the table"
    python -m tools spot --fake --task "Move the mug from the stool to the table"
    python -m tools spot --fake --episode smoke-00001 --agent helios
    python -m tools spot 192.168.80.3 --agent helios --task "Move the mug from the stool to the table" \
        --detector-weights weights/owlv2 --scorer-weights weights/clip          # HELIOS, real perception
    python -m tools spot --fake --episode smoke-00001 --agent helios --perception real \
        --detector-weights weights/owlv2 --scorer-weights weights/clip

Bring-up: resolve, TLS + authenticate (credentials from the environment only), time sync, e-stop
check, lease, power on, stand. Shutdown (always, also after a fault or Ctrl-C): stop, stow, sit
and power off, return the lease. A run folder (``--out``/name) gets the resolved backend config,
the session log and the outcome; never credentials or tokens.

Agents come from ``tasks.registry``, the registry ``tools trials`` uses. On the demo layout:
``scripted-demo`` (``tasks.scripted_demo``, the pick-and-place of ``tools demo``, given the demo
layout instead of a detector). ``--fake --episode ID`` instead serves a task episode's home and
runs any task-episode agent (HELIOS with its simulated detector fed the fake's ground truth for
each SDK image) through ``tasks.fake_sdk``, scored by the simulator's judge: the same episode and
agent code as ``tools trials`` on the sim backend, over the SDK.

HELIOS (and the other task-episode agents that need no ground truth: ``helios``, ``trusting``,
...) runs on a real robot with real perception: the OWLv2 detector and CLIP scorer of
``helios.perception.adapters`` from local weight folders (``--models FILE.yaml``, a
``helios.perception.config.ModelConfig``, and/or ``--detector-weights``/``--scorer-weights``),
loaded before the robot is touched. The run is capped at ``--max-time`` (600 s, the paper's 10
minutes). At the end the robot is shut down and the operator is asked what the robot cannot
judge (is the object on the goal receptacle, at rest; collisions it did not report), or answers
with ``--on-goal``/``--at-rest``/``--extra-collisions``; one record in the schema of simulated
trials is appended to the run folder's ``episodes.jsonl`` (``tasks.hardware``), with a rerun
recording in ``recordings/``, so ``python -m tools report`` reads hardware folders next to sim
runs. ``--fake --episode ID --perception real`` runs the same agent with the same models on the
fake (scored by the simulator's judge) and records it the same way.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import secrets
import signal
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

from tasks.registry import (DEMO, EPISODE, RunContext, agent_names, check_agent, check_robot_agent, make_agent,
                            robot_agent_names)
from tasks.scripted_demo import DemoHints, physical_outcome

_LOG = logging.getLogger("helios.spot")
DEFAULT_MAX_TIME = 600.0        # s of robot time per task-episode run (the paper's 10 minutes)
FAKE_CONNECTION_KEYS = ("hostname", "port", "cert_path")
"""The SdkBackendConfig keys ``--fake`` replaces with the fake Spot's own (127.0.0.1, its ephemeral
port, its throwaway CA: ``_start_fake``, and ``tasks.fake_sdk`` for ``--fake --episode``). Given
with ``--fake`` (``--set``, ``--config``) they would be silently dropped, so they are refused."""


# ============================================================================ command line
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("hostname", nargs="?", help="the robot's hostname or IP address (omit with --fake)")
    parser.add_argument("--task", default=None,
                        help='what to do, e.g. "Move the mug from the stool to the table" (not with --episode)')
    parser.add_argument("--agent", default=None,
                        help=f"agent to run (demo layout: {', '.join(agent_names(DEMO))}, the default; with "
                             f"--episode: an agent of `python -m tools trials`, default helios)")
    parser.add_argument("--episode", default=None, metavar="ID",
                        help="--fake only: serve this task episode's scene (e.g. smoke-00001) and run the agent "
                             "on it, scored like a simulated trial")
    parser.add_argument("--split", default=None, help="--episode: split to look the id up in (default: the id's prefix)")
    parser.add_argument("--fake", action="store_true",
                        help="start a fake Spot on 127.0.0.1 backed by the simulator and run against it "
                             "(a hardware dry run through the unmodified Spot SDK over TLS)")
    parser.add_argument("--port", type=int, default=None, help="the robot's secure gRPC port (default 443)")
    parser.add_argument("--cert", default=None,
                        help="CA certificate (PEM) the robot's TLS certificate must chain to "
                             "(default: Boston Dynamics' root CA shipped with bosdyn-client)")
    parser.add_argument("--estop", choices=("external", "endpoint"), default=None,
                        help="external: an e-stop held elsewhere must be released (default); endpoint: this "
                             "client registers its own software e-stop")
    parser.add_argument("--take-lease", action="store_true", help="take the body lease from its current holder")
    parser.add_argument("--seed", type=int, default=0,
                        help="--fake: demo scene seed (mug placement); with --episode: the seed `tools trials "
                             "--seed` takes (the episode's agent and simulated perception get the seed the trial "
                             "gives that episode)")
    parser.add_argument("--out", default="runs/spot", help="parent folder of the run folder")
    parser.add_argument("--name", default=None, help="run folder name (default: a timestamp)")
    parser.add_argument("--set", dest="overrides", action="extend", nargs="+", default=[], metavar="KEY=VALUE",
                        help="SDK backend config overrides, e.g. --set rpc_timeout=2.0 estop_timeout=5 "
                             "(schema: robots/spot/sdk_config.py SdkBackendConfig)")
    parser.add_argument("--config", default=None, metavar="FILE.yaml",
                        help="SDK backend scenario file (SdkBackendConfig YAML, e.g. configs/spot_fake.yaml or a run "
                             "folder's robot.yaml); HOSTNAME, --port, --cert, --estop, --take-lease and --set "
                             "override it. With --fake neither it nor --set may set hostname, port or cert_path "
                             "(the fake Spot's own)")
    hw = parser.add_argument_group("task-episode agents on a robot (HELIOS with real perception)")
    hw.add_argument("--perception", choices=("real", "sim"), default=None,
                    help="real: OWLv2 + CLIP from local weights (the default on a robot); sim: the simulated detector "
                         "(--fake --episode only, its default)")
    hw.add_argument("--models", default=None, metavar="FILE.yaml",
                    help="real perception settings (helios.perception.config.ModelConfig YAML: detector_weights, "
                         "scorer_weights, device, detector_min_score, depth_mask_tolerance; relative folders are "
                         "taken from the current directory, not the file's)")
    hw.add_argument("--detector-weights", default=None, metavar="DIR", help="OWLv2 weight folder (overrides --models)")
    hw.add_argument("--scorer-weights", default=None, metavar="DIR", help="CLIP weight folder (overrides --models)")
    hw.add_argument("--device", choices=("cpu", "cuda", "auto"), default=None,
                    help="torch device for the models (overrides --models; default cpu)")
    hw.add_argument("--max-time", type=float, default=None,
                    help=f"s of robot time per run before the agent is stopped (default {DEFAULT_MAX_TIME:g}: the "
                         f"paper's 10 minutes)")
    hw.add_argument("--trial-id", default=None, help="episode id of this robot run (default hw-<time>-<task>)")
    hw.add_argument("--on-goal", default=None, metavar="yes|no",
                    help="operator's answer: the object is on the goal receptacle (default: asked at the end)")
    hw.add_argument("--at-rest", default=None, metavar="yes|no",
                    help="operator's answer: the object is at rest (default: asked at the end)")
    hw.add_argument("--extra-collisions", type=int, default=None, metavar="N",
                    help="operator's answer: collisions the robot did not report (default: asked, 0)")
    hw.add_argument("--no-recording", action="store_true", help="no rerun recording of the run")
    parser.add_argument("--time-scale", type=float, default=None, metavar="S",
                        help="--fake: wall seconds per robot second (1 = real time: motions take as long as on "
                             "Spot; default: as fast as the simulator runs)")


class _RunLog(logging.Handler):
    """Session log of the run folder: our loggers at INFO, everything else at WARNING. Lines are
    buffered until the folder exists (it is made only once the robot is connected, so a typo in
    the hostname leaves no empty run behind)."""

    def __init__(self):
        super().__init__(logging.INFO)
        self._fh = None
        self._failed = False
        self._buffer: list[str] = []
        self.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))

    def open(self, path: Path) -> None:
        self._fh = open(path, "a", encoding="utf-8")
        self._fh.writelines(line + "\n" for line in self._buffer)
        self._fh.flush()
        self._buffer = []

    def emit(self, record: logging.LogRecord) -> None:
        if self._failed or (record.levelno < logging.WARNING and not record.name.startswith("helios")):
            return
        try:
            line = self.format(record)
            if self._fh is None:
                self._buffer.append(line)
            else:
                self._fh.write(line + "\n")
                self._fh.flush()
        except OSError as exc:      # a full disk: one warning, then the run goes on without its log
            self._failed = True     # (logging's handleError printed a traceback for every line)
            print(f"[spot] warning: session.log cannot be written ({exc.strerror or exc}); the run goes on "
                  f"without it", file=sys.stderr)
        except Exception:  # noqa: BLE001 - logging must not break the run
            self.handleError(record)

    def close(self) -> None:
        if self._fh is not None:
            try:
                self._fh.close()
            except OSError:         # its last buffered write failed (a full disk): said in emit()
                pass
        super().close()


def _refuse_ignored(args: argparse.Namespace) -> None:
    """A flag that would have no effect in this mode is one error saying so, never silently ignored.
    Modes: a demo-layout agent (``--fake --task``, or ``scripted-demo`` on a robot), a task-episode
    agent on a robot (``HOSTNAME --agent helios --task``), and ``--fake --episode ID``."""
    from tools.cli import CliError

    episode_agent = args.episode is not None or check_agent(args.agent, None).runs_on == EPISODE
    operator = (("--on-goal", args.on_goal is not None), ("--at-rest", args.at_rest is not None),
                ("--extra-collisions", args.extra_collisions is not None))
    models = (("--models", args.models), ("--detector-weights", args.detector_weights),
              ("--scorer-weights", args.scorer_weights), ("--device", args.device))
    if not episode_agent:
        for flag, given in (("--perception", args.perception is not None), *models,
                            ("--max-time", args.max_time is not None), ("--trial-id", args.trial_id is not None),
                            *operator, ("--no-recording", args.no_recording)):
            if given:
                raise CliError(f"{flag} is for task-episode agents (--fake --episode ID, or HELIOS & co. on a robot); "
                               f"{args.agent} is given the demo layout, where {flag} is ignored")
        return
    if args.perception != "real":
        for flag, given in models:
            if given:
                raise CliError(f"{flag} sets up real perception; it is ignored with --perception {args.perception} "
                               f"(give --perception real to run the models)")
    if args.fake:                                   # --fake --episode: the simulator judges and names the run
        if args.trial_id is not None:
            raise CliError("--trial-id names a run on a real robot; with --episode the record takes the episode's id")
        for flag, given in operator:
            if given:
                raise CliError(f"{flag} is the operator's answer on a real robot; it is ignored with --fake --episode, "
                               f"where the simulator judges the episode")


DEMO_OBJECT, DEMO_GOAL = "mug", "table"     # the demo layout: a mug on its pick table, a place table


def _check_demo_task(spec, agent: str) -> None:
    """A demo-layout agent carries the layout's mug to its place table whatever the task says; a
    task asking for another object or goal is refused, not run as the demo and reported SUCCESS
    (audit 2026-12-05). The start receptacle is the layout's pick table under whatever name the
    task gives it (the paper's hardware set-up calls it the stool)."""
    from tools.cli import CliError

    if (spec.object, spec.goal_receptacle) != (DEMO_OBJECT, DEMO_GOAL):
        raise CliError(f"{agent} carries the demo layout's {DEMO_OBJECT} to its place {DEMO_GOAL}; the task asks for "
                       f"the {spec.object} to the {spec.goal_receptacle} (a task agent takes any task: --fake --episode "
                       f"ID, or --agent helios on a robot)")


def _validate(args: argparse.Namespace):
    from tools.cli import CliError, check_seed

    if args.hostname is not None and "=" in args.hostname:
        # `spot --task ... rpc_timeout=2`: argparse takes the override for the hostname; caught
        # here, before any other check would name the wrong problem (an unresolvable host, or
        # "leave out the hostname" with --fake).
        from helios.schema import short_repr

        raise CliError(f"hostname {short_repr(args.hostname, 80)} looks like a setting; pass settings with "
                       f"--set KEY=VALUE")
    from tasks.plugin_agents import is_plugin_spec

    if args.agent is not None and is_plugin_spec(args.agent):         # `tools trials` only
        from helios.schema import short_repr

        raise CliError(f"--agent {short_repr(args.agent, 80)}: agents of your own run in simulated trials (`tools "
                       f"trials --agent FILE.py:FACTORY`), not on a robot or the fake one; agents here: "
                       f"{', '.join(agent_names(None))}")
    if args.episode is not None:
        if not args.fake:
            raise CliError("--episode needs --fake: an episode's scene exists only in the simulator")
        if args.task is not None:
            raise CliError("--episode brings its own task; leave out --task")
        if args.agent is None:
            args.agent = "helios"
        entry = check_agent(args.agent, EPISODE)
        if args.perception is None:
            args.perception = "sim"
        if args.perception == "real" and not entry.real_robot:
            # the oracle and the -gt agents read the simulator's ground truth: real models would be
            # loaded and ignored (oracle), or refused only after the robot stood up (-gt) (audit)
            raise CliError(f"--perception real: agent {args.agent!r} reads the simulator's ground truth and uses no "
                           f"detector; agents that take real perception: "
                           f"{', '.join(n for n in robot_agent_names() if check_agent(n, None).runs_on == EPISODE)}")
    else:
        if not args.task or not args.task.strip():
            raise CliError("--task must not be empty (e.g. --task \"Move the mug from the stool to the table\")")
        from tasks.spec import parse_task

        spec = parse_task(args.task)               # a task the agents can read, else one TaskSpecError line
        if args.agent is None:
            args.agent = "scripted-demo"
        entry = check_agent(args.agent, DEMO) if args.fake else check_robot_agent(args.agent)
        if entry.runs_on == DEMO:
            _check_demo_task(spec, args.agent)
        if entry.runs_on == EPISODE:             # HELIOS & co. on a real robot: real perception only
            if args.perception == "sim":
                raise CliError("--perception sim needs the simulator's ground truth: on a robot HELIOS runs with "
                               "real perception (--perception real)")
            args.perception = "real"
    _refuse_ignored(args)
    if args.perception == "real" and not (args.models or args.detector_weights or args.scorer_weights):
        raise CliError("real perception needs the models' weight folders: --models FILE.yaml, or --detector-weights "
                       "DIR and --scorer-weights DIR (helios.perception.config.ModelConfig)")
    if args.max_time is not None and not (isinstance(args.max_time, float) and 0 < args.max_time <= 3600):
        raise CliError(f"--max-time must be within (0, 3600] s, got {args.max_time}")
    if args.max_time is None:
        args.max_time = DEFAULT_MAX_TIME
    if args.trial_id is not None:
        from helios.schema import short_repr
        from tasks.episodes import is_episode_id

        if not is_episode_id(args.trial_id):
            raise CliError(f"--trial-id {short_repr(args.trial_id, 80)} must be 1-100 letters, digits, '-', '_' or '.' "
                           f"(it names the run's recording)")
    if args.time_scale is not None:
        if not args.fake:
            raise CliError("--time-scale paces the fake Spot: it needs --fake")
        if not 0 < args.time_scale <= 100:
            raise CliError(f"--time-scale must be within (0, 100] wall seconds per robot second, got {args.time_scale}")
    if args.extra_collisions is not None and not 0 <= args.extra_collisions <= 1000:
        raise CliError(f"--extra-collisions must be within 0..1000, got {args.extra_collisions}")
    if args.fake and args.hostname:
        raise CliError("--fake runs against a local fake robot; leave out the hostname")
    if not args.fake and not args.hostname and not getattr(args, "config", None):
        raise CliError("the robot's HOSTNAME is required (or --fake for a dry run against a simulated Spot)")
    if args.port is not None and not 0 < args.port < 65536:
        raise CliError(f"--port must be within 1..65535, got {args.port}")
    if args.split is not None and not args.split.strip():    # an empty one once meant the id's prefix
        raise CliError("--split must not be empty")
    if args.episode is None and args.split:
        raise CliError("--split is where --episode ID is looked up; without --episode it is ignored")
    if args.fake:
        for flag, given in (("--port", args.port is not None), ("--cert", args.cert is not None)):
            if given:
                raise CliError(f"{flag} is ignored with --fake: the fake Spot listens on a port of its own with a "
                               f"throwaway certificate")
        _refuse_fake_connection_keys(args)
    check_seed(args.seed)
    if args.name is not None:
        import re

        from helios.schema import short_repr

        if not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,99}", args.name):
            raise CliError(f"--name {short_repr(args.name, 80)} must be 1-100 letters, digits, '-', '_' or '.' "
                           f"(it names a folder under --out)")


def _refuse_fake_connection_keys(args: argparse.Namespace) -> None:
    """With ``--fake``, a connection key (``FAKE_CONNECTION_KEYS``) from ``--set`` or the ``--config``
    file is one error, as ``--port``/``--cert`` are: the fake Spot replaces them with its own, so
    the value given would be silently ignored. The file is only read here (``_run`` loads it)."""
    from tools.cli import CliError

    why = ("the fake Spot sets hostname, port and cert_path itself (127.0.0.1, a port of its own, a throwaway "
           "certificate)")
    for item in args.overrides:
        key = item.split("=", 1)[0].strip()
        if key in FAKE_CONNECTION_KEYS:
            raise CliError(f"--set {key}=... is ignored with --fake: {why}")
    config_file = getattr(args, "config", None)
    if config_file:
        from helios.schema import read_config_file, short_repr

        given = [key for key in FAKE_CONNECTION_KEYS if key in read_config_file(config_file)]
        if given:
            raise CliError(f"config file {short_repr(str(config_file))} sets {', '.join(given)}, which --fake "
                           f"ignores: {why}; leave {'it' if len(given) == 1 else 'them'} out of the file for --fake")


def run(args: argparse.Namespace) -> int:
    _validate(args)
    with _terminate_as_interrupt():
        return _run(args)


@contextlib.contextmanager
def _terminate_as_interrupt():
    """SIGTERM (systemd, Docker, kill) and SIGHUP (a closed terminal or SSH session) end a robot run
    the way Ctrl-C does: through the shutdown path (stop, stow, sit, power off, return the lease).
    By default they kill the process at once and leave the robot powered and standing, holding our
    lease (QA 2026-12-04). All three raise KeyboardInterrupt only outside gRPC (held while an RPC
    is in flight, raised once it returns: ``robots.spot.signals.outside_grpc``); raised inside a blocking
    RPC it corrupted the heap or left the channel's lock held, and the shutdown that followed
    crashed (SIGABRT) or hung. A signal the process was started with ignored (SIG_IGN: SIGHUP
    under ``nohup``, SIGINT in a background job) stays ignored. Main thread only; the old handlers
    are restored after."""
    from robots.spot.signals import handling_signals, outside_grpc

    ctrl_c = signal.getsignal(signal.SIGINT)        # Python's KeyboardInterrupt, unless SIGINT is ignored

    def interrupt(signum, frame):
        if signum == signal.SIGINT:
            return ctrl_c(signum, frame)
        raise KeyboardInterrupt(signal.Signals(signum).name)

    names = ("SIGINT", "SIGTERM", "SIGHUP") if callable(ctrl_c) else ("SIGTERM", "SIGHUP")
    with handling_signals(names, outside_grpc(interrupt)):     # one ignored at start stays ignored (nohup)
        yield


def backend_config(hostname: str | None = None, *, port: int | None = None, cert: str | None = None,
                   estop: str | None = None, take_lease: bool = False, config_file: str | None = None,
                   overrides=(), fake: bool = False):
    """The ``SdkBackendConfig`` of a robot run: defaults < the ``--config`` file < the flags given
    (HOSTNAME, ``--port``, ``--cert``, ``--estop``, ``--take-lease``) < ``--set KEY=VALUE``. For a
    robot (not ``fake``) a hostname is required and a ``cert_path`` must be a regular file; each
    problem is one ``CliError``. ``tests/test_hardware.py`` builds its robot's config here too."""
    from helios.schema import load_config, with_overrides
    from robots.spot.sdk_config import SdkBackendConfig
    from tools.cli import CliError

    flags = {"hostname": hostname} if hostname else {}
    if port is not None:
        flags["port"] = port
    if cert is not None:
        flags["cert_path"] = cert
    if estop is not None:
        flags["estop_mode"] = estop
    if take_lease:
        flags["take_lease"] = True
    base = load_config(SdkBackendConfig, config_file) if config_file else SdkBackendConfig(hostname="127.0.0.1")
    config = with_overrides(with_overrides(base, flags), list(overrides))
    if not fake and not config.hostname:
        raise CliError(f"the robot's HOSTNAME is required: {config_file} sets none (or --fake for a dry run)")
    if not fake and config.cert_path is not None:     # --cert or the config file's cert_path
        path = Path(config.cert_path)
        if not path.exists():
            raise CliError(f"certificate file {config.cert_path!r} does not exist (--cert: the CA bundle, PEM)")
        if not path.is_file():
            raise CliError(f"certificate file {config.cert_path!r} is not a regular file (--cert: the CA bundle, PEM)")
    return config


def _run(args: argparse.Namespace) -> int:
    # grpc's C core prints its own TLS/connection diagnostics to stderr; our errors say it clearly.
    os.environ.setdefault("GRPC_VERBOSITY", "NONE")
    from helios.schema import dump_yaml
    from robots.hal import HalError
    from robots.spot.sdk_backend import PASSWORD_ENV, USERNAME_ENV, SdkSpotBackend
    from tools.cli import CliError

    config = backend_config(args.hostname, port=args.port, cert=args.cert, estop=args.estop,
                            take_lease=args.take_lease, config_file=getattr(args, "config", None),
                            overrides=args.overrides, fake=args.fake)

    from tools.cli import check_output_dir

    run_dir = check_output_dir(Path(check_output_dir(args.out)) / (args.name or time.strftime("%Y%m%d-%H%M%S")))
    if args.episode is not None:
        from tasks.episodes import load_split

        split = args.split or args.episode.split("-")[0]
        if not any(e.episode_id == args.episode for e in load_split(split)):
            from helios.schema import short_repr

            raise CliError(f"no episode {short_repr(args.episode, 80)} in split {short_repr(split, 40)}")
    trial = None
    if args.episode is not None or check_agent(args.agent, None).runs_on == EPISODE:
        trial = _prepare_trial(args, run_dir)        # folder, operator answers and models: before any robot
    else:
        if (run_dir / "outcome.json").exists():     # a scripted run's record is one outcome: never replaced
            raise CliError(f"run folder {run_dir} already holds a run (outcome.json); give another --name "
                           f"(or none: the date and time)")
        if not args.fake and args.seed != 0:
            raise CliError(f"--seed is ignored by agent {args.agent!r} on a robot (the scripted demo draws nothing "
                           f"at random; the seed places the mug in the fake Spot's scene)")
    handler = _RunLog()
    root = logging.getLogger()
    root.addHandler(handler)
    old_level = root.level
    root.setLevel(min(old_level or logging.WARNING, logging.INFO))
    demo = None
    saved_env: dict[str, str | None] = {}
    try:
        if args.episode is not None:
            return _run_episode(args, config, run_dir, handler, USERNAME_ENV, PASSWORD_ENV, trial)
        if trial is not None:
            return _run_hardware(args, config, run_dir, handler, trial)
        if args.fake:
            demo, config, saved_env = _start_fake(args, config, USERNAME_ENV, PASSWORD_ENV)
        hints = None
        print(f"[spot] connecting to {config.hostname}:{config.port}" + (" (fake Spot, dry run)" if demo else ""))
        backend = SdkSpotBackend(config)
        outcome, physical, agent_error = None, None, None
        try:
            run_dir.mkdir(parents=True, exist_ok=True)
            (run_dir / "config.yaml").write_text(dump_yaml(config))
            handler.open(run_dir / "session.log")
            rid = backend.robot_id
            print(f"[spot] connected to {rid.nickname or 'robot'} (serial {rid.serial_number}); "
                  f"e-stop {config.estop_mode}, lease held, standing")
            if demo is not None:
                hints = DemoHints.from_facts(demo.facts)
            else:
                hints = DemoHints.from_layout(backend.observe().body_pose)
            mug = hints.mug_position
            print(f"[spot] task: {args.task!r} (agent {args.agent}: mug expected at ({mug[0]:.2f}, {mug[1]:.2f}); "
                  f"goal: {hints.place_table.name})")
            agent = make_agent(args.agent, RunContext(task=args.task, seed=args.seed, hints=hints, say=print))
            outcome = agent.run(backend)
        except KeyboardInterrupt:
            print("[spot] interrupted: stopping the robot", file=sys.stderr)
            raise
        except (HalError, OSError):
            raise                     # robot faults, bad input, a run folder that cannot be written (a
                                      # full disk): one line from the command line, never "the agent failed"
        except Exception as exc:      # noqa: BLE001 - a bug in the agent: the robot is shut down below
            _LOG.exception("the agent failed")        # the traceback goes to session.log only
            agent_error = f"{type(exc).__name__}: {exc}"
        finally:
            print("[spot] shutting down: stop, stow, sit, power off, return the lease")
            backend.close()
        problem = backend.close_problem     # the shutdown could not stop the robot (the lease was not ours)
        if agent_error is not None:
            (run_dir / "outcome.json").write_text(json.dumps({"agent": args.agent, "task": args.task,
                                                              "success": False, "agent_error": agent_error,
                                                              "close_problem": problem}, indent=2))
            from tools.cli import one_line

            print(f"error: the agent failed ({one_line(agent_error, 300)}); {problem or 'the robot was shut down'}; "
                  f"traceback in {run_dir / 'session.log'}", file=sys.stderr)
            return 1
        if demo is not None:
            with demo.fake.sim_lock:
                physical = physical_outcome(demo.world, demo.scene, outcome.place_target)
        result = {"agent": args.agent, "task": args.task, "hostname": config.hostname, "fake": bool(demo),
                  "success": bool(outcome.success and (physical is None or physical["success"])),
                  "agent_success": outcome.success, "fault": outcome.fault,
                  "steps": [asdict(s) for s in outcome.steps], "physical": physical, "close_problem": problem}
        (run_dir / "outcome.json").write_text(json.dumps(result, indent=2))
        print()
        print(_format(result, run_dir))
        return _exit_status(result["success"], problem)
    finally:
        with _teardown_deferred(demo is not None):   # a further Ctrl-C/TERM/HUP is held, raised after
            try:
                if demo is not None:
                    from robots.spot.fake_spot.launch import stop_fake

                    stop_fake(demo, demo.pki.ca_cert.parent)
            finally:
                _restore_env(saved_env)
                root.removeHandler(handler)
                root.setLevel(old_level)
                handler.close()


class _Trial:
    """A task-episode agent's run on a robot (or the fake): its configuration, the run folder's
    fingerprint, the loaded perception, the operator's answers given as flags."""

    def __init__(self, config, fingerprint: str, perception, verdict):
        self.config, self.fingerprint, self.perception, self.verdict = config, fingerprint, perception, verdict


def _model_config(args):
    from helios.perception.config import ModelConfig
    from helios.schema import load_config, with_overrides

    models = load_config(ModelConfig, args.models) if args.models else ModelConfig()
    flags = {k: v for k, v in (("detector_weights", args.detector_weights), ("scorer_weights", args.scorer_weights),
                               ("device", args.device)) if v is not None}
    return with_overrides(models, flags) if flags else models


def _prepare_trial(args, run_dir: Path) -> _Trial:
    """Everything a task-episode run needs that can fail, checked before a robot is touched: the
    run folder takes this configuration, the operator can be asked (or answered by flags), the
    models' weights load."""
    from tasks.hardware import HardwareConfig, HardwareTrialError, load_robot_perception, prepare_hardware_folder, \
        verdict_from_flags
    from tasks.runner import RunnerConfig
    from tools.cli import CliError

    models = _model_config(args)
    setting = "fake" if args.fake else "hardware"
    config = HardwareConfig(agent=args.agent, setting=setting, seed=args.seed,
                            runner=RunnerConfig(max_sim_time=float(args.max_time)),
                            models=models if args.perception == "real" else type(models)())
    try:
        fingerprint = prepare_hardware_folder(run_dir, config, dry_run=True)
        verdict = verdict_from_flags(args.on_goal, args.at_rest, args.extra_collisions)
    except HardwareTrialError as exc:
        raise CliError(str(exc)) from None
    if setting == "hardware" and verdict is None and not sys.stdin.isatty():
        raise CliError("no terminal to ask the operator at the end of the run: give their answers with --on-goal "
                       "yes|no --at-rest yes|no [--extra-collisions N]")
    if setting == "fake" and verdict is not None:
        raise CliError("--on-goal/--at-rest are the operator's answers on a real robot; on the fake the simulator "
                       "judges the episode")
    perception = None
    if args.perception == "real" and models.device == "cuda":
        import torch

        if not torch.cuda.is_available():
            raise CliError(f"{'--device' if args.device else '--models ' + str(args.models) + ':'} cuda: no CUDA "
                           f"device here (torch.cuda.is_available() is False; torch {torch.__version__}); use cpu "
                           f"or auto")
    if args.perception == "real":
        from helios.perception.adapters import check_weights_dir

        # checked here first, so that the message names this command's flags (the loaders name the
        # config keys: perception.models.*)
        check_weights_dir(models.detector_weights, "OWLv2 detector", "--detector-weights (or detector_weights "
                          "in the --models file)", "google/owlv2-base-patch16-ensemble", model_type="owlv2")
        check_weights_dir(models.scorer_weights, "CLIP scorer", "--scorer-weights (or scorer_weights in the "
                          "--models file)", "openai/clip-vit-base-patch32", model_type="clip")
        print(f"[spot] loading real perception: detector {models.detector_weights or '?'}, scorer "
              f"{models.scorer_weights or '?'} ({models.device})")
        perception = load_robot_perception(models)       # missing weights: one error, no robot touched
    return _Trial(config, fingerprint, perception, verdict)


def _run_hardware(args, config, run_dir: Path, handler: "_RunLog", trial: _Trial) -> int:
    """A task-episode agent (HELIOS...) with real perception on a real robot: one hardware trial."""
    from helios.schema import dump_yaml
    from robots.spot.sdk_backend import SdkSpotBackend
    from tasks.hardware import HardwareTrialError, RobotTask, ask_operator, prepare_hardware_folder, \
        run_hardware_trial, trial_id
    from tools.cli import CliError

    task = RobotTask(args.trial_id or trial_id(args.task), args.task, args.seed)
    print(f"[spot] connecting to {config.hostname}:{config.port}")
    backend = SdkSpotBackend(config)
    try:
        try:
            prepare_hardware_folder(run_dir, trial.config)
        except HardwareTrialError as exc:
            raise CliError(str(exc)) from None
        (run_dir / "robot.yaml").write_text(dump_yaml(config))
        handler.open(run_dir / "session.log")
        rid = backend.robot_id
        print(f"[spot] connected to {rid.nickname or 'robot'} (serial {rid.serial_number}); e-stop {config.estop_mode}, "
              f"lease held, standing")
        print(f"[spot] {task.episode_id}: {args.agent} on {task.task!r}, at most {args.max_time:.0f} s")

        def close_robot():
            print("[spot] shutting down: stop, stow, sit, power off, return the lease")
            backend.close()

        def verdict():
            if trial.verdict is not None:
                return trial.verdict
            print(f"[spot] {backend.close_problem}. Operator, take over the robot, then check the scene:"
                  if backend.close_problem else "[spot] the robot is sitting, powered off. Operator, please check "
                                                "the scene:")
            return ask_operator(task.task)

        record = run_hardware_trial(backend, trial.config, task, trial.perception, run_dir, verdict=verdict,
                                    robot_info={"hostname": config.hostname, "nickname": rid.nickname,
                                                "serial": rid.serial_number},
                                    fingerprint=trial.fingerprint, record_rrd=not args.no_recording,
                                    close_robot=close_robot)
    except KeyboardInterrupt:
        print("[spot] interrupted: stopping the robot", file=sys.stderr)
        raise
    finally:
        backend.close()
    print()
    print(_format_record(record, run_dir))
    return _exit_status(record["success"], backend.close_problem)


def _exit_status(success: bool, close_problem: str | None) -> int:
    """0 for a successful run, 1 otherwise; a shutdown that could not stop the robot (the backend's
    ``close_problem``: the lease was not ours) fails the run whatever the task did, with one line."""
    if close_problem:
        print(f"error: {close_problem}", file=sys.stderr)
        return 1
    return 0 if success else 1


def _format_record(record: dict, run_dir: Path) -> str:
    from tools.tables import format_table

    m = record["metrics"]
    rows = [("result", "SUCCESS" if record["success"] else f"FAILED ({m['failure_reason']})"),
            ("episode", f"{record['episode_id']}: {record['task']}"),
            ("agent", f"{record['agent']} (seed {record['seed']})"),
            ("phases", "  ".join(f"{k}={'yes' if m[k] else 'no'}" for k in ("find_obj", "pick", "find_rec", "place"))),
            ("collisions", str(m["collisions"])), ("commands", str(record["commands"])),
            ("robot time", f"{record['sim_time']:.1f} s" + (" (limit reached)" if record["limit_hit"] else ""))]
    hw = record.get("hardware") or {}
    if hw.get("operator"):
        op = hw["operator"]
        rows.append(("operator", f"on goal: {'yes' if op['on_goal'] else 'no'}, at rest: "
                                 f"{'yes' if op['at_rest'] else 'no'}, unreported collisions: {op['extra_collisions']}"))
    if record.get("error"):
        rows.append(("error", record["error"].splitlines()[0]))
    if record.get("recording"):
        rows.append(("recording", record["recording"]["path"]))
    rows.append(("run folder", f"{run_dir} (python -m tools report {run_dir})"))
    return format_table(["outcome", "value"], rows, title="Spot trial")


def _check_fake_available() -> None:
    from tools.cli import CliError

    try:
        import cryptography  # noqa: F401  (makes the fake's throwaway CA)
        import robots.spot.fake_spot.launch  # noqa: F401
    except ImportError as exc:
        raise CliError(f"--fake needs {exc.name or 'cryptography'}: pip install -e '.[spot]' (in the checkout)") from None


def _dry_run_credentials(user_env: str, password_env: str) -> dict[str, str | None]:
    """Credentials for a dry run: the environment's, else a throwaway pair for this process only
    (never written anywhere). Returns the previous values, to restore."""
    saved = {user_env: os.environ.get(user_env), password_env: os.environ.get(password_env)}
    os.environ[user_env] = os.environ.get(user_env) or "helios-dry-run"
    os.environ[password_env] = os.environ.get(password_env) or secrets.token_urlsafe(16)
    return saved


def _restore_env(saved: dict[str, str | None]) -> None:
    """Put environment variables back as ``_dry_run_credentials`` found them."""
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value


def _run_episode(args, config, run_dir: Path, handler: "_RunLog", user_env: str, password_env: str,
                 trial: _Trial) -> int:
    """``--fake --episode``: the episode through SDK -> fake Spot -> PyBullet, scored by the judge;
    one record appended to the run folder's episodes.jsonl (with a rerun recording)."""
    from helios.schema import dump_yaml
    from tasks.episodes import load_split
    from tasks.fake_sdk import run_fake_sdk_episode
    from tasks.hardware import HardwareTrialError, prepare_hardware_folder
    from tasks.instrument import InstrumentedAgent
    from tasks.runner import RunnerConfig
    from tasks.run_folder import append_result
    from tasks.trial_config import episode_seed
    from tools.cli import CliError

    _check_fake_available()
    matches = [e for e in load_split(args.split or args.episode.split("-")[0]) if e.episode_id == args.episode]
    if not matches:
        raise CliError(f"no episode {args.episode!r} in split {args.split or args.episode.split('-')[0]!r}")
    episode = matches[0]
    # the seed `tools trials --seed` gives this episode (perception and agent): the same run as the trial's
    seed = episode_seed(args.seed, episode.episode_id)
    saved = _dry_run_credentials(user_env, password_env)

    def connected(backend) -> None:
        try:
            prepare_hardware_folder(run_dir, trial.config)
        except HardwareTrialError as exc:
            raise CliError(str(exc)) from None
        (run_dir / "robot.yaml").write_text(dump_yaml(backend.config))
        handler.open(run_dir / "session.log")
        rid = backend.robot_id
        print(f"[spot] connected to {rid.nickname or 'robot'} on 127.0.0.1:{backend.config.port} (fake Spot, "
              f"episode scene); e-stop {backend.config.estop_mode}, lease held, standing")
        print(f"[spot] running {args.agent} (seed {seed}: `tools trials --seed {args.seed}`'s for this episode)")

    print(f"[spot] episode {episode.episode_id}: {episode.task!r} (scene {episode.scene.seed}); "
          f"starting a fake Spot on it")
    holder: dict = {}

    def wrap(agent, ep):
        recorder = None
        if not args.no_recording:
            from tasks.recording import EpisodeRecorder

            path = run_dir / "recordings" / f"{episode.episode_id}-s{args.seed}.rrd"
            path.parent.mkdir(parents=True, exist_ok=True)
            recorder = EpisodeRecorder(path, recording_id=f"{args.agent}-{episode.episode_id}-fake")
            holder["path"] = path
        sim = ep.fake.sim
        state = lambda: (sim.world.time, sim.spot.T_world_body(), sim.spot.joint_positions())  # noqa: E731

        def locked_state():
            with ep.fake.sim_lock:
                return state()

        holder["agent"] = InstrumentedAgent(agent, recorder, locked_state if recorder is not None else None)
        return holder["agent"]

    options = {"perception": trial.perception} if trial.perception is not None else {}
    fake_options = {"time_scale": args.time_scale} if args.time_scale is not None else {}
    try:
        result = run_fake_sdk_episode(args.agent, episode, seed=seed, backend_config=config,
                                      config=RunnerConfig(max_sim_time=float(args.max_time)), agent_options=options,
                                      on_connected=connected, wrap_agent=wrap, fake_options=fake_options)
    finally:
        _restore_env(saved)
        inst = holder.get("agent")
        if inst is not None and inst.recorder is not None:
            from tasks.recording import close_recording

            failed = close_recording(inst.recorder, holder.get("path"),
                                     say=lambda line: print(line, file=sys.stderr))
            if failed:
                holder["recording_error"] = failed
    problem = result.extra.get("close_problem")
    if not problem:
        print("[spot] shut down: stopped, stowed, sat, powered off, lease returned; fake Spot stopped")
    outcome = {"fake": True, **result.as_dict()}
    (run_dir / "outcome.json").write_text(json.dumps(outcome, indent=2, default=str))
    record = result.as_dict()
    record["config_fingerprint"] = trial.fingerprint
    record["collision_events"] = record["extra"].pop("collision_events", [])
    record["memory"] = holder["agent"].probe.summary() if "agent" in holder else None
    record["hardware"] = {"setting": "fake", "operator": None, "perception": args.perception,
                          "log_file": "session.log"}
    if "path" in holder:
        record["recording"] = {"path": str(holder["path"]), "errors": list(holder["agent"].hook_errors)
                               + ([holder["recording_error"]] if "recording_error" in holder else [])}
    append_result(run_dir / "episodes.jsonl", record)
    print()
    print(_format_episode(result, run_dir))
    return _exit_status(result.success, problem)


def _format_episode(result, run_dir: Path) -> str:
    from tools.tables import format_table

    m = result.metrics
    rows = [("result", "SUCCESS" if result.success else f"FAILED ({m.failure_reason if m else 'no metrics'})"),
            ("episode", f"{result.episode_id}: {result.task}"), ("agent", f"{result.agent} (seed {result.seed})")]
    if m is not None:
        rows += [(name, "yes" if getattr(m, name) else "no") for name in ("find_obj", "pick", "find_rec", "place")]
        rows += [("collisions", str(m.collisions)), ("released on", m.released_on or "-")]
    rows += [("commands", str(result.commands)), ("robot time", f"{result.sim_time:.1f} s"),
             ("wall time", f"{result.wall_time:.1f} s")]
    if result.limit_hit:
        rows.append(("limit", "episode budget used up"))
    if result.error:
        rows.append(("error", result.error.splitlines()[0]))
    rows.append(("run folder", str(run_dir)))
    return format_table(["outcome", "value"], rows, title="Spot episode (fake robot, SDK)")


def _start_fake(args, config, user_env: str, password_env: str):
    """Start the fake Spot (demo scene) and point the config at it. Without credentials in the
    environment, a throwaway pair is made for this process only (never written anywhere)."""
    _check_fake_available()
    from robots.spot.fake_spot.launch import start_demo_fake, stop_fake

    saved = _dry_run_credentials(user_env, password_env)
    user, password = os.environ[user_env], os.environ[password_env]
    pki_dir = tempfile.mkdtemp(prefix="helios-fake-spot-")
    demo = None
    try:
        demo = start_demo_fake(pki_dir, user, password, seed=args.seed, time_scale=args.time_scale)
        from helios.schema import with_overrides

        config = with_overrides(config, {"hostname": "127.0.0.1", "port": demo.port,     # FAKE_CONNECTION_KEYS
                                         "cert_path": str(demo.pki.ca_cert)})
        print(f"[spot] fake Spot (demo scene, seed {args.seed}) on 127.0.0.1:{demo.port}, test CA {demo.pki.ca_cert}")
    except BaseException:                # also Ctrl-C before _run holds the fake: stop it, remove the CA
        with _teardown_deferred():
            try:
                stop_fake(demo, pki_dir)
            finally:
                _restore_env(saved)
        raise
    return demo, config, saved


def _teardown_deferred(fake: bool = True):
    """Ctrl-C, SIGTERM and SIGHUP held while the run's log is closed and (``fake``) the fake Spot
    stopped (``robots.spot.fake_spot.launch.stop_fake``), delivered after
    (``robots.spot.signals.signals_deferred``)."""
    from robots.spot.signals import signals_deferred

    if fake:
        from robots.spot.fake_spot.launch import TEARDOWN_MESSAGE

        return signals_deferred(message=TEARDOWN_MESSAGE)
    return signals_deferred(message="closing the session log first")


def _format(result: dict, run_dir: Path) -> str:
    from tools.tables import format_table

    rows = [("result", "SUCCESS" if result["success"] else "FAILED"),
            ("agent", f"{result['agent']} ({'all steps ok' if result['agent_success'] else 'a step failed'})")]
    if result["fault"]:
        rows.append(("robot fault", result["fault"]))
    phys = result.get("physical")
    if phys:
        rows.append(("mug resting on", phys["resting_on"] or "nothing (in the air or on the floor)"))
        rows.append(("mug settled", "yes" if phys["settled"] else "no"))
        rows.append(("final mug position", "(" + ", ".join(f"{v:.3f}" for v in phys["final_position"]) + ") m"))
        if "offset_from_target" in phys:
            rows.append(("offset from release point", f"{100 * phys['offset_from_target']:.1f} cm"))
    rows.append(("run folder", str(run_dir)))
    return format_table(["outcome", "value"], rows, title="Spot run" + (" (fake robot)" if result["fake"] else ""))
