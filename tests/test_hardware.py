"""Hardware bring-up checks on a real Spot, staged from least motion to most (marker ``hardware``).

Run them with ``make test-hardware`` (or ``python -m pytest -m hardware -x tests/test_hardware.py``,
in one process, in this order; ``-x`` stops at the first failing stage, before the next one moves
the robot more). They are skipped, with the reason, unless ``HELIOS_SPOT_HOST`` names the robot,
``BOSDYN_CLIENT_USERNAME`` / ``BOSDYN_CLIENT_PASSWORD`` hold its credentials and ``-m hardware``
selects them (``make test`` and ``make test-all`` leave them out: a robot address left in the
environment must not make the unit test suite stand the robot up), and under pytest-xdist (the
stages drive one robot in turn; in parallel they would fight over its lease).

The environment (the same path to the robot as ``python -m tools spot HOST``: the backend config is
built by ``tools.spot.backend_config`` from these, as from that command's flags):

* ``HELIOS_SPOT_HOST``: the robot's hostname or IP address (HOSTNAME)
* ``BOSDYN_CLIENT_USERNAME``, ``BOSDYN_CLIENT_PASSWORD``: its credentials (never anywhere else)
* ``HELIOS_SPOT_PORT``: its secure gRPC port (``--port``; default 443)
* ``HELIOS_SPOT_CA``: the CA certificate (PEM) its TLS certificate must chain to (``--cert``;
  default: Boston Dynamics' root CA shipped with bosdyn-client)
* ``HELIOS_SPOT_ESTOP``: ``external`` (default: an e-stop held elsewhere, the tablet or the e-stop
  app, must be released) or ``endpoint`` (this client registers its own software e-stop, which
  replaces the robot's e-stop configuration while it runs) (``--estop``)
* ``HELIOS_SPOT_CONFIG``: an ``SdkBackendConfig`` YAML file (``--config``; e.g. longer timeouts,
  or ``take_lease: true`` to take the body lease from the tablet)

What each stage makes the robot do (each connects, then shuts down as ``tools spot`` does:
``SdkSpotBackend.close()``: stop, stow, sit and power off, return the lease, deregister our e-stop
endpoint), and what it asserts:

(a) ``test_a_connect_only``, **no motion, no power**: TLS and authentication, time sync
    established (its clock skew and round trip are printed), the e-stop status readable and
    released, the robot state readable (battery charge within 0-100 % and at least
    ``MIN_BATTERY_PERCENT``, no critical system fault, no behavior fault), the body lease ours
    while connected (the robot's own ListLeases says so) and returned at close; motor power as
    it found it, no thread of the session left, our e-stop endpoint (if any) gone.
(b) ``test_b_power_stand_sit``: **powers on and stands up in place, then stops, sits down and
    powers off**. After close: motors off, the lease returned, our e-stop endpoint gone, no
    thread left, ``close()`` within ``CLOSE_POWERED_S`` and nothing it could not do
    (``close_problem``).
(c) ``test_c_hand_camera``, **no motion, no power**: one hand-camera observation (colour + depth
    registered to it): plausible intrinsics (matching the image size, focal lengths within
    100-5000 px and within 10 % of each other, principal point inside the image, horizontal
    field of view 30-150 deg), a colour image that is not blank, depth readings in at least
    ``MIN_DEPTH_FRACTION`` of the image within 0.05-10 m (with the arm stowed the hand camera
    looks ahead over the floor; something within 2 m in front of the robot helps), camera and
    body poses that are rigid transforms a plausible distance apart, and a frame time taken from
    the robot's clock through time sync (within ``FRAME_AGE_S`` of when it was asked for, on this
    computer's clock, whatever the two clocks' skew).
(d) ``test_d_arm_gaze_and_stow``: **powers on, stands, unstows the arm to point the hand camera
    at the floor about 1 m in front of the body** (Spot's own gaze command chooses the arm's
    path; the body does not walk), checks the camera looks at that point (optical axis within
    ``GAZE_ANGLE_DEG``; its depth there lands within ``GAZE_DEPTH_TOLERANCE_M`` of it), **stows
    the arm**, then sits and powers off. Every command's result must be a success and the arm
    stowed in the robot's state afterwards.

**Safety.** The operator stands by with an e-stop at hand (the tablet or the e-stop app, or with
``HELIOS_SPOT_ESTOP=endpoint`` ready to stop this process: our endpoint cuts motor power
``estop_timeout`` s after its last check-in), with a clear 2 m around the robot (it stands up and
its arm unfolds forward), on flat ground, the robot sitting and its battery charged. The motions
are Spot's own stand, sit, gaze and stow; nothing walks.

The same stages run against the fake Spot in the normal suite (``tests/test_hardware_on_fake.py``:
``pytest -m hardware`` in a subprocess with these variables pointing at it), so a change that
breaks this file shows there first.
"""

