"""The fake Spot speaks the real protocol: the unmodified bosdyn client connects to it over TLS on
127.0.0.1 with a test CA and drives it as it drives a robot; it refuses what a robot refuses."""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time

import numpy as np
import pytest

pytest.importorskip("bosdyn.client")

import bosdyn.client  # noqa: E402
from bosdyn.api import basic_command_pb2, image_pb2, manipulation_api_pb2  # noqa: E402
from bosdyn.client import frame_helpers  # noqa: E402
from bosdyn.client.auth import InvalidLoginError  # noqa: E402
from bosdyn.client.estop import EstopClient, EstopEndpoint, EstopKeepAlive  # noqa: E402
from bosdyn.client.exceptions import InvalidRequestError, RpcError  # noqa: E402
from bosdyn.client.image import ImageClient, build_image_request  # noqa: E402
from bosdyn.client.lease import LeaseClient, LeaseKeepAlive  # noqa: E402
from bosdyn.client.manipulation_api_client import ManipulationApiClient  # noqa: E402
from bosdyn.client.robot_command import (  # noqa: E402
    RobotCommandBuilder,
    RobotCommandClient,
    UnknownFrameError,
    blocking_stand,
)
from bosdyn.client.robot_state import RobotStateClient  # noqa: E402

from robots.spot import sdk_conversions as cv  # noqa: E402
from robots.spot.fake_spot.certs import make_test_pki  # noqa: E402
from robots.spot.fake_spot.server import FAULTS  # noqa: E402
from spot_fake_fixtures import TEST_PASSWORD, TEST_USER, session_pki, start_fake  # noqa: E402

pytestmark = pytest.mark.timeout(60)


@pytest.fixture
def demo():
    d = start_fake(seed=0)
    yield d
    d.stop()


def _robot(demo, ca=None, name="test"):
    sdk = bosdyn.client.create_standard_sdk(name, cert_resource_glob=str(ca or session_pki().ca_cert))
    robot = sdk.create_robot("127.0.0.1")
    robot.update_secure_channel_port(demo.port)
    return sdk, robot


def _teardown(sdk, robot, *keepalives):
    for k in keepalives:
        k.shutdown()
    sdk.clear_robots()                      # stops the time-sync and token threads
    robot.shutdown()


@contextlib.contextmanager
def _powered(demo):
    """An unmodified SDK session on the fake, authenticated, time-synced, holding the lease, motors
    on: yields the robot, torn down after."""
    sdk, robot = _robot(demo)
    robot.authenticate(TEST_USER, TEST_PASSWORD, timeout=3)
    robot.time_sync.wait_for_sync(timeout_sec=3)
    lease_keepalive = LeaseKeepAlive(robot.ensure_client(LeaseClient.default_service_name), must_acquire=True,
                                     return_at_exit=True)
    try:
        robot.power_on(timeout_sec=3, update_frequency=50)
        yield robot
    finally:
        _teardown(sdk, robot, lease_keepalive)


