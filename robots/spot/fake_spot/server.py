"""The fake Spot: a TLS gRPC server on 127.0.0.1 that implements the Spot services the SDK backend
uses, backed by the PyBullet simulation, so images, poses and grasps are physically real.

The unmodified ``bosdyn-client`` talks to it exactly as to a robot: it authenticates, discovers
services through the directory, keeps time sync, registers (or checks) the e-stop, holds the body
lease with keep-alives, powers on, sends ``RobotCommand``/``ManipulationApi`` requests and polls
their feedback. Only the CA file and the port differ from a real robot (see ``certs.py``).

Execution model: one "robot" thread executes accepted commands one after another on the
simulator (PyBullet is not thread-safe; every simulator access holds ``sim_lock``). A command's
RPC returns as soon as it is accepted and its feedback reports progress, as on the robot. With
``time_scale`` (wall seconds per robot second: 1.0 = real time, 0.1 = ten times faster) base and
arm motions take the time the robot would take (the ruckig trajectories of
``robots.spot.motion`` at Spot's limits, as the simulator executes them), the simulator lock is
released between control steps so robot state and images are always fresh while it moves, and
at every control step the motion checks the e-stop, the lease, motor power, the connection and
the command's end time, stopping where it is when one fails. Without ``time_scale`` motions run
as fast as the simulator can (feedback turns final as soon as the simulated motion ends). The
robot clock is the wall clock plus a fixed skew that the client's time sync must find.

Faults (``FakeSpot.inject``) model what goes wrong on real hardware; each persists until
``clear``: see ``FAULTS``. Scripted faults: ``inject_at`` (at a time), ``inject_on_call`` (on
the Nth call of an RPC), ``fail_calls`` (an RPC fails N times, then recovers), ``delay_calls``
(N calls of one RPC are acted on at once but answered late, the other RPCs promptly).
"""

from __future__ import annotations

import contextlib
import hmac
import logging
import math
import queue
import secrets
import threading
import time
from collections import OrderedDict
from concurrent import futures
from dataclasses import dataclass, field

import grpc
import numpy as np
from bosdyn.api import (
    arm_command_pb2,
    auth_pb2,
    auth_service_pb2_grpc,
    basic_command_pb2,
    directory_pb2,
    directory_service_pb2_grpc,
    estop_pb2,
    estop_service_pb2_grpc,
    gripper_command_pb2,
    header_pb2,
    image_pb2,
    image_service_pb2_grpc,
    lease_pb2,
    lease_service_pb2_grpc,
    manipulation_api_pb2,
    manipulation_api_service_pb2_grpc,
    power_pb2,
    power_service_pb2_grpc,
    robot_command_pb2,
    robot_command_service_pb2_grpc,
    robot_id_pb2,
    robot_id_service_pb2_grpc,
    robot_state_pb2,
    robot_state_service_pb2_grpc,
    time_sync_pb2,
    time_sync_service_pb2_grpc,
)

from robots.hal import HalError, Observation, Reason
from robots.spot import model
from robots.spot import sdk_conversions as cv
from robots.spot.fake_spot.certs import TestPKI
from robots.spot.fake_spot.sim_robot import FakeRobotSim, TimedSE2Path
from robots.spot.sim_backend import MotionInterrupted
from robots.transforms import invert_transform, make_transform, rot_z

_LOG = logging.getLogger("helios.fake_spot")

FAULTS: dict[str, str] = {
    "estop": "the (hardware) e-stop is pressed: motor power is cut, running commands end, new ones are refused",
    "lease_revoked": "another client takes the body lease: motion stops, commands with our lease are refused",
    "connection_drop": "the robot drops off the network (the server stops); the robot's comms-loss "
                       "behaviour stops it and cuts power",
    "command_timeout": "commands are accepted but never finish (their feedback stays 'in progress'); a motion "
                       "in progress stalls where it is",
    "grasp_failure": "pick requests end with MANIP_STATE_GRASP_FAILED (a pick in progress stops where it is)",
    "time_sync_loss": "the time-sync service fails and timed commands are refused with STATUS_NO_TIMESYNC "
                      "(stop, sit and safe power off, which carry no time, are still accepted); a motion in "
                      "progress goes on to its end time",
    "slow": "every reply is delayed by `delay` seconds (default 3): the robot acts on each request when it "
            "arrives, the caller hears back late (or gives up)",
    "power_off_stalls": "a safe power off is accepted and never carried out (the robot cannot sit: it goes on "
                        "standing with motor power on, the command's feedback stays 'in progress')",
}

# Services the directory lists: name -> (type, authority). The authorities must be covered by the
# server certificate's subjectAltNames ("*.spot.robot" covers the non-bootstrap ones).
SERVICES: dict[str, tuple[str, str]] = {
    "auth": ("bosdyn.api.AuthService", "auth.spot.robot"),
    "directory": ("bosdyn.api.DirectoryService", "api.spot.robot"),
    "robot-id": ("bosdyn.api.RobotIdService", "id.spot.robot"),
    "time-sync": ("bosdyn.api.TimeSyncService", "api.spot.robot"),
    "robot-state": ("bosdyn.api.RobotStateService", "api.spot.robot"),
    "lease": ("bosdyn.api.LeaseService", "api.spot.robot"),
    "estop": ("bosdyn.api.EstopService", "api.spot.robot"),
    "power": ("bosdyn.api.PowerService", "api.spot.robot"),
    "robot-command": ("bosdyn.api.RobotCommandService", "command.spot.robot"),
    "image": ("bosdyn.api.ImageService", "api.spot.robot"),
    "manipulation": ("bosdyn.api.ManipulationApiService", "manipulation.spot.robot"),
}
_UNAUTHENTICATED_SERVICES = ("bosdyn.api.AuthService", "bosdyn.api.RobotIdService")

_STOP_LEVEL_NAMES = {estop_pb2.ESTOP_LEVEL_CUT: "CUT", estop_pb2.ESTOP_LEVEL_SETTLE_THEN_CUT: "SETTLE_THEN_CUT",
                     estop_pb2.ESTOP_LEVEL_NONE: "NONE"}
_FB = basic_command_pb2.RobotCommandFeedbackStatus
_MAX_ARM_POINTS = 250
_CACHED_FRAMES = 16
_CONTROL_DT = 0.05          # s of robot time between the safety checks of a moving robot
_UNTIMED = ("stop", "sit", "safe_power_off")   # commands without a time that a robot takes without time sync


@dataclass
class _Endpoint:
    proto: estop_pb2.EstopEndpoint
    level: int = estop_pb2.ESTOP_LEVEL_CUT
    last_checkin: float = field(default_factory=time.monotonic)
    challenge: int = 0


@dataclass
class _Command:
    """A robot command and its progress. ``state``: queued | running | done | overridden | frozen | hung."""

    id: int
    kind: str                      # stand, sit, stop, safe_power_off, se2, arm_joint, arm_cartesian,
    request: object                # arm_gaze, arm_named, arm_stop, claw, pick
    state: str = "queued"
    success: bool = False          # meaningful once done
    detail: str = ""
    extra: dict = field(default_factory=dict)


START_TIMEOUT_S = 10.0       # for a started fake Spot to accept connections
STOP_TIMEOUT_S = 15.0        # for stop(): the server, the robot thread, the RPC threads, the simulator
RPC_SIM_WAIT_S = 30.0        # for an RPC handler waiting for the simulator (a command holds it); at once after stop()


class SimulatorBusy(Exception):
    """An RPC handler could not get the simulator (stopped, or held by a hung command)."""


class FakeSpotStartError(HalError):
    """The fake Spot did not come up (no port, or not accepting connections in time)."""