from __future__ import annotations

import contextlib
import math
import os
import time
from dataclasses import replace

import numpy as np
import pytest

pytestmark = pytest.mark.hardware

HOST_ENV, PORT_ENV, CA_ENV, ESTOP_ENV, CONFIG_ENV = ("HELIOS_SPOT_HOST", "HELIOS_SPOT_PORT", "HELIOS_SPOT_CA",
                                                    "HELIOS_SPOT_ESTOP", "HELIOS_SPOT_CONFIG")
SKIP_NO_HOST = (f"needs a real Spot: set {HOST_ENV} (and BOSDYN_CLIENT_USERNAME/BOSDYN_CLIENT_PASSWORD), then run "
                f"make test-hardware (README, 'Hardware checks first')")
SKIP_NOT_SELECTED = ("moves a real Spot: select the hardware stages explicitly with -m hardware (make "
                     "test-hardware); make test and make test-all leave them out")
SKIP_XDIST = "the hardware stages drive one robot in turn: run them in one process (make test-hardware), not under xdist"

MIN_BATTERY_PERCENT = 20.0     # below it stage (a) fails: charge the robot before the stages that power it
CLOSE_POWERED_S = 20.0         # s for close() on a standing robot: stop, stow, sit, power off, lease, e-stop
CLOSE_UNPOWERED_S = 5.0        # s for close() on a robot that was never powered
THREADS_END_S = 5.0            # s for the session's threads to end after close()
FRAME_AGE_S = 1.0              # s a hand-camera frame may be older than the request for it
MIN_DEPTH_FRACTION = 0.01      # of the image with a depth reading
GAZE_DISTANCE_M = 1.0          # the gaze point: this far ahead of the body, at floor height
GAZE_ANGLE_DEG = 15.0          # the camera's optical axis to the gaze point
GAZE_DEPTH_TOLERANCE_M = 0.25  # the depth at the gaze point's pixel, back-projected, to the gaze point


# ============================================================================ configuration
def _skip_reason(config) -> str | None:
    """Why the stages must not run here, or None."""
    if not os.environ.get(HOST_ENV, "").strip():
        return SKIP_NO_HOST
    from robots.spot.sdk_config import PASSWORD_ENV, USERNAME_ENV

    missing = [name for name in (USERNAME_ENV, PASSWORD_ENV) if not os.environ.get(name)]
    if missing:
        return f"{HOST_ENV} is set but {' and '.join(missing)} {'is' if len(missing) == 1 else 'are'} not: the " \
               f"robot's credentials come from the environment only"
    expr = (config.getoption("markexpr", "") or "").replace(" ", "")
    if "hardware" not in expr or "nothardware" in expr:
        return SKIP_NOT_SELECTED
    if os.environ.get("PYTEST_XDIST_WORKER"):
        return SKIP_XDIST
    return None


@pytest.fixture(scope="module")
def robot_config(request):
    """The robot's ``SdkBackendConfig``, built by ``tools spot``'s own code from the environment."""
    reason = _skip_reason(request.config)
    if reason is not None:
        pytest.skip(reason)
    from tools.cli import CliError
    from tools.spot import backend_config

    port = os.environ.get(PORT_ENV, "").strip() or None
    estop = os.environ.get(ESTOP_ENV, "").strip() or None
    try:
        if port is not None and not port.isdigit():
            raise CliError(f"{PORT_ENV}={port!r} is not a port number")
        if estop is not None and estop not in ("external", "endpoint"):
            raise CliError(f"{ESTOP_ENV}={estop!r}: give external or endpoint")
        return backend_config(os.environ[HOST_ENV].strip(), port=int(port) if port else None,
                              cert=os.environ.get(CA_ENV, "").strip() or None, estop=estop,
                              config_file=os.environ.get(CONFIG_ENV, "").strip() or None)
    except (CliError, ValueError, OSError) as exc:
        pytest.fail(f"the robot's configuration from the environment: {exc}", pytrace=False)


