"""Bringing a Spot up for the SDK backend: connect, authenticate, time sync, e-stop, lease, power.

A mixin of :class:`robots.spot.sdk_backend.SdkSpotBackend` (the state it sets is declared in that
class's ``__init__``): host resolution and the TLS/credential errors named in one line, time sync
with bounded RPCs, an external e-stop checked or our own endpoint registered with its keep-alive,
the body lease acquired with a keep-alive whose check-ins are bounded, then (``stand_on_connect``)
power on and stand. Each step checks whether ``close()`` began in another thread and stops there;
``close()`` (:mod:`robots.spot.sdk_shutdown`) then shuts down what the bring-up had brought up.
"""

from __future__ import annotations

import glob
import logging
import os
import socket
import ssl
import threading
import time

from robots.hal import (
    BackendClosedError,
    EstopError,
    LeaseLostError,
    PowerError,
    TimeSyncLostError,
)
from robots.spot.sdk_config import (
    PASSWORD_ENV,
    USERNAME_ENV,
    CredentialsError,
    GrpcTracingError,
    SpotConnectError,
    credentials_from_env,
    grpc_tracing_hazard,
)

_LOG = logging.getLogger("helios.spot")

_BRING_UP_CUT_SHORT = "the bring-up was cut short: close() was called from another thread"


def _lease_keep_alive_class(bd):
    """LeaseKeepAlive whose check-ins use a bounded RPC timeout (the SDK's default is 30 s, which
    would stall shutdown on a dead link) and report each confirmed one (``on_retained``)."""

    class BoundedLeaseKeepAlive(bd.lease.LeaseKeepAlive):
        rpc_timeout = 1.5
        on_retained = None

        def _check_in(self):
            lease = self._lease_wallet.get_lease(self._resource)
            if not lease:
                return None
            return self._lease_client.retain_lease(lease, timeout=self.rpc_timeout)

        def _ok(self):
            super()._ok()
            if self.on_retained is not None:
                self.on_retained()

    return BoundedLeaseKeepAlive