class FakeSpot:
    """A fake Spot robot on ``127.0.0.1:<port>`` backed by a :class:`FakeRobotSim`.

    ``username``/``password`` are the only accepted credentials; tokens it issues are recorded in
    ``issued_tokens`` (tests grep logs for them). Inspection attributes for tests: ``powered``,
    ``estop_level``, ``commands``, ``rpc_log``, ``lease_owner``.
    """

    def __init__(self, sim: FakeRobotSim, pki: TestPKI, username: str, password: str, *,
                 clock_skew: float = 7.25, depth_scale: float = 999.0, jpeg_quality: int = 90,
                 robot_name: str = "helios-fake-spot", max_workers: int = 16, time_scale: float | None = None):
        if not username or not password:
            raise ValueError("the fake Spot needs a username and a password to accept")
        if time_scale is not None and not (isinstance(time_scale, (int, float)) and math.isfinite(time_scale)
                                           and 0.0 < time_scale <= 100.0):
            raise ValueError(f"time_scale must be within (0, 100] wall seconds per robot second (or None), "
                             f"got {time_scale!r}")
        self.time_scale = None if time_scale is None else float(time_scale)
        self.sim = sim
        self.pki = pki
        self.sim_lock = threading.RLock()
        self.clock_skew = float(clock_skew)
        self.depth_scale = float(depth_scale)
        self.jpeg_quality = int(jpeg_quality)
        self.robot_name = robot_name
        self._username, self._password = username, password
        self._lock = threading.RLock()            # bookkeeping (never held while the sim runs)
        self.issued_tokens: list[str] = []
        self._tokens: set[str] = set()
        self.rpc_log: list[str] = []
        self.faults: dict[str, dict] = {}
        self._fault_event = threading.Event()     # interrupts 'slow' delays on clear/stop
        self._clock_id = "fake-clock-" + secrets.token_hex(4)
        # power, e-stop, lease
        self.powered = False
        self.standing = False
        self._estop_config_id = "estop-config-1"
        self._endpoints: dict[str, _Endpoint] = {}
        self._lease_epoch = "epoch-" + secrets.token_hex(4)
        self._lease_seq = 0
        self.lease_owner: str | None = None
        # commands
        self.commands: dict[int, _Command] = {}
        self._next_id = 1
        self._jobs: queue.Queue = queue.Queue()
        self._frames: OrderedDict[int, tuple[np.ndarray, Observation]] = OrderedDict()
        self._state_cache: robot_state_pb2.RobotState | None = None
        # the motion in progress (robot thread) and its pacing
        self._current: _Command | None = None
        self._pace_wall0 = 0.0
        self._pace_sim = 0.0
        self._pace_next_check = 0.0
        self._wake = threading.Condition(self.sim_lock)
        # scripted faults
        self._calls: dict[str, int] = {}
        self._call_rules: list[dict] = []
        self._timers: list[threading.Timer] = []
        # server
        self._executor = futures.ThreadPoolExecutor(max_workers=max_workers, thread_name_prefix="fake-spot-rpc")
        self._server: grpc.Server | None = None
        self._robot_thread: threading.Thread | None = None
        self.port: int | None = None
        self.dropped = False
        self._stopped = False

    # ================================================================== lifecycle
    def start(self) -> "FakeSpot":
        servicer = _SpotServicer(self)
        server = grpc.server(self._executor, interceptors=[_Gate(self)],
                             options=[("grpc.so_reuseport", 0),
                                      ("grpc.max_receive_message_length", 32 * 1024 * 1024),
                                      ("grpc.max_send_message_length", 32 * 1024 * 1024)])
        for add in (auth_service_pb2_grpc.add_AuthServiceServicer_to_server,
                    directory_service_pb2_grpc.add_DirectoryServiceServicer_to_server,
                    robot_id_service_pb2_grpc.add_RobotIdServiceServicer_to_server,
                    time_sync_service_pb2_grpc.add_TimeSyncServiceServicer_to_server,
                    robot_state_service_pb2_grpc.add_RobotStateServiceServicer_to_server,
                    lease_service_pb2_grpc.add_LeaseServiceServicer_to_server,
                    estop_service_pb2_grpc.add_EstopServiceServicer_to_server,
                    power_service_pb2_grpc.add_PowerServiceServicer_to_server,
                    robot_command_service_pb2_grpc.add_RobotCommandServiceServicer_to_server,
                    image_service_pb2_grpc.add_ImageServiceServicer_to_server,
                    manipulation_api_service_pb2_grpc.add_ManipulationApiServiceServicer_to_server):
            add(servicer, server)
        creds = grpc.ssl_server_credentials([self.pki.server_credentials()])
        self.port = server.add_secure_port("127.0.0.1:0", creds)
        if not self.port:
            raise FakeSpotStartError("the fake Spot could not bind a port on 127.0.0.1")
        self.sim.pacer = self._pace
        self._robot_thread = threading.Thread(target=self._run_robot, name="fake-spot-robot", daemon=True)
        self._robot_thread.start()
        server.start()
        self._server = server
        self._wait_listening(START_TIMEOUT_S)
        _LOG.info("fake Spot %r listening on 127.0.0.1:%d", self.robot_name, self.port)
        return self

    def _wait_listening(self, timeout: float) -> None:
        """Return once 127.0.0.1:port accepts a connection; FakeSpotStartError after ``timeout`` s."""
        import socket

        deadline = time.monotonic() + timeout
        while True:
            try:
                socket.create_connection(("127.0.0.1", int(self.port)), timeout=1.0).close()
                return
            except OSError as exc:
                if time.monotonic() >= deadline:
                    raise FakeSpotStartError(f"the fake Spot did not accept connections on 127.0.0.1:{self.port} "
                                             f"within {timeout:g} s ({exc.strerror or exc})") from None
                time.sleep(0.05)

    @contextlib.contextmanager
    def sim_for_rpc(self, what: str):
        """``sim_lock`` for an RPC handler, bounded: given up (SimulatorBusy, answered UNAVAILABLE)
        after ``RPC_SIM_WAIT_S``, or within 0.1 s once stop() began. Handler threads are not
        daemons: one blocked on the lock for good would hold up the process's exit."""
        deadline = time.monotonic() + RPC_SIM_WAIT_S
        while not self.sim_lock.acquire(timeout=0.1):
            if self._stopped or time.monotonic() > deadline:
                raise SimulatorBusy(f"the fake Spot's simulator is {'stopped' if self._stopped else 'busy'} "
                                    f"({what})")
        try:
            yield
        finally:
            self.sim_lock.release()

    def stop(self, timeout: float | None = None) -> None:
        """Stop serving, end the robot thread and the RPC threads, close the simulation. Safe to
        call twice. Bounded: returns within ``timeout`` s (default ``STOP_TIMEOUT_S``), also when a
        command hangs in the simulator; what has not ended by then (the robot thread, an RPC thread,
        the simulator still in use) is left behind with a warning saying so."""
        if self._stopped:
            return
        self._stopped = True
        t0 = time.monotonic()
        deadline = t0 + (STOP_TIMEOUT_S if timeout is None else float(timeout))

        def left(cap: float) -> float:
            return max(0.0, min(cap, deadline - time.monotonic()))

        self._fault_event.set()
        with self._lock:
            timers, self._timers = self._timers, []
        for t in timers:
            t.cancel()
        if self._server is not None:                     # grace=None: RPCs in flight are cancelled now
            wait = left(5.0)
            if not self._server.stop(grace=None).wait(wait):
                _LOG.warning("fake Spot: the gRPC server did not shut down within %.1f s", wait)
        self._jobs.put(None)
        stuck: list[str] = []
        if self._robot_thread is not None:
            self._robot_thread.join(left(10.0))
            if self._robot_thread.is_alive():
                stuck.append(self._robot_thread.name)
        # the RPC threads: no wait=True (a handler blocked on sim_lock behind a hung command would
        # never end); queued calls are cancelled, running ones get what is left of the budget
        self._executor.shutdown(wait=False, cancel_futures=True)
        for t in list(getattr(self._executor, "_threads", ())):
            t.join(left(5.0))
            if t.is_alive():
                stuck.append(t.name)
        if stuck:
            _LOG.warning("fake Spot: %s still running %.1f s after stop() began (a command hung in the "
                         "simulator?); left behind", ", ".join(stuck), time.monotonic() - t0)
        if self.sim_lock.acquire(timeout=left(5.0)):
            try:
                self.sim.close()
            finally:
                self.sim_lock.release()
        else:
            _LOG.warning("fake Spot: the simulator is still in use (sim_lock held) %.1f s after stop() began; "
                         "not closed", time.monotonic() - t0)

    def __enter__(self) -> "FakeSpot":
        return self.start() if self._server is None else self

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def address(self) -> str:
        return "127.0.0.1"

    # ================================================================== faults
    def inject(self, fault: str, **params) -> None:
        """Switch a fault on (see ``FAULTS``); ``slow`` takes ``delay`` (seconds)."""
        if fault not in FAULTS:
            raise ValueError(f"unknown fault {fault!r}; known: {', '.join(FAULTS)}")
        _LOG.info("fault injected: %s %s", fault, params or "")
        with self._lock:
            self.faults[fault] = dict(params)
            if fault == "estop":
                self._cut_power("e-stop pressed")
            elif fault == "lease_revoked":
                self._lease_seq += 1
                self.lease_owner = "tablet (fault injection)"
                self._end_commands("overridden", "lease taken by another client")
                self._jobs.put(self._sim_stop)
            elif fault == "time_sync_loss":
                self._clock_id = "fake-clock-" + secrets.token_hex(4)   # old identifiers become invalid
            elif fault == "command_timeout":
                for cmd in self.commands.values():
                    if cmd.state in ("queued", "running") and cmd.kind not in ("stop", "safe_power_off"):
                        cmd.state, cmd.detail = "hung", "stalled (fault injection)"
        if fault == "connection_drop":
            self.dropped = True
            if self._server is not None:
                self._server.stop(grace=None)
            with self._lock:
                self._cut_power("communication lost")   # the robot's comms-loss behaviour

    def clear(self, fault: str | None = None) -> None:
        with self._lock:
            if fault is None:
                self.faults.clear()
            else:
                self.faults.pop(fault, None)
            self._fault_event.set()
            self._fault_event = threading.Event()

    def has_fault(self, fault: str) -> bool:
        return fault in self.faults

    def inject_at(self, seconds: float, fault: str, **params) -> threading.Timer:
        """Inject ``fault`` ``seconds`` from now (wall clock); cancelled when the fake stops."""
        if fault not in FAULTS:
            raise ValueError(f"unknown fault {fault!r}; known: {', '.join(FAULTS)}")
        timer = threading.Timer(float(seconds), lambda: None if self._stopped else self.inject(fault, **params))
        timer.daemon = True
        timer.name = f"fake-spot-fault-{fault}"
        with self._lock:
            self._timers.append(timer)
        timer.start()
        return timer

    def inject_on_call(self, method: str, n: int, fault: str, **params) -> None:
        """Inject ``fault`` when the ``n``-th call (counted from now) of RPC ``method`` (e.g.
        ``"RobotCommand"``) arrives, before it is processed."""
        if fault not in FAULTS:
            raise ValueError(f"unknown fault {fault!r}; known: {', '.join(FAULTS)}")
        with self._lock:
            self._call_rules.append({"method": method, "at": self._calls.get(method, 0) + int(n), "fault": fault,
                                     "params": dict(params)})

    def fail_calls(self, method: str, times: int, code: grpc.StatusCode = grpc.StatusCode.UNAVAILABLE,
                   after: int = 0) -> None:
        """The next ``times`` calls of RPC ``method`` (after ``after`` more that succeed) fail with
        the gRPC status ``code`` without being processed; later calls succeed again."""
        with self._lock:
            first = self._calls.get(method, 0) + int(after) + 1
            self._call_rules.append({"method": method, "fail": (first, first + int(times) - 1), "code": code})

    def delay_calls(self, method: str, times: int, delay: float, after: int = 0) -> None:
        """The next ``times`` calls of RPC ``method`` (after ``after`` more answered promptly) are
        processed when they arrive but answered ``delay`` seconds late (ended early by ``clear`` or
        ``stop``): the robot acts on the request, a caller with a shorter deadline gives up. Unlike
        the 'slow' fault, no other RPC is delayed."""
        if not (isinstance(delay, (int, float)) and math.isfinite(delay) and delay >= 0):
            raise ValueError(f"delay must be a non-negative number of seconds, got {delay!r}")
        with self._lock:
            first = self._calls.get(method, 0) + int(after) + 1
            self._call_rules.append({"method": method, "delay_calls": (first, first + int(times) - 1),
                                     "delay": float(delay)})

    def on_call(self, method: str, context) -> float:
        """Count a call of ``method`` and apply the scripted faults due on it (RPC threads). Returns
        how long its reply is to be held back (``delay_calls``; 0 for none)."""
        fire, fail, delay = [], None, 0.0
        with self._lock:
            self.rpc_log.append(method)
            n = self._calls[method] = self._calls.get(method, 0) + 1
            for rule in self._call_rules:
                if rule["method"] != method:
                    continue
                if "fault" in rule and rule["at"] == n:
                    fire.append(rule)
                elif "fail" in rule and rule["fail"][0] <= n <= rule["fail"][1]:
                    fail = rule["code"]
                elif "delay_calls" in rule and rule["delay_calls"][0] <= n <= rule["delay_calls"][1]:
                    delay = max(delay, rule["delay"])
        for rule in fire:
            self.inject(rule["fault"], **rule["params"])
        if fail is not None:
            context.abort(fail, f"scripted failure of {method} (call {n})")
        return delay

    # ================================================================== helpers used by servicers
    def robot_now(self) -> float:
        return time.time() + self.clock_skew

    def header(self, response, request, code: int = header_pb2.CommonError.CODE_OK, message: str = "",
               received: float | None = None):
        """Fill a response header (robot-clock timestamps; the request is not echoed back)."""
        h = response.header
        h.request_header.CopyFrom(request.header)
        h.request_received_timestamp.CopyFrom(cv.seconds_to_timestamp(received or self.robot_now()))
        h.response_timestamp.CopyFrom(cv.seconds_to_timestamp(self.robot_now()))
        h.error.code = code
        if message:
            h.error.message = message
        return response

    def check_token(self, metadata: dict) -> bool:
        auth = metadata.get("authorization", "")
        if not auth.startswith("Bearer "):
            return False
        token = auth[len("Bearer "):]
        with self._lock:
            return any(hmac.compare_digest(token, t) for t in self._tokens)

    def issue_token(self) -> str:
        token = secrets.token_urlsafe(24)
        with self._lock:
            self._tokens.add(token)
            self.issued_tokens.append(token)
        return token

    def credentials_ok(self, username: str, password: str) -> bool:
        return hmac.compare_digest(username.encode(), self._username.encode()) and \
            hmac.compare_digest(password.encode(), self._password.encode())

    def slow_delay(self, context, extra: float = 0.0) -> None:
        """Apply the 'slow' fault to a reply: hold it back ``delay`` seconds (ended early by
        ``clear`` or ``stop``); ``extra``: this call's own delay (``delay_calls``), whichever is
        longer."""
        with self._lock:
            params = self.faults.get("slow")
            event = self._fault_event
        wait = max(float(params.get("delay", 3.0)) if params is not None else 0.0, float(extra))
        if wait > 0:
            event.wait(wait)

    # ---------------------------------------------------------------- e-stop
    def stop_level(self) -> tuple[int, str]:
        """Most severe level over the hardware stop and all software endpoints (lazy timeouts)."""
        with self._lock:
            if "estop" in self.faults:
                return estop_pb2.ESTOP_LEVEL_CUT, "hardware e-stop pressed"
            level, who = estop_pb2.ESTOP_LEVEL_NONE, ""
            now = time.monotonic()
            for ep in self._endpoints.values():
                timeout = cv.duration_to_seconds(ep.proto.timeout)
                lvl = ep.level
                if timeout > 0 and now - ep.last_checkin > timeout:
                    lvl = min(lvl, estop_pb2.ESTOP_LEVEL_SETTLE_THEN_CUT)
                if lvl < level:
                    level, who = lvl, f"endpoint {ep.proto.name!r}"
            if level != estop_pb2.ESTOP_LEVEL_NONE and self.powered:
                self._cut_power(f"e-stop {_STOP_LEVEL_NAMES.get(level, level)} from {who}")
            return level, who

    @property
    def estop_level(self) -> int:
        return self.stop_level()[0]

    def _cut_power(self, why: str) -> None:
        """Motor power off (locked by caller): running commands end as 'robot frozen'."""
        if self.powered:
            _LOG.info("motor power cut: %s", why)
        self.powered = False
        self.standing = False
        self._end_commands("frozen", why)
        self._jobs.put(self._sim_stop)

    def _end_commands(self, state: str, why: str) -> None:
        for cmd in self.commands.values():
            if cmd.state in ("queued", "running", "hung"):
                cmd.state, cmd.detail = state, why

    def _sim_stop(self) -> None:
        self.sim.stop()

    # ---------------------------------------------------------------- lease
    def current_lease(self) -> lease_pb2.Lease:
        return lease_pb2.Lease(resource="body", epoch=self._lease_epoch, sequence=[self._lease_seq],
                               client_names=[self.lease_owner or ""])

    def check_lease(self, lease: lease_pb2.Lease) -> lease_pb2.LeaseUseResult:
        """The robot's verdict on a lease attached to a command."""
        with self._lock:
            result = lease_pb2.LeaseUseResult(attempted_lease=lease, latest_known_lease=self.current_lease())
            if self.lease_owner:
                result.owner.client_name = self.lease_owner
            if not lease.resource or not lease.sequence:
                result.status = lease_pb2.LeaseUseResult.STATUS_INVALID_LEASE
            elif lease.epoch != self._lease_epoch:
                result.status = lease_pb2.LeaseUseResult.STATUS_WRONG_EPOCH
            elif lease.sequence[0] < self._lease_seq:
                result.status = lease_pb2.LeaseUseResult.STATUS_OLDER
            elif lease.sequence[0] > self._lease_seq or self.lease_owner is None:
                result.status = lease_pb2.LeaseUseResult.STATUS_REVOKED if self.lease_owner is None \
                    else lease_pb2.LeaseUseResult.STATUS_INVALID_LEASE
            else:
                result.status = lease_pb2.LeaseUseResult.STATUS_OK
            return result

    # ---------------------------------------------------------------- commands
    def add_command(self, kind: str, request, **extra) -> _Command:
        with self._lock:
            cmd = _Command(self._next_id, kind, request, extra=dict(extra))
            self._next_id += 1
            self.commands[cmd.id] = cmd
            if "command_timeout" in self.faults and kind not in ("stop", "safe_power_off"):
                cmd.state = "hung"          # accepted, never executed
                return cmd
        if kind in ("stop", "safe_power_off", "sit", "stand"):
            self._run_now(cmd)
        else:
            self._jobs.put(lambda: self._execute(cmd))
        return cmd

    def _run_now(self, cmd: _Command) -> None:
        """Commands the robot completes on the spot (bookkeeping only; the sim side is queued)."""
        with self._lock:
            if cmd.kind == "stop":
                for other in self.commands.values():
                    if other is not cmd and other.state in ("queued", "running", "hung"):
                        other.state, other.detail = "overridden", "stop command"
                self._jobs.put(self._sim_stop)
            elif cmd.kind == "safe_power_off":
                if "power_off_stalls" in self.faults:
                    cmd.state, cmd.detail = "running", "cannot sit (fault injection)"
                    return
                self._end_commands("overridden", "safe power off")
                self.powered = False
                self.standing = False
            elif cmd.kind == "sit":
                self.standing = False
            elif cmd.kind == "stand":
                self.standing = True
            cmd.state, cmd.success = "done", True

    def _run_robot(self) -> None:
        """The robot thread: executes queued jobs in order on the simulator."""
        while True:
            job = self._jobs.get()
            if job is None:
                return
            try:
                with self.sim_lock:
                    job()
            except Exception:  # keep the robot thread alive; the command reports failure
                _LOG.exception("fake Spot: a command raised in the simulator")

    def _execute(self, cmd: _Command) -> None:
        with self._lock:
            if cmd.state != "queued":
                return
            cmd.state = "running"
        self._current = cmd
        self._pace_wall0, self._pace_sim, self._pace_next_check = time.monotonic(), 0.0, 0.0
        try:
            ok, detail, extra = _execute_on_sim(self, cmd)
        except MotionInterrupted:
            ok, detail, extra = False, "interrupted", {}
            self.sim.stop()                       # the arm holds where it is
        except Exception as exc:  # noqa: BLE001 - reported through feedback
            ok, detail, extra = False, f"simulator error: {exc}", {}
            _LOG.exception("fake Spot: command %s failed in the simulator", cmd.kind)
        finally:
            self._current = None
        self.sim.settle_loose_objects()
        self._state_cache = None
        with self._lock:
            if cmd.state == "running":
                cmd.state, cmd.success, cmd.detail = "done", ok, detail
                cmd.extra.update(extra)

    # ---------------------------------------------------------------- pacing (robot thread, sim_lock held)
    def _pace(self, dt: float) -> None:
        """The simulator's pacer: after every ``dt`` of simulated motion, check at each control
        step that the motion may go on, and (``time_scale``) wait for the wall clock, releasing
        the simulator lock meanwhile so state and images stay fresh."""
        cmd = self._current
        if cmd is None:
            return
        self._pace_sim += dt
        if self._pace_sim + 1e-9 < self._pace_next_check:
            return
        self._pace_next_check = self._pace_sim + _CONTROL_DT
        self._check_motion(cmd)
        if self.time_scale is None:
            return
        target = self._pace_wall0 + self._pace_sim * self.time_scale
        while True:
            remaining = target - time.monotonic()
            if remaining <= 0:
                return
            self._wake.wait(min(remaining, 0.02))   # releases sim_lock (all levels) while waiting
            self._check_motion(cmd)

    def _check_motion(self, cmd: _Command) -> None:
        """End the motion (MotionInterrupted) once it must not go on: e-stop (including an
        endpoint timeout), motor power cut, connection lost, lease lost, stop command, a stall, a
        failing pick, or the command's end time passed."""
        self.stop_level()                         # cuts power on an e-stop or an endpoint timeout
        with self._lock:
            if cmd.state == "running":
                if cmd.kind == "pick" and "grasp_failure" in self.faults:
                    cmd.state, cmd.success, cmd.detail = "done", False, "grasp failure (fault injection)"
                    cmd.extra["manip_state"] = manipulation_api_pb2.MANIP_STATE_GRASP_FAILED
                end = cmd.extra.get("end_time")
                if end is not None and self.robot_now() > end:
                    cmd.state, cmd.success, cmd.detail = "done", False, "the command's end time passed"
            if cmd.state != "running" or self._stopped or self.dropped:
                raise MotionInterrupted(cmd.state)

    # ---------------------------------------------------------------- sensing (hold sim_lock)
    def remember_frame(self, obs: Observation) -> None:
        self._frames[obs.frame_id] = (obs.T_world_cam.copy(), obs)
        while len(self._frames) > _CACHED_FRAMES:
            self._frames.popitem(last=False)

    def find_frame(self, T_world_cam: np.ndarray, tol: float = 1e-4) -> Observation | None:
        for T, obs in reversed(self._frames.values()):
            if np.max(np.abs(T - T_world_cam)) < tol:
                return obs
        return None