# ============================================================================ the robot's own view
class Observer:
    """A second, read-only SDK session on the robot (its own client name, no lease, no e-stop, no
    command): what the robot itself says about the lease, the e-stop and its state, also after
    the backend under test has closed."""

    def __init__(self, config):
        import bosdyn.client
        from bosdyn.client.estop import EstopClient
        from bosdyn.client.lease import LeaseClient
        from bosdyn.client.robot_state import RobotStateClient
        from robots.spot.sdk_config import credentials_from_env

        self.timeout = config.rpc_timeout
        glob_ = None
        if config.cert_path is not None:
            import glob

            glob_ = glob.escape(os.path.abspath(config.cert_path))
        self.sdk = bosdyn.client.create_standard_sdk("helios-hardware-check", cert_resource_glob=glob_)
        try:
            robot = self.sdk.create_robot(config.hostname)
            robot.update_secure_channel_port(int(config.port))
            user, password = credentials_from_env()
            robot.authenticate(user, password, timeout=config.connect_timeout)
            robot.sync_with_services_list(robot.ensure_client("directory").list(timeout=self.timeout))
            self.lease = robot.ensure_client(LeaseClient.default_service_name)
            self.estop = robot.ensure_client(EstopClient.default_service_name)
            self.state_client = robot.ensure_client(RobotStateClient.default_service_name)
        except BaseException:
            self.close()
            raise

    def body_lease_owner(self) -> str:
        """The client name holding the body lease ('' when nobody does)."""
        for res in self.lease.list_leases(timeout=self.timeout):
            if res.resource == "body":
                return res.lease_owner.client_name
        return ""

    def estop_endpoints(self) -> dict[str, str]:
        """unique id -> name of the endpoints in the robot's active e-stop configuration."""
        return {ep.unique_id: ep.name for ep in self.estop.get_config(timeout=self.timeout).endpoints}

    def state(self):
        return self.state_client.get_robot_state(timeout=self.timeout)

    def motor_power(self) -> str:
        """"on", "off" or what else the robot's power state says (powering on or off, error)."""
        PS = self.state().power_state
        return {PS.MOTOR_POWER_STATE_ON: "on", PS.MOTOR_POWER_STATE_OFF: "off"}.get(
            PS.motor_power_state, PS.MotorPowerState.Name(PS.motor_power_state))

    def close(self) -> None:
        self.sdk.clear_robots()      # stops the token and time-sync threads


@pytest.fixture(scope="module")
def observer(robot_config):
    obs = Observer(robot_config)
    yield obs
    obs.close()


@contextlib.contextmanager
def robot_session(config, observer: Observer, close_within: float):
    """Connect ``SdkSpotBackend(config)`` (the bring-up ``tools spot`` does), yield it, close it;
    then check what every stage must leave behind: the body lease returned (the robot says
    another owner or none), our e-stop endpoint (endpoint mode) gone and the robot's other
    endpoints untouched, no thread of the session left, close() within ``close_within`` s with
    nothing it could not do."""
    from robots.spot.sdk_backend import SdkSpotBackend
    from spot_fake_fixtures import python_threads, wait_for_threads_to_end

    endpoints_before = observer.estop_endpoints()
    before = python_threads()
    backend = SdkSpotBackend(config)           # a failed bring-up closes what it had brought up, then raises
    try:
        ours = observer.body_lease_owner()
        assert ours.startswith(config.client_name + "-"), \
            f"the robot says the body lease is held by {ours or 'nobody'!r}, not by this session"
        added = {k: v for k, v in observer.estop_endpoints().items() if k not in endpoints_before}
        if config.estop_mode == "endpoint":
            assert len(added) == 1 and next(iter(added.values())).startswith(config.client_name + "-estop-"), added
        else:
            assert not added, f"e-stop endpoints appeared with an external e-stop: {added}"
        yield backend
    except BaseException:
        backend.close()
        raise
    t0 = time.monotonic()
    backend.close()
    took = time.monotonic() - t0
    print(f"close() took {took:.2f} s")
    assert backend.close_problem is None, backend.close_problem
    assert took <= close_within, f"close() took {took:.1f} s (> {close_within} s)"
    owner = observer.body_lease_owner()
    assert owner != ours, f"the body lease is still ours after close(): {owner!r}"
    left = {k: v for k, v in observer.estop_endpoints().items() if k not in endpoints_before}
    assert not left, f"our e-stop endpoint is still on the robot after close(): {left}"
    if config.estop_mode == "external":
        assert observer.estop_endpoints() == endpoints_before, "the robot's e-stop configuration changed"
    leaked = wait_for_threads_to_end(before, THREADS_END_S)
    assert not leaked, f"threads left after close(): {sorted(t.name for t in leaked)}"