def test_unmodified_bosdyn_robot_drives_the_fake_over_tls(demo):
    sdk, robot = _robot(demo)
    robot.authenticate(TEST_USER, TEST_PASSWORD, timeout=3)
    robot.time_sync.wait_for_sync(timeout_sec=3)
    # Time sync found the robot's clock skew.
    skew = robot.time_sync.get_robot_clock_skew()
    assert abs(skew.seconds + skew.nanos * 1e-9 - demo.fake.clock_skew) < 0.05
    assert robot.get_id().serial_number == "FAKE-SPOT-0001"
    assert {"robot-command", "manipulation", "image", "estop"} <= {s.name for s in robot.list_services()}

    endpoint = EstopEndpoint(robot.ensure_client(EstopClient.default_service_name), "pytest-estop", 9.0)
    endpoint.force_simple_setup()
    estop_keepalive = EstopKeepAlive(endpoint)
    assert not robot.is_estopped()
    lease_keepalive = LeaseKeepAlive(robot.ensure_client(LeaseClient.default_service_name), must_acquire=True,
                                     return_at_exit=True)
    try:
        robot.power_on(timeout_sec=3, update_frequency=50)
        assert robot.is_powered_on()
        command = robot.ensure_client(RobotCommandClient.default_service_name)
        blocking_stand(command, timeout_sec=3, update_frequency=50)

        # An SE2 trajectory command in odom with an end time (converted to robot time by the client).
        goal = RobotCommandBuilder.synchro_se2_trajectory_point_command(0.4, 0.1, 0.3, frame_helpers.ODOM_FRAME_NAME)
        cmd_id = command.robot_command(goal, end_time_secs=time.time() + 5.0)
        for _ in range(200):
            fb = command.robot_command_feedback(cmd_id).feedback.synchronized_feedback.mobility_command_feedback
            if fb.se2_trajectory_feedback.status == basic_command_pb2.SE2TrajectoryCommand.Feedback.STATUS_AT_GOAL:
                break
            time.sleep(0.01)
        state = robot.ensure_client(RobotStateClient.default_service_name).get_robot_state()
        odom_body = frame_helpers.get_a_tform_b(state.kinematic_state.transforms_snapshot,
                                                frame_helpers.ODOM_FRAME_NAME, frame_helpers.BODY_FRAME_NAME)
        assert math.hypot(odom_body.x - 0.4, odom_body.y - 0.1) < 1e-6
        assert abs(odom_body.rot.to_yaw() - 0.3) < 1e-6
        with demo.fake.sim_lock:
            np.testing.assert_allclose(demo.fake.sim.spot.T_world_body()[:2, 3], [0.4, 0.1], atol=1e-9)

        # Colour + registered depth, decoded the way Spot documents them.
        images = robot.ensure_client(ImageClient.default_service_name).get_image([
            build_image_request(cv.HAND_COLOR_SOURCE, image_format=image_pb2.Image.FORMAT_RAW,
                                pixel_format=image_pb2.Image.PIXEL_FORMAT_RGB_U8),
            build_image_request(cv.HAND_DEPTH_SOURCE, pixel_format=image_pb2.Image.PIXEL_FORMAT_DEPTH_U16)])
        color, depth = images
        assert depth.source.depth_scale == pytest.approx(999.0)
        raw = np.frombuffer(depth.shot.image.data, dtype=np.uint16)
        assert raw.size == depth.source.rows * depth.source.cols and raw.max() > 0
        assert color.shot.frame_name_image_sensor in color.shot.transforms_snapshot.child_to_parent_edge_map

        # Pick-in-image with the image's own snapshot and camera model; feedback reaches a final state.
        manip = robot.ensure_client(ManipulationApiClient.default_service_name)
        pick = manipulation_api_pb2.PickObjectInImage(
            pixel_xy=cv.geometry_pb2.Vec2(x=10, y=10), transforms_snapshot_for_camera=color.shot.transforms_snapshot,
            frame_name_image_sensor=color.shot.frame_name_image_sensor, camera_model=color.source.pinhole)
        resp = manip.manipulation_api_command(
            manipulation_api_request=manipulation_api_pb2.ManipulationApiRequest(pick_object_in_image=pick))
        final = {manipulation_api_pb2.MANIP_STATE_GRASP_SUCCEEDED, manipulation_api_pb2.MANIP_STATE_GRASP_FAILED,
                 manipulation_api_pb2.MANIP_STATE_GRASP_PLANNING_NO_SOLUTION,
                 manipulation_api_pb2.MANIP_STATE_GRASP_FAILED_TO_RAYCAST_INTO_MAP}
        for _ in range(500):
            fb = manip.manipulation_api_feedback_command(
                manipulation_api_feedback_request=manipulation_api_pb2.ManipulationApiFeedbackRequest(
                    manipulation_cmd_id=resp.manipulation_cmd_id))
            if fb.current_state in final:
                break
            time.sleep(0.01)
        assert fb.current_state in final
        robot.power_off(cut_immediately=False, timeout_sec=3, update_frequency=50)
        assert not robot.is_powered_on()
    finally:
        _teardown(sdk, robot, lease_keepalive, estop_keepalive)
    assert demo.fake.lease_owner is None          # returned at exit