class SdkBringUp:
    """``connect()`` and its steps, for :class:`robots.spot.sdk_backend.SdkSpotBackend`."""

    # ================================================================== bring-up
    def connect(self) -> None:
        """Authenticate, time sync, e-stop, lease, and (``stand_on_connect``) power on and stand.

        close() from another thread meanwhile: the bring-up stops at its next step (each is
        bounded by its RPC timeout; a power-on by ``power_on_timeout``) with BackendClosedError,
        and close() then shuts down what it had brought up (lease, e-stop endpoint, power)."""
        with self._close_lock:
            if self._closed or self._closing:
                raise BackendClosedError("this backend has been closed")
            self._connecting = threading.current_thread()
            self._connect_done.clear()
        try:
            self._bring_up()
        except Exception:
            if self._closing_elsewhere():
                raise BackendClosedError(_BRING_UP_CUT_SHORT) from None
            raise
        finally:
            self._connecting = None
            self._connect_done.set()

    def _bring_up_step(self) -> None:
        """Between bring-up steps: stop here when close() runs in another thread."""
        if self._closing_elsewhere():
            raise BackendClosedError(_BRING_UP_CUT_SHORT)

    def _bring_up(self) -> None:
        cfg, bd = self.config, self._bd
        hazard = grpc_tracing_hazard()
        if hazard is not None:
            if not cfg.allow_grpc_tracing:
                raise GrpcTracingError(f"refusing to connect: {hazard}, and gRPC's tracing prints request metadata "
                                       f"including the robot session token; unset GRPC_TRACE (or set "
                                       f"allow_grpc_tracing=true to accept that)")
            _LOG.warning("%s: gRPC tracing may print the session token to the terminal", hazard)
        if os.environ.get("GRPC_VERBOSITY", "").strip().lower() in ("debug", "info"):
            _LOG.warning("GRPC_VERBOSITY=%s: gRPC logs verbosely; with any GRPC_TRACE it would print credentials",
                         os.environ["GRPC_VERBOSITY"])
        user, password = credentials_from_env()
        self._resolve(cfg.hostname, cfg.port)
        cert_glob = None
        if cfg.cert_path is not None:
            if not os.path.isfile(cfg.cert_path):
                raise SpotConnectError(f"certificate file {cfg.cert_path!r} does not exist")
            cert_glob = glob.escape(os.path.abspath(cfg.cert_path))
        try:
            self._sdk = bd.client.create_standard_sdk(f"{cfg.client_name}-{self._session}-",
                                                      cert_resource_glob=cert_glob)
        except OSError as exc:
            raise SpotConnectError(f"cannot load the CA certificate: {exc}") from None
        robot = self._sdk.create_robot(cfg.hostname)
        robot.update_secure_channel_port(int(cfg.port))
        self.robot = robot
        self._quiet_auth_logging()
        _LOG.info("connecting to %s:%d (%s)", cfg.hostname, cfg.port,
                  "CA " + cfg.cert_path if cfg.cert_path else "Boston Dynamics root CA")
        try:
            robot.authenticate(user, password, timeout=cfg.connect_timeout)
        except bd.auth.InvalidLoginError:
            raise CredentialsError(f"the robot at {cfg.hostname} rejected the credentials in "
                                   f"{USERNAME_ENV}/{PASSWORD_ENV}") from None
        except bd.exc.Error as exc:
            raise self._connect_error(exc) from None
        finally:
            del password
        self._token_manager_thread = getattr(getattr(robot, "_token_manager", None), "th", None)
        try:
            # the service directory, with our deadline: the SDK's first ensure_client of a service
            # it has no authority for lists it without one (30 s; safety audit: 8 s held connect())
            robot.sync_with_services_list(robot.ensure_client("directory").list(timeout=cfg.rpc_timeout))
        except bd.exc.TimedOutError:
            raise SpotConnectError(f"the robot at {cfg.hostname}:{cfg.port} did not list its services within "
                                   f"{cfg.rpc_timeout} s") from None
        except bd.exc.Error as exc:
            raise self._connect_error(exc) from None
        self._bound_time_sync_rpcs(robot)
        self._bring_up_step()
        try:
            self.robot_id = robot.ensure_client("robot-id").get_id(timeout=cfg.rpc_timeout)
            robot.time_sync.time_sync_interval_sec = cfg.time_sync_interval
            try:
                robot.time_sync.wait_for_sync(timeout_sec=cfg.connect_timeout)
            except (bd.ts.TimedOutError, bd.ts.InactiveThreadError):
                raise                           # below: no time sync within connect_timeout
            except bd.exc.Error as exc:         # the time-sync service failed: say it was time sync
                raise self._translate(exc, "establishing time sync") from None
            self._state_client = robot.ensure_client(bd.RobotStateClient.default_service_name)
            self._cmd_client = robot.ensure_client(bd.rc.RobotCommandClient.default_service_name)
            self._image_client = robot.ensure_client(bd.ImageClient.default_service_name)
            self._manip_client = robot.ensure_client(bd.ManipulationApiClient.default_service_name)
            self._lease_client = robot.ensure_client(bd.lease.LeaseClient.default_service_name)
            self._estop_client = robot.ensure_client(bd.estop.EstopClient.default_service_name)
        except (bd.ts.TimedOutError, bd.ts.InactiveThreadError) as exc:
            raise TimeSyncLostError(f"no time sync with the robot within {cfg.connect_timeout} s "
                                    f"({type(exc).__name__})") from None
        except bd.exc.Error as exc:
            raise self._translate(exc, "connecting") from None
        _LOG.info("connected to %s (serial %s), time sync established", self.robot_id.nickname or "robot",
                  self.robot_id.serial_number)
        self._bring_up_step()
        self._setup_estop()
        self._bring_up_step()
        self._acquire_lease()
        self._bring_up_step()
        if cfg.stand_on_connect:
            res = self.stand()
            if not res:
                raise PowerError(f"the robot did not stand up: {res.message}")

    def _bound_time_sync_rpcs(self, robot) -> None:
        """The SDK's time-sync thread calls the robot without an RPC timeout (30 s by default): on a
        silent robot it would hang there, and ``close()`` would wait for it. Bound its calls."""
        client = robot.ensure_client("time-sync")
        update = client.get_time_sync_update
        timeout = self.config.rpc_timeout

        def bounded(*args, **kwargs):
            kwargs.setdefault("timeout", timeout)
            return update(*args, **kwargs)

        client.get_time_sync_update = bounded

    def _resolve(self, host: str, port: int) -> None:
        try:
            socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
        except (socket.gaierror, UnicodeError) as exc:
            raise SpotConnectError(f"cannot resolve robot hostname {host!r}: {getattr(exc, 'strerror', None) or exc}") from None

    def _quiet_auth_logging(self) -> None:
        """The SDK logs every request and response at DEBUG; for the auth service those carry the
        password and the token. Keep that logger (and its per-method children) at INFO."""
        auth = self.robot.ensure_client("auth")
        for lg in (auth.logger, auth.logger.getChild("GetAuthToken")):
            lg.setLevel(logging.INFO)

    def _connect_error(self, exc) -> SpotConnectError:
        """A clear message for why authentication could not reach the robot."""
        cfg, bd = self.config, self._bd
        where = f"{cfg.hostname}:{cfg.port}"
        if isinstance(exc, (bd.exc.UnknownDnsNameError,)):
            return SpotConnectError(f"cannot resolve robot hostname {cfg.hostname!r}")
        if isinstance(exc, bd.exc.TimedOutError):
            return SpotConnectError(f"no answer from {where} within {cfg.connect_timeout} s")
        if isinstance(exc, bd.exc.RpcError):
            return SpotConnectError(self._diagnose_link(where))
        return SpotConnectError(f"cannot connect to {where}: {type(exc).__name__}")

    def _diagnose_link(self, where: str) -> str:
        """Tell 'nothing listening' from 'certificate not trusted / wrong name' (verification on)."""
        cfg = self.config
        ca = "CA " + cfg.cert_path if cfg.cert_path else "the Boston Dynamics root CA"
        try:
            sock = socket.create_connection((cfg.hostname, int(cfg.port)), timeout=min(cfg.connect_timeout, 2.0))
        except OSError as exc:
            return f"cannot connect to {where}: {exc.strerror or exc}"
        try:
            ctx = ssl.create_default_context(cadata=self._sdk.cert.decode("ascii", "ignore"))
            ctx.set_alpn_protocols(["h2"])
            with ctx.wrap_socket(sock, server_hostname="auth.spot.robot"):
                pass   # the handshake (chain and name verified) is all we need
        except ssl.SSLCertVerificationError as exc:
            return (f"TLS verification of the robot at {where} failed against {ca}: {exc.verify_message}; "
                    f"give the CA that signed the robot's certificate (cert_path / --cert); verification is "
                    f"never disabled")
        except (ssl.SSLError, OSError) as exc:
            return f"TLS handshake with {where} failed: {exc}"
        finally:
            sock.close()
        return f"the robot at {where} accepted TLS but its API did not answer (is it a Spot?)"

    def _setup_estop(self) -> None:
        """External e-stop: check it is released. Endpoint mode: the SDK's ``force_simple_setup()``
        with bounded RPCs (our endpoint replaces the robot's e-stop configuration), a first check-in
        and a keep-alive.

        A SetEstopConfig or RegisterEstopEndpoint whose reply comes after ``rpc_timeout`` may have
        put our endpoint on the robot (it acted on the request) under a unique id we never heard:
        before those calls go out the endpoint's name and the endpoints already there are
        remembered (``_estop_unconfirmed``), and ``close()`` asks the robot for its configuration
        and deregisters what they left (:meth:`_clean_up_unanswered_bring_up`). Once registration
        is answered the endpoint itself is remembered and deregistered by its unique id."""
        cfg, bd = self.config, self._bd
        try:
            if cfg.estop_mode == "endpoint":
                client, t = self._estop_client, cfg.rpc_timeout
                name = f"{cfg.client_name}-estop-{self._session}"
                ep = bd.estop.EstopEndpoint(client, name, cfg.estop_timeout)
                config = bd.estop_pb2.EstopConfig()
                config.endpoints.add().CopyFrom(ep.to_proto())
                active = client.get_config(timeout=t)
                self._estop_unconfirmed = (name, frozenset(e.unique_id for e in active.endpoints))
                active = client.set_config(config, active.unique_id, timeout=t)
                ep._unique_id = active.endpoints[0].unique_id
                ep._config_id = active.unique_id
                ep.from_proto(client.register(active.unique_id, ep, timeout=t))
                self._estop_endpoint, self._estop_unconfirmed = ep, None
                ep.stop(timeout=t)              # the first check-in seeds the challenge (as register() does)
                self._estop_keepalive = bd.estop.EstopKeepAlive(ep, rpc_timeout_seconds=cfg.rpc_timeout,
                                                               rpc_interval_seconds=min(cfg.estop_timeout / 3.0, 2.0))
                _LOG.info("registered software e-stop endpoint %r (timeout %.1f s)", name, cfg.estop_timeout)
            status = self._estop_client.get_status(timeout=cfg.rpc_timeout)
        except bd.exc.Error as exc:
            raise self._translate(exc, "setting up the e-stop") from None
        if status.stop_level != bd.estop_pb2.ESTOP_LEVEL_NONE:
            level = bd.estop_pb2.EstopStopLevel.Name(status.stop_level)
            details = f" ({status.stop_level_details})" if status.stop_level_details else ""
            raise EstopError(f"the robot is e-stopped: {level}{details}; release the e-stop before connecting")

    def _acquire_lease(self) -> None:
        """Acquire (``take_lease``: take) the body lease and keep it alive.

        An AcquireLease or TakeLease whose reply comes after ``rpc_timeout`` may have given us the
        lease on the robot with no keep-alive or wallet entry here: from the request until the
        keep-alive holds the lease, ``_lease_unconfirmed`` says so, and ``close()`` asks the robot
        who holds the lease and returns it if the holder is this client
        (:meth:`_clean_up_unanswered_bring_up`). A refusal (another client holds it) is an answer:
        nothing to return."""
        cfg, bd = self.config, self._bd
        self._lease_unconfirmed = True
        try:
            if cfg.take_lease:
                self._lease_client.take(timeout=cfg.rpc_timeout)
            else:
                self._lease_client.acquire(timeout=cfg.rpc_timeout)
        except bd.lease.ResourceAlreadyClaimedError:
            self._lease_unconfirmed = False
            raise LeaseLostError("another client holds the body lease (the tablet?); release it, or take it with "
                                 "take_lease=true") from None
        except bd.exc.Error as exc:
            raise self._translate(exc, "acquiring the lease") from None
        cls = _lease_keep_alive_class(bd)
        cls.rpc_timeout = cfg.rpc_timeout
        backend = self
        cls.on_retained = staticmethod(lambda: backend._note_retain(True))
        self._note_retain(True)                 # acquiring it is the robot hearing from us
        # must_acquire=False: the lease was just acquired into the wallet above; with True the SDK
        # acquires again, without a deadline (30 s), should the wallet have lost it meanwhile (safety audit)
        self._lease_keepalive = cls(self._lease_client, must_acquire=False, return_at_exit=False,
                                    rpc_interval_seconds=cfg.lease_retain_period,
                                    on_failure_callback=self._on_lease_keepalive_error, warnings=False)
        self._lease_unconfirmed = False
        _LOG.info("body lease acquired")

    def _note_retain(self, confirmed: bool) -> None:
        """A RetainLease of ours the robot confirmed, or one it did not answer (a slow link, or
        retains that do not reach it). Retains the robot does not hear are what a Spot's
        comms-loss behaviour acts on (it stops, sits, powers off and marks the lease stale:
        ``_comms_loss_fault``): the first unanswered one is said once, and so is the recovery."""
        now = time.monotonic()
        if confirmed:
            if self._retain_failing:
                _LOG.info("lease keep-alive: the robot confirms our RetainLease again (%.1f s without)",
                          now - (self._retain_confirmed_at or now))
            self._retain_confirmed_at, self._retain_failing = now, False
        elif not self._retain_failing:
            self._retain_failing = True
            _LOG.warning("lease keep-alive: a RetainLease went unanswered; a Spot that hears none for its comms-loss "
                         "timeout stops, sits and powers off and marks our lease stale")

    def _retain_overdue(self) -> float:
        """Seconds after a confirmed retain by which the next one is overdue: the keep-alive
        retains every ``lease_retain_period``, and an answer takes milliseconds (0.25 s of slack
        for a loaded client)."""
        return self.config.lease_retain_period + 0.25

    def _retain_gap_note(self) -> str | None:
        """What our keep-alive's record says about the robot's comms-loss behaviour: no retain
        confirmed for longer than one was due, or None while the keep-alive is in time. It knows
        before its own unanswered call times out (``rpc_timeout`` may be longer than the robot's
        comms-loss timeout is past the last retain it heard). A stretch that is over is not kept:
        a power loss long after it would be blamed on it."""
        if self._retain_confirmed_at is None:
            return None
        silent = time.monotonic() - self._retain_confirmed_at
        if silent < self._retain_overdue():
            return None
        return (f"no lease keep-alive (RetainLease) of ours confirmed for {silent:.1f} s (one is due every "
                f"{self.config.lease_retain_period:g} s)")

    def _on_lease_keepalive_error(self, exc) -> None:
        bd = self._bd
        if self._overtaken(exc):            # a check-in that one of our commands overtook: still ours
            return
        if self._lease_returning:            # our own ReturnLease: the wallet and the robot say it is gone
            return
        if isinstance(exc, bd.exc.RpcError) and not self._closing:     # unanswered (a timeout) or lost
            self._note_retain(False)
        if isinstance(exc, bd.exc.LeaseUseError) or (
                isinstance(exc, (bd.lease.LeaseNotOwnedByWallet, bd.lease.NoSuchLease)) and not self._closing):
            # the robot refused our lease: recorded also after another fault and during close(), so
            # the shutdown neither commands nor returns it and tells the operator (safety audit)
            why = f"the body lease was revoked or taken by another client ({type(exc).__name__})"
            if self._lease_lost is None:
                self._lease_lost = why
            if self._fault is None and not self._closing:
                self._fault = LeaseLostError(why)
                _LOG.warning("lease keep-alive: %s", self._fault)