def _check_robot_state(state) -> None:
    from bosdyn.api import robot_state_pb2

    SF = robot_state_pb2.SystemFault
    critical = [f"{f.name} [{', '.join(f.attributes)}]" for f in state.system_fault_state.faults
                if f.severity == SF.SEVERITY_CRITICAL]
    assert not critical, f"critical system faults: {critical}"
    behavior = [str(f.cause) for f in state.behavior_fault_state.faults]
    assert not behavior, f"behavior faults (clear them on the tablet): {behavior}"
    assert state.estop_states, "the robot state lists no e-stop"
    engaged = [e.name for e in state.estop_states if e.state == e.STATE_ESTOPPED]
    assert not engaged, f"e-stopped: {engaged}"
    assert state.battery_states, "the robot state lists no battery"
    for battery in state.battery_states:
        charge = battery.charge_percentage.value
        assert 0.0 <= charge <= 100.0, f"battery {battery.identifier!r}: charge {charge} %"
        print(f"battery {battery.identifier or '?'}: {charge:.0f} %")
        assert charge >= MIN_BATTERY_PERCENT, \
            f"battery {battery.identifier!r} at {charge:.0f} %: charge it before powering the robot"


def _unpowered(config):
    return replace(config, stand_on_connect=False)


def _powered(config):
    """Power on and stand at connect, sit and power off at close, whatever HELIOS_SPOT_CONFIG says."""
    return replace(config, stand_on_connect=True, power_off_on_close=True)


# ============================================================================ the stages
@pytest.mark.timeout(120)
def test_a_connect_only(robot_config, observer):
    from bosdyn.api import estop_pb2

    power_before = observer.motor_power()
    with robot_session(_unpowered(robot_config), observer, CLOSE_UNPOWERED_S) as backend:
        rid = backend.robot_id
        print(f"connected to {rid.nickname or 'robot'} (serial {rid.serial_number}, software "
              f"{rid.software_release.version.major_version}.{rid.software_release.version.minor_version})")
        assert rid.serial_number
        ts = backend.robot.time_sync
        assert ts.has_established_time_sync, "no time sync with the robot"
        skew = ts.get_robot_clock_skew()
        rtt = ts.endpoint.round_trip_time
        skew_s = skew.seconds + skew.nanos * 1e-9
        rtt_s = rtt.seconds + rtt.nanos * 1e-9
        print(f"time sync: robot clock skew {skew_s:+.3f} s, round trip {1000 * rtt_s:.1f} ms")
        assert math.isfinite(skew_s) and 0.0 <= rtt_s < 1.0, (skew_s, rtt_s)
        status = observer.estop.get_status(timeout=observer.timeout)
        assert status.stop_level == estop_pb2.ESTOP_LEVEL_NONE, estop_pb2.EstopStopLevel.Name(status.stop_level)
        _check_robot_state(observer.state())
        assert observer.motor_power() == power_before, "connecting changed motor power"
    assert observer.motor_power() == power_before


@pytest.mark.timeout(180)
def test_b_power_stand_sit(robot_config, observer):
    with robot_session(_powered(robot_config), observer, CLOSE_POWERED_S) as backend:
        assert observer.motor_power() == "on"
        res = backend.stop()
        assert res.success, res.message
    assert observer.motor_power() == "off", "the robot is still powered after close()"