# ====================================================================== execution on the simulator
def _execute_on_sim(fake: FakeSpot, cmd: _Command) -> tuple[bool, str, dict]:
    """Run one accepted command on the simulator (robot thread, sim_lock held)."""
    sim = fake.sim
    if cmd.kind == "se2":
        res = sim.follow_base_path(cmd.extra["path"])
        return res.success, res.message, {"blocked": res.reason is Reason.COLLISION}
    if cmd.kind == "arm_joint":
        res = sim.move_arm_joints(cmd.extra["goal"])
        return res.success, res.message, {}
    if cmd.kind == "arm_cartesian":
        res = sim.move_hand(cmd.extra["T_body_hand"])
        return res.success, res.message, {}
    if cmd.kind == "arm_gaze":
        res = sim.gaze_at(cmd.extra["point"])
        return res.success, res.message, {}
    if cmd.kind == "arm_named":
        pos = cmd.extra["position"]
        if pos == arm_command_pb2.NamedArmPositionsCommand.POSITIONS_STOW and sim.holding:
            return False, "cannot stow while holding an item", {"holding_item": True}
        if pos == arm_command_pb2.NamedArmPositionsCommand.POSITIONS_READY:
            res = sim.move_arm_joints(model.ARM_READY)
        else:  # stow, or carry (the sim's stow goes to its carry pose while holding)
            res = sim.stow_arm()
        return res.success, res.message, {}
    if cmd.kind == "arm_stop":
        sim.stop()
        return True, "", {}
    if cmd.kind == "claw":
        sim.set_claw(cmd.extra["angle"])
        return True, "", {}
    if cmd.kind == "pick":
        return _pick_on_sim(fake, cmd)
    return False, f"unsupported command {cmd.kind}", {}


