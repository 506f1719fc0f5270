"""What the Spot SDK backend needs before it connects: its configuration (every wait on the robot
bounded), the credentials (from the environment only, never from config or the command line), the
check that gRPC's own tracing would not print them, and the errors these raise (all HalErrors: the
command line reports each as one line, no traceback).

Importing this module needs no bosdyn: ``tools spot`` validates a configuration and the
environment before anything reaches for the robot.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Literal

from robots.hal import ConnectionLostError, HalError, RobotFault
from robots.spot.motion import MotionConfig

USERNAME_ENV = "BOSDYN_CLIENT_USERNAME"
PASSWORD_ENV = "BOSDYN_CLIENT_PASSWORD"


# --------------------------------------------------------------------------------------------
# Errors (all HalError: the command line reports them as one line, no traceback)
# --------------------------------------------------------------------------------------------
class SpotSdkMissingError(HalError):
    """bosdyn-client is not installed."""


class CredentialsError(HalError):
    """Credentials are missing from the environment or were rejected by the robot."""


class SpotConnectError(ConnectionLostError):
    """The robot could not be reached or its TLS certificate was not accepted."""


class NotConnectedError(HalError):
    """A command on a backend that has not brought the robot up (``connect()`` still running in
    another thread, not called, or failed): nothing of this backend moves the robot yet."""


class CommandRejectedError(RobotFault):
    """The robot refused or could not execute a command for a reason the HAL has no type for."""


# --------------------------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------------------------
MAX_WAIT_S = 600.0   # the longest any single wait on the robot may be configured to take


@dataclass(frozen=True)
class SdkBackendConfig:
    """How to reach and drive a Spot. Credentials are not part of it (environment only)."""

    hostname: str = ""
    port: int = 443                        # the robot's secure gRPC port
    cert_path: str | None = None           # CA bundle (PEM); None = BD's root CA shipped with bosdyn-client
    estop_mode: Literal["external", "endpoint"] = "external"
    # external: someone else holds the e-stop (tablet, e-stop app) and must have released it;
    # endpoint: this client registers its own software e-stop and keeps it alive (replaces the
    # robot's e-stop configuration; only for setups without another e-stop).
    estop_timeout: float = 9.0             # s without our check-in before our endpoint stops the robot
    take_lease: bool = False               # take the body lease from its current holder instead of failing
    client_name: str = "helios"
    rpc_timeout: float = 1.5               # s per RPC: bounds how long a dead or slow link takes to surface
    image_rpc_timeout: float = 3.0         # s for an image request (larger payloads)
    connect_timeout: float = 5.0           # s for authentication and the first time sync
    power_on_timeout: float = 20.0
    stand_timeout: float = 10.0
    feedback_period: float = 0.05          # s between command feedback polls
    command_margin: float = 2.0            # s a command may run past its planned duration before it times out
    arm_move_timeout: float = 10.0         # s for moves the robot plans itself (gaze, stow, carry)
    grasp_timeout: float = 20.0            # s for a pick-in-image
    grasp_edge_wait: float = 2.0           # s a pick may wait for data at the image's edge (the robot does
    #                                        not gaze by itself in PICK_NO_AUTO_WALK_OR_GAZE) before it is
    #                                        given up as unreachable from this view (home-robot's Spot client: 2 s)
    time_sync_interval: float = 1.0        # s between time-sync updates (SDK default 60): bounds how long a
    #                                        time-sync loss takes to surface during a motion
    close_budget: float = 2.0              # s of wall time close() may spend on a robot after a fault or
    #                                        on a failing link (stop, safe power off, lease, e-stop in flight)
    stall_time: float = 1.0                # s a moving command may make no progress while its plan moves
    #                                        before it is stopped as stalled (CommandTimeoutError)
    allow_grpc_tracing: bool = False       # connect although GRPC_TRACE / GRPC_VERBOSITY=debug would print
    #                                        the session token to the terminal (a warning instead of an error)
    lease_retain_period: float = 2.0       # s between lease keep-alive check-ins (the SDK's default); keep it
    #                                        well under the robot's comms-loss timeout over the lease (not
    #                                        published; Spot sits 3 s after a signal loss, and so does the fake)
    stand_on_connect: bool = True          # power on and stand during bring-up
    power_off_on_close: bool = True        # sit and power off in close()
    image_format: Literal["jpeg", "raw"] = "jpeg"
    jpeg_quality: int = 90
    max_trajectory_points: int = 250       # per SE2 or arm joint trajectory command (Spot's arm limit)
    goal_tolerance: float = 0.05           # m / rad: a navigation counts as arrived within this
    release_retreat: float = 0.12          # m the hand backs off after releasing an object
    motion: MotionConfig = MotionConfig()

    def __post_init__(self) -> None:
        if not (0 < int(self.port) < 65536):
            raise ValueError(f"port must be within 1..65535, got {self.port}")
        for name in ("estop_timeout", "rpc_timeout", "image_rpc_timeout", "connect_timeout", "power_on_timeout",
                     "stand_timeout", "feedback_period", "arm_move_timeout", "grasp_timeout", "grasp_edge_wait",
                     "time_sync_interval", "lease_retain_period", "close_budget", "stall_time"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number of seconds, got {v!r}")
            if v > MAX_WAIT_S:
                raise ValueError(f"{name} must be at most {MAX_WAIT_S:g} s (a wait on the robot longer than "
                                 f"that is a hang, not a timeout), got {v!r}")
        if not (0 <= self.command_margin <= MAX_WAIT_S and math.isfinite(self.command_margin)):
            raise ValueError(f"command_margin must be within 0..{MAX_WAIT_S:g} s, got {self.command_margin!r}")
        if not 2 <= int(self.max_trajectory_points) <= 250:
            raise ValueError(f"max_trajectory_points must be within 2..250, got {self.max_trajectory_points}")
        if not 1 <= int(self.jpeg_quality) <= 100:
            raise ValueError(f"jpeg_quality must be within 1..100, got {self.jpeg_quality}")
        for name in ("goal_tolerance", "release_retreat"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and 0 <= v <= 1.0):
                raise ValueError(f"{name} must be within [0, 1], got {v!r}")


_TRACE_OFF = ("", "none", "-all")


def grpc_tracing_hazard(environ=None) -> str | None:
    """Why gRPC's own tracing in the environment would print credentials, or None when it is off.
    Any GRPC_TRACE tracer counts: with GRPC_TRACE=all grpcio 1.85 prints the session token 17 times
    in one connect (with or without GRPC_VERBOSITY); tracers differ by version, so none is trusted."""
    env = os.environ if environ is None else environ
    trace = env.get("GRPC_TRACE", "").strip()
    if trace.lower() not in _TRACE_OFF:
        return f"GRPC_TRACE={trace!r} is set"
    return None


class GrpcTracingError(HalError):
    """gRPC tracing is on in the environment and would print credentials."""


def credentials_from_env(environ=None) -> tuple[str, str]:
    """(username, password) from the environment, or one clear CredentialsError."""
    env = os.environ if environ is None else environ
    user, password = env.get(USERNAME_ENV, ""), env.get(PASSWORD_ENV, "")
    missing = [n for n, v in ((USERNAME_ENV, user), (PASSWORD_ENV, password)) if not v]
    if missing:
        raise CredentialsError(f"Spot credentials missing: set {' and '.join(missing)} in the environment "
                               f"(credentials are never read from config files or the command line)")
    return user, password