@pytest.mark.timeout(120)
def test_c_hand_camera(robot_config, observer):
    with robot_session(_unpowered(robot_config), observer, CLOSE_UNPOWERED_S) as backend:
        t0 = time.time()
        obs = backend.observe()
        t1 = time.time()
    K = obs.intrinsics
    h, w = obs.depth.shape
    print(f"hand camera {K.width}x{K.height}, fx {K.fx:.1f} fy {K.fy:.1f} cx {K.cx:.1f} cy {K.cy:.1f}, "
          f"horizontal fov {math.degrees(K.horizontal_fov):.0f} deg")
    assert (K.width, K.height) == (w, h) == obs.rgb.shape[1::-1]
    assert 100.0 <= K.fx <= 5000.0 and 100.0 <= K.fy <= 5000.0 and abs(K.fx / K.fy - 1.0) < 0.1, K
    assert 0.0 < K.cx < K.width and 0.0 < K.cy < K.height, K
    assert 30.0 <= math.degrees(K.horizontal_fov) <= 150.0, K
    assert float(obs.rgb.std()) > 2.0, "the colour image is blank"
    valid = obs.depth > 0
    fraction = float(valid.mean())
    print(f"depth: {100 * fraction:.1f} % of the image, median {np.median(obs.depth[valid]) if fraction else 0:.2f} m")
    assert fraction >= MIN_DEPTH_FRACTION, f"depth in only {100 * fraction:.2f} % of the image"
    assert 0.05 <= float(np.median(obs.depth[valid])) <= 10.0
    for name, T in (("camera", obs.T_world_cam), ("body", obs.T_world_body)):
        R = T[:3, :3]
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-3) and abs(np.linalg.det(R) - 1.0) < 1e-3, (name, T)
    assert np.linalg.norm(obs.T_world_cam[:3, 3] - obs.T_world_body[:3, 3]) < 1.5
    print(f"frame time {obs.stamp - t0:+.3f} s after the request (this computer's clock)")
    assert t0 - FRAME_AGE_S <= obs.stamp <= t1 + 0.05, \
        f"frame time {obs.stamp:.3f} not within [{t0 - FRAME_AGE_S:.3f}, {t1 + 0.05:.3f}]: not the robot's clock " \
        f"converted through time sync"


@pytest.mark.timeout(180)
def test_d_arm_gaze_and_stow(robot_config, observer):
    from bosdyn.api import robot_state_pb2

    from robots.spot import model

    with robot_session(_powered(robot_config), observer, CLOSE_POWERED_S) as backend:
        T_body = backend.observe().T_world_body
        heading = T_body[:2, 0] / np.linalg.norm(T_body[:2, 0])
        floor = T_body[2, 3] - model.stand_body_height()
        target = np.array([*(T_body[:2, 3] + GAZE_DISTANCE_M * heading), floor])
        print(f"gaze at ({target[0]:.2f}, {target[1]:.2f}, {target[2]:.2f}) in odom")
        res = backend.gaze_at(target)
        assert res.success, f"gaze: {res.reason.value}: {res.message}"
        obs = backend.observe()
        cam = obs.T_world_cam
        to_target = target - cam[:3, 3]
        angle = math.degrees(math.acos(np.clip(cam[:3, 2] @ to_target / np.linalg.norm(to_target), -1.0, 1.0)))
        print(f"optical axis {angle:.1f} deg from the gaze point")
        assert angle <= GAZE_ANGLE_DEG, f"the hand camera looks {angle:.1f} deg away from the gaze point"
        p_cam = np.linalg.inv(cam) @ np.append(target, 1.0)
        (u, v), _ = obs.intrinsics.project(p_cam[:3])
        u, v = int(round(float(u))), int(round(float(v)))
        assert 0 <= u < obs.intrinsics.width and 0 <= v < obs.intrinsics.height, \
            f"the gaze point is outside the hand camera's image (pixel {u}, {v})"
        window = obs.depth[max(v - 10, 0):v + 11, max(u - 10, 0):u + 11]
        assert window.size and (window > 0).mean() >= 0.25, "no depth reading at the gaze point"
        point = obs.point_at_pixel(u, v) if obs.depth[v, u] > 0 else None
        if point is None:           # the pixel itself has no reading: its neighbours' median depth
            d = float(np.median(window[window > 0]))
            point = (cam @ np.append(obs.intrinsics.backproject(u, v, d), 1.0))[:3]
        miss = float(np.linalg.norm(np.asarray(point) - target))
        print(f"depth at the gaze point lands {100 * miss:.1f} cm from it")
        assert miss <= GAZE_DEPTH_TOLERANCE_M, f"the depth at the gaze point lands {miss:.2f} m from it"
        res = backend.stow_arm()
        assert res.success, f"stow: {res.reason.value}: {res.message}"
        MS = robot_state_pb2.ManipulatorState
        stow = observer.state().manipulator_state.stow_state
        assert stow == MS.STOWSTATE_STOWED, MS.StowState.Name(stow)
    assert observer.motor_power() == "off"
