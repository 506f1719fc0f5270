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
robot clock is the wall clock plus a fixed skew that the client's time sync must find: the
time-sync service estimates it from the round trips the client reports (``time_sync.py``).

Faults (``FakeSpot.inject``) model what goes wrong on real hardware; each persists until
``clear``: see ``FAULTS``. Scripted faults: ``inject_at`` (at a time), ``inject_on_call`` (on
the Nth call of an RPC), ``fail_calls`` (an RPC fails N times, then recovers), ``delay_calls``
(N calls of one RPC are acted on at once but answered late, the other RPCs promptly). Without
any fault, a lease owner that stops retaining its lease for ``comms_loss_timeout`` meets the
robot's comms-loss behaviour (``comms_loss.py``).

This module is the robot: :class:`FakeSpot` (faults, leases, e-stop, power, commands and the robot
thread) and its fault switchboard ``FAULTS``. ``servicer.py`` holds the gRPC gate and the RPC
handlers it serves, ``protocol.py`` builds the Spot messages they answer with and parses the
commands they accept, ``sim_execution.py`` carries out accepted commands on the simulator,
``bookkeeping.py`` holds the records they all name (e-stop endpoints, commands), ``time_sync.py``
is the time-sync service and ``comms_loss.py`` the watchdog of the lease owner's retains.
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

import grpc
import numpy as np
from bosdyn.api import (
    auth_service_pb2_grpc,
    directory_service_pb2_grpc,
    estop_pb2,
    estop_service_pb2_grpc,
    header_pb2,
    image_service_pb2_grpc,
    lease_pb2,
    lease_service_pb2_grpc,
    manipulation_api_pb2,
    manipulation_api_service_pb2_grpc,
    power_service_pb2_grpc,
    robot_command_service_pb2_grpc,
    robot_id_service_pb2_grpc,
    robot_state_pb2,
    robot_state_service_pb2_grpc,
    time_sync_service_pb2_grpc,
)

from bosdyn.client.lease import Lease

from robots.hal import HalError, Observation
from robots.spot import sdk_conversions as cv
from robots.spot.fake_spot.bookkeeping import STOP_LEVEL_NAMES, Command, Endpoint
from robots.spot.fake_spot.certs import TestPKI
from robots.spot.fake_spot.comms_loss import DEFAULT_COMMS_LOSS_TIMEOUT, CommsLossWatch
from robots.spot.fake_spot.servicer import Gate, SimulatorBusy, SpotServicer
from robots.spot.fake_spot.sim_execution import execute_on_sim
from robots.spot.fake_spot.sim_robot import FakeRobotSim
from robots.spot.fake_spot.time_sync import TimeSyncService
from robots.spot.sim_backend import MotionInterrupted

_LOG = logging.getLogger("helios.fake_spot")