def test_wrong_password_and_missing_token_are_refused(demo):
    sdk, robot = _robot(demo)
    try:
        with pytest.raises(InvalidLoginError):
            robot.authenticate(TEST_USER, "not-the-password", timeout=3)
        # Without a token every service but auth / robot-id is refused.
        with pytest.raises(RpcError):
            robot.ensure_client(RobotStateClient.default_service_name)
    finally:
        _teardown(sdk, robot)
    assert not demo.fake.issued_tokens


@pytest.mark.parametrize("which", ["bd_root_ca", "other_ca", "wrong_names"])
def test_the_client_refuses_a_server_it_cannot_verify(tmp_path, which):
    """TLS verification is on: the default BD CA, an unrelated CA, or a certificate for other names
    (not *.spot.robot) all fail the handshake."""
    from robots.spot.fake_spot.launch import start_demo_fake

    if which == "wrong_names":
        pki = make_test_pki(tmp_path, dns_names=("robot.example.com",))
    else:
        pki = session_pki()
    demo = start_demo_fake(pki, TEST_USER, TEST_PASSWORD)
    try:
        ca = {"bd_root_ca": None, "other_ca": make_test_pki(tmp_path / "other").ca_cert,
              "wrong_names": pki.ca_cert}[which]
        sdk = bosdyn.client.create_standard_sdk("t", cert_resource_glob=str(ca) if ca else None)
        robot = sdk.create_robot("127.0.0.1")
        robot.update_secure_channel_port(demo.port)
        t0 = time.monotonic()
        with pytest.raises(RpcError):
            robot.authenticate(TEST_USER, TEST_PASSWORD, timeout=3)
        assert time.monotonic() - t0 < 3.0
        sdk.clear_robots()
        robot.shutdown()
    finally:
        demo.stop()
    assert not demo.fake.issued_tokens


def test_the_fake_refuses_what_a_robot_refuses(demo):
    with _powered(demo) as robot:
        command = robot.ensure_client(RobotCommandClient.default_service_name)
        goal = RobotCommandBuilder.synchro_se2_trajectory_point_command(0.4, 0.1, 0.3, frame_helpers.ODOM_FRAME_NAME)
        with pytest.raises(InvalidRequestError):      # trajectory without an end time
            command.robot_command(goal)
        in_body = RobotCommandBuilder.synchro_se2_trajectory_point_command(0.4, 0.1, 0.3, "gripper_tip")
        with pytest.raises(UnknownFrameError):
            command.robot_command(in_body, end_time_secs=time.time() + 5)
        too_long = RobotCommandBuilder.arm_joint_move_helper([[0.0, -1.2, 1.9, 0.0, -0.7, 0.0]] * 251,
                                                             [0.01 * (i + 1) for i in range(251)])
        with pytest.raises(InvalidRequestError):
            command.robot_command(too_long)
        assert not any(c.kind in ("se2", "arm_joint") for c in demo.fake.commands.values())


def test_fault_switchboard_names():
    assert set(FAULTS) == {"estop", "lease_revoked", "connection_drop", "command_timeout", "grasp_failure",
                           "time_sync_loss", "slow", "power_off_stalls", "power_loss", "behavior_fault",
                           "lease_retains_lost", "battery_critical", "manip_feedback_stale", "object_dropped"}


