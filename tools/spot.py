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

Agents: on the demo scene, ``scripted-demo`` (the scripted pick-and-place of ``tools demo``, given
the demo layout instead of a detector). ``--fake --episode ID`` instead serves a task episode's
home and runs any agent of ``tasks.registry`` (HELIOS with its simulated detector fed the fake's
ground truth for each SDK image) through ``tasks.fake_sdk``, scored by the simulator's judge: the
same episode and agent code as ``tools trials`` on the sim backend, over the SDK.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import secrets
import shutil
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from robots.hal import SE2Pose

_LOG = logging.getLogger("helios.spot")


# ============================================================================ the scripted demo agent
@dataclass(frozen=True)
class TableHint:
    """A table the scripted demo is told about (an agent would perceive it)."""

    name: str
    centre: tuple[float, float]          # odom frame, m
    yaw: float                           # rad
    half_extents: tuple[float, float]    # top, along its own x and y, m
    top_height: float                    # m

    def extent_along(self, d: np.ndarray) -> float:
        """Half-width of the top along unit direction ``d`` (support function of its rectangle)."""
        u = np.array([math.cos(self.yaw), math.sin(self.yaw)])
        v = np.array([-math.sin(self.yaw), math.cos(self.yaw)])
        return abs(float(d @ u)) * self.half_extents[0] + abs(float(d @ v)) * self.half_extents[1]


@dataclass(frozen=True)
class DemoHints:
    """What the scripted demo knows in advance: the two tables and where the mug should be."""

    pick_table: TableHint
    place_table: TableHint
    mug_position: tuple[float, float, float]

    @staticmethod
    def from_facts(facts: dict) -> "DemoHints":
        """From the fake's (or the simulator's) ground truth (``launch.scene_facts``)."""
        def table(f):
            return TableHint(f["name"], tuple(map(float, f["centre"])), float(f["yaw"]),
                             tuple(map(float, f["half_extents"])), float(f["top_height"]))
        return DemoHints(table(facts["pick_table"]), table(facts["place_table"]),
                         tuple(float(v) for v in facts["mug_position"]))

    @staticmethod
    def from_layout(start: SE2Pose) -> "DemoHints":
        """The demo layout (``sim.scenes.demo.DemoLayout``) measured from the robot's start pose:
        what a real robot needs when the room is set up like the demo scene."""
        from sim.scenes.demo import DemoLayout

        lay = DemoLayout()

        def at(x: float, y: float) -> tuple[float, float]:
            p = start.compose(SE2Pose(x, y, 0.0))
            return (p.x, p.y)

        pick = TableHint("table_pick", at(*lay.pick_table_xy), start.yaw, (0.4, 0.4), lay.table_height)
        place = TableHint("table_place", at(*lay.place_table_xy), start.yaw + 0.3, (0.5, 0.35), lay.table_height)
        mx, my = at(lay.pick_table_xy[0] - 0.22, lay.pick_table_xy[1])
        return DemoHints(pick, place, (mx, my, lay.table_height))   # the mug stands on the table


@dataclass
class AgentStep:
    name: str
    ok: bool
    detail: str
    seconds: float


@dataclass
class AgentOutcome:
    success: bool                      # every step succeeded (the agent's own view)
    steps: list[AgentStep] = field(default_factory=list)
    fault: str | None = None           # a robot fault that ended the run, if any
    place_target: tuple[float, float, float] | None = None


def _approach_pose(table: TableHint, target_xy: np.ndarray, robot_xy: np.ndarray, clearance: float) -> SE2Pose:
    """A pose facing ``target_xy`` from the robot's side, ``clearance`` in front of the table edge
    (the same geometry as ``tools.demo``)."""
    centre = np.asarray(table.centre, dtype=float)
    d = target_xy - robot_xy
    d = d / np.linalg.norm(d)
    body_front = 0.45
    p = centre - d * (table.extent_along(d) + body_front + clearance)
    perp = np.array([-d[1], d[0]])
    p = p + perp * float((target_xy - centre) @ perp)
    return SE2Pose(p[0], p[1], math.atan2(d[1], d[0]))


def _pixel_of(obs, point) -> tuple[int, int] | None:
    p_cam = np.linalg.inv(obs.T_world_cam) @ np.append(np.asarray(point, dtype=float), 1.0)
    if p_cam[2] <= 0:
        return None
    (u, v), _ = obs.intrinsics.project(p_cam[:3])
    u, v = int(round(float(u))), int(round(float(v)))
    if 0 <= u < obs.intrinsics.width and 0 <= v < obs.intrinsics.height:
        return u, v
    return None