def _pick_on_sim(fake: FakeSpot, cmd: _Command) -> tuple[bool, str, dict]:
    sim = fake.sim
    if fake.has_fault("grasp_failure"):
        return False, "grasp failure (fault injection)", {"manip_state": manipulation_api_pb2.MANIP_STATE_GRASP_FAILED}
    T_world_cam = cmd.extra["T_world_cam"]
    obs = fake.find_frame(T_world_cam)
    if obs is None:
        obs = sim.render_at(T_world_cam)
    u, v = cmd.extra["pixel"]
    if not (0 <= u < obs.intrinsics.width and 0 <= v < obs.intrinsics.height):
        return False, "pixel outside the image", {"manip_state": manipulation_api_pb2.MANIP_STATE_GRASP_FAILED_TO_RAYCAST_INTO_MAP}
    sim.last_grasp_hand_pose = None
    res = sim.grasp(obs, (u, v))
    if res.success:
        state = manipulation_api_pb2.MANIP_STATE_GRASP_SUCCEEDED
    elif res.reason in (Reason.OUT_OF_REACH, Reason.IK_FAILED):
        state = manipulation_api_pb2.MANIP_STATE_GRASP_PLANNING_NO_SOLUTION
    elif res.reason is Reason.NO_DEPTH:
        state = manipulation_api_pb2.MANIP_STATE_GRASP_FAILED_TO_RAYCAST_INTO_MAP
    else:
        state = manipulation_api_pb2.MANIP_STATE_GRASP_FAILED
    extra = {"manip_state": state}
    if sim.last_grasp_hand_pose is not None:
        extra["grasp_hand_pose"] = sim.last_grasp_hand_pose
    return res.success, res.message, extra


# ====================================================================== robot state and images
def _flat_body(T_world_body: np.ndarray) -> np.ndarray:
    yaw = math.atan2(T_world_body[1, 0], T_world_body[0, 0])
    return make_transform(rot_z(yaw), T_world_body[:3, 3])


def _kinematic_tree(sim: FakeRobotSim) -> dict:
    """Frame edges {child: (parent, T_parent_child)} rooted at body, as Spot publishes them."""
    T_wb = sim.spot.T_world_body()
    T_bw = invert_transform(T_wb)
    T_wwr = sim.spot.link_pose(cv.WRIST)
    return {
        cv.BODY: ("", np.eye(4)),
        cv.ODOM: (cv.BODY, T_bw),
        cv.VISION: (cv.BODY, T_bw),
        cv.FLAT_BODY: (cv.BODY, T_bw @ _flat_body(T_wb)),
        cv.HAND: (cv.BODY, T_bw @ sim.spot.T_world_hand()),
        cv.WRIST: (cv.BODY, T_bw @ T_wwr),
        cv.HAND_COLOR_SENSOR: (cv.WRIST, invert_transform(T_wwr) @ sim.spot.T_world_camera()),
    }


def robot_state(fake: FakeSpot) -> robot_state_pb2.RobotState:
    """The robot state message (sim_lock held)."""
    sim = fake.sim
    state = robot_state_pb2.RobotState()
    ks = state.kinematic_state
    ks.acquisition_timestamp.CopyFrom(cv.seconds_to_timestamp(fake.robot_now()))
    ks.transforms_snapshot.CopyFrom(cv.frame_tree(_kinematic_tree(sim)))
    joints = sim.spot.joint_positions()
    for name, q in joints.items():
        js = ks.joint_states.add()
        js.name = name
        js.position.value = float(q)
        js.velocity.value = 0.0
    _fill_status(fake, state)
    ms = state.manipulator_state
    ms.is_gripper_holding_item = sim.holding
    ms.gripper_open_percentage = float(100.0 * min(1.0, max(0.0, sim.gripper_angle / model.GRIPPER_LIMITS[0])))
    ms.stow_state = (robot_state_pb2.ManipulatorState.STOWSTATE_STOWED if sim.arm_is_stowed()
                     else robot_state_pb2.ManipulatorState.STOWSTATE_DEPLOYED)
    ms.carry_state = (robot_state_pb2.ManipulatorState.CARRY_STATE_CARRIABLE_AND_STOWABLE if sim.holding
                      else robot_state_pb2.ManipulatorState.CARRY_STATE_UNKNOWN)
    return state


