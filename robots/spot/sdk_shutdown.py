"""The Spot SDK backend's shutdown (``close()``): stop, stow, sit and power off, return the lease,
deregister our e-stop endpoint and stop every keep-alive thread, bounded in wall time whatever
state the robot or the link is in, from any thread, and safe to call twice.

How long it takes: on a healthy robot each step waits for the steps it depends on and for no
other (``_shutdown_in_turn``), so on a link that answers every RPC ``d`` s late (but within
``rpc_timeout``) ``close()`` takes about 4 ``d`` with the arm stowed and 7 ``d`` with it out (its
stow: a gripper check, the command, its feedback) plus the robot's own time to stow and sit
(measured with ``d`` = 0.8 s: 3.2 s and 5.6 s; they were 5.6 s and 8.0 s, every step one after the
other; ``tests/test_spot_sdk_faults.py::test_close_on_a_slow_link_waits_only_for_the_steps_the_next_one_needs``).
It is not made shorter by cutting the healthy shutdown over to the in-flight one: that one neither
stows nor waits for the sit, which a robot that answers, however slowly, is owed; the safety order
stays (stop before stow, stow before the sit and power off, the lease return and the e-stop
deregistration only once the robot says its motors are off). After a fault or once a step goes
unanswered the bound is ``close_budget`` + 0.5 s (see ``close``).

A mixin of :class:`robots.spot.sdk_backend.SdkSpotBackend` (the state it reads and the commands it
sends, such as ``stow_arm``, are the backend's); it lives apart because it is the safety-critical
part a reviewer reads on its own.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Callable

from robots.hal import HalError, LeaseLostError
from robots.spot.sdk_futures import cancel_future, future_result
from robots.spot.signals import signals_deferred

_LOG = logging.getLogger("helios.spot")


class _Unanswered(Exception):
    """A shutdown step found the robot not answering (go on without waiting)."""


class SdkShutdown:
    """``close()`` and the steps it takes (see :class:`robots.spot.sdk_backend.SdkSpotBackend`)."""

    def add_close_callback(self, fn: Callable[[], None]) -> None:
        """Call ``fn`` at the end of ``close()`` (e.g. to stop a fake robot this backend talks to)."""
        self._on_close.append(fn)

    def close(self) -> None:
        """Safe shutdown, whatever happened before: stop; stow (healthy robot, nothing held); sit
        and power off; return the lease; deregister our e-stop endpoint; stop every keep-alive,
        time-sync and token thread and close the connection. Never raises (a SIGINT, SIGTERM or
        SIGHUP that arrives meanwhile is held and delivered after it: :func:`signals_deferred`);
        safe to call twice.

        Healthy robot: each step in turn, waiting for the steps it depends on (about 4 round
        trips with the arm stowed, 7 with it out, plus the stow and the sit: the module
        docstring). After a fault, a timed-out command or
        once a step goes unanswered, the remaining steps go out back to back without waiting for
        one another (a robot on a slow link acts on each as it arrives) and their replies are
        awaited at most ``close_budget`` s in all; on a silent or dead link ``close()`` therefore
        returns within about ``close_budget`` + 0.5 s. After a lost lease no motion command is
        sent (it is not ours to command); the e-stop endpoint is deregistered whenever the robot
        answers.

        From another thread while a command runs: that command ends in BackendClosedError (see the
        class docstring). A second close() from another thread returns once the first is done."""
        with self._close_lock:
            first = not (self._closed or self._closing)
            if first:
                self._closing, self._close_thread = True, threading.current_thread()
        if not first:
            if self._close_thread is not threading.current_thread() and \
                    not self._close_done.wait(self._close_bound()):
                _LOG.warning("close() in another thread did not finish within %.0f s", self._close_bound())
            return
        try:
            self._let_other_threads_finish()
            self._close_once()
        finally:
            self._close_done.set()

    def _let_other_threads_finish(self) -> None:
        """Before the shutdown: a bring-up in another thread stops at its next step (bounded by
        that step's timeout), and motion commands other threads are sending reach the robot
        (bounded by ``rpc_timeout``), so close()'s stop comes after them."""
        cfg, me = self.config, threading.current_thread()
        connecting = self._connecting
        if connecting is not None and connecting is not me:
            bound = max(cfg.connect_timeout, cfg.power_on_timeout) + cfg.rpc_timeout + 0.5
            if not self._connect_done.wait(bound):
                _LOG.warning("the bring-up in another thread did not stop within %.0f s; shutting down anyway", bound)
        with self._sends:
            if not self._sends.wait_for(lambda: self._sending == 0, timeout=cfg.rpc_timeout + 0.5):
                _LOG.warning("a motion command from another thread was still being sent after %.1f s",
                             cfg.rpc_timeout + 0.5)

    def _close_bound(self) -> float:
        """The longest a close() can take (a healthy, slow shutdown of every step): how long a second
        close() waits for the first."""
        cfg = self.config
        return (7 * cfg.rpc_timeout + cfg.power_on_timeout + cfg.arm_move_timeout + cfg.command_margin
                + cfg.stand_timeout + cfg.close_budget + 2.0)

    def _close_once(self) -> None:
        t0 = time.monotonic()
        with signals_deferred():
            try:
                if self.robot is not None and hasattr(self, "_cmd_client"):
                    self._shutdown_robot(t0)
            except Exception as exc:  # noqa: BLE001 - shutdown never raises
                _LOG.warning("shutdown step failed: %s: %s", type(exc).__name__, str(exc).split("\n")[0])
            finally:
                self._closed = True
                self._stop_threads(max(t0 + self.config.close_budget + 0.6, time.monotonic() + 0.5))
                callbacks, self._on_close = self._on_close, []
                for fn in callbacks:
                    try:
                        fn()
                    except Exception:  # noqa: BLE001
                        _LOG.exception("close callback failed")

    def _lease_gone(self) -> str | None:
        """Why the body lease is not ours any more (the robot said so), or None."""
        if isinstance(self._fault, LeaseLostError):
            return str(self._fault)
        return self._lease_lost

    def _our_lease(self):
        if self._lease_keepalive is None or self._lease_gone() is not None:
            return None
        try:
            return self._lease_client.lease_wallet.get_lease()
        except Exception:  # noqa: BLE001 - not ours (any more)
            return None

    def _shutdown_robot(self, t0: float) -> None:
        cfg, bd = self.config, self._bd
        lease = self._our_lease()
        healthy = self._fault is None and not self._unresponsive
        self._close_steps = set()
        if healthy and lease is not None:
            try:
                self._shutdown_in_turn(lease)
                return
            except (bd.exc.TimedOutError, bd.exc.RpcError, bd.power.CommandTimedOutError, _Unanswered) as exc:
                # a fault during the shutdown (an e-stop, a lost lease) is named as such, not as silence
                why = (f"{type(self._fault).__name__} during shutdown: {self._fault}" if self._fault is not None
                       else f"the robot stopped answering during shutdown ({type(exc).__name__})")
                _LOG.warning("%s; sending the remaining steps without waiting", why)
            except (bd.exc.LeaseUseError, bd.lease.Error) as exc:
                if self._overtaken(exc):
                    # one of our own requests overtook this step's: the lease is still ours, and the
                    # steps go out again, back to back, with newer sub-leases
                    _LOG.warning("a shutdown step was overtaken by another request of ours; sending the "
                                 "remaining steps without waiting")
                else:
                    # another client (the tablet) took the lease while we shut down: nothing more of
                    # ours may move the robot; say so (the shutdown is not done), never log it and go on
                    why = f"the body lease was taken by another client during the shutdown ({type(exc).__name__})"
                    self._lease_lost = self._lease_lost or why
                    self._fault = self._fault or LeaseLostError(why)
            except Exception as exc:  # noqa: BLE001
                _LOG.warning("shutdown step failed: %s: %s", type(exc).__name__, str(exc).split("\n")[0])
            # a ReturnLease that failed took the lease out of the wallet first (the SDK's
            # return_lease): it is still ours to return unless the robot said otherwise (safety audit)
            lease = None if self._lease_gone() else (self._our_lease() or lease)
        deadline = max(t0 + cfg.close_budget, time.monotonic() + 0.5)
        asks = self._ask_what_is_left(deadline) if self._lease_gone() is not None else []
        self._shutdown_in_flight(lease, deadline)
        self._say_if_lease_lost(self._what_is_left(asks, deadline))     # also a refusal during it

    def _ask_what_is_left(self, deadline: float) -> list:
        """The lease is not ours: nothing of ours may move the robot, so close() cannot know it
        sat and powered off unless the robot says so. Its state (motor power) and the lease's
        holder (ListLeases) are asked at once, with the rest of the shutdown in flight, for
        ``close_problem`` (neither needs the lease). (QA 2026-12-05: after the robot's comms-loss
        behaviour had powered it off and another client acquired the stale lease, close_problem
        said "possibly standing with motor power on".)"""
        asks = []
        left = max(0.05, deadline - time.monotonic())
        for what, ask in (("power", lambda: self._state_client.get_robot_state_async(timeout=left)),
                          ("holder", lambda: self._lease_client.list_leases_async(timeout=left))):
            try:
                asks.append((what, ask()))
            except Exception as exc:  # noqa: BLE001 - e.g. the channel is gone: not known, said so
                _LOG.debug("shutdown: could not ask the robot about %s: %s", what, type(exc).__name__)
        return asks

    def _what_is_left(self, asks: list, deadline: float) -> dict:
        """The answers to :meth:`_ask_what_is_left` that came by ``deadline``: ``motors_off``
        (bool) and ``holder`` (the body lease's owner's client name when it is not us)."""
        known: dict = {}
        for what, fut in asks:
            try:
                answer = future_result(fut, max(0.0, deadline - time.monotonic()))
            except Exception as exc:  # noqa: BLE001 - unanswered: not known
                cancel_future(fut)
                _LOG.debug("shutdown: the robot did not say %s: %s", what, type(exc).__name__)
                continue
            if what == "power":
                PS = answer.power_state
                known["motors_off"] = PS.motor_power_state == PS.MOTOR_POWER_STATE_OFF
            elif (holder := self._body_lease_holder(answer)[1]) is not None:
                known["holder"] = holder
        return known

    def _say_if_lease_lost(self, known: dict | None = None) -> None:
        """The lease was taken or revoked (before or during the shutdown, also after another fault):
        the robot was not shut down by us, and ``close_problem`` says so, with what the robot said
        of itself (``known``: :meth:`_what_is_left`); "possibly standing with motor power on" only
        when it did not say."""
        gone = self._lease_gone()
        if gone is None or (self.close_problem or "").startswith("the robot was not shut down by us"):
            return
        known = known or {}
        holder = (f"the body lease is held by another client ({known['holder']}), which the robot is left to"
                  if "holder" in known else "it is left to the client holding the lease (the tablet?)")
        if known.get("motors_off") and self._comms_loss_seen:
            power = ("its comms-loss behaviour (our lease keep-alive went unheard) had already sat it down and "
                     "powered it off: the robot reports motor power off")
        elif known.get("motors_off"):
            power = "the robot reports motor power off"
        else:
            said = " (the robot reports it on)" if "motors_off" in known else ""
            power = f"possibly standing with motor power on{said}"
        note = f"the robot was not shut down by us: {gone}; {power}; {holder}"
        _LOG.warning(note)
        if self._fault is None:                             # the session's fault, as the README says
            self._fault = LeaseLostError(gone)
        # close_problem is set here first; an endpoint note said before the loss was known joins it
        self.close_problem = f"{note}; {self._estop_note}" if self._estop_note else note

    def _shutdown_in_turn(self, lease) -> None:
        """Healthy robot: stop, stow, sit and power off, return the lease, deregister the e-stop.

        Each step waits for the one it depends on, and no longer (on a slow link every round trip
        counts: the module docstring has the measured times):

        * the stop, and the robot state that decides the stow, go out together (the state no
          longer waits for the stop's reply); the stow is skipped only when both this state and the
          one before the stop say the arm is stowed (a state answered before the robot acted on
          the stop cannot skip a stow that the arm, moving, needed);
        * the stow is sent after the stop's reply (it must come after the stop), the sit and power
          off after the stow has finished;
        * the safe power off and its first robot-state polls go out together
          (:meth:`_safe_power_off`), not one round trip after the other;
        * the lease return and the e-stop deregistration go out together once the robot says its
          motors are off: neither needs the other, and both need the power off (a robot standing
          with motor power on must not be left without a lease holder, nor without our endpoint;
          one refuses to deregister an endpoint while its motors are on anyway)."""
        cfg, bd = self.config, self._bd
        state = before = self._after_power_on(self._state_client.get_robot_state(timeout=cfg.rpc_timeout))
        PS = state.power_state
        motors = PS.motor_power_state
        if motors == PS.MOTOR_POWER_STATE_OFF:
            self._close_steps |= {"stop", "safe power off"}
        else:
            stop = self._cmd_client.robot_command_async(bd.Builder.stop_command(), timeout=cfg.rpc_timeout)
            ask = self._state_client.get_robot_state_async(timeout=cfg.rpc_timeout)
            try:
                future_result(stop, cfg.rpc_timeout + 0.5)
            except BaseException:
                cancel_future(ask)
                raise
            self._close_steps.add("stop")
            state = future_result(ask, cfg.rpc_timeout + 0.5)
        MS = state.manipulator_state
        stowed = MS.stow_state == MS.STOWSTATE_STOWED and \
            before.manipulator_state.stow_state == before.manipulator_state.STOWSTATE_STOWED
        if motors == PS.MOTOR_POWER_STATE_ON and not MS.is_gripper_holding_item and not stowed:
            try:
                self._guard()
                self._stow_or_carry(holding=False)        # the state just read says the claw is empty
            except HalError as exc:
                _LOG.warning("could not stow the arm at shutdown: %s", exc)
                if self._fault is not None or self._unresponsive:
                    raise _Unanswered("stow failed") from None
        # anything but off is powered: a power-on still in progress after its wait, an error state
        if motors != PS.MOTOR_POWER_STATE_OFF and cfg.power_off_on_close:
            _LOG.info("sitting down and powering off")
            try:
                self._safe_power_off()
            except bd.power.CommandTimedOutError:
                self._warn_if_still_powered()
        self._close_steps.add("safe power off")        # done, or taken by a robot that could not sit
        self._lease_returning = True
        returning = self._return_lease_async(lease, timeout=cfg.rpc_timeout)
        ep = self._estop_endpoint
        deregistering = None
        if ep is not None:
            try:
                deregistering = self._estop_client.deregister_async(ep._config_id, ep, timeout=cfg.rpc_timeout)
            except Exception:  # noqa: BLE001 - not sent: the lease return's answer decides, then in flight
                pass
        lease_exc = dereg_exc = None
        try:
            future_result(returning, cfg.rpc_timeout + 0.5)
        except Exception as exc:  # noqa: BLE001 - raised below, once the deregistration is settled
            lease_exc = exc
        if deregistering is not None:
            try:
                future_result(deregistering, cfg.rpc_timeout + 0.5)
                _LOG.info("e-stop endpoint deregistered")
                self._estop_endpoint = None
            except bd.estop.MotorsOnError:
                self._estop_kept_powered()
                self._estop_endpoint = None
            except Exception as exc:  # noqa: BLE001 - e.g. unanswered: sent again in flight
                dereg_exc = exc
        if lease_exc is not None:
            raise lease_exc
        self._close_steps.add("lease return")
        _LOG.info("lease returned")
        if dereg_exc is not None or (ep is not None and deregistering is None):
            raise dereg_exc or _Unanswered("e-stop deregistration not sent")

    def _safe_power_off(self) -> None:
        """The SDK's safe power off (``Robot.power_off(cut_immediately=False)``: a SafePowerOff
        robot command, then the robot state polled until the motors are off, within
        ``stand_timeout``; raises as it does), with its polls going out while the command is on
        its way instead of one round trip after its reply: a state is asked every
        ``feedback_period``, at most four unanswered at a time, so on a slow link the motors-off
        is seen about one round trip after it happened. Returns once the robot says its motors
        are off and the command was answered without error."""
        cfg, bd = self.config, self._bd
        end = time.monotonic() + cfg.stand_timeout
        period = cfg.feedback_period
        command = self._cmd_client.robot_command_async(bd.Builder.safe_power_off_command(), timeout=cfg.rpc_timeout)
        asks: list = []
        next_ask = time.monotonic()
        off = False
        try:
            while True:
                now = time.monotonic()
                if command.done():
                    future_result(command, 0.0)      # the robot refused it, or it went unanswered: raise
                    if off:
                        return
                if not off and now >= next_ask and len(asks) < 4:
                    asks.append(self._state_client.get_robot_state_async(timeout=cfg.rpc_timeout))
                    next_ask = now + period
                for ask in [a for a in asks if a.done()]:
                    asks.remove(ask)
                    state = future_result(ask, 0.0)  # unanswered within rpc_timeout: raise, as the SDK
                    PS = state.power_state
                    off = off or PS.motor_power_state == PS.MOTOR_POWER_STATE_OFF
                if now >= end:
                    raise bd.power.CommandTimedOutError
                time.sleep(0.01)
        finally:
            for ask in asks:
                cancel_future(ask)
            if not command.done():
                cancel_future(command)

    def _after_power_on(self, state):
        """The robot state once a power-on in progress has ended: a robot takes one power command
        at a time and does not interrupt it (power_service.proto), so a power off sent meanwhile is
        refused and, the lease returned, the robot finished powering on with nobody holding it
        (fidelity audit). Waits at most ``power_on_timeout``; after that the shutdown goes on and
        the power off is tried anyway."""
        cfg = self.config
        PS = state.power_state
        if state.power_state.motor_power_state != PS.MOTOR_POWER_STATE_POWERING_ON:
            return state
        t0 = time.monotonic()
        while state.power_state.motor_power_state == PS.MOTOR_POWER_STATE_POWERING_ON and \
                time.monotonic() - t0 < cfg.power_on_timeout:
            time.sleep(cfg.feedback_period)
            state = self._state_client.get_robot_state(timeout=cfg.rpc_timeout)
        still = state.power_state.motor_power_state == PS.MOTOR_POWER_STATE_POWERING_ON
        _LOG.warning("a power-on was in progress at shutdown (power commands cannot be interrupted): %s",
                     f"waited {time.monotonic() - t0:.1f} s for it to end" if not still else
                     f"still powering on after {cfg.power_on_timeout:g} s; powering off anyway")
        return state

    def _estop_kept_powered(self) -> None:
        """Our e-stop endpoint could not be deregistered: a robot keeps an endpoint while its motors
        are on (estop.proto), and with our check-ins stopped it settles the robot and cuts its power
        within ``estop_timeout``, also under another client that took the lease (fidelity audit: the
        fake deregistered it). Said once, and in ``close_problem`` where the robot is another's."""
        note = (f"our e-stop endpoint stays registered (the robot refuses to deregister one while its motors are "
                f"on): with its check-ins stopped the robot settles and cuts motor power within "
                f"{self.config.estop_timeout:g} s")
        _LOG.warning(note)
        self._estop_note = note
        if self.close_problem is not None:
            self.close_problem = f"{self.close_problem}; {note}"

    def _warn_if_still_powered(self) -> None:
        """The safe power off did not end within ``stand_timeout``. A robot that answers and still
        has motor power took the command and could not sit (something under it, a slope): it stays
        with the robot, which may yet sit, the shutdown goes on in turn (lease, e-stop endpoint),
        and the operator is told to take over. A robot that does not answer ends the shutdown in
        flight, as any silent step does."""
        cfg = self.config
        try:
            state = self._state_client.get_robot_state(timeout=cfg.rpc_timeout)
        except Exception:  # noqa: BLE001 - no answer: the in-flight shutdown takes over
            raise _Unanswered("safe power off") from None
        if state.power_state.motor_power_state == state.power_state.MOTOR_POWER_STATE_OFF:
            return          # it powered off just after the last check
        _LOG.warning("the robot did not power off within %.1f s of the safe power off (it could not sit "
                     "down): it may still be standing with motor power on; returning the lease (our e-stop "
                     "endpoint, if any, cuts power once its check-ins stop), take over with the tablet or the "
                     "e-stop", cfg.stand_timeout)

    def _shutdown_in_flight(self, lease, deadline: float) -> None:
        """Degraded robot or link: stop and safe power off (with our lease), return the lease and
        deregister the e-stop endpoint, without waiting for one another, until ``deadline``. A step
        the link failed (an RPC error, a server error) is sent again after a short pause while
        there is time: one or two lost RPCs once left the robot standing with motor power on and
        nobody holding it, or our lease on the robot (safety audit). The lease goes back only once
        the robot took the safe power off (or stop, with ``power_off_on_close`` off), says its motors
        are off, or the power off has been on its way 0.3 s without failing (a slow link: the robot
        acts on it when it arrives, and on the return after it); a power off the link lost fails
        fast and goes again first. Kept, a real Spot treats our silence as a communications loss
        and powers off; returned before the power off, a robot standing with motor power on would
        be nobody's. Steps the healthy shutdown already finished (``_close_steps``) are not sent
        again. After a bring-up call that went unanswered, the robot is asked what it left and
        that is returned / deregistered too (:meth:`_clean_up_unanswered_bring_up`)."""
        cfg, bd = self.config, self._bd
        plan = []                                          # (step, function, arguments), in order
        if lease is not None:
            plan.append(("stop", self._cmd_client.robot_command_async, (bd.Builder.stop_command(),)))
            if cfg.power_off_on_close:
                plan.append(("safe power off", self._cmd_client.robot_command_async,
                             (bd.Builder.safe_power_off_command(),)))
            plan.append(("lease return", self._return_lease_async, (lease,)))
        if self._estop_endpoint is not None:
            ep = self._estop_endpoint
            plan.append(("e-stop deregistration", self._estop_client.deregister_async, (ep._config_id, ep)))
        done = {name for name, _, _ in plan if name in self._close_steps}
        given_up: set[str] = set()
        flying: dict[str, object] = {}
        ready_at: dict[str, float] = {}
        sent_at: dict[str, float] = {}
        motors_off = [False]

        def left() -> float:
            return max(0.05, deadline - time.monotonic())

        def send(name, fn, *args):          # one call, its reply awaited with the others (no retry)
            try:
                extra.append((name, fn(*args, timeout=left())))
            except Exception as exc:  # noqa: BLE001 - e.g. a refused connection: fails at once
                _LOG.debug("shutdown: %s not sent: %s", name, type(exc).__name__)

        extra: list = []
        state_ask = None
        if lease is not None and not {"stop", "safe power off"} <= done:
            try:                                # motors already off (an e-stop, a power fault): no sit needed
                state_ask = self._state_client.get_robot_state_async(timeout=left())
            except Exception:  # noqa: BLE001
                state_ask = None
        power_step = "safe power off" if cfg.power_off_on_close else "stop"

        def powered_off_or_on_its_way() -> bool:
            """The power off taken, the motors off, or the power off on its way for a while (a slow
            link acts on it when it arrives; one the link lost fails fast and goes again)."""
            return power_step in done or motors_off[0] or (
                power_step in flying and time.monotonic() - sent_at[power_step] >= 0.3)

        def may_send(name: str) -> bool:
            if name == "lease return":
                return powered_off_or_on_its_way()
            if name in ("stop", "safe power off"):
                return not motors_off[0]
            if name == "e-stop deregistration" and lease is not None:    # refused while the motors are on
                return power_step in given_up or powered_off_or_on_its_way()
            return True

        self._clean_up_unanswered_bring_up(send, deadline)
        while time.monotonic() < deadline:
            now = time.monotonic()
            for name, fn, args in plan:
                if name in done or name in given_up or name in flying or ready_at.get(name, 0.0) > now \
                        or not may_send(name):
                    continue
                if name == "lease return":
                    self._lease_returning = True
                try:
                    flying[name], sent_at[name] = fn(*args, timeout=left()), now
                except bd.lease.Error as exc:
                    # the wallet has no lease of ours: after our own return the step is moot; before
                    # it, a refusal told the wallet the lease is another's (fuzz seed 263: the tablet
                    # took it during the stow, and the power off was retried until the deadline)
                    if "lease return" not in sent_at and not self._lease_returning:
                        self._lease_lost = self._lease_lost or f"the body lease is not ours any more ({type(exc).__name__})"
                    given_up.add(name)
                except Exception as exc:  # noqa: BLE001 - failed before it left: try again shortly
                    _LOG.debug("shutdown: %s not sent: %s", name, type(exc).__name__)
                    ready_at[name] = now + 0.1
            if state_ask is not None and state_ask.done():
                try:
                    state = future_result(state_ask, 0.0)
                    PS = state.power_state
                    motors_off[0] = PS.motor_power_state == PS.MOTOR_POWER_STATE_OFF
                except Exception:  # noqa: BLE001 - unanswered: the steps decide
                    pass
                state_ask = None
            if motors_off[0]:
                done |= {"stop", "safe power off"} & {name for name, _, _ in plan}
            if "safe power off" in done and "stop" not in done:
                given_up.add("stop")             # the power off took over from it (retrying it was noise)
            for name, fut in list(flying.items()):
                if not fut.done():
                    continue
                del flying[name]
                try:
                    future_result(fut, 0.0)
                    done.add(name)
                except Exception as exc:  # noqa: BLE001 - sorted below
                    self._shutdown_step_failed(name, exc, given_up, ready_at, lease=lease,
                                               returning="lease return" in sent_at or "lease return" in done,
                                               powering_off=power_step in sent_at or motors_off[0],
                                               deadline=deadline)
            if self._lease_gone() is not None:      # refused by the robot: nothing of ours to command or return
                given_up |= {"stop", "safe power off", "lease return"} & {name for name, _, _ in plan}
            if all(name in done or name in given_up for name, _, _ in plan):
                break
            time.sleep(0.02)
        for name, fut in flying.items():
            cancel_future(fut)
        for name, _, _ in plan:
            if name in done:
                _LOG.info("shutdown: %s done", name)
            elif name not in given_up:
                _LOG.warning("shutdown: %s not confirmed by the robot", name)
        if lease is not None and "lease return" not in done and self._lease_gone() is None:
            if "lease return" in sent_at:
                _LOG.warning("shutdown: the lease return was sent but not confirmed (a slow or lost link)")
            else:
                _LOG.warning("shutdown: the body lease is kept (not returned) because the robot did not confirm it "
                             "stopped and powered off: with our keep-alive stopped, a Spot treats the silence as a "
                             "communications loss and powers off")
        if "e-stop deregistration" in done:
            self._estop_endpoint = None
        extra_done = self._await(extra, deadline)
        for name, fut in extra:
            if name not in extra_done:
                cancel_future(fut)
                _LOG.warning("shutdown: %s not confirmed by the robot", name)
        if "left e-stop endpoint deregistration" in extra_done:
            self._estop_unconfirmed = None
        if "left lease return" in extra_done:
            self._lease_unconfirmed = False

    def _older_than_ours(self, exc, lease) -> bool:
        """A STATUS_OLDER refusal whose newest known lease is a sub-lease of ``lease`` (ours): a newer
        request of ours arrived first. Compared with the lease we hold, not the wallet's, which our
        own lease return empties (a race under load read as a lost lease)."""
        result = getattr(exc, "lease_use_result", None)
        if lease is None or result is None or result.status != result.STATUS_OLDER:
            return False
        latest, ours = result.latest_known_lease, lease.lease_proto
        return (latest.resource == ours.resource and latest.epoch == ours.epoch and len(latest.sequence) > 0
                and len(ours.sequence) > 0 and latest.sequence[0] == ours.sequence[0])

    def _shutdown_step_failed(self, name: str, exc: BaseException, given_up: set, ready_at: dict, *,
                              lease=None, returning: bool = False, powering_off: bool = False,
                              deadline: float = 0.0) -> None:
        """A shutdown step's reply was an error: the link (an RPC or server error) is tried again
        after a pause; a refusal because a newer request of ours arrived first is tried again with
        a newer sub-lease (moot once the lease is on its way back); any other refusal of our lease
        means it is not ours any more; a deregistration refused with the motors on is tried again
        while the power off is on its way, else the endpoint stays (it cuts power when its
        check-ins stop); any other refusal is final."""
        bd = self._bd
        if isinstance(exc, bd.exc.LeaseUseError) and self._older_than_ours(exc, lease):
            # overtaken by a newer request of ours (the steps go out back to back): again, with a
            # newer sub-lease, unless the lease is already on its way back (then it is moot)
            if returning:
                given_up.add(name)
            else:
                ready_at[name] = time.monotonic() + 0.05
        elif isinstance(exc, bd.exc.LeaseUseError) or (name == "lease return" and isinstance(
                exc, getattr(bd.lease, "NotActiveLeaseError", ()))):
            self._lease_lost = self._lease_lost or f"the robot refused our lease at shutdown ({type(exc).__name__})"
            given_up.add(name)
        elif name == "e-stop deregistration" and isinstance(exc, bd.estop.MotorsOnError):
            if powering_off and time.monotonic() < deadline - 0.25:
                ready_at[name] = time.monotonic() + 0.15        # the power off is on its way: once it is done
            else:
                given_up.add(name)
                self._estop_kept_powered()
        elif isinstance(exc, (bd.exc.RpcError, bd.exc.ServerError)):
            ready_at[name] = time.monotonic() + 0.1
            _LOG.debug("shutdown: %s failed (%s); sending it again", name, type(exc).__name__)
        else:
            given_up.add(name)
            _LOG.warning("shutdown: %s refused by the robot: %s", name, str(exc).split("\n")[0])

    def _clean_up_unanswered_bring_up(self, send, deadline: float) -> None:
        """What a bring-up call answered too late (the robot acted on it, our call had timed out)
        left on the robot: ask the robot, then ``send`` the return / deregistration (the replies
        are awaited with the other shutdown steps). Every RPC is bounded by ``deadline``; a robot
        that does not answer the question leaves nothing to do but warn.

        * Lease (``_lease_unconfirmed``): ListLeases; the body lease is ours when its owner's
          ``client_name`` is the client name this SDK puts in every request header (the SDK's
          ``generate_client_name``: prefix, host, program and process id; the prefix carries this
          session's random token, so it is unique also among backends in one process: QA found
          one session's clean-up returning another's lease when they shared it). Assumes, as the
          LeaseService documents, that the robot names the client that acquired or took a lease
          in ``lease_owner.client_name``, and that ReturnLease accepts the active lease as
          ListLeases reports it (``include_full_lease_info``).
        * E-stop (``_estop_unconfirmed``): GetEstopConfig; an endpoint is ours when it has our
          endpoint's name, which carries this session's random token (another session's endpoint,
          even one of the same ``client_name`` started at the same moment, is left alone: with a
          shared name, a refused SetEstopConfig once deregistered a live session's endpoint) and
          its unique id is new since our SetEstopConfig. Assumes, as for the healthy shutdown, that
          DeregisterEstopEndpoint with the active configuration's id removes it.

        Both questions go out on the same connection as the late calls, after them, so they reach
        the robot after the late calls did (a robot that handles requests in parallel could in
        principle answer before acting on a late call that it received just before; not seen in
        practice, and not coverable without an answer to wait for). The body lease is returned
        without a stop or power off: an unanswered acquire comes before power-on."""
        if self._lease_keepalive is not None:
            self._lease_unconfirmed = False
        if not self._lease_unconfirmed and self._estop_unconfirmed is None:
            return

        def left(seconds: float = 0.05) -> float:
            return max(seconds, deadline - time.monotonic())

        asks = []
        for what, wanted, ask in (
                ("lease", self._lease_unconfirmed,
                 lambda: self._lease_client.list_leases_async(include_full_lease_info=True, timeout=left())),
                ("e-stop", self._estop_unconfirmed is not None,
                 lambda: self._estop_client.get_config_async(timeout=left()))):
            if not wanted:
                continue
            try:
                asks.append((what, ask()))
            except Exception as exc:  # noqa: BLE001 - e.g. the channel is already gone
                _LOG.warning("shutdown: could not ask the robot what an unanswered bring-up call left (%s): %s",
                             what, type(exc).__name__)
        for what, fut in asks:
            try:
                answer = future_result(fut, left(0.0))
            except Exception as exc:  # noqa: BLE001
                cancel_future(fut)
                _LOG.warning("shutdown: a bring-up call went unanswered and the robot did not say whether "
                             "it left %s of ours (%s)", "the body lease" if what == "lease" else
                             "an e-stop endpoint", type(exc).__name__)
                continue
            if what == "lease":
                lease = self._lease_left_with_us(answer)
                if lease is not None:
                    _LOG.warning("shutdown: the robot gave us the body lease although our request went "
                                 "unanswered; returning it")
                    send("left lease return", self._return_lease_async, lease)
                else:
                    self._lease_unconfirmed = False
            else:
                ours = self._endpoints_left_by_us(answer)
                for ep in ours:
                    _LOG.warning("shutdown: e-stop endpoint %r is on the robot although our request went "
                                 "unanswered; deregistering it", ep.name)
                    send("left e-stop endpoint deregistration", self._estop_client.deregister_async,
                         answer.unique_id, ep)
                if not ours:
                    self._estop_unconfirmed = None

    def _client_name_in_headers(self) -> str | None:
        """The client name the SDK puts in our request headers (``create_standard_sdk``'s
        ``AddRequestHeader``), which the robot records as a lease's owner."""
        for proc in getattr(self._sdk, "request_processors", ()):
            get = getattr(proc, "get_client_name", None)
            if callable(get):
                try:
                    name = get()
                except Exception:  # noqa: BLE001
                    continue
                if name:
                    return str(name)
        return None

    def _body_lease_holder(self, resources):
        """The body's entry in a ListLeases answer (None when nobody holds it) and its holder's
        client name when that holder is not us (None when it is us or cannot be told)."""
        body = next((r for r in resources if r.resource == "body" and r.lease_owner.client_name), None)
        ours = self._client_name_in_headers() if body is not None else None
        other = body.lease_owner.client_name if ours is not None and body.lease_owner.client_name != ours else None
        return body, other

    def _lease_left_with_us(self, resources):
        """The body lease from a ListLeases answer when this client holds it, else None."""
        bd = self._bd
        ours = self._client_name_in_headers()
        if ours is None:
            _LOG.warning("shutdown: cannot tell which client name the robot knows us by; an unanswered "
                         "lease request may have left the body lease with us")
            return None
        for res in resources:
            if res.resource == "body" and res.lease_owner.client_name == ours and \
                    bd.lease.Lease.is_valid_proto(res.lease):
                return bd.lease.Lease(res.lease)
        return None

    def _endpoints_left_by_us(self, active) -> list:
        """Endpoints in the robot's active e-stop configuration that our unanswered
        SetEstopConfig / RegisterEstopEndpoint put there (see :meth:`_clean_up_unanswered_bring_up`)."""
        name, ids_before = self._estop_unconfirmed
        return [ep for ep in active.endpoints if ep.name == name and ep.unique_id and ep.unique_id not in ids_before]

    def _return_lease_async(self, lease, **kwargs):
        """ReturnLease without waiting (bosdyn 5.2's ``return_lease_async`` blocks: it uses ``call``)."""
        client = self._lease_client
        if client.lease_wallet:
            client.lease_wallet.remove(lease)
        return client.call_async(client._stub.ReturnLease, client._make_return_request(lease), None,
                                 client._handle_return_errors, copy_request=False, **kwargs)

    @staticmethod
    def _await(pending, deadline: float) -> set:
        """Names of the pending calls that completed without error by ``deadline``."""
        done = set()
        for name, fut in pending:
            try:
                future_result(fut, max(0.0, deadline - time.monotonic()))
                done.add(name)
            except Exception as exc:  # noqa: BLE001
                _LOG.debug("shutdown: %s: %s", name, type(exc).__name__)
        return done

    def _stop_threads(self, deadline: float) -> None:
        """Stop the keep-alive, time-sync and token threads, close every channel (which cancels
        RPCs still in flight: a silent robot holds nothing up), forget the robot. Joins are
        bounded by ``deadline``; no thread survives the connection."""
        robot = self.robot
        threads = []
        for keepalive in (self._lease_keepalive, self._estop_keepalive):
            if keepalive is not None:
                keepalive._end_periodic_check_in()
                threads.append(keepalive._thread)
        if robot is None:
            self._join(threads, deadline)
            return
        ts = getattr(robot, "_time_sync_thread", None)
        if ts is not None:
            with ts._lock:                    # TimeSyncThread.stop() without its unbounded join
                ts._locked_should_exit = True
            ts._event.set()
            if ts._thread is not None:
                threads.append(ts._thread)
        manager = getattr(robot, "_token_manager", None)
        if manager is not None:
            manager.stop()
        token_thread = getattr(manager, "th", None) or self._token_manager_thread
        if token_thread is not None:
            threads.append(token_thread)
        try:
            robot.shutdown()                  # closes every channel, cancelling RPCs in flight
        except Exception:  # noqa: BLE001
            pass
        self._join(threads, deadline)
        robot._time_sync_thread = None        # already stopped: the SDK's _shutdown() must not join again
        robot._token_manager = None
        if self._sdk is not None:
            self._sdk.clear_robots()
        self._lease_keepalive = self._estop_keepalive = None
        self.robot = None

    @staticmethod
    def _join(threads, deadline: float) -> None:
        for th in threads:
            if th is not None and th is not threading.current_thread():
                th.join(timeout=max(0.05, deadline - time.monotonic()))
            if th is not None and th.is_alive():
                _LOG.warning("thread %s did not stop in time", th.name)
