"""Faults injected into the fake Spot end in the HAL's typed errors within 2 s, leave the robot
safe (no command accepted after an e-stop, motion stopped), never hang, and every keep-alive
thread is gone after close()."""

from __future__ import annotations

import threading
import time

import pytest

pytest.importorskip("bosdyn.client")

from robots.hal import (  # noqa: E402
    CommandTimeoutError,
    ConnectionLostError,
    EstopError,
    LeaseLostError,
    Reason,
    SE2Pose,
    TimeSyncLostError,
)
from robots.spot import model  # noqa: E402
from spot_fake_fixtures import connect, python_threads, start_fake, wait_for_threads_to_end  # noqa: E402

pytestmark = pytest.mark.timeout(60)

SURFACE_WITHIN = 2.0   # s from the faulty call to the typed error
CLOSE_WITHIN = 3.0     # s for close() after a fault (bounded by close_budget, never the SDK's 30 s)

# fault -> (params, expected error, sticky: later commands fail locally without reaching the robot)
FAULTS = {
    "estop": ({}, EstopError, True),
    "lease_revoked": ({}, LeaseLostError, True),
    "connection_drop": ({}, ConnectionLostError, True),
    "command_timeout": ({}, CommandTimeoutError, False),
    "time_sync_loss": ({}, TimeSyncLostError, True),
    "slow": ({"delay": 1.5}, CommandTimeoutError, False),   # slower than the 1 s RPC timeout
}


def _active(fake) -> list:
    return [(c.kind, c.state) for c in fake.commands.values() if c.state in ("queued", "running", "hung")]


def _robot_commands(fake) -> int:
    return sum(1 for name in fake.rpc_log if name == "RobotCommand")


@pytest.mark.parametrize("fault", sorted(FAULTS))
def test_fault_ends_in_a_typed_error_and_leaves_the_robot_safe(fault):
    params, expected, sticky = FAULTS[fault]
    before = python_threads()
    demo = start_fake(seed=0)
    backend = connect(demo)
    fake = demo.fake
    try:
        assert backend.move_arm_joints(model.ARM_READY).success
        with fake.sim_lock:
            pose_before = fake.sim.spot.base_pose()
        fake.inject(fault, **params)
        t0 = time.monotonic()
        with pytest.raises(expected) as info:
            backend.navigate_to(SE2Pose(0.05, 0.0, 0.0))
        elapsed = time.monotonic() - t0
        assert elapsed < SURFACE_WITHIN, f"{fault} took {elapsed:.2f} s to surface"
        message = str(info.value)
        assert message and "Traceback" not in message and "\n" not in message

        # The robot is safe: nothing moving, the base where it was (or stopped by the robot itself).
        with fake.sim_lock:
            assert fake.sim.spot.base_pose().distance_to(pose_before) < 0.06
        assert not _active(fake), _active(fake)
        if fault == "estop":
            assert not fake.powered
        if fault == "connection_drop":
            assert not fake.powered          # the robot's comms-loss behaviour
        if fault == "command_timeout":
            assert [c.state for c in fake.commands.values() if c.kind == "se2"] == ["overridden"]
        if fault in ("estop", "lease_revoked", "time_sync_loss", "slow"):
            assert not any(c.kind == "se2" for c in fake.commands.values())   # refused or dropped

        if sticky:
            # Later commands fail with the same error without reaching the robot.
            sent = _robot_commands(fake)
            t1 = time.monotonic()
            with pytest.raises(expected):
                backend.move_arm_joints(model.ARM_STOW)
            with pytest.raises(expected):
                backend.stow_arm()
            if fault in ("estop", "lease_revoked"):
                backend.observe()            # sensing needs neither motor power nor the lease
            else:
                with pytest.raises(expected):
                    backend.observe()
            assert time.monotonic() - t1 < 0.5
            assert _robot_commands(fake) == sent
            assert isinstance(backend.fault, expected)
    finally:
        t2 = time.monotonic()
        backend.close()
        closing = time.monotonic() - t2
    assert closing < CLOSE_WITHIN, f"close() after {fault} took {closing:.2f} s"
    leaked = wait_for_threads_to_end(before)
    assert not leaked, f"threads left after close(): {sorted(t.name for t in leaked)}"