def test_a_behavior_fault_is_in_the_robot_state_refuses_motion_and_clears_only_when_clearable(demo):
    """What the SDK backend reads, through the unmodified SDK: the fault in the robot state with its
    cause and status, BehaviorFaultError for motion (stop and safe power off still go through), and
    ClearBehaviorFault clears a clearable fault only."""
    from bosdyn.api import robot_state_pb2
    from bosdyn.client.robot_command import BehaviorFaultError, NotClearedError

    BF = robot_state_pb2.BehaviorFault
    fake = demo.fake
    with pytest.raises(ValueError, match="cause must be one of fall, hardware"):
        fake.inject("behavior_fault", cause="meteor")
    with _powered(demo) as robot:
        command = robot.ensure_client(RobotCommandClient.default_service_name)
        states = robot.ensure_client(RobotStateClient.default_service_name)
        fake.inject("behavior_fault", cause="hardware", clearable=False)
        (fault,) = states.get_robot_state().behavior_fault_state.faults
        assert (fault.cause, fault.status) == (BF.CAUSE_HARDWARE, BF.STATUS_UNCLEARABLE)
        assert fake.powered                                  # a fault is not a power cut
        with pytest.raises(BehaviorFaultError):
            command.robot_command(RobotCommandBuilder.arm_stow_command())
        command.robot_command(RobotCommandBuilder.stop_command())      # still accepted
        with pytest.raises(NotClearedError):
            command.clear_behavior_fault(fault.behavior_fault_id)
        fake.clear("behavior_fault")                         # the operator, on the tablet
        fake.inject("behavior_fault")                        # a fall, clearable
        (fault,) = states.get_robot_state().behavior_fault_state.faults
        assert (fault.cause, fault.status) == (BF.CAUSE_FALL, BF.STATUS_CLEARABLE)
        with pytest.raises(NotClearedError):
            command.clear_behavior_fault(fault.behavior_fault_id + 1)    # not this fault's id
        assert command.clear_behavior_fault(fault.behavior_fault_id)
        assert not states.get_robot_state().behavior_fault_state.faults
        command.robot_command(RobotCommandBuilder.arm_stow_command())   # accepted again


def test_a_critical_battery_is_a_critical_system_fault_that_cuts_power_and_refuses_power_on(demo):
    """What the SDK backend reads, through the unmodified SDK: the battery's charge in the robot
    state (BatteryState, PowerState.locomotion_charge_percentage); at a critical charge a
    SEVERITY_CRITICAL system fault with the 'battery' attribute (also in the aggregated map), the
    motors cut by the robot itself, a running command ended as ROBOT_FROZEN, and power-on refused
    with the SDK's FaultedError until the battery is swapped."""
    from bosdyn.api import robot_state_pb2
    from bosdyn.client.power import FaultedError

    SF = robot_state_pb2.SystemFault
    fake = demo.fake
    with pytest.raises(ValueError, match="charge must be a percentage"):
        fake.inject("battery_critical", charge=150)
    with _powered(demo) as robot:
        command = robot.ensure_client(RobotCommandClient.default_service_name)
        states = robot.ensure_client(RobotStateClient.default_service_name)
        state = states.get_robot_state()
        assert state.battery_states[0].charge_percentage.value == state.power_state.locomotion_charge_percentage.value
        assert state.battery_states[0].charge_percentage.value > 50 and not state.system_fault_state.faults
        fake.inject("command_timeout")                   # a command that stays in progress ...
        cmd_id = command.robot_command(RobotCommandBuilder.arm_ready_command())
        fake.clear("command_timeout")
        fake.inject("battery_critical", charge=4)        # ... when the battery gives out
        assert not fake.powered
        state = states.get_robot_state()
        (fault,) = state.system_fault_state.faults
        assert fault.severity == SF.SEVERITY_CRITICAL and "battery" in fault.attributes
        assert state.system_fault_state.aggregated["battery"] == SF.SEVERITY_CRITICAL
        assert state.battery_states[0].charge_percentage.value == 4
        assert state.power_state.motor_power_state == state.power_state.MOTOR_POWER_STATE_OFF
        fb = command.robot_command_feedback(cmd_id).feedback.synchronized_feedback.arm_command_feedback
        assert fb.status == basic_command_pb2.RobotCommandFeedbackStatus.STATUS_ROBOT_FROZEN
        with pytest.raises(FaultedError):
            robot.power_on(timeout_sec=2, update_frequency=50)
        assert not fake.powered
        fake.clear("battery_critical")                   # a fresh battery
        state = states.get_robot_state()
        assert not state.system_fault_state.faults and state.battery_states[0].charge_percentage.value > 50
        robot.power_on(timeout_sec=2, update_frequency=50)
        assert fake.powered


