"""The fake Spot's comms-loss behaviour towards the owner of the body lease: a watchdog that stops,
sits and powers off the robot and marks the lease stale once the owner has not retained its
lease for longer than the robot's comms-loss timeout.

What a Spot does (the sources; none publishes the lease's own timeout for an SDK client):

* ``bosdyn.client.lease.LeaseKeepAlive`` (bosdyn-client 5.2.0) sends ``RetainLease`` every
  ``rpc_interval_seconds`` (2 s by default), because "the robot's lease system expects
  lease-holders to check in at a regular cadence. If the check-ins do not happen, the robot will
  treat it as a communications loss. Typically this will result in the robot stopping, powering
  off, and the lease-holder getting their lease revoked."
* ``docs/concepts/lease_service.md`` (spot-sdk): "If an owner can no longer be reached within a
  certain period of time, the lease will become 'stale' and may be acquired by another client.
  If the owner returns to valid communications before another client acquires, the lease will
  become 'fresh' again."
* ``bosdyn/api/lease.proto``, ``LeaseResource``: "A stale lease can be acquired with an
  AcquireLeaseRequest OR a TakeLeaseRequest, while a lease that is not stale can only be acquired
  with a TakeLeaseRequest. [...] Commands & RetainLeaseRequests issued with a stale lease will
  still be accepted. Stale leases, when used, will cause the used lease to no longer be stale";
  ``is_stale``: "This lease has been marked stale, and may be acquired by another client."
  ``LeaseUseResult.STATUS_REVOKED``: "The Lease holder did not check in regularly enough, and the
  Lease is stale."
* ``docs/concepts/keepalive_service.md``: since 3.3 the Keepalive service carries this out;
  "Acquiring a Lease automatically adds a Policy with LeaseStale actions at the previously
  hardcoded timeout" (the value is not given).
* Boston Dynamics support, "Spot Stopping Functions" (archived 2025-06-15): "Signal loss: After 3
  seconds without controller communication, Spot will sit. After 8 seconds without communication,
  Spot will turn off its motors." ``docs/concepts/autonomy/auto_return.md``: on a lost link "the
  standard behavior is for Spot to sit down and power off".

What the fake does: the owner is heard from when a ``RetainLease`` with its current lease
arrives (:meth:`CommsLossWatch.heard`), and when a stale lease of its is used (it is fresh again).
Commands with a fresh lease do not count: the proto says only "some types of commands" retain
the lease and names none, so a client that relies on its keep-alive is held to it. After
``timeout`` s without hearing from the owner (default 3 s, Spot's sit after a signal loss) the
robot ends what it is doing, sits and powers off in one step (a Spot's motors go off 5 s after it
sits; the fake's safe power off is instantaneous too) and the lease turns stale: AcquireLease
then succeeds for anyone, the owner's own retain or command makes it fresh (the robot stays
powered off), ``ListLeases`` reports ``is_stale``. An owner the fake plays itself (the tablet of
``inject("lease_revoked")``) is not watched: that client is alive by assumption. A pause of the
fake itself (its watchdog ticks late: a loaded machine, the GIL shared with an in-process client)
is not counted as the owner's silence.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from typing import Callable

_LOG = logging.getLogger("helios.fake_spot")

DEFAULT_COMMS_LOSS_TIMEOUT = 3.0    # s: Spot sits 3 s after a signal loss (BD support, see above)


def check_timeout(timeout: float) -> float:
    """``timeout`` as a float, or ValueError (a positive number of seconds, at most 600)."""
    if not (isinstance(timeout, (int, float)) and math.isfinite(timeout) and 0.0 < timeout <= 600.0):
        raise ValueError(f"comms_loss_timeout must be a positive number of seconds (at most 600), got {timeout!r}")
    return float(timeout)


class CommsLossWatch:
    """When the body lease's owner was last heard from, whether its lease is stale, and the
    watchdog thread that calls ``on_loss(silent_seconds)`` (with ``lock`` held) once the owner has
    been silent for longer than ``timeout``. ``lock`` is the robot's bookkeeping lock: the
    watch's state changes with the lease's, under it."""

    def __init__(self, timeout: float, lock: threading.RLock, on_loss: Callable[[float], None]):
        self.timeout = check_timeout(timeout)
        self._lock = lock
        self._on_loss = on_loss
        self._heard: float | None = None      # monotonic; None: no owner to watch
        self.stale = False
        self._halt = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ the lease's owner
    def heard(self) -> None:
        """The owner retained its lease (or used it while stale): fresh, and the clock restarts."""
        with self._lock:
            self._heard, self.stale = time.monotonic(), False

    def unwatched(self) -> None:
        """No owner to watch (the lease was returned, or the fake plays its owner)."""
        with self._lock:
            self._heard, self.stale = None, False

    # ------------------------------------------------------------------ the watchdog
    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="fake-spot-comms-watch", daemon=True)
        self._thread.start()

    def stop(self, timeout: float) -> threading.Thread | None:
        """End the watchdog; returns its thread if it did not end within ``timeout`` s."""
        self._halt.set()
        if self._thread is None:
            return None
        self._thread.join(timeout)
        return self._thread if self._thread.is_alive() else None

    def _run(self) -> None:
        """Every ``period``: has the owner been silent too long? A tick that comes late means the
        fake itself was paused (in tests and ``tools spot --fake`` it shares a process, the GIL
        and two CPUs with its client): the pause is not counted as the owner's silence, for a
        robot's watchdog runs on the robot's own computer while the client stalls or not."""
        period = min(0.05, self.timeout / 10.0)
        last_tick = time.monotonic()
        while not self._halt.wait(period):
            with self._lock:
                now = time.monotonic()
                late, last_tick = now - last_tick - period, now
                if self._heard is None or self.stale:
                    continue
                if late > period:
                    self._heard += late
                silent = now - self._heard
                if silent <= self.timeout:
                    continue
                self.stale = True
                try:
                    self._on_loss(silent)
                except Exception:  # noqa: BLE001 - the watchdog outlives a failing reaction
                    _LOG.exception("fake Spot: the comms-loss behaviour failed")