def test_estop_during_a_command_cuts_it_and_nothing_is_accepted_afterwards():
    demo = start_fake(seed=0)
    backend = connect(demo)
    fake = demo.fake
    try:
        fake.inject("command_timeout")        # the walk never finishes on its own ...
        timer = threading.Timer(0.3, fake.inject, args=("estop",))   # ... an operator presses the e-stop
        timer.start()
        t0 = time.monotonic()
        with pytest.raises(EstopError, match="e-stopped"):
            backend.navigate_to(SE2Pose(0.3, 0.0, 0.0))
        assert time.monotonic() - t0 < 0.3 + SURFACE_WITHIN
        timer.join()
        assert not fake.powered and not _active(fake)
        fake.clear("command_timeout")
        sent = _robot_commands(fake)
        for call in (lambda: backend.gaze_at([2.0, 0.0, 0.5]), backend.stow_arm,
                     lambda: backend.navigate_to(SE2Pose(0.0, 0.0, 0.0))):
            with pytest.raises(EstopError):
                call()
        assert _robot_commands(fake) == sent
        assert backend.stop().success         # stopping an e-stopped robot is fine: it is stopped
        # Once the e-stop is released, stand() powers the robot up again.
        fake.clear("estop")
        assert backend.stand().success and fake.powered
        assert backend.navigate_to(SE2Pose(0.2, 0.0, 0.0)).success
    finally:
        backend.close()


def test_lease_revocation_is_noticed_by_the_keep_alive_without_a_command():
    demo = start_fake(seed=0)
    backend = connect(demo, lease_retain_period=0.1)
    fake = demo.fake
    try:
        fake.inject("lease_revoked")
        deadline = time.monotonic() + SURFACE_WITHIN
        while backend.fault is None and time.monotonic() < deadline:
            time.sleep(0.02)
        assert isinstance(backend.fault, LeaseLostError)
        sent = _robot_commands(fake)
        with pytest.raises(LeaseLostError, match="lease"):
            backend.navigate_to(SE2Pose(0.2, 0.0, 0.0))
        assert _robot_commands(fake) == sent
    finally:
        backend.close()


def test_grasp_failure_feedback_is_a_failed_grasp_result():
    demo = start_fake(seed=0)
    backend = connect(demo)
    fake = demo.fake
    try:
        mug = demo.facts["mug_position"]
        assert backend.navigate_to(SE2Pose(mug[0] - 0.95, mug[1], 0.0)).success
        assert backend.gaze_at(mug + [0, 0, 0.05]).success
        obs = backend.observe()
        fake.inject("grasp_failure")
        t0 = time.monotonic()
        res = backend.grasp(obs, (obs.intrinsics.width // 2, obs.intrinsics.height // 2))
        assert time.monotonic() - t0 < SURFACE_WITHIN
        assert not res.success and res.reason is Reason.GRASP_MISSED and not res.holding
        assert "MANIP_STATE_GRASP_FAILED" in res.message
        assert not _active(fake) and not backend.observe().holding
        fake.clear()
        assert backend.stow_arm().success       # the session goes on
    finally:
        backend.close()


def test_keep_alive_threads_stop_at_close():
    before = python_threads()
    demo = start_fake(seed=0)
    backend = connect(demo)       # e-stop endpoint mode: an EstopKeepAlive runs too
    backend.observe()
    assert backend.navigate_to(SE2Pose(0.2, 0.0, 0.0)).success
    running = python_threads() - before
    targets = " ".join(f"{t.name} {getattr(t, '_target', '')}" for t in running)
    for expected in ("token_manager", "_timesync_thread", "_periodic_check_in"):
        assert expected in targets, f"{expected} not running: {targets}"
    assert sum("_periodic_check_in" in f"{getattr(t, '_target', '')}" for t in running) == 2   # lease + e-stop
    backend.close()
    backend.close()                                    # twice is fine
    assert backend.robot is None
    leaked = wait_for_threads_to_end(before)
    assert not leaked, f"threads left after close(): {sorted(t.name for t in leaked)}"
    assert demo.fake.lease_owner is None and not demo.fake.powered   # lease returned, powered off


def test_stop_interrupts_a_running_command():
    demo = start_fake(seed=0)
    backend = connect(demo)
    try:
        demo.fake.inject("command_timeout")   # the walk would never finish by itself
        results = []
        walker = threading.Thread(target=lambda: results.append(backend.navigate_to(SE2Pose(1.0, 0.0, 0.0))))
        walker.start()
        time.sleep(0.3)
        assert backend.stop().success          # e.g. from a safety monitor thread
        walker.join(SURFACE_WITHIN)
        assert not walker.is_alive()
        (res,) = results
        assert not res.success and res.reason is Reason.STOPPED
        assert not _active(demo.fake)
    finally:
        backend.close()