def run_scripted_demo(backend, task: str, hints: DemoHints, say: Callable[[str], None] = print) -> AgentOutcome:
    """Walk to the pick table, look at the mug, grasp it by pixel, carry it, release it 10 cm above
    the place table (20 cm inside its near edge), stow. Only HAL calls; the one shortcut is that
    the mug's expected position is given (no detector yet)."""
    from robots.hal import RobotFault

    out = AgentOutcome(success=False)

    def step(name: str, result) -> bool:
        ok = bool(result)
        detail = result.message or result.reason.value
        out.steps.append(AgentStep(name, ok, detail, float(result.duration)))
        say(f"[spot] {len(out.steps)}. {name:<34} {'ok' if ok else 'FAILED':<6} {detail}  [{result.duration:.2f} s]")
        return ok

    mug = np.asarray(hints.mug_position, dtype=float)
    say(f"[spot] task: {task!r} (agent scripted-demo: mug expected at ({mug[0]:.2f}, {mug[1]:.2f}); "
        f"goal: {hints.place_table.name})")
    try:
        here = backend.observe().body_pose
        robot_xy = np.array([here.x, here.y])
        if not step("walk to the pick table", backend.navigate_to(
                _approach_pose(hints.pick_table, mug[:2], robot_xy, 0.30))):
            return out
        look = mug + np.array([0.0, 0.0, 0.05])
        if not step("look at the mug with the hand camera", backend.gaze_at(look)):
            return out
        obs = backend.observe()
        pixel = _pixel_of(obs, look)
        if pixel is None:
            out.steps.append(AgentStep("find the mug in the image", False, "mug not in view", 0.0))
            return out
        if not step(f"grasp at pixel {pixel}", backend.grasp(obs, pixel)):
            return out
        if not step("carry pose", backend.stow_arm()):
            return out
        here = backend.observe().body_pose
        robot_xy = np.array([here.x, here.y])
        centre = np.asarray(hints.place_table.centre, dtype=float)
        d = (centre - robot_xy) / np.linalg.norm(centre - robot_xy)
        place_xy = centre - d * hints.place_table.extent_along(d) + d * 0.20
        if not step("walk to the place table", backend.navigate_to(
                _approach_pose(hints.place_table, place_xy, robot_xy, 0.20))):
            return out
        target = (float(place_xy[0]), float(place_xy[1]), hints.place_table.top_height)
        out.place_target = target
        if not step("release 10 cm above the table", backend.place(target, release_height=0.10)):
            return out
        step("stow the arm", backend.stow_arm())
        out.success = all(s.ok for s in out.steps)
    except RobotFault as exc:
        out.fault = f"{type(exc).__name__}: {exc}"
        say(f"[spot] robot fault: {out.fault}")
    return out


# name -> (callable(backend, task, hints, say) -> AgentOutcome, description). The HELIOS agent joins here.
AGENTS: dict[str, tuple[Callable, str]] = {
    "scripted-demo": (run_scripted_demo, "scripted pick-and-place in the demo layout (tools demo's sequence)"),
}


def physical_outcome(world, scene: dict, place_target=None) -> dict:
    """Ground truth after a run in the simulator: where the mug came to rest (sim/fake only)."""
    from sim.grasping import support_body

    mug = scene["mug"]
    world.settle([b.body_id for b in world.bodies_of_kind("object")], max_time=3.0)
    final = world.position(mug)
    support = support_body(world, mug)
    resting_on = world.bodies[support].name if support is not None else None
    settled = world.is_at_rest(mug)
    out = {"resting_on": resting_on, "settled": bool(settled), "final_position": [float(v) for v in final],
           "success": bool(resting_on == scene["place_table"] and settled)}
    if place_target is not None:
        out["offset_from_target"] = float(np.linalg.norm(final[:2] - np.asarray(place_target[:2])))
    return out


# ============================================================================ command line
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("hostname", nargs="?", help="the robot's hostname or IP address (omit with --fake)")
    parser.add_argument("--task", default=None,
                        help='what to do, e.g. "Move the mug from the stool to the table" (not with --episode)')
    parser.add_argument("--agent", default=None,
                        help=f"agent to run (demo: {', '.join(AGENTS)}, the default; with --episode: an agent of "
                             f"`python -m tools trials`, default helios)")
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
        from tasks.registry import AGENTS as EPISODE_AGENTS
        from tasks.registry import UnknownAgentError, agent_names

        if args.agent not in EPISODE_AGENTS:
            raise UnknownAgentError(f"unknown agent {args.agent!r}; valid agents: {', '.join(agent_names())}")
    else:
        if not args.task or not args.task.strip():
            raise CliError("--task must not be empty (e.g. --task \"Move the mug from the stool to the table\")")
        if args.agent is None:
            args.agent = "scripted-demo"
        if args.agent not in AGENTS:
            raise CliError(f"unknown agent {args.agent!r}; available: {', '.join(sorted(AGENTS))}")
    if args.fake and args.hostname:
        raise CliError("--fake runs against a local fake robot; leave out the hostname")
    if not args.fake and not args.hostname:
        raise CliError("the robot's HOSTNAME is required (or --fake for a dry run against a simulated Spot)")
    if args.port is not None and not 0 < args.port < 65536:
        raise CliError(f"--port must be within 1..65535, got {args.port}")


def run(args: argparse.Namespace) -> int:
    _validate(args)
    # grpc's C core prints its own TLS/connection diagnostics to stderr; our errors say it clearly.
    os.environ.setdefault("GRPC_VERBOSITY", "NONE")
    from helios.configuration import dump_yaml, with_overrides
    from robots.spot.sdk_backend import PASSWORD_ENV, USERNAME_ENV, SdkBackendConfig, SdkSpotBackend

    base = {"port": args.port} if args.port is not None else {}
    if args.cert is not None:
        base["cert_path"] = args.cert
    if args.estop is not None:
        base["estop_mode"] = args.estop
    if args.take_lease:
        base["take_lease"] = True
    config = with_overrides(SdkBackendConfig(hostname=args.hostname or "127.0.0.1", **base), list(args.overrides))

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
            agent, _ = AGENTS[args.agent]
            outcome = agent(backend, args.task, hints, print)
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
    from helios.configuration import dump_yaml
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
    from helios.configuration import with_overrides

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