def _fill_status(fake: FakeSpot, state: robot_state_pb2.RobotState) -> None:
    """Power and e-stop states (bookkeeping, never stale)."""
    with fake._lock:
        powered = fake.powered
        endpoints = list(fake._endpoints.values())
        hw = "estop" in fake.faults
    del state.estop_states[:]
    state.power_state.motor_power_state = (robot_state_pb2.PowerState.MOTOR_POWER_STATE_ON if powered
                                           else robot_state_pb2.PowerState.MOTOR_POWER_STATE_OFF)
    state.power_state.timestamp.CopyFrom(cv.seconds_to_timestamp(fake.robot_now()))
    es = state.estop_states.add()
    es.name, es.type = "hardware_estop", robot_state_pb2.EStopState.TYPE_HARDWARE
    es.state = robot_state_pb2.EStopState.STATE_ESTOPPED if hw else robot_state_pb2.EStopState.STATE_NOT_ESTOPPED
    for ep in endpoints:
        s = state.estop_states.add()
        s.name, s.type = ep.proto.name, robot_state_pb2.EStopState.TYPE_SOFTWARE
        s.state = (robot_state_pb2.EStopState.STATE_NOT_ESTOPPED if ep.level == estop_pb2.ESTOP_LEVEL_NONE
                   else robot_state_pb2.EStopState.STATE_ESTOPPED)


def _image_response(fake: FakeSpot, req: image_pb2.ImageRequest, obs: Observation, snapshot,
                    acquired: float) -> image_pb2.ImageResponse:
    resp = image_pb2.ImageResponse()
    name = req.image_source_name
    intr = obs.intrinsics
    resp.source.name = name
    resp.source.rows, resp.source.cols = intr.height, intr.width
    resp.source.pinhole.CopyFrom(cv.intrinsics_to_pinhole(intr))
    resp.shot.acquisition_time.CopyFrom(cv.seconds_to_timestamp(acquired))
    resp.shot.transforms_snapshot.CopyFrom(snapshot)
    resp.shot.frame_name_image_sensor = cv.HAND_COLOR_SENSOR
    img = resp.shot.image
    img.rows, img.cols = intr.height, intr.width
    if name == cv.HAND_COLOR_SOURCE:
        resp.source.image_type = image_pb2.ImageSource.IMAGE_TYPE_VISUAL
        resp.source.pixel_formats.append(image_pb2.Image.PIXEL_FORMAT_RGB_U8)
        resp.source.image_formats.extend([image_pb2.Image.FORMAT_JPEG, image_pb2.Image.FORMAT_RAW])
        fmt = req.image_format or image_pb2.Image.FORMAT_JPEG
        if req.pixel_format not in (image_pb2.Image.PIXEL_FORMAT_UNKNOWN, image_pb2.Image.PIXEL_FORMAT_RGB_U8):
            resp.status = image_pb2.ImageResponse.STATUS_UNSUPPORTED_PIXEL_FORMAT_REQUESTED
            return resp
        if fmt not in (image_pb2.Image.FORMAT_JPEG, image_pb2.Image.FORMAT_RAW):
            resp.status = image_pb2.ImageResponse.STATUS_UNSUPPORTED_IMAGE_FORMAT_REQUESTED
            return resp
        quality = int(req.quality_percent) if req.quality_percent > 0 else fake.jpeg_quality
        img.format, img.pixel_format = fmt, image_pb2.Image.PIXEL_FORMAT_RGB_U8
        img.data = cv.encode_rgb(obs.rgb, fmt, quality)
    else:  # registered depth
        resp.source.image_type = image_pb2.ImageSource.IMAGE_TYPE_DEPTH
        resp.source.depth_scale = fake.depth_scale
        resp.source.pixel_formats.append(image_pb2.Image.PIXEL_FORMAT_DEPTH_U16)
        resp.source.image_formats.append(image_pb2.Image.FORMAT_RAW)
        if req.pixel_format not in (image_pb2.Image.PIXEL_FORMAT_UNKNOWN, image_pb2.Image.PIXEL_FORMAT_DEPTH_U16):
            resp.status = image_pb2.ImageResponse.STATUS_UNSUPPORTED_PIXEL_FORMAT_REQUESTED
            return resp
        if req.image_format not in (image_pb2.Image.FORMAT_UNKNOWN, image_pb2.Image.FORMAT_RAW):
            resp.status = image_pb2.ImageResponse.STATUS_UNSUPPORTED_IMAGE_FORMAT_REQUESTED
            return resp
        img.format, img.pixel_format = image_pb2.Image.FORMAT_RAW, image_pb2.Image.PIXEL_FORMAT_DEPTH_U16
        img.data = cv.encode_depth(obs.depth, fake.depth_scale)
    resp.status = image_pb2.ImageResponse.STATUS_OK
    return resp