FAULTS: dict[str, str] = {
    "estop": "the (hardware) e-stop is pressed: motor power is cut, running commands end, new ones are refused",
    "lease_revoked": "another client takes the body lease: motion stops, commands with our lease are refused",
    "power_loss": "motor power goes off without an e-stop (a battery or motor fault): running commands end and "
                  "the robot drops to the ground; its state says motors off, the e-stop released",
    "connection_drop": "the robot drops off the network (the server stops); the robot's comms-loss "
                       "behaviour stops it and cuts power",
    "command_timeout": "commands are accepted but never finish (their feedback stays 'in progress'); a motion "
                       "in progress stalls where it is (a pick stalled mid-reach goes on reporting "
                       "MANIP_STATE_MOVING_TO_GRASP, one accepted under the fault MANIP_STATE_SEARCHING_FOR_GRASP)",
    "grasp_failure": "pick requests end with MANIP_STATE_GRASP_FAILED (a pick in progress stops where it is)",
    "manip_feedback_stale": "a pick the robot ends by itself (an e-stop, a power cut, a critical battery, a fall) "
                            "goes on reporting the manipulation state it last reported (e.g. "
                            "MANIP_STATE_MOVING_TO_GRASP or a planning state) instead of MANIP_STATE_GRASP_FAILED: "
                            "whether a real Spot's ManipulationApiFeedback turns to a failed state then is "
                            "unverified, so the backend must not rely on it (combine with those faults); `state` "
                            "(a ManipulationFeedbackState name, e.g. 'MANIP_STATE_GRASP_PLANNING_SUCCEEDED') is "
                            "reported instead of the last one",
    "time_sync_loss": "the time-sync service fails and timed commands are refused with STATUS_NO_TIMESYNC "
                      "(stop, sit and safe power off, which carry no time, are still accepted); a motion in "
                      "progress goes on to its end time",
    "slow": "every reply is delayed by `delay` seconds (default 3): the robot acts on each request when it "
            "arrives, the caller hears back late (or gives up)",
    "behavior_fault": "the robot falls (a behavior fault; `cause` 'fall' (default) or 'hardware', `clearable` "
                      "True by default): running commands end, it stops where it is with motor power on, its "
                      "state lists the fault and motion commands are refused with STATUS_BEHAVIOR_FAULT until "
                      "ClearBehaviorFault clears it (stop and safe power off are still accepted)",
    "power_off_stalls": "a safe power off is accepted and never carried out (the robot cannot sit: it goes on "
                        "standing with motor power on, the command's feedback stays 'in progress')",
    "battery_critical": "the battery runs critically low (`charge` percent, default 3): the robot state lists a "
                        "SEVERITY_CRITICAL system fault with the 'battery' attribute, the battery's charge and the "
                        "locomotion charge, and the robot shuts its motors down at once (robot_state.proto: a critical "
                        "'battery' fault 'likely means the robot is going to shutdown immediately'): running commands "
                        "end, motor power goes off, and power-on is refused with STATUS_FAULTED (the SDK's "
                        "FaultedError) until the battery is swapped (`clear`)",
    "object_dropped": "the claw loses the held object as soon as the robot is idle (a command in progress ends "
                      "first: the simulated carry holds the object rigidly mid-motion, and letting go there "
                      "made the falling object a collision that stopped the walk): the claw opens, the object "
                      "falls and the state's is_gripper_holding_item turns false; once (a later grasp holds)",
    "lease_retains_lost": "the lease owner's RetainLease requests never reach the robot (its keep-alive thread is "
                          "wedged, or the link loses just those; each call goes unanswered until its deadline), "
                          "everything else gets through: `comms_loss_timeout` s after the last retain the robot's "
                          "comms-loss behaviour stops it, sits it and powers it off and marks the lease stale, "
                          "which any client may then acquire (comms_loss.py)",
}

FULL_BATTERY_CHARGE = 80.0      # % of a fresh battery in the robot state (BatteryState.charge_percentage)
BATTERY_FAULT_NAME = "battery_critical"   # SystemFault.name of inject("battery_critical")

_CACHED_FRAMES = 16
_CONTROL_DT = 0.05          # s of robot time between the safety checks of a moving robot

START_TIMEOUT_S = 10.0       # for a started fake Spot to accept connections
STOP_TIMEOUT_S = 15.0        # for stop(): the server, the robot thread, the RPC threads, the simulator
RPC_SIM_WAIT_S = 30.0        # for an RPC handler waiting for the simulator (a command holds it); at once after stop()


class FakeSpotStartError(HalError):
    """The fake Spot did not come up (no port, or not accepting connections in time)."""


