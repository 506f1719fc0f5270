"""Run an agent on a real Spot through the Spot SDK (--fake: a dry run against a simulated Spot).

``--fake`` starts a local fake Spot backed by the simulator and runs the same code path end to
end (unmodified bosdyn client, TLS, gRPC): a hardware dry run.

    BOSDYN_CLIENT_USERNAME=... BOSDYN_CLIENT_PASSWORD=... \\
        python -m tools spot 192.168.80.3 --task "Move the mug from the stool to the table"
    python -m tools spot --fake --task "Move the mug from the stool to the table"
    python -m tools spot --fake --episode smoke-00001 --agent helios

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
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import secrets
import shutil
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

from tasks.registry import DEMO, EPISODE, RunContext, agent_names, check_agent, make_agent
from tasks.scripted_demo import DemoHints, physical_outcome

_LOG = logging.getLogger("helios.spot")


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
    parser.add_argument("--split", default="", help="--episode: split to look the id up in (default: the id's prefix)")
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
                        help="--fake: demo scene seed (mug placement); with --episode: the agent's seed")
    parser.add_argument("--out", default="runs/spot", help="parent folder of the run folder")
    parser.add_argument("--name", default=None, help="run folder name (default: a timestamp)")
    parser.add_argument("--set", dest="overrides", action="extend", nargs="+", default=[], metavar="KEY=VALUE",
                        help="SDK backend config overrides, e.g. --set rpc_timeout=2.0 estop_timeout=5 "
                             "(schema: robots/spot/sdk_backend.py SdkBackendConfig)")
    parser.add_argument("--config", default=None, metavar="FILE.yaml",
                        help="SDK backend scenario file (SdkBackendConfig YAML, e.g. configs/spot_fake.yaml or a run "
                             "folder's config.yaml); HOSTNAME, --port, --cert, --estop, --take-lease and --set "
                             "override it")


class _RunLog(logging.Handler):
    """Session log of the run folder: our loggers at INFO, everything else at WARNING. Lines are
    buffered until the folder exists (it is made only once the robot is connected, so a typo in
    the hostname leaves no empty run behind)."""

    def __init__(self):
        super().__init__(logging.INFO)
        self._fh = None
        self._buffer: list[str] = []
        self.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))

    def open(self, path: Path) -> None:
        self._fh = open(path, "a", encoding="utf-8")
        self._fh.writelines(line + "\n" for line in self._buffer)
        self._fh.flush()
        self._buffer = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.levelno < logging.WARNING and not record.name.startswith("helios"):
            return
        try:
            line = self.format(record)
            if self._fh is None:
                self._buffer.append(line)
            else:
                self._fh.write(line + "\n")
                self._fh.flush()
        except Exception:  # noqa: BLE001 - logging must not break the run
            self.handleError(record)

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
        super().close()


def _validate(args: argparse.Namespace):
    from tools.cli import CliError

    if args.episode is not None:
        if not args.fake:
            raise CliError("--episode needs --fake: an episode's scene exists only in the simulator")
        if args.task is not None:
            raise CliError("--episode brings its own task; leave out --task")
        if args.agent is None:
            args.agent = "helios"
        check_agent(args.agent, EPISODE)
    else:
        if not args.task or not args.task.strip():
            raise CliError("--task must not be empty (e.g. --task \"Move the mug from the stool to the table\")")
        if args.agent is None:
            args.agent = "scripted-demo"
        check_agent(args.agent, DEMO)
    if args.fake and args.hostname:
        raise CliError("--fake runs against a local fake robot; leave out the hostname")
    if not args.fake and not args.hostname and not getattr(args, "config", None):
        raise CliError("the robot's HOSTNAME is required (or --fake for a dry run against a simulated Spot)")
    if args.port is not None and not 0 < args.port < 65536:
        raise CliError(f"--port must be within 1..65535, got {args.port}")


def run(args: argparse.Namespace) -> int:
    _validate(args)
    # grpc's C core prints its own TLS/connection diagnostics to stderr; our errors say it clearly.
    os.environ.setdefault("GRPC_VERBOSITY", "NONE")
    from helios.schema import dump_yaml, load_config, with_overrides
    from robots.spot.sdk_backend import PASSWORD_ENV, USERNAME_ENV, SdkBackendConfig, SdkSpotBackend
    from tools.cli import CliError

    # defaults < --config file < flags given < --set KEY=VALUE
    flags = {"hostname": args.hostname} if args.hostname else {}
    if args.port is not None:
        flags["port"] = args.port
    if args.cert is not None:
        flags["cert_path"] = args.cert
    if args.estop is not None:
        flags["estop_mode"] = args.estop
    if args.take_lease:
        flags["take_lease"] = True
    config_file = getattr(args, "config", None)
    base = load_config(SdkBackendConfig, config_file) if config_file else SdkBackendConfig(hostname="127.0.0.1")
    config = with_overrides(with_overrides(base, flags), list(args.overrides))
    if not args.fake and not config.hostname:
        raise CliError(f"the robot's HOSTNAME is required: {config_file} sets none (or --fake for a dry run)")

    run_dir = Path(args.out) / (args.name or time.strftime("%Y%m%d-%H%M%S"))
    handler = _RunLog()
    root = logging.getLogger()
    root.addHandler(handler)
    old_level = root.level
    root.setLevel(min(old_level or logging.WARNING, logging.INFO))
    demo = None
    saved_env: dict[str, str | None] = {}
    try:
        if args.episode is not None:
            return _run_episode(args, config, run_dir, handler, USERNAME_ENV, PASSWORD_ENV)
        if args.fake:
            demo, config, saved_env = _start_fake(args, config, USERNAME_ENV, PASSWORD_ENV)
        hints = None
        print(f"[spot] connecting to {config.hostname}:{config.port}" + (" (fake Spot, dry run)" if demo else ""))
        backend = SdkSpotBackend(config)
        outcome, physical = None, None
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
        finally:
            print("[spot] shutting down: stop, stow, sit, power off, return the lease")
            backend.close()
        if demo is not None:
            with demo.fake.sim_lock:
                physical = physical_outcome(demo.world, demo.scene, outcome.place_target)
        result = {"agent": args.agent, "task": args.task, "hostname": config.hostname, "fake": bool(demo),
                  "success": bool(outcome.success and (physical is None or physical["success"])),
                  "agent_success": outcome.success, "fault": outcome.fault,
                  "steps": [asdict(s) for s in outcome.steps], "physical": physical}
        (run_dir / "outcome.json").write_text(json.dumps(result, indent=2))
        print()
        print(_format(result, run_dir))
        return 0 if result["success"] else 1
    finally:
        if demo is not None:
            demo.stop()
            shutil.rmtree(demo.pki.ca_cert.parent, ignore_errors=True)   # the throwaway CA and server key
        _restore_env(saved_env)
        root.removeHandler(handler)
        root.setLevel(old_level)
        handler.close()


def _check_fake_available() -> None:
    from tools.cli import CliError

    try:
        import cryptography  # noqa: F401  (makes the fake's throwaway CA)
        import robots.spot.fake_spot.launch  # noqa: F401
    except ImportError as exc:
        raise CliError(f"--fake needs {exc.name or 'cryptography'}: pip install 'helios-testbed[dev]'") from None


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


def _run_episode(args, config, run_dir: Path, handler: "_RunLog", user_env: str, password_env: str) -> int:
    """``--fake --episode``: the episode through SDK -> fake Spot -> PyBullet, scored by the judge."""
    from helios.schema import dump_yaml
    from tasks.episodes import load_split
    from tasks.fake_sdk import run_fake_sdk_episode
    from tools.cli import CliError

    _check_fake_available()
    matches = [e for e in load_split(args.split or args.episode.split("-")[0]) if e.episode_id == args.episode]
    if not matches:
        raise CliError(f"no episode {args.episode!r} in split {args.split or args.episode.split('-')[0]!r}")
    episode = matches[0]
    saved = _dry_run_credentials(user_env, password_env)

    def connected(backend) -> None:
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / "config.yaml").write_text(dump_yaml(backend.config))
        handler.open(run_dir / "session.log")
        rid = backend.robot_id
        print(f"[spot] connected to {rid.nickname or 'robot'} on 127.0.0.1:{backend.config.port} (fake Spot, "
              f"episode scene); e-stop {backend.config.estop_mode}, lease held, standing")
        print(f"[spot] running {args.agent} (seed {args.seed})")

    print(f"[spot] episode {episode.episode_id}: {episode.task!r} (scene {episode.scene.seed}); "
          f"starting a fake Spot on it")
    try:
        result = run_fake_sdk_episode(args.agent, episode, seed=args.seed, backend_config=config,
                                      on_connected=connected)
    finally:
        _restore_env(saved)
    print("[spot] shut down: stopped, stowed, sat, powered off, lease returned; fake Spot stopped")
    outcome = {"fake": True, **result.as_dict()}
    (run_dir / "outcome.json").write_text(json.dumps(outcome, indent=2, default=str))
    print()
    print(_format_episode(result, run_dir))
    return 0 if result.success else 1


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
    from robots.spot.fake_spot.launch import start_demo_fake

    saved = _dry_run_credentials(user_env, password_env)
    user, password = os.environ[user_env], os.environ[password_env]
    pki_dir = tempfile.mkdtemp(prefix="helios-fake-spot-")
    try:
        demo = start_demo_fake(pki_dir, user, password, seed=args.seed)
    except BaseException:
        shutil.rmtree(pki_dir, ignore_errors=True)
        raise
    from helios.schema import with_overrides

    config = with_overrides(config, {"hostname": "127.0.0.1", "port": demo.port, "cert_path": str(demo.pki.ca_cert)})
    print(f"[spot] fake Spot (demo scene, seed {args.seed}) on 127.0.0.1:{demo.port}, test CA {demo.pki.ca_cert}")
    return demo, config, saved


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
