"""How the Spot SDK backend sends a command and turns what goes wrong into the HAL's errors.

A mixin of :class:`robots.spot.sdk_backend.SdkSpotBackend` (the state it reads is set up by that
class's ``__init__``): the sticky fault and the guard every command passes; the translation of
bosdyn exceptions into typed HAL errors (:meth:`SdkCommands._translate`) and, after a command
ended abnormally, the robot asked why (:meth:`SdkCommands._diagnose`: lease, power, e-stop,
critical system faults such as a flat battery, behavior fault); time sync checked and probed
while a command runs; and the send-then-poll loop every motion goes through
(:meth:`SdkCommands._run_command`), which sends a stop first whatever error ends it. Kept apart
from the commands themselves so the safety plumbing reads in one place.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from typing import Callable

import numpy as np

from robots.hal import (
    BackendClosedError,
    BehaviorFaultError,
    CommandTimeoutError,
    ConnectionLostError,
    EstopError,
    HalError,
    LeaseLostError,
    PowerError,
    RobotFault,
    TimeSyncLostError,
)
from robots.spot import model
from robots.spot.sdk_config import CommandRejectedError, NotConnectedError
from robots.spot.sdk_futures import cancel_future, future_result
from robots.spot.stall_watch import StallWatch

_LOG = logging.getLogger("helios.spot")

_FATAL = (LeaseLostError, ConnectionLostError, TimeSyncLostError)   # no command can reach the robot

_TIME_SYNC_PROBE = 0.25     # s between our own time-sync updates while a command runs

# s a diagnosis waits for its RetainLease once the robot state, asked with it, says the motors went
# off (SdkCommands._diagnose): the robot answers both at once; 0.25 s is slack for a loaded client's
# gRPC and GIL, well under the rpc_timeout (1.5 s by default) that was waited out before
_RETAIN_GRACE = 0.25


def _answer(fut, wait: float):
    """(done, result, exception) of a bosdyn future after waiting at most ``wait`` s: done False
    when it has not completed by then (left running: the caller cancels it or not)."""
    try:
        return True, future_result(fut, wait), None
    except Exception as exc:  # noqa: BLE001 - sorted by the caller
        return getattr(fut, "original_future", fut).done(), None, exc


class SdkCommands:
    """Fault handling and command plumbing of :class:`robots.spot.sdk_backend.SdkSpotBackend`."""

    # ================================================================== fault handling
    @property
    def fault(self) -> RobotFault | None:
        """The sticky fault that ended this session, if any."""
        return self._fault

    def _guard(self, sensing: bool = False) -> None:
        """Refuse to work on a closed backend or after a sticky fault. Sensing (images, state)
        needs neither motor power nor the lease, so it goes on after an e-stop or a lost lease."""
        self._check_open()
        if self._fault is not None and not (sensing and isinstance(self._fault, (EstopError, PowerError,
                                                                                  LeaseLostError, BehaviorFaultError))):
            raise type(self._fault)(str(self._fault))

    def _closing_elsewhere(self) -> bool:
        """close() runs (or ran), in another thread than this one."""
        return self._closing and self._close_thread is not threading.current_thread()

    def _closed_to_this_thread(self) -> bool:
        """Nothing more may be sent from this thread: closed, or close() runs in another one."""
        return self._closed or self._closing_elsewhere()

    def _check_open(self) -> None:
        """BackendClosedError when :meth:`_closed_to_this_thread`."""
        if self._closed:
            raise BackendClosedError("this backend has been closed")
        if self._closing_elsewhere():
            raise BackendClosedError("this backend is shutting the robot down (close() was called); no more "
                                     "commands")
        if not hasattr(self, "_cmd_client") or not hasattr(self, "_image_client"):
            # a safety monitor's stop() during connect(), or a call on a backend whose connect()
            # failed: once an AttributeError (safety audit); nothing of ours moves the robot yet
            raise NotConnectedError("the robot is not brought up (connect() has not got as far as the command "
                                    "clients, or it failed): nothing of ours is moving it")

    def _set_fault(self, fault: RobotFault) -> RobotFault:
        if isinstance(fault, (*_FATAL, EstopError, PowerError, BehaviorFaultError)) and self._fault is None:
            self._fault = fault
            _LOG.warning("robot fault: %s: %s", type(fault).__name__, fault)
        return fault

    def _translate(self, exc: BaseException, during: str, timeout: float | None = None) -> HalError:
        """A bosdyn exception to the HAL's typed error (recording sticky faults). ``timeout``: the
        RPC's own deadline when it was not ``rpc_timeout`` (an image request's), for the message."""
        bd = self._bd
        what = f"while {during}"
        if isinstance(exc, (bd.exc.LeaseUseError, bd.lease.LeaseNotOwnedByWallet, bd.lease.NoSuchLease,
                            bd.lease.LeaseResponseError)):
            return self._set_fault(LeaseLostError(f"the body lease is no longer ours {what} "
                                                  f"(revoked or taken by another client){self._stale_lease_hint()}"))
        if isinstance(exc, (bd.rc.NotPoweredOnError, bd.power.EstoppedError, bd.power.KeepaliveMotorsOffError)):
            return self._power_fault(what)
        if isinstance(exc, bd.power.FaultedError):
            # "Cannot power on due to a fault; inspect FaultState for more info" (bosdyn.client.power)
            return self._set_fault(PowerError(f"the robot refuses motor power {what}: "
                                              f"{self._critical_fault_note() or 'it reports a fault (see the tablet)'}"))
        if isinstance(exc, bd.rc.BehaviorFaultError):
            return self._behavior_fault(what)
        if isinstance(exc, (bd.rc.NoTimeSyncError, bd.ts.TimeSyncError, bd.exc.TimeSyncRequired)):
            return self._set_fault(TimeSyncLostError(f"time sync with the robot was lost {what}; timed commands "
                                                     f"cannot be sent safely"))
        if isinstance(exc, bd.exc.TimedOutError):
            waited = self.config.rpc_timeout if timeout is None else timeout
            return CommandTimeoutError(f"the robot did not answer within {waited:g} s {what}")
        if isinstance(exc, (bd.power.CommandTimedOutError, bd.rc.CommandTimedOutError)):
            return CommandTimeoutError(f"the robot did not finish {during} in time")
        if isinstance(exc, (bd.exc.UnableToConnectToRobotError, bd.exc.ProxyConnectionError,
                            bd.exc.TransientFailureError, bd.exc.ServiceUnavailableError,
                            bd.exc.UnknownDnsNameError, bd.exc.ClientCancelledOperationError,
                            bd.exc.NonexistentAuthorityError, bd.exc.InvalidClientCertificateError,
                            bd.exc.UnauthenticatedError, bd.exc.PermissionDeniedError)):
            return self._set_fault(ConnectionLostError(f"lost the connection to the robot {what} "
                                                       f"({type(exc).__name__})"))
        if isinstance(exc, bd.exc.RpcError):
            return self._set_fault(ConnectionLostError(f"communication with the robot failed {what} "
                                                       f"({type(exc).__name__})"))
        msg = getattr(exc, "error_message", None) or str(exc).split("\n")[0]
        return CommandRejectedError(f"the robot rejected a command {what}: {type(exc).__name__}: {msg}")

    def _power_fault(self, what: str, state=None) -> RobotFault:
        """Motors are off: because of an e-stop (EstopError), a critical system fault such as a
        flat battery (:meth:`_critical_fault_note`; PowerError naming it), the robot's comms-loss
        behaviour (:meth:`_comms_loss_fault`), or otherwise (PowerError). ``state``: the robot
        state already in hand (asked for when None)."""
        bd = self._bd
        try:
            status = self._estop_client.get_status(timeout=self.config.rpc_timeout)
            if status.stop_level != bd.estop_pb2.ESTOP_LEVEL_NONE:
                level = bd.estop_pb2.EstopStopLevel.Name(status.stop_level)
                details = f" ({status.stop_level_details})" if status.stop_level_details else ""
                return self._set_fault(EstopError(f"the robot is e-stopped {what}: {level}{details}; motion is cut "
                                                  f"and commands are refused"))
        except bd.exc.Error:
            pass
        critical = self._critical_fault_note(state)
        if critical:
            return self._set_fault(PowerError(f"motor power is off {what}: the robot shut its motors down on {critical}"))
        return self._comms_loss_fault(what) or self._set_fault(PowerError(f"motor power is off {what}"))

    def _critical_fault_note(self, state=None) -> str | None:
        """The robot's active SEVERITY_CRITICAL system faults in one line, or None (also when the
        state cannot be read). Such a fault is why a Spot cuts its motors by itself and then
        refuses power-on (STATUS_FAULTED): robot_state.proto says a "battery" fault of that
        severity "likely means the robot is going to shutdown immediately". It was reported as a
        bare "motor power is off", which sent an operator looking for an e-stop or a link problem
        and had ``stand()`` power on again into the same refusal; the battery's charge is named
        with a battery fault (BatteryState.charge_percentage)."""
        bd = self._bd
        try:
            if state is None:
                state = self._state_client.get_robot_state(timeout=self.config.rpc_timeout)
        except bd.exc.Error:
            return None
        critical = [f for f in state.system_fault_state.faults if f.severity == f.SEVERITY_CRITICAL]
        if not critical:
            return None
        charges = [b.charge_percentage.value for b in state.battery_states if b.HasField("charge_percentage")]
        named = []
        for f in critical:
            attrs = f" [{', '.join(f.attributes)}]" if f.attributes else ""
            charge = f" (battery at {min(charges):.0f} %)" if "battery" in f.attributes and charges else ""
            text = " ".join(f.error_message.split())          # the robot's words, on one line
            message = f': "{text}"' if text else ""
            named.append(f"{f.name or 'an unnamed fault'}{attrs}{charge}{message}")
        note = f"a critical system fault, {'; '.join(named)}"
        if any("battery" in f.attributes for f in critical):
            note += "; charge or swap the battery before powering on again"
        else:
            note += "; it refuses motor power until the fault is gone (the tablet shows it)"
        return note

    def _comms_loss_fault(self, what: str) -> RobotFault | None:
        """Motors off, no e-stop: did the robot stop hearing our lease keep-alive? A Spot that gets
        no RetainLease from the lease's owner for its comms-loss timeout stops, sits and powers
        off, and marks the lease stale: any client may then acquire it
        (``robots/spot/fake_spot/comms_loss.py`` has the sources). Two witnesses: our keep-alive's
        record (no retain confirmed for longer than one was due: ``_retain_gap_note``) and the
        robot's lease list (``is_stale``: certain, but using a stale lease of ours, even in a
        command the robot then refuses for the power, makes it fresh again, so it is often gone
        by the time we ask). Either makes a PowerError saying why (``stand()`` may power on
        again); the lease held by another client is a LeaseLostError (close() then neither
        commands nor returns it; the owner told apart by the client name in our request headers,
        as at shutdown: ``_body_lease_holder``). None when neither says so."""
        bd = self._bd
        reasons = [note] if (note := self._retain_gap_note()) else []
        try:
            resources = self._lease_client.list_leases(timeout=self.config.rpc_timeout)
        except bd.exc.Error:
            resources = ()
        body, other = self._body_lease_holder(resources)
        if other is not None:
            return self._set_fault(LeaseLostError(f"the body lease is held by another client {what} and the "
                                                  f"robot is powered off{self._stale_lease_hint()}"))
        stale = body is not None and body.is_stale
        if stale:
            reasons.append("the robot marked our lease stale (another client may acquire it)")
        if not reasons:
            return None
        self._comms_loss_seen = True
        return self._set_fault(PowerError(
            f"motor power is off {what}: the robot's comms-loss behaviour{'' if stale else ', it seems'} (a Spot "
            f"that stops hearing the lease keep-alive stops, sits and powers off): {'; '.join(reasons)}"))

    def _stale_lease_hint(self) -> str:
        """Said with a lost lease when our retains went unconfirmed long enough: a Spot marks the
        lease of an owner it stops hearing stale, and any client may then acquire it."""
        note = self._retain_gap_note()
        if not note:
            return ""
        self._comms_loss_seen = True            # close() says what the comms-loss behaviour left
        return (f"; {note}: the robot's comms-loss behaviour marks the lease of a silent owner stale, which "
                f"any client may acquire")

    def _behavior_fault(self, what: str, state=None) -> RobotFault:
        """The robot refuses motion because of a behavior fault (it fell, a hardware fault): the
        fault named from its state (asked for when ``state`` is None) and kept, so the session ends
        and close() powers the robot off; clearing it is the operator's (the tablet)."""
        faults = []
        try:
            if state is None:
                state = self._state_client.get_robot_state(timeout=self.config.rpc_timeout)
            for f in state.behavior_fault_state.faults:
                cause = type(f).Cause.Name(f.cause).removeprefix("CAUSE_").lower().replace("_", " ")
                how = {f.STATUS_CLEARABLE: "clearable", f.STATUS_UNCLEARABLE: "not clearable: power cycle"}.get(
                    f.status, "status unknown")
                faults.append(f"{cause} ({how})")
        except self._bd.exc.Error:
            pass
        named = ", ".join(faults) or "cause not reported"
        return self._set_fault(BehaviorFaultError(f"the robot has a behavior fault {what}: {named}; it stopped and "
                                                  f"refuses motion until the fault is cleared (the tablet)"))

    def _diagnose(self, during: str) -> RobotFault | None:
        """After a command ended abnormally: the fault that explains it, if there is one. Ended by
        close() from another thread: BackendClosedError, without asking the robot anything.

        The robot is asked two things at once: a RetainLease (its word on our lease: the
        keep-alive may not have checked in since another client took it) and its state (motor
        power, behavior faults). The lease's answer comes first, as before: refused, the lease
        is lost whatever the state says. The state is no longer read only after the retain's
        answer: a retain that does not reach the robot (a wedged keep-alive, which the robot's
        comms-loss behaviour acts on by powering off) was waited out for ``rpc_timeout`` before
        the state was even asked (measured: the PowerError 1.71-1.75 s after the retains stopped
        at a comms-loss timeout of 0.8 s, of which 1.0 s was our own retain's deadline). When the
        state says the motors went off under us and the retain, sent with it, is still
        unanswered :data:`_RETAIN_GRACE` s (or the state's own round trip, if longer) after the
        state's answer, the retain is not reaching the robot, and the power fault is diagnosed
        at once. That loses no diagnosis: the lost lease it could have named is found by
        :meth:`_power_fault` too (ListLeases names another holder: LeaseLostError), as is the
        comms loss (our keep-alive's record, the stale lease). Otherwise the retain is awaited for
        its full deadline, as before."""
        if self._closed_to_this_thread():
            raise BackendClosedError(f"the backend was closed (close() from another thread; {during})")
        if self._fault is not None:
            return self._fault
        bd, cfg = self._bd, self.config
        what = f"while {during}"
        try:
            lease = self._lease_client.lease_wallet.get_lease()
        except (bd.lease.LeaseNotOwnedByWallet, bd.lease.NoSuchLease):
            return self._set_fault(LeaseLostError(f"the body lease was taken by another client {what}"))
        t0 = time.monotonic()
        try:
            retain = self._lease_client.retain_lease_async(lease, timeout=cfg.rpc_timeout)
            asked = self._state_client.get_robot_state_async(timeout=cfg.rpc_timeout)
        except bd.exc.Error as exc:             # not sent (e.g. the channel is gone)
            fault = self._translate(exc, during)
            return fault if isinstance(fault, RobotFault) else None
        _, state, state_exc = _answer(asked, cfg.rpc_timeout + 0.5)    # bounded by its deadline
        round_trip = time.monotonic() - t0
        power_lost = state is not None and self._power_wanted and \
            state.power_state.motor_power_state != state.power_state.MOTOR_POWER_STATE_ON
        wait = max(_RETAIN_GRACE, round_trip) if power_lost else max(0.0, t0 + cfg.rpc_timeout + 0.5 - time.monotonic())
        answered, _, retain_exc = _answer(retain, wait)
        unanswered = None
        if answered and retain_exc is None:
            self._note_retain(True)
        elif answered and isinstance(retain_exc, (bd.exc.LeaseUseError, bd.lease.Error)):
            if not self._overtaken(retain_exc):  # (a check-in overtaken by a command of ours: still ours)
                return self._set_fault(LeaseLostError(f"the body lease was revoked or taken by another client "
                                                      f"{what} ({type(retain_exc).__name__})"))
        elif answered and isinstance(retain_exc, bd.exc.Error) and not isinstance(retain_exc, bd.exc.TimedOutError):
            fault = self._translate(retain_exc, during)
            return fault if isinstance(fault, RobotFault) else None
        else:
            # unanswered (its deadline, or the grace once the state is in): a slow link, or retains
            # that do not reach the robot (a wedged keep-alive), after which the robot's comms-loss
            # behaviour powers it off: its state says which (the walk ended as "the robot did not
            # answer" while the robot had powered off)
            cancel_future(retain)
            self._note_retain(False)
            unanswered = CommandTimeoutError(f"the robot did not answer within {cfg.rpc_timeout:g} s {what}")
        if state is None:
            if isinstance(state_exc, bd.exc.Error):
                fault = self._translate(state_exc, during)
                return fault if isinstance(fault, RobotFault) else None
            return None                           # no answer within its deadline: nothing known
        if power_lost:
            return self._power_fault(what, state)
        if state.behavior_fault_state.faults:
            return self._behavior_fault(what, state)
        return unanswered

    def _stop_quietly(self, wait: float = 0.3) -> None:
        """Best-effort full-body stop after a failure: sent at once (a robot on a slow link acts on
        it when it arrives), its reply awaited at most ``wait`` s; errors are ignored. Not while
        close() runs in another thread: it stops the robot itself, and a stop from here would cut
        its stow or sit short."""
        if not hasattr(self, "_cmd_client") or self._closed_to_this_thread():
            return
        try:
            with self._sending_to_robot("stopping"):
                fut = self._cmd_client.robot_command_async(self._bd.Builder.stop_command(),
                                                           timeout=self.config.rpc_timeout)
            future_result(fut, wait)
        except Exception as exc:  # noqa: BLE001 - best effort on an already failing link
            _LOG.debug("stop after a failure not confirmed: %s", type(exc).__name__)

    def _probe_time_sync(self, during: str) -> None:
        """One time-sync update of our own (a motion must not wait for the SDK thread's next one):
        TimeSyncLostError when the service fails, CommandTimeoutError when it does not answer."""
        ts = getattr(self.robot, "_time_sync_thread", None)
        if ts is None:
            return
        bd = self._bd
        try:
            ok = ts.endpoint.get_new_estimate()   # bounded by rpc_timeout (_bound_time_sync_rpcs)
        except bd.exc.TimedOutError:
            raise CommandTimeoutError(f"the robot did not answer within {self.config.rpc_timeout} s while "
                                      f"{during}") from None
        except bd.exc.Error as exc:
            raise self._set_fault(TimeSyncLostError(f"time sync with the robot was lost while {during} "
                                                    f"({type(exc).__name__}); timed commands cannot be sent "
                                                    f"safely")) from None
        if not ok:
            raise self._set_fault(TimeSyncLostError(f"time sync with the robot was lost while {during}; timed "
                                                    f"commands cannot be sent safely"))

    def _check_time_sync(self) -> None:
        """Raise TimeSyncLostError (sticky) once time sync is lost. The SDK's time-sync thread ends
        on its first failed update; one more update of our own decides: the robot answers (the
        thread is restarted) or time sync is lost."""
        robot = self.robot
        ts = getattr(robot, "_time_sync_thread", None)
        if ts is None:
            robot.time_sync                     # starts it
            return
        if not ts.stopped:
            return
        bd = self._bd
        try:
            ok = ts.endpoint.get_new_estimate()   # bounded by rpc_timeout (_bound_time_sync_rpcs)
        except bd.exc.Error as exc:
            ok, why = False, type(exc).__name__
        else:
            why = "the robot reports time sync is not established"
        if ok:
            robot.time_sync                     # restarts the thread
            return
        raise self._set_fault(TimeSyncLostError(f"time sync with the robot was lost ({why}); timed commands "
                                                f"cannot be sent safely"))

    # ================================================================== command plumbing
    @contextlib.contextmanager
    def _sending_to_robot(self, during: str, moves: bool = True):
        """Around sending a call to the robot: refused once close() has begun in another thread.
        A motion command (``moves``) from a thread other than close()'s is counted while in
        flight, so close() sends its own stop only after it (the check and the count are one step
        under close()'s lock: no command slips in between)."""
        with self._sends:
            if self._closed_to_this_thread():
                raise BackendClosedError(f"the backend was closed before {during}")
            counted = moves and self._close_thread is not threading.current_thread()
            self._sending += counted
        try:
            yield
        finally:
            if counted:
                with self._sends:
                    self._sending -= 1
                    self._sends.notify_all()

    def _call(self, fn, *args, during: str, moves: bool = False, **kwargs):
        """An SDK call with HAL error translation. Nothing is sent from another thread once close()
        has begun; ``moves``: a motion command (see :meth:`_sending_to_robot`). A request that
        another of ours overtook on its way (the robot refuses the older sub-lease) is sent once
        more, with a newer one (:meth:`_overtaken`)."""
        for attempt in (1, 2):
            try:
                with self._sending_to_robot(during, moves):
                    return fn(*args, **kwargs)
            except BackendClosedError:
                raise
            except Exception as exc:
                if self._closed_to_this_thread():   # our own teardown, not the robot's fault
                    raise BackendClosedError(f"the backend was closed while {during}") from None
                if not isinstance(exc, (self._bd.exc.Error, self._bd.lease.Error)):
                    raise
                if attempt == 1 and self._overtaken(exc):
                    _LOG.info("a request of ours was overtaken by a newer one while %s; sent again", during)
                    continue
                err = self._translate(exc, during, kwargs.get("timeout"))
                self._unresponsive = isinstance(err, CommandTimeoutError)
                raise err from None

    def _overtaken(self, exc: BaseException) -> bool:
        """A lease refusal that says nothing about who holds the lease: every request carries a
        newer sub-lease of ours, a robot refuses one older than the newest it has seen
        (STATUS_OLDER), and two of our threads' requests can arrive out of order (a safety stop
        overtaken by the agent's next command; a keep-alive check-in by a command). As the SDK's
        wallet does (``LeaseState.update_from_lease_use_result``; it is not told of check-in
        results), the robot's newest known lease decides: ours when our current sub-lease is as new
        or newer, another client's otherwise. Taken as a lost lease, such a refusal ended the
        session and close() left the robot powered under our lease (fidelity audit)."""
        bd = self._bd
        result = getattr(exc, "lease_use_result", None)
        if not isinstance(exc, bd.exc.LeaseUseError) or result is None or result.status != result.STATUS_OLDER:
            return False
        try:
            ours = self._lease_client.lease_wallet.get_lease()
        except bd.lease.Error:
            return False                        # the wallet saw another client's newer lease: lost
        latest = bd.lease.Lease(result.latest_known_lease)
        C = bd.lease.Lease.CompareResult
        return latest.is_valid_lease() and ours.compare(latest) in (C.NEWER, C.SAME)

    def _end_if_stalled(self, watch, elapsed: float, state, what: str) -> None:
        """Give a command's stall watch the robot's ``state``; once nothing has moved for the
        watch's window, the robot counts as unresponsive (the shutdown then goes out without
        waiting) and the command ends in CommandTimeoutError saying ``what`` did not move (the
        caller's error path sends the stop)."""
        watch.add(elapsed, state)
        if watch.stalled():
            self._unresponsive = True
            raise CommandTimeoutError(f"the robot stopped making progress {what}; it was told to stop")

    def _run_command(self, command, *, during: str, expected: float, done: Callable, end_time_secs=None,
                     track: "tuple | None" = None):
        """Send a RobotCommand and poll its feedback until ``done(feedback) -> (finished, ok)``
        reports it finished. Returns (ok, feedback response, seconds); ok is None when the command
        was interrupted (overridden, e.g. by stop()). Abnormal endings are diagnosed first (the
        typed fault is raised when there is one); a command that overruns its planned duration +
        margin, or (``track``: (actual(state) -> vector, planned(t) -> vector), or (actual, None,
        arrived(state) -> bool) for a move the robot plans itself) makes no progress for
        ``stall_time`` while it is not there yet, raises CommandTimeoutError. Whatever error ends the
        wait (a fault, a lost time sync, an unanswered RPC), a stop is sent first, and so is one after
        a command that ends without success (blocked, stalled), which a robot keeps active."""
        self._guard()
        cfg = self.config
        try:
            self._check_time_sync()
        except TimeSyncLostError:
            self._stop_quietly()
            raise
        self._restamp(command)
        t0 = time.monotonic()
        try:
            cmd_id = self._call(self._cmd_client.robot_command, command, end_time_secs=end_time_secs, moves=True,
                                timeout=cfg.rpc_timeout, during=during)
        except CommandTimeoutError:
            self._stop_quietly()                # the robot may have accepted it and be moving
            raise
        deadline = t0 + expected + cfg.command_margin
        stall = StallWatch(track, cfg.stall_time, expected) if track is not None else None
        next_sync = t0 + _TIME_SYNC_PROBE
        try:
            while True:
                fb = self._call(self._cmd_client.robot_command_feedback, cmd_id, timeout=cfg.rpc_timeout,
                                during=during)
                ended = self._ended(fb)
                if ended:
                    fault = self._diagnose(during)
                    if fault is not None:
                        raise type(fault)(str(fault))
                    return None, fb, time.monotonic() - t0
                finished, ok = done(fb)
                if finished:
                    self._unresponsive = False
                    if not ok:
                        # blocked or stalled is not over on a real Spot: an SE2 trajectory "may start
                        # to move again if a blocked path clears", a stalled arm trajectory is "not
                        # cancelled" (basic_command.proto, arm_command.proto); stop it here
                        self._stop_quietly()
                    return ok, fb, time.monotonic() - t0
                self._guard()                   # e.g. the lease keep-alive found the lease gone
                self._check_time_sync()
                now = time.monotonic()
                if now >= next_sync:            # while the robot moves, ask about time sync ourselves
                    self._probe_time_sync(during)
                    next_sync = time.monotonic() + _TIME_SYNC_PROBE
                if stall is not None and stall.due(now):
                    self._end_if_stalled(stall, now - t0, self._state(during),
                                         f"{during} ({stall.window:.1f} s without motion while "
                                         f"{'not there yet' if stall.planned is None else 'its plan moves'})")
                if now > deadline:
                    self._unresponsive = True
                    raise CommandTimeoutError(f"the robot did not finish {during} within "
                                              f"{expected + cfg.command_margin:.1f} s (planned {expected:.1f} s); "
                                              f"it was told to stop")
                time.sleep(cfg.feedback_period)
        except BaseException:
            # whatever ended the wait (a fault, an unanswered RPC, a bug of ours in this loop, e.g. a
            # KeyError from a robot state missing a frame, or Ctrl-C): the robot must not go on moving
            self._stop_quietly()
            raise

    def _restamp(self, command) -> None:
        """A trajectory's reference time set to now, just before it is sent: the command was built
        (and stamped) before the time-sync check, which can take an RPC timeout, and a trajectory
        that starts in the past has the robot hurry to where its plan is by now (fidelity audit)."""
        sync = command.synchronized_command
        now = self._local_now_ts(self._bd.cv)
        stamps = []
        if sync.HasField("mobility_command") and sync.mobility_command.HasField("se2_trajectory_request"):
            stamps.append(sync.mobility_command.se2_trajectory_request.trajectory)
        if sync.HasField("arm_command"):
            arm = sync.arm_command
            if arm.HasField("arm_joint_move_command"):
                stamps.append(arm.arm_joint_move_command.trajectory)
            if arm.HasField("arm_cartesian_command"):
                stamps.append(arm.arm_cartesian_command.pose_trajectory_in_task)
        for trajectory in stamps:
            if trajectory.HasField("reference_time"):
                trajectory.reference_time.CopyFrom(now)

    def _ended(self, fb) -> bool:
        """True when the command is no longer being processed (overridden, timed out, frozen)."""
        P = self._bd.basic.RobotCommandFeedbackStatus.STATUS_PROCESSING
        f = fb.feedback
        if f.HasField("full_body_feedback"):
            return f.full_body_feedback.status != P
        s = f.synchronized_feedback
        for part in ("mobility_command_feedback", "arm_command_feedback", "gripper_command_feedback"):
            if s.HasField(part) and getattr(s, part).status != P:
                return True
        return False

    def _state(self, during: str):
        return self._call(self._state_client.get_robot_state, timeout=self.config.rpc_timeout, during=during)

    def _tree(self, state):
        return state.kinematic_state.transforms_snapshot

    def _T(self, state, a: str, b: str) -> np.ndarray:
        return self._bd.cv.tform(self._tree(state), a, b)

    @staticmethod
    def _arm_stowed(state) -> bool:
        ms = state.manipulator_state
        return ms.stow_state == ms.STOWSTATE_STOWED

    def _arm_and_gripper_q(self, state) -> np.ndarray:
        """Arm joints and the gripper's: a stow that begins by closing the claw is making progress."""
        gripper = [j.position.value for j in state.kinematic_state.joint_states if j.name == model.GRIPPER_JOINT]
        return np.concatenate([self._arm_q(state), gripper])

    def _arm_q(self, state) -> np.ndarray:
        joints = {j.name: j.position.value for j in state.kinematic_state.joint_states}
        try:
            return np.array([joints[n] for n in model.ARM_JOINTS])
        except KeyError as exc:
            raise CommandRejectedError(f"the robot reports no arm joint {exc}; is the arm attached?") from None

    @staticmethod
    def _local_now_ts(cv):
        return cv.seconds_to_timestamp(time.time())