def test_unknown_fault_is_a_clear_error(demo):
    with pytest.raises(ValueError, match="unknown fault 'meteor'; known: estop, lease_revoked"):
        demo.fake.inject("meteor")


def test_delay_calls_answers_one_rpc_late_after_acting_on_it(demo):
    """``delay_calls``: the robot acts on the request at once, only its reply is late, and no other
    RPC is held back (a caller with a shorter deadline times out on that call alone)."""
    from bosdyn.client.exceptions import TimedOutError

    sdk, robot = _robot(demo)
    try:
        robot.authenticate(TEST_USER, TEST_PASSWORD)
        lease_client = robot.ensure_client(LeaseClient.default_service_name)
        demo.fake.delay_calls("AcquireLease", 1, delay=1.0)
        t0 = time.monotonic()
        with pytest.raises(TimedOutError):
            lease_client.acquire(timeout=0.3)
        assert time.monotonic() - t0 < 0.8
        assert demo.fake.lease_owner                       # granted although we never heard back
        t1 = time.monotonic()
        [body] = [r for r in lease_client.list_leases(timeout=0.3) if r.resource == "body"]
        assert time.monotonic() - t1 < 0.3                 # other RPCs are answered promptly
        assert body.lease_owner.client_name == demo.fake.lease_owner
        with pytest.raises(ValueError, match="delay"):
            demo.fake.delay_calls("AcquireLease", 1, delay=-1)
    finally:
        _teardown(sdk, robot)


def test_stop_is_bounded_when_a_command_hangs_in_the_simulator(caplog, monkeypatch):
    """(Review 2026-12-04) ``FakeSpot.stop()`` waited without bound: ``executor.shutdown(wait=True)``
    on an RPC blocked on ``sim_lock``, and ``with sim_lock: sim.close()`` forever once the robot
    thread outlived its 10 s join (a command hung in the simulator). Now every wait is bounded by
    ``STOP_TIMEOUT_S`` and what is left behind is named in a warning."""
    from robots.spot.fake_spot import server

    monkeypatch.setattr(server, "STOP_TIMEOUT_S", 1.0, raising=False)
    demo = start_fake(seed=0)
    fake = demo.fake
    started, release = threading.Event(), threading.Event()

    def hung_command():                       # runs on the robot thread, sim_lock held
        started.set()
        release.wait(30.0)

    sdk, robot = _robot(demo)
    stopper = None
    try:
        robot.authenticate(TEST_USER, TEST_PASSWORD, timeout=3)
        images = robot.ensure_client(ImageClient.default_service_name)
        fake._jobs.put(hung_command)
        assert started.wait(5.0), "the robot thread did not start the job"
        # an RPC thread blocked on sim_lock behind the hung command (its client gives up after 5 s)
        pending = images.get_image_async([build_image_request(cv.HAND_COLOR_SOURCE)], timeout=5.0)
        deadline = time.monotonic() + 5.0
        while "GetImage" not in fake.rpc_log and time.monotonic() < deadline:
            time.sleep(0.01)
        assert "GetImage" in fake.rpc_log
        caplog.set_level(logging.WARNING, logger="helios.fake_spot")
        t0 = time.monotonic()
        stopper = threading.Thread(target=demo.stop, name="test-fake-stop", daemon=True)
        stopper.start()
        stopper.join(5.0)
        took = time.monotonic() - t0
        assert not stopper.is_alive(), "FakeSpot.stop() still waiting 5 s after a command hung in the simulator"
        assert took < 2.5, f"stop() took {took:.2f} s with a 1 s budget"
        warnings = " ".join(r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING)
        assert "fake-spot-robot" in warnings and "left behind" in warnings, warnings
        assert "fake-spot-rpc" in warnings, warnings
        assert "simulator is still in use" in warnings, warnings
        with pytest.raises(RpcError):
            pending.result(timeout=6.0)           # cancelled by the server's stop
        # The RPC thread gives up on the simulator once stop() began (it is no daemon: blocked for
        # good it would hold up the process's exit), while the hung command still holds it.
        deadline = time.monotonic() + 2.0
        rpc_threads = lambda: [t for t in threading.enumerate()  # noqa: E731
                               if t.name.startswith("fake-spot-rpc") and t.is_alive()]
        while rpc_threads() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not rpc_threads(), f"RPC threads still blocked after stop(): {[t.name for t in rpc_threads()]}"
        assert not release.is_set()
    finally:
        release.set()
        if stopper is not None:
            stopper.join(15.0)
        if fake._robot_thread is not None:
            fake._robot_thread.join(5.0)
        _teardown(sdk, robot)
        fake.sim.close()                          # stop() could not: the hung command held it (idempotent)