class FakeSpot:
    """A fake Spot robot on ``127.0.0.1:<port>`` backed by a :class:`FakeRobotSim`.

    ``username``/``password`` are the only accepted credentials; tokens it issues are recorded in
    ``issued_tokens`` (tests grep logs for them). Inspection attributes for tests: ``powered``,
    ``estop_level``, ``commands``, ``rpc_log``, ``lease_owner``, ``lease_stale``.

    ``comms_loss_timeout``: seconds the lease's owner may go without retaining it before the
    robot's comms-loss behaviour stops and powers it off and the lease turns stale (3 s; see
    ``comms_loss.py``, where the numbers come from).
    """

    def __init__(self, sim: FakeRobotSim, pki: TestPKI, username: str, password: str, *,
                 clock_skew: float = 7.25, depth_scale: float = 999.0, jpeg_quality: int = 90,
                 robot_name: str = "helios-fake-spot", max_workers: int = 16, time_scale: float | None = None,
                 comms_loss_timeout: float = DEFAULT_COMMS_LOSS_TIMEOUT):
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
        self.time_sync = TimeSyncService()       # the clients' clocks, estimated from their round trips
        # power, e-stop, lease
        self.powered = False
        self.standing = False
        self.behavior_fault: robot_state_pb2.BehaviorFault | None = None   # inject("behavior_fault")
        # The battery (robot_state.proto BatteryState) and the active system faults (SystemFault):
        # a fresh battery by default; inject("battery_critical") drains it and adds the fault.
        self.battery_charge = FULL_BATTERY_CHARGE
        self.system_faults: list[robot_state_pb2.SystemFault] = []
        # A real power-on takes seconds (MOTOR_POWER_STATE_POWERING_ON, feedback IN_PROGRESS) and no
        # other power command is taken meanwhile; 0 powers on at once (most tests).
        self.power_on_seconds = 0.0
        self._powering_on_until: float | None = None
        self._estop_config_id = "estop-config-1"
        self._endpoints: dict[str, Endpoint] = {}
        self._lease_epoch = "epoch-" + secrets.token_hex(4)
        self._lease_seq = 0
        self._newest_used = None        # (lease sequence, the newest sub-lease a command used under it)
        self.lease_owner: str | None = None
        # the owner's retains, and the robot's comms-loss behaviour when they stop (comms_loss.py)
        self._comms = CommsLossWatch(comms_loss_timeout, self._lock, self._comms_lost)
        # commands
        self.commands: dict[int, Command] = {}
        self._next_id = 1
        self._jobs: queue.Queue = queue.Queue()
        self._frames: OrderedDict[int, tuple[np.ndarray, Observation]] = OrderedDict()
        self._state_cache: robot_state_pb2.RobotState | None = None
        # the motion in progress (robot thread) and its pacing
        self._current: Command | None = None
        self._pace_wall0 = 0.0
        self._pace_sim = 0.0
        self._pace_next_check = 0.0
        self._wake = threading.Condition(self.sim_lock)
        # scripted faults
        self._calls: dict[str, int] = {}
        self._call_rules: list[dict] = []
        self._timers: list[threading.Timer] = []
        # server
        # the RPC threads note themselves as they start, so stop() can join them (the executor
        # keeps its own list private)
        self._rpc_threads: list[threading.Thread] = []
        self._executor = futures.ThreadPoolExecutor(max_workers=max_workers, thread_name_prefix="fake-spot-rpc",
                                                    initializer=self._note_rpc_thread)
        self._server: grpc.Server | None = None
        self._robot_thread: threading.Thread | None = None
        self.port: int | None = None
        self.dropped = False
        self._stopped = False

    # ================================================================== lifecycle
    def start(self) -> "FakeSpot":
        servicer = SpotServicer(self)
        server = grpc.server(self._executor, interceptors=[Gate(self)],
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
        self._comms.start()
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
        watchdog = self._comms.stop(left(1.0))
        if watchdog is not None:
            stuck.append(watchdog.name)
        if self._robot_thread is not None:
            self._robot_thread.join(left(10.0))
            if self._robot_thread.is_alive():
                stuck.append(self._robot_thread.name)
        # the RPC threads: no wait=True (a handler blocked on sim_lock behind a hung command would
        # never end); queued calls are cancelled, running ones get what is left of the budget
        self._executor.shutdown(wait=False, cancel_futures=True)
        with self._lock:
            rpc_threads = list(self._rpc_threads)
        for t in rpc_threads:
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

    def _note_rpc_thread(self) -> None:
        with self._lock:
            self._rpc_threads.append(threading.current_thread())

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
            elif fault == "power_loss":
                self._cut_power("power fault")
            elif fault == "behavior_fault":
                self._behavior_fault(params.get("cause", "fall"), bool(params.get("clearable", True)))
            elif fault == "battery_critical":
                self._battery_critical(float(params.get("charge", 3.0)))
            elif fault == "lease_revoked":
                self._lease_seq += 1
                self.lease_owner = "tablet (fault injection)"
                self._comms.unwatched()        # the fake plays the tablet, which keeps its lease alive
                self._end_commands("overridden", "lease taken by another client")
                self._jobs.put(self._sim_stop)
            elif fault == "object_dropped":
                self._jobs.put(self._drop_held_object_if_due)    # at once if idle, else after the command in progress
            elif fault == "time_sync_loss":
                self.time_sync.forget()        # old identifiers become invalid
            elif fault == "command_timeout":
                for cmd in self.commands.values():
                    if cmd.state in ("queued", "running") and cmd.kind not in ("stop", "safe_power_off"):
                        if cmd.kind == "pick" and cmd.state == "running":
                            # a pick stalled mid-reach (the arm blocked) goes on saying it moves
                            # to the grasp: its feedback has no state for a stall
                            cmd.extra["hung_manip_state"] = manipulation_api_pb2.MANIP_STATE_MOVING_TO_GRASP
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
            if fault in (None, "behavior_fault"):
                self.behavior_fault = None          # the operator cleared it (the tablet)
            if fault in (None, "battery_critical"):
                self.battery_charge = FULL_BATTERY_CHARGE   # the battery was swapped
                self.system_faults = [f for f in self.system_faults if f.name != BATTERY_FAULT_NAME]
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
                self._cut_power(f"e-stop {STOP_LEVEL_NAMES.get(level, level)} from {who}")
            return level, who

    @property
    def estop_level(self) -> int:
        return self.stop_level()[0]

    def powering_on(self) -> bool:
        """A power-on in progress (locked by caller); one that has run its time ends here, powered."""
        if self._powering_on_until is not None and time.monotonic() >= self._powering_on_until:
            self._powering_on_until, self.powered = None, True
        return self._powering_on_until is not None

    def _cut_power(self, why: str) -> None:
        """Motor power off (locked by caller): running commands end as 'robot frozen'; an e-stop or
        a power fault also ends a power-on in progress."""
        if self.powered:
            _LOG.info("motor power cut: %s", why)
        self._powering_on_until = None
        self.powered = False
        self.standing = False
        self._end_commands("frozen", why)
        self._jobs.put(self._sim_stop)

    def _behavior_fault(self, cause: str, clearable: bool) -> None:
        """The robot faults (locked by caller): it stops where it is, motor power stays on, and the
        fault stays in its state until ClearBehaviorFault clears it (a clearable one)."""
        BF = robot_state_pb2.BehaviorFault
        causes = {"fall": BF.CAUSE_FALL, "hardware": BF.CAUSE_HARDWARE}
        if cause not in causes:
            raise ValueError(f"behavior_fault: cause must be one of {', '.join(causes)}, got {cause!r}")
        self.behavior_fault = BF(behavior_fault_id=self._next_id, cause=causes[cause],
                                 status=BF.STATUS_CLEARABLE if clearable else BF.STATUS_UNCLEARABLE)
        self._next_id += 1
        self.behavior_fault.onset_timestamp.CopyFrom(cv.seconds_to_timestamp(self.robot_now()))
        self._end_commands("frozen", f"behavior fault ({cause})")
        self._jobs.put(self._sim_stop)

    def _battery_critical(self, charge: float) -> None:
        """The battery runs critically low (locked by caller): a SEVERITY_CRITICAL system fault
        with the 'battery' (and 'robot') attribute appears in the robot state and the robot shuts
        its motors down at once, ending what it was doing ("a 'battery' fault with severity level
        SEVERITY_CRITICAL likely means the robot is going to shutdown immediately",
        robot_state.proto, SystemFault.severity). Power-on is refused (STATUS_FAULTED) while the
        fault is active (``critical_system_faults``)."""
        if not (math.isfinite(charge) and 0.0 <= charge <= 100.0):
            raise ValueError(f"battery_critical: charge must be a percentage within [0, 100], got {charge!r}")
        SF = robot_state_pb2.SystemFault
        self.battery_charge = charge
        self.system_faults = [f for f in self.system_faults if f.name != BATTERY_FAULT_NAME]
        fault = SF(name=BATTERY_FAULT_NAME, code=1, uid=self._next_id, severity=SF.SEVERITY_CRITICAL,
                   attributes=["battery", "robot"],
                   error_message=f"Battery charge critically low ({charge:.0f}%). Robot is shutting down.")
        self._next_id += 1
        fault.onset_timestamp.CopyFrom(cv.seconds_to_timestamp(self.robot_now()))
        self.system_faults.append(fault)
        self._cut_power(f"critical battery ({charge:.0f} %)")

    def critical_system_faults(self) -> list:
        """The active SEVERITY_CRITICAL system faults (locked by caller): power-on is refused."""
        return [f for f in self.system_faults if f.severity == robot_state_pb2.SystemFault.SEVERITY_CRITICAL]

    def _end_commands(self, state: str, why: str) -> None:
        for cmd in self.commands.values():
            if cmd.state in ("queued", "running", "hung"):
                cmd.state, cmd.detail = state, why

    def _sim_stop(self) -> None:
        self.sim.stop()

    def _drop_held_object_if_due(self) -> None:
        """The ``object_dropped`` fault, a job on the simulator's thread: the claw lets go, the object lands."""
        with self._lock:
            if self.faults.pop("object_dropped", None) is None:
                return
        self.sim.drop_held_object()
        self.sim.settle_loose_objects()
        self._state_cache = None

    # ---------------------------------------------------------------- lease
    @property
    def lease_stale(self) -> bool:
        """The owner went silent for longer than ``comms_loss_timeout``: anyone may acquire it."""
        return self._comms.stale

    def lease_granted(self) -> None:
        """A client acquired or took the lease (locked by caller): its retains are watched now."""
        self._comms.heard()

    def lease_retained(self) -> None:
        """The owner retained its lease (a RetainLease it was told is OK): fresh, clock restarted."""
        self._comms.heard()

    def lease_used(self) -> None:
        """A command with the owner's lease was accepted: a stale lease, used, is fresh again
        (lease.proto); a fresh one is not retained by it (comms_loss.py)."""
        with self._lock:
            if self._comms.stale:
                self._comms.heard()

    def lease_returned(self) -> None:
        """The owner returned the lease (locked by caller): nobody to watch."""
        self._comms.unwatched()

    def _comms_lost(self, silent: float) -> None:
        """The robot's comms-loss behaviour (the watchdog, ``_lock`` held): it ends what it is
        doing, sits and powers off (one step in the fake), and the lease is stale from now on."""
        why = (f"comms loss: no RetainLease from {self.lease_owner!r} for {silent:.2f} s (comms-loss timeout "
               f"{self._comms.timeout:g} s); the lease is stale")
        _LOG.info("%s%s", why, "; sitting and powering off" if self.powered or self.powering_on() else "")
        self._end_commands("overridden", why)
        self._powering_on_until = None
        self.powered = False
        self.standing = False
        self._jobs.put(self._sim_stop)

    def lost_on_the_way(self, method: str) -> bool:
        """Whether a call of RPC ``method`` is lost before it reaches the robot (``lease_retains_lost``)."""
        return method == "RetainLease" and self.has_fault("lease_retains_lost")

    def hold_lost_call(self, context) -> None:
        """A lost call has no answer: hold its handler until the caller's deadline has passed (at
        most ``RPC_SIM_WAIT_S``), or ``clear``/``stop`` come first."""
        with self._lock:
            event = self._fault_event
        remaining = context.time_remaining()
        event.wait(RPC_SIM_WAIT_S if remaining is None else max(0.0, min(remaining + 0.05, RPC_SIM_WAIT_S)))

    def current_lease(self) -> lease_pb2.Lease:
        return lease_pb2.Lease(resource="body", epoch=self._lease_epoch, sequence=[self._lease_seq],
                               client_names=[self.lease_owner or ""])

    def check_lease(self, lease: lease_pb2.Lease, newest: bool = False) -> lease_pb2.LeaseUseResult:
        """The robot's verdict on a lease attached to a command. ``newest`` (commands): as a robot's
        lease validator does, the newest sub-lease used so far under the current lease is kept and an
        older one is refused (STATUS_OLDER), so two requests of one client that arrive out of order
        are told apart from a lease taken by another (bosdyn/client/lease_validator.py)."""
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
            elif newest and self._newest_used is not None and self._newest_used[0] == self._lease_seq and \
                    Lease(lease).compare(self._newest_used[1]) in (Lease.CompareResult.OLDER,
                                                                   Lease.CompareResult.SUPER_LEASE):
                result.status = lease_pb2.LeaseUseResult.STATUS_OLDER
                result.latest_known_lease.CopyFrom(self._newest_used[1].lease_proto)
            else:
                result.status = lease_pb2.LeaseUseResult.STATUS_OK
                if newest:
                    self._newest_used = (self._lease_seq, Lease(lease))
            return result

    # ---------------------------------------------------------------- commands
    def add_command(self, kind: str, request, **extra) -> Command:
        with self._lock:
            cmd = Command(self._next_id, kind, request, extra=dict(extra))
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

    def _run_now(self, cmd: Command) -> None:
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

    def _execute(self, cmd: Command) -> None:
        with self._lock:
            if cmd.state != "queued":
                return
            cmd.state = "running"
        self._current = cmd
        self._pace_wall0, self._pace_sim, self._pace_next_check = time.monotonic(), 0.0, 0.0
        try:
            ok, detail, extra = execute_on_sim(self, cmd)
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

    def _check_motion(self, cmd: Command) -> None:
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
                if end is not None and self.robot_now() > end:   # a robot: STATUS_COMMAND_TIMED_OUT
                    cmd.state, cmd.success, cmd.detail = "timed_out", False, "the command's end time passed"
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