# ====================================================================== request parsing
class _Reject(Exception):
    """A command the robot refuses: carries the RobotCommandResponse status and a message."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


def _world_from(fake: FakeSpot, frame: str, T: np.ndarray) -> np.ndarray:
    """A pose given in a Spot frame (odom, vision, body, flat_body) to world (sim_lock held)."""
    if frame in cv.WORLD_FRAMES:
        return T
    T_wb = fake.sim.spot.T_world_body()
    if frame == cv.BODY:
        return T_wb @ T
    if frame == cv.FLAT_BODY:
        return _flat_body(T_wb) @ T
    raise _Reject(robot_command_pb2.RobotCommandResponse.STATUS_UNKNOWN_FRAME, f"unknown frame {frame!r}")


def _parse_command(fake: FakeSpot, cmd: robot_command_pb2.RobotCommand, request) -> tuple[str, dict]:
    """(kind, extra) of a RobotCommand, or raise _Reject. One sub-command per request."""
    R = robot_command_pb2.RobotCommandResponse
    if cmd.HasField("full_body_command"):
        which = cmd.full_body_command.WhichOneof("command")
        if which == "stop_request":
            return "stop", {"full_body": True}
        if which == "safe_power_off_request":
            return "safe_power_off", {}
        raise _Reject(R.STATUS_UNSUPPORTED, f"full-body {which} is not supported by the fake")
    sync = cmd.synchronized_command
    parts = [p for p in ("mobility_command", "arm_command", "gripper_command") if sync.HasField(p)]
    if len(parts) != 1:
        raise _Reject(R.STATUS_UNSUPPORTED, "the fake executes exactly one sub-command per RobotCommand")
    part = parts[0]
    if part == "mobility_command":
        which = sync.mobility_command.WhichOneof("command")
        if which == "stand_request":
            return "stand", {}
        if which == "sit_request":
            return "sit", {}
        if which == "stop_request":
            return "stop", {"full_body": False}
        if which == "se2_trajectory_request":
            se2 = sync.mobility_command.se2_trajectory_request
            if se2.se2_frame_name not in cv.WORLD_FRAMES:
                raise _Reject(R.STATUS_UNKNOWN_FRAME, f"SE2 trajectories must be in odom or vision, "
                                                      f"not {se2.se2_frame_name!r}")
            if not se2.HasField("end_time"):
                raise _Reject(R.STATUS_INVALID_REQUEST, "trajectory commands need an end time")
            if cv.timestamp_to_seconds(se2.end_time) < fake.robot_now():
                raise _Reject(R.STATUS_EXPIRED, "the command's end time has passed")
            if cv.timestamp_to_seconds(se2.end_time) > fake.robot_now() + 600.0:
                raise _Reject(R.STATUS_TOO_DISTANT, "the command's end time is too far in the future")
            pts = se2.trajectory.points
            if not pts:
                raise _Reject(R.STATUS_INVALID_REQUEST, "empty SE2 trajectory")
            try:
                path = TimedSE2Path([cv.duration_to_seconds(p.time_since_reference) for p in pts],
                                    [cv.proto_to_se2(p.pose) for p in pts])
            except ValueError as exc:
                raise _Reject(R.STATUS_INVALID_REQUEST, str(exc)) from None
            return "se2", {"path": path, "end_time": cv.timestamp_to_seconds(se2.end_time)}
        raise _Reject(R.STATUS_UNSUPPORTED, f"mobility {which} is not supported by the fake")
    if part == "gripper_command":
        claw = sync.gripper_command.claw_gripper_command
        if not sync.gripper_command.HasField("claw_gripper_command") or not claw.trajectory.points:
            raise _Reject(R.STATUS_INVALID_REQUEST, "gripper commands need a claw trajectory")
        return "claw", {"angle": float(claw.trajectory.points[-1].point)}
    arm = sync.arm_command
    which = arm.WhichOneof("command")
    if which == "arm_joint_move_command":
        pts = arm.arm_joint_move_command.trajectory.points
        if not pts or len(pts) > _MAX_ARM_POINTS:
            raise _Reject(R.STATUS_INVALID_REQUEST, f"arm joint trajectories need 1..{_MAX_ARM_POINTS} points, "
                                                    f"got {len(pts)}")
        times = [cv.duration_to_seconds(p.time_since_reference) for p in pts]
        if any(b <= a for a, b in zip(times[:-1], times[1:])):
            raise _Reject(R.STATUS_INVALID_REQUEST, "arm trajectory times must increase strictly")
        with fake.sim_for_rpc("reading the arm"):
            current = fake.sim.spot.arm_q()
        goal = current.copy()
        last = pts[-1].position
        for i, name in enumerate(("sh0", "sh1", "el0", "el1", "wr0", "wr1")):
            if last.HasField(name):
                goal[i] = getattr(last, name).value
        lo, hi = model.arm_limits_array()
        if np.any(goal < lo - 1e-6) or np.any(goal > hi + 1e-6):
            raise _Reject(R.STATUS_INVALID_REQUEST, "arm trajectory leaves the joint limits")
        return "arm_joint", {"goal": np.clip(goal, lo, hi)}
    if which == "arm_cartesian_command":
        c = arm.arm_cartesian_command
        if not c.pose_trajectory_in_task.points:
            raise _Reject(R.STATUS_INVALID_REQUEST, "empty hand trajectory")
        T_task_hand = cv.se3_to_matrix(c.pose_trajectory_in_task.points[-1].pose)
        T_root_task = cv.se3_to_matrix(c.root_tform_task) if c.HasField("root_tform_task") else np.eye(4)
        if c.HasField("wrist_tform_tool"):
            raise _Reject(R.STATUS_UNSUPPORTED, "the fake supports the default tool frame (hand) only")
        with fake.sim_for_rpc("reading the hand frame"):
            T_world_hand = _world_from(fake, c.root_frame_name, T_root_task @ T_task_hand)
            T_body_hand = invert_transform(fake.sim.spot.T_world_body()) @ T_world_hand
        return "arm_cartesian", {"T_body_hand": T_body_hand}
    if which == "arm_gaze_command":
        g = arm.arm_gaze_command
        if not g.target_trajectory_in_frame1.points:
            raise _Reject(R.STATUS_INVALID_REQUEST, "empty gaze target trajectory")
        p = g.target_trajectory_in_frame1.points[-1].point
        with fake.sim_for_rpc("reading the gaze frame"):
            T = _world_from(fake, g.frame1_name, make_transform(None, (p.x, p.y, p.z)))
        return "arm_gaze", {"point": T[:3, 3].copy()}
    if which == "named_arm_position_command":
        return "arm_named", {"position": arm.named_arm_position_command.position}
    if which == "arm_stop_command":
        return "arm_stop", {}
    raise _Reject(R.STATUS_UNSUPPORTED, f"arm {which} is not supported by the fake")


def _untimed(cmd: robot_command_pb2.RobotCommand) -> bool:
    """Stop, sit and safe power off: commands without a time, which need no time sync."""
    if cmd.HasField("full_body_command"):
        return cmd.full_body_command.WhichOneof("command") in ("stop_request", "safe_power_off_request")
    sync = cmd.synchronized_command
    parts = [p for p in ("mobility_command", "arm_command", "gripper_command") if sync.HasField(p)]
    return parts == ["mobility_command"] and \
        sync.mobility_command.WhichOneof("command") in ("stop_request", "sit_request")


# ====================================================================== feedback
def _feedback(cmd: _Command) -> robot_command_pb2.RobotCommandFeedback:
    fb = robot_command_pb2.RobotCommandFeedback()
    done = cmd.state == "done"
    ended = cmd.state in ("overridden", "frozen")
    outer = (_FB.STATUS_PROCESSING if not ended else
             _FB.STATUS_COMMAND_OVERRIDDEN if cmd.state == "overridden" else _FB.STATUS_ROBOT_FROZEN)
    ok = done and cmd.success
    k = cmd.kind
    if k in ("stop", "safe_power_off") and cmd.extra.get("full_body", True):
        fb.full_body_feedback.status = outer
        if k == "stop":
            fb.full_body_feedback.stop_feedback.SetInParent()
        else:
            fb.full_body_feedback.safe_power_off_feedback.status = (
                basic_command_pb2.SafePowerOffCommand.Feedback.STATUS_POWERED_OFF if done
                else basic_command_pb2.SafePowerOffCommand.Feedback.STATUS_IN_PROGRESS)
        return fb
    sync = fb.synchronized_feedback
    if k in ("stand", "sit", "se2", "stop"):
        mob = sync.mobility_command_feedback
        mob.status = outer
        if k == "stand":
            mob.stand_feedback.status = (basic_command_pb2.StandCommand.Feedback.STATUS_IS_STANDING if done
                                         else basic_command_pb2.StandCommand.Feedback.STATUS_IN_PROGRESS)
        elif k == "sit":
            mob.sit_feedback.status = (basic_command_pb2.SitCommand.Feedback.STATUS_IS_SITTING if done
                                       else basic_command_pb2.SitCommand.Feedback.STATUS_IN_PROGRESS)
        elif k == "stop":
            mob.stop_feedback.SetInParent()
        else:
            F = basic_command_pb2.SE2TrajectoryCommand.Feedback
            se2 = mob.se2_trajectory_feedback
            if done:
                se2.status = F.STATUS_AT_GOAL if ok else F.STATUS_STOPPED
                se2.body_movement_status = F.BODY_STATUS_SETTLED
                se2.final_goal_status = (F.FINAL_GOAL_STATUS_BLOCKED if cmd.extra.get("blocked")
                                         else F.FINAL_GOAL_STATUS_ACHIEVABLE)
            else:
                se2.status = F.STATUS_GOING_TO_GOAL if not ended else F.STATUS_STOPPED
                se2.body_movement_status = F.BODY_STATUS_MOVING
                se2.final_goal_status = F.FINAL_GOAL_STATUS_IN_PROGRESS
        return fb
    if k == "claw":
        g = sync.gripper_command_feedback
        g.status = outer
        C = gripper_command_pb2.ClawGripperCommand.Feedback
        g.claw_gripper_feedback.status = C.STATUS_AT_GOAL if done else C.STATUS_IN_PROGRESS
        return fb
    arm = sync.arm_command_feedback
    arm.status = outer
    A = arm_command_pb2
    if k == "arm_joint":
        S = A.ArmJointMoveCommand.Feedback
        arm.arm_joint_move_feedback.status = (S.STATUS_COMPLETE if ok else S.STATUS_STALLED if done
                                              else S.STATUS_IN_PROGRESS)
    elif k == "arm_cartesian":
        S = A.ArmCartesianCommand.Feedback
        arm.arm_cartesian_feedback.status = (S.STATUS_TRAJECTORY_COMPLETE if ok else S.STATUS_TRAJECTORY_STALLED
                                             if done else S.STATUS_TRAJECTORY_CANCELLED if ended
                                             else S.STATUS_IN_PROGRESS)
    elif k == "arm_gaze":
        S = A.GazeCommand.Feedback
        arm.arm_gaze_feedback.status = (S.STATUS_TRAJECTORY_COMPLETE if ok else S.STATUS_TOOL_TRAJECTORY_STALLED
                                        if done else S.STATUS_IN_PROGRESS)
    elif k == "arm_named":
        S = A.NamedArmPositionsCommand.Feedback
        arm.named_arm_position_feedback.status = (S.STATUS_COMPLETE if ok else S.STATUS_STALLED_HOLDING_ITEM
                                                  if done else S.STATUS_IN_PROGRESS)
    elif k == "arm_stop":
        arm.arm_stop_feedback.SetInParent()
    return fb


# ====================================================================== the servicer
class _Gate(grpc.ServerInterceptor):
    """Every RPC: record it, apply scripted faults, require a valid user token (except for the
    auth and robot-id services, as on the robot), and hold the reply back under the 'slow' fault
    or a ``delay_calls`` rule."""

    def __init__(self, fake: FakeSpot):
        self._fake = fake

    def intercept_service(self, continuation, handler_call_details):
        handler = continuation(handler_call_details)
        if handler is None or handler.unary_unary is None:
            return handler
        fake = self._fake
        method = handler_call_details.method
        metadata = {k: v for k, v in (handler_call_details.invocation_metadata or ())}
        inner = handler.unary_unary
        service = method.strip("/").split("/")[0]

        def gated(request, context):
            delay = fake.on_call(method.rsplit("/", 1)[-1], context)
            if service not in _UNAUTHENTICATED_SERVICES and not fake.check_token(metadata):
                context.abort(grpc.StatusCode.UNAUTHENTICATED, "missing or invalid user token")
            try:
                response = inner(request, context)
            except SimulatorBusy as exc:
                context.abort(grpc.StatusCode.UNAVAILABLE, str(exc))
            fake.slow_delay(context, delay)
            return response

        return grpc.unary_unary_rpc_method_handler(gated, request_deserializer=handler.request_deserializer,
                                                   response_serializer=handler.response_serializer)


class _SpotServicer(auth_service_pb2_grpc.AuthServiceServicer,
                    directory_service_pb2_grpc.DirectoryServiceServicer,
                    robot_id_service_pb2_grpc.RobotIdServiceServicer,
                    time_sync_service_pb2_grpc.TimeSyncServiceServicer,
                    robot_state_service_pb2_grpc.RobotStateServiceServicer,
                    lease_service_pb2_grpc.LeaseServiceServicer,
                    estop_service_pb2_grpc.EstopServiceServicer,
                    power_service_pb2_grpc.PowerServiceServicer,
                    robot_command_service_pb2_grpc.RobotCommandServiceServicer,
                    image_service_pb2_grpc.ImageServiceServicer,
                    manipulation_api_service_pb2_grpc.ManipulationApiServiceServicer):
    """All the Spot services of the fake in one object (method names do not collide)."""

    def __init__(self, fake: FakeSpot):
        self.f = fake

    # ---------------------------------------------------------------- auth, directory, id, time
    def GetAuthToken(self, request, context):
        resp = auth_pb2.GetAuthTokenResponse()
        f = self.f
        if request.token:
            ok = f.check_token({"authorization": "Bearer " + request.token})
            resp.status = resp.STATUS_OK if ok else resp.STATUS_INVALID_TOKEN
        else:
            ok = f.credentials_ok(request.username, request.password)
            resp.status = resp.STATUS_OK if ok else resp.STATUS_INVALID_LOGIN
        if ok:
            resp.token = f.issue_token()
        return f.header(resp, request)

    def ListServiceEntries(self, request, context):
        resp = directory_pb2.ListServiceEntriesResponse()
        for name, (type_, authority) in SERVICES.items():
            resp.service_entries.add(name=name, type=type_, authority=authority, user_token_required=True)
        return self.f.header(resp, request)

    def GetServiceEntry(self, request, context):
        resp = directory_pb2.GetServiceEntryResponse()
        if request.service_name in SERVICES:
            type_, authority = SERVICES[request.service_name]
            resp.status = resp.STATUS_OK
            resp.service_entry.CopyFrom(directory_pb2.ServiceEntry(name=request.service_name, type=type_,
                                                                   authority=authority))
        else:
            resp.status = resp.STATUS_NONEXISTENT_SERVICE
        return self.f.header(resp, request)

    def GetRobotId(self, request, context):
        resp = robot_id_pb2.RobotIdResponse()
        rid = resp.robot_id
        rid.serial_number, rid.species, rid.version = "FAKE-SPOT-0001", "spot", "V3"
        rid.nickname, rid.computer_serial_number = self.f.robot_name, "FAKE-CORE-0001"
        rid.software_release.version.major_version = 5
        rid.software_release.version.minor_version = 2
        return self.f.header(resp, request)

    def TimeSyncUpdate(self, request, context):
        f = self.f
        received = f.robot_now()
        resp = time_sync_pb2.TimeSyncUpdateResponse()
        if f.has_fault("time_sync_loss"):
            return f.header(resp, request, header_pb2.CommonError.CODE_INTERNAL_SERVER_ERROR,
                            "time-sync service failed", received=received)
        resp.clock_identifier = f._clock_id
        st = resp.state
        st.status = time_sync_pb2.TimeSyncState.STATUS_OK
        st.best_estimate.clock_skew.CopyFrom(cv.seconds_to_duration(f.clock_skew))
        st.best_estimate.round_trip_time.CopyFrom(cv.seconds_to_duration(0.001))
        st.measurement_time.CopyFrom(cv.seconds_to_timestamp(received))
        return f.header(resp, request, received=received)

    # ---------------------------------------------------------------- robot state
    def GetRobotState(self, request, context):
        f = self.f
        f.stop_level()   # applies e-stop endpoint timeouts lazily
        resp = robot_state_pb2.RobotStateResponse()
        # A paced robot releases the simulator between control steps: the state is always fresh.
        if f.sim_lock.acquire(timeout=0.5 if f.time_scale is None else 5.0):
            try:
                state = robot_state(f)
                f._state_cache = state
            finally:
                f.sim_lock.release()
        else:  # unpaced, busy in the simulator: the last kinematic state, power and e-stop as they are now
            state = robot_state_pb2.RobotState()
            if f._state_cache is not None:
                state.CopyFrom(f._state_cache)
            _fill_status(f, state)
        resp.robot_state.CopyFrom(state)
        return f.header(resp, request)

    # ---------------------------------------------------------------- lease
    def _lease_owner_proto(self):
        return lease_pb2.LeaseOwner(client_name=self.f.lease_owner or "")

    def _grant_lease(self, resp, request) -> None:
        """Give the body lease to the caller (a new sequence number); call with ``f._lock`` held."""
        f = self.f
        f._lease_seq += 1
        f.lease_owner = request.header.client_name or "unnamed client"
        resp.status = resp.STATUS_OK
        resp.lease.CopyFrom(f.current_lease())
        resp.lease_owner.CopyFrom(self._lease_owner_proto())

    def AcquireLease(self, request, context):
        f = self.f
        resp = lease_pb2.AcquireLeaseResponse()
        with f._lock:
            if request.resource != "body":
                resp.status = resp.STATUS_INVALID_RESOURCE
            elif f.lease_owner is not None:
                resp.status = resp.STATUS_RESOURCE_ALREADY_CLAIMED
                resp.lease_owner.CopyFrom(self._lease_owner_proto())
            else:
                self._grant_lease(resp, request)
        return f.header(resp, request)

    def TakeLease(self, request, context):
        f = self.f
        resp = lease_pb2.TakeLeaseResponse()
        with f._lock:
            if request.resource != "body":
                resp.status = resp.STATUS_INVALID_RESOURCE
            else:
                self._grant_lease(resp, request)
        return f.header(resp, request)

    def ReturnLease(self, request, context):
        f = self.f
        resp = lease_pb2.ReturnLeaseResponse()
        result = f.check_lease(request.lease)
        with f._lock:
            if result.status == lease_pb2.LeaseUseResult.STATUS_OK:
                f.lease_owner = None
                resp.status = resp.STATUS_OK
            else:
                resp.status = resp.STATUS_NOT_ACTIVE_LEASE
        return f.header(resp, request)

    def RetainLease(self, request, context):
        resp = lease_pb2.RetainLeaseResponse()
        resp.lease_use_result.CopyFrom(self.f.check_lease(request.lease))
        return self.f.header(resp, request)

    def ListLeases(self, request, context):
        f = self.f
        resp = lease_pb2.ListLeasesResponse()
        with f._lock:
            res = resp.resources.add(resource="body")
            if f.lease_owner:
                res.lease.CopyFrom(f.current_lease())
                res.lease_owner.CopyFrom(self._lease_owner_proto())
        return f.header(resp, request)

    # ---------------------------------------------------------------- e-stop
    def _config(self) -> estop_pb2.EstopConfig:
        f = self.f
        cfg = estop_pb2.EstopConfig(unique_id=f._estop_config_id)
        for ep in f._endpoints.values():
            cfg.endpoints.add().CopyFrom(ep.proto)
        return cfg

    def GetEstopConfig(self, request, context):
        resp = estop_pb2.GetEstopConfigResponse()
        with self.f._lock:
            resp.active_config.CopyFrom(self._config())
        return self.f.header(resp, request)

    def SetEstopConfig(self, request, context):
        f = self.f
        resp = estop_pb2.SetEstopConfigResponse()
        with f._lock:
            if f.powered:
                resp.status = resp.STATUS_MOTORS_ON
            elif request.target_config_id != f._estop_config_id:
                resp.status = resp.STATUS_INVALID_ID
            else:
                f._estop_config_id = "estop-config-" + secrets.token_hex(3)
                f._endpoints = {}
                for ep in request.config.endpoints:
                    proto = estop_pb2.EstopEndpoint()
                    proto.CopyFrom(ep)
                    proto.unique_id = "endpoint-" + secrets.token_hex(3)
                    f._endpoints[proto.unique_id] = _Endpoint(proto)
                resp.status = resp.STATUS_SUCCESS
            resp.active_config.CopyFrom(self._config())
        return f.header(resp, request)

    def RegisterEstopEndpoint(self, request, context):
        f = self.f
        resp = estop_pb2.RegisterEstopEndpointResponse()
        with f._lock:
            # The target names a slot of the active configuration, by unique id or by role.
            target = request.target_endpoint
            slot = next((uid for uid, ep in f._endpoints.items()
                         if (target.unique_id and uid == target.unique_id)
                         or (not target.unique_id and target.role and ep.proto.role == target.role)), None)
            if request.target_config_id != f._estop_config_id:
                resp.status = resp.STATUS_CONFIG_MISMATCH
            elif slot is None:
                resp.status = resp.STATUS_ENDPOINT_MISMATCH
            else:
                old = f._endpoints.pop(slot)
                proto = estop_pb2.EstopEndpoint()
                proto.CopyFrom(request.new_endpoint)
                proto.unique_id = "endpoint-" + secrets.token_hex(3)
                proto.role = proto.role or old.proto.role
                f._endpoints[proto.unique_id] = _Endpoint(proto)
                resp.new_endpoint.CopyFrom(proto)
                resp.status = resp.STATUS_SUCCESS
        return f.header(resp, request)

    def DeregisterEstopEndpoint(self, request, context):
        f = self.f
        resp = estop_pb2.DeregisterEstopEndpointResponse()
        with f._lock:
            if request.target_endpoint.unique_id in f._endpoints:
                del f._endpoints[request.target_endpoint.unique_id]
                resp.status = resp.STATUS_SUCCESS
            else:
                resp.status = resp.STATUS_ENDPOINT_MISMATCH
        return f.header(resp, request)

    def EstopCheckIn(self, request, context):
        f = self.f
        resp = estop_pb2.EstopCheckInResponse()
        with f._lock:
            ep = f._endpoints.get(request.endpoint.unique_id)
            if ep is None:
                resp.status = resp.STATUS_ENDPOINT_UNKNOWN
            else:
                ep.level = request.stop_level
                ep.last_checkin = time.monotonic()
                ep.challenge = secrets.randbits(63)
                resp.challenge = ep.challenge
                resp.status = resp.STATUS_OK
        f.stop_level()   # a CUT check-in cuts power
        return f.header(resp, request)

    def GetEstopSystemStatus(self, request, context):
        f = self.f
        resp = estop_pb2.GetEstopSystemStatusResponse()
        level, who = f.stop_level()
        with f._lock:
            now = time.monotonic()
            for ep in f._endpoints.values():
                e = resp.status.endpoints.add()
                e.endpoint.CopyFrom(ep.proto)
                e.stop_level = ep.level
                e.time_since_valid_response.CopyFrom(cv.seconds_to_duration(now - ep.last_checkin))
        resp.status.stop_level = level
        resp.status.stop_level_details = who
        return f.header(resp, request)

    # ---------------------------------------------------------------- power
    def PowerCommand(self, request, context):
        f = self.f
        resp = power_pb2.PowerCommandResponse()
        resp.lease_use_result.CopyFrom(f.check_lease(request.lease))
        if resp.lease_use_result.status != lease_pb2.LeaseUseResult.STATUS_OK:
            resp.status = power_pb2.STATUS_UNKNOWN
            return f.header(resp, request)
        level, _ = f.stop_level()
        with f._lock:
            resp.power_command_id = f._next_id
            f._next_id += 1
            if request.request == power_pb2.PowerCommandRequest.REQUEST_ON_MOTORS:
                if level != estop_pb2.ESTOP_LEVEL_NONE:
                    resp.status = power_pb2.STATUS_ESTOPPED
                else:
                    f.powered = True
                    resp.status = power_pb2.STATUS_SUCCESS
            elif request.request == power_pb2.PowerCommandRequest.REQUEST_OFF_MOTORS:
                f._cut_power("power off requested")
                resp.status = power_pb2.STATUS_SUCCESS
            else:
                resp.status = power_pb2.STATUS_INTERNAL_ERROR
        return f.header(resp, request)

    def PowerCommandFeedback(self, request, context):
        resp = power_pb2.PowerCommandFeedbackResponse(status=power_pb2.STATUS_SUCCESS)
        return self.f.header(resp, request)

    # ---------------------------------------------------------------- robot command
    def RobotCommand(self, request, context):
        f = self.f
        R = robot_command_pb2.RobotCommandResponse
        resp = R()
        resp.lease_use_result.CopyFrom(f.check_lease(request.lease))
        if resp.lease_use_result.status != lease_pb2.LeaseUseResult.STATUS_OK:
            return f.header(resp, request)
        try:
            with f._lock:
                clock_ok = request.clock_identifier == f._clock_id and not f.has_fault("time_sync_loss")
            if not clock_ok and not _untimed(request.command):
                raise _Reject(R.STATUS_NO_TIMESYNC, "unknown clock identifier: time sync with the robot first")
            kind, extra = _parse_command(f, request.command, request)
            level, who = f.stop_level()
            if kind not in ("stop", "safe_power_off") and not f.powered:
                raise _Reject(R.STATUS_NOT_POWERED_ON, "motor power is off" +
                              (f" (e-stop {_STOP_LEVEL_NAMES.get(level)} from {who})"
                               if level != estop_pb2.ESTOP_LEVEL_NONE else ""))
        except _Reject as rej:
            resp.status, resp.message = rej.status, str(rej)
            return f.header(resp, request)
        cmd = f.add_command(kind, request.command, **extra)
        resp.status, resp.robot_command_id = R.STATUS_OK, cmd.id
        return f.header(resp, request)

    def RobotCommandFeedback(self, request, context):
        f = self.f
        resp = robot_command_pb2.RobotCommandFeedbackResponse()
        f.stop_level()
        with f._lock:
            cmd = f.commands.get(request.robot_command_id)
            if cmd is None or cmd.kind == "pick":
                return f.header(resp, request, header_pb2.CommonError.CODE_INVALID_REQUEST,
                                f"unknown robot command id {request.robot_command_id}")
            resp.feedback.CopyFrom(_feedback(cmd))
        return f.header(resp, request)

    def ClearBehaviorFault(self, request, context):
        resp = robot_command_pb2.ClearBehaviorFaultResponse(status=robot_command_pb2.ClearBehaviorFaultResponse.STATUS_CLEARED)
        return self.f.header(resp, request)

    # ---------------------------------------------------------------- images
    def ListImageSources(self, request, context):
        f = self.f
        resp = image_pb2.ListImageSourcesResponse()
        intr = f.sim.intrinsics
        for name, kind in ((cv.HAND_COLOR_SOURCE, image_pb2.ImageSource.IMAGE_TYPE_VISUAL),
                           (cv.HAND_DEPTH_SOURCE, image_pb2.ImageSource.IMAGE_TYPE_DEPTH)):
            src = resp.image_sources.add(name=name, rows=intr.height, cols=intr.width, image_type=kind)
            src.pinhole.CopyFrom(cv.intrinsics_to_pinhole(intr))
            if kind == image_pb2.ImageSource.IMAGE_TYPE_DEPTH:
                src.depth_scale = f.depth_scale
        return f.header(resp, request)

    def GetImage(self, request, context):
        f = self.f
        resp = image_pb2.GetImageResponse()
        names = [r.image_source_name for r in request.image_requests]
        known = (cv.HAND_COLOR_SOURCE, cv.HAND_DEPTH_SOURCE)
        obs = snapshot = None
        if any(n in known for n in names):
            with f.sim_for_rpc("rendering the hand camera"):
                obs = f.sim.observe()
                f.remember_frame(obs)
                snapshot = cv.frame_tree(_kinematic_tree(f.sim))
            acquired = f.robot_now()
        for r in request.image_requests:
            if r.image_source_name not in known:
                resp.image_responses.add(status=image_pb2.ImageResponse.STATUS_UNKNOWN_CAMERA).source.name = \
                    r.image_source_name
                continue
            resp.image_responses.add().CopyFrom(_image_response(f, r, obs, snapshot, acquired))
        return f.header(resp, request)

    # ---------------------------------------------------------------- manipulation
    def ManipulationApi(self, request, context):
        f = self.f
        resp = manipulation_api_pb2.ManipulationApiResponse()
        resp.lease_use_result.CopyFrom(f.check_lease(request.lease))
        if resp.lease_use_result.status != lease_pb2.LeaseUseResult.STATUS_OK:
            return f.header(resp, request)
        if request.WhichOneof("manipulation_cmd") != "pick_object_in_image":
            return f.header(resp, request, header_pb2.CommonError.CODE_INVALID_REQUEST,
                            "the fake implements pick_object_in_image only")
        pick = request.pick_object_in_image
        try:
            T_world_cam = cv.tform(pick.transforms_snapshot_for_camera, cv.ODOM, pick.frame_name_image_sensor)
        except (KeyError, ValueError) as exc:
            return f.header(resp, request, header_pb2.CommonError.CODE_INVALID_REQUEST,
                            f"bad camera snapshot: {exc}")
        pixel = (int(round(pick.pixel_xy.x)), int(round(pick.pixel_xy.y)))
        if not f.powered:
            cmd = f.add_command("pick", request, T_world_cam=T_world_cam, pixel=pixel)
            with f._lock:
                cmd.state, cmd.success = "frozen", False
                cmd.extra["manip_state"] = manipulation_api_pb2.MANIP_STATE_GRASP_FAILED
        else:
            cmd = f.add_command("pick", request, T_world_cam=T_world_cam, pixel=pixel)
        resp.manipulation_cmd_id = cmd.id
        return f.header(resp, request)

    def ManipulationApiFeedback(self, request, context):
        f = self.f
        resp = manipulation_api_pb2.ManipulationApiFeedbackResponse()
        with f._lock:
            cmd = f.commands.get(request.manipulation_cmd_id)
            if cmd is None or cmd.kind != "pick":
                return f.header(resp, request, header_pb2.CommonError.CODE_INVALID_REQUEST,
                                f"unknown manipulation command id {request.manipulation_cmd_id}")
            resp.manipulation_cmd_id = cmd.id
            if cmd.state in ("queued", "hung"):
                resp.current_state = manipulation_api_pb2.MANIP_STATE_SEARCHING_FOR_GRASP
            elif cmd.state == "running":
                resp.current_state = manipulation_api_pb2.MANIP_STATE_MOVING_TO_GRASP
            elif cmd.state in ("overridden", "frozen") and "manip_state" not in cmd.extra:
                resp.current_state = manipulation_api_pb2.MANIP_STATE_GRASP_FAILED
            else:
                resp.current_state = cmd.extra.get("manip_state", manipulation_api_pb2.MANIP_STATE_GRASP_FAILED)
            T_grasp = cmd.extra.get("grasp_hand_pose")
        if T_grasp is not None:
            resp.transforms_snapshot_manipulation_data.CopyFrom(cv.frame_tree({
                cv.ODOM: ("", np.eye(4)), cv.VISION: (cv.ODOM, np.eye(4)),
                cv.GRASP_SOLUTION_FRAME: (cv.ODOM, T_grasp)}))
        return f.header(resp, request)