def _wait_for(condition, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def test_an_estop_check_in_must_answer_the_previous_challenge(demo):
    """estop.proto: after the first check-in, each must carry the response to the previous
    challenge; the SDK's EstopEndpoint answers with the 64-bit complement of the challenge
    (``bosdyn.client.estop.response_from_challenge``). The fake issued challenges and never
    checked them, so our check-ins were never proven right. A wrong answer is now refused with
    STATUS_INCORRECT_CHALLENGE_RESPONSE (and a new challenge), releases no stop and does not count
    as a check-in for the endpoint's timeout; the SDK's own endpoint and keep-alive pass."""
    from bosdyn.api import estop_pb2
    from bosdyn.client.estop import IncorrectChallengeResponseError, response_from_challenge

    sdk, robot = _robot(demo)
    keepalive = None
    try:
        robot.authenticate(TEST_USER, TEST_PASSWORD, timeout=3)
        client = robot.ensure_client(EstopClient.default_service_name)
        endpoint = EstopEndpoint(client, "pytest-estop", 0.6)
        endpoint.force_simple_setup()                 # registers; the first check-in (CUT) seeds a challenge
        current = endpoint.get_challenge()
        assert current is not None and robot.is_estopped()

        def refused(challenge, response):
            with pytest.raises(IncorrectChallengeResponseError) as info:
                client.check_in(estop_pb2.ESTOP_LEVEL_NONE, endpoint, challenge, response, timeout=2)
            return info.value.response.challenge      # the robot's next challenge comes with the refusal

        current = refused(current, response_from_challenge(current) ^ 1)          # a wrong response
        current = refused(current ^ 1, response_from_challenge(current ^ 1))      # another challenge's answer
        current = refused(current, 0)                                             # no answer
        assert robot.is_estopped()                    # a wrong answer releases nothing
        endpoint.set_challenge(current)
        endpoint.allow(timeout=2)                     # the SDK's answer is accepted
        assert not robot.is_estopped()
        released = time.monotonic()
        while time.monotonic() - released < 1.0:      # only wrong answers for longer than the timeout ...
            current = refused(current, response_from_challenge(current) ^ (1 << 63))
            time.sleep(0.05)
        level, _ = demo.fake.stop_level()
        assert level == estop_pb2.ESTOP_LEVEL_SETTLE_THEN_CUT    # ... and the endpoint timed out
        endpoint.set_challenge(current)
        keepalive = EstopKeepAlive(endpoint, rpc_timeout_seconds=1.0, rpc_interval_seconds=0.1)
        time.sleep(1.5)                               # 2.5 timeouts: only accepted check-ins keep it released
        assert not robot.is_estopped()
        statuses = []
        while not keepalive.status_queue.empty():
            statuses.append(keepalive.status_queue.get_nowait()[0])
        assert EstopKeepAlive.KeepAliveStatus.ERROR not in statuses, statuses
    finally:
        if keepalive is not None:
            keepalive.shutdown()
        _teardown(sdk, robot)


def test_time_sync_is_estimated_from_the_round_trips_the_client_reports(demo):
    """time_sync.proto: the service answers STATUS_MORE_SAMPLES_NEEDED until it has an estimate,
    which it makes from the round trips the client reports (``previous_round_trip``). The fake
    answered STATUS_OK at once with its own clock skew, whatever the client reported. A client
    whose clock runs 100 s ahead of ours reports its own stamps: the skew it is given is the
    robot's clock minus its clock, not ours."""
    from bosdyn.api import time_sync_pb2
    from bosdyn.client.exceptions import InvalidRequestError
    from bosdyn.client.time_sync import TimeSyncClient

    from robots.spot.fake_spot.time_sync import SAMPLES_FOR_ESTIMATE

    S = time_sync_pb2.TimeSyncState
    ahead = 100.0
    sdk, robot = _robot(demo)
    try:
        robot.authenticate(TEST_USER, TEST_PASSWORD, timeout=3)
        client = robot.ensure_client(TimeSyncClient.default_service_name)
        sent = time.time()
        answer = client.get_time_sync_update(None, None, timeout=2)
        got = time.time()
        clock_id = answer.clock_identifier
        assert clock_id and answer.state.status == S.STATUS_MORE_SAMPLES_NEEDED
        statuses = []
        for _ in range(SAMPLES_FOR_ESTIMATE):
            trip = time_sync_pb2.TimeSyncRoundTrip(
                client_tx=cv.seconds_to_timestamp(sent + ahead), server_rx=answer.header.request_received_timestamp,
                server_tx=answer.header.response_timestamp, client_rx=cv.seconds_to_timestamp(got + ahead))
            sent = time.time()
            answer = client.get_time_sync_update(trip, clock_id, timeout=2)
            got = time.time()
            assert answer.clock_identifier == clock_id
            statuses.append(answer.state.status)
        assert statuses == [S.STATUS_MORE_SAMPLES_NEEDED] * (SAMPLES_FOR_ESTIMATE - 1) + [S.STATUS_OK]
        skew = cv.duration_to_seconds(answer.state.best_estimate.clock_skew)
        assert abs(skew - (demo.fake.clock_skew - ahead)) < 0.05, skew
        assert 0.0 <= cv.duration_to_seconds(answer.state.best_estimate.round_trip_time) < 0.5
        assert abs(cv.duration_to_seconds(answer.previous_estimate.clock_skew) - skew) < 0.05
        # an identifier the robot does not know starts over; a round trip without one is refused
        fresh = client.get_time_sync_update(None, "never-assigned", timeout=2)
        assert fresh.clock_identifier not in ("never-assigned", clock_id)
        assert fresh.state.status == S.STATUS_MORE_SAMPLES_NEEDED
        with pytest.raises(InvalidRequestError):
            client.get_time_sync_update(trip, None, timeout=2)
        # the SDK's own time-sync thread gets there, and finds the skew between our clock and the robot's
        robot.time_sync.wait_for_sync(timeout_sec=3)
        found = robot.time_sync.get_robot_clock_skew()
        assert abs(found.seconds + found.nanos * 1e-9 - demo.fake.clock_skew) < 0.05
    finally:
        _teardown(sdk, robot)


def test_a_silent_lease_owner_goes_stale_the_robot_powers_off_and_anyone_may_acquire_it():
    """lease.proto, lease_service.md: an owner that stops retaining its lease for the robot's
    comms-loss timeout loses it to staleness: the robot stops, sits and powers off, and the lease
    may be acquired by any client (AcquireLease, not only TakeLease); the owner's next retain
    makes it fresh again (the robot stays off). The fake's AcquireLease refused whenever an owner
    existed and nothing happened when the retains stopped (``lease_retains_lost`` drops them)."""
    from bosdyn.client.lease import ResourceAlreadyClaimedError

    for bad in (0, -1.0, float("nan"), 601.0):
        with pytest.raises(ValueError, match="comms_loss_timeout"):
            start_fake(seed=0, comms_loss_timeout=bad)
    timeout = 0.5
    demo = start_fake(seed=0, comms_loss_timeout=timeout)
    fake = demo.fake
    owner_sdk, owner = _robot(demo, name="owner")
    tablet_sdk, tablet = _robot(demo, name="tablet")
    keepalive = None
    try:
        owner.authenticate(TEST_USER, TEST_PASSWORD, timeout=3)
        owner.time_sync.wait_for_sync(timeout_sec=3)
        keepalive = LeaseKeepAlive(owner.ensure_client(LeaseClient.default_service_name), must_acquire=True,
                                   rpc_interval_seconds=0.1)
        owner.power_on(timeout_sec=3, update_frequency=50)
        tablet.authenticate(TEST_USER, TEST_PASSWORD, timeout=3)
        tablet_leases = tablet.ensure_client(LeaseClient.default_service_name)

        def body():
            return next(r for r in tablet_leases.list_leases(timeout=2) if r.resource == "body")

        time.sleep(3 * timeout)                       # retained: fresh, powered, not to be acquired
        assert fake.powered and not body().is_stale
        with pytest.raises(ResourceAlreadyClaimedError):
            tablet_leases.acquire(timeout=2)
        fake.inject("lease_retains_lost")
        t0 = time.monotonic()
        assert _wait_for(lambda: not fake.powered, 3.0), "the robot stayed powered without retains"
        silent = time.monotonic() - t0
        assert silent < timeout + 0.5, silent         # within the timeout of the last retain heard
        assert body().is_stale and not fake.standing
        fake.clear("lease_retains_lost")              # the owner is heard again: fresh, still off
        assert _wait_for(lambda: not body().is_stale, 2.0)
        assert not fake.powered
        with pytest.raises(ResourceAlreadyClaimedError):
            tablet_leases.acquire(timeout=2)
        fake.inject("lease_retains_lost")
        assert _wait_for(lambda: body().is_stale, 3.0)
        lease = tablet_leases.acquire(timeout=2)      # stale: AcquireLease is enough
        assert fake.lease_owner.startswith("tablet") and not body().is_stale
        assert lease.lease_proto.sequence[0] > 1
    finally:
        fake.clear()                                  # answers a retain held as lost (the SDK waits 30 s)
        if keepalive is not None:
            keepalive.shutdown()
        _teardown(tablet_sdk, tablet)
        _teardown(owner_sdk, owner)
        demo.stop()


def test_the_comms_loss_watchdog_does_not_count_the_fakes_own_pause():
    """In tests and ``tools spot --fake`` the fake shares a process, the GIL and two busy CPUs with
    its client: a pause of the fake itself (here its bookkeeping lock held for 1 s) stalls its
    watchdog and its RPC handlers alike, and must not read as the lease owner's silence (a robot's
    watchdog runs on its own computer). The owner's real silence is still acted on."""
    from robots.spot.fake_spot.comms_loss import CommsLossWatch

    lock, fired = threading.RLock(), []
    watch = CommsLossWatch(0.5, lock, lambda silent: fired.append((time.monotonic(), silent)))
    watch.start()
    try:
        watch.heard()
        with lock:                                   # the fake is paused for twice the timeout
            time.sleep(1.0)
        resumed = time.monotonic()
        time.sleep(0.2)
        assert not fired and not watch.stale
        assert _wait_for(lambda: bool(fired), 2.0)   # then the owner stays silent
        at, silent = fired[0]
        assert 0.4 <= at - resumed < 0.9 and 0.5 <= silent < 0.9, (at - resumed, silent)   # a tick of slack
        assert watch.stale
    finally:
        assert watch.stop(2.0) is None               # the thread ended
