"""The fake Spot's time-sync service: the robot's clock skew estimated, as a robot does, from the
round trips each client reports, never from the fake's own knowledge of its skew.

What the protocol says (``bosdyn/api/time_sync.proto``, bosdyn-api 5.2.0; the client side is
``bosdyn.client.time_sync.TimeSyncEndpoint``):

* The first ``TimeSyncUpdate`` carries no clock identifier; the service assigns one, and the
  client echoes it with every later request. A request that carries a round trip without an
  identifier is an invalid request (the SDK's ``_get_update`` comment says the server answers it
  with an invalid-request error, so the SDK never sends one).
* Every later request carries ``previous_round_trip``: the client's send time (``client_tx``,
  the previous request header's timestamp), the robot's receive and send times (``server_rx``,
  ``server_tx``, the previous response header's ``request_received_timestamp`` and
  ``response_timestamp``) and the client's receive time (``client_rx``).
* ``state.status`` is STATUS_MORE_SAMPLES_NEEDED until the service has an estimate, then
  STATUS_OK with ``best_estimate`` (``clock_skew``: add it to the client's clock to get the
  robot's; ``round_trip_time``: the network delay, without the robot's processing time) and
  ``measurement_time`` (robot clock). ``previous_estimate`` is the estimate from the previous
  round trip alone. ``TimeSyncThread`` asks again at once while more samples are needed.

From one round trip (the NTP offset and delay; the only reading of those four stamps that gives
the proto's skew and "network delay"):
``round_trip = (client_rx - client_tx) - (server_tx - server_rx)`` and
``skew = ((server_rx - client_tx) + (server_tx - client_rx)) / 2``.

The fake's own choices, where BD publishes none: an estimate after ``SAMPLES_FOR_ESTIMATE``
round trips; the best estimate is the recent sample (of the last ``WINDOW``) with the shortest
round trip, the one least disturbed by network delay (the proto calls it "a recent average"; a
late reply then spoils one sample, not the estimate); a round trip with a missing or impossible
stamp (a negative delay) is not a sample; an identifier the service does not know (never
assigned, or forgotten when the service failed: the ``time_sync_loss`` fault) starts over with a
new identifier. Commands are accepted only with an identifier whose time sync is established
(:meth:`TimeSyncService.established`), as a robot refuses them with STATUS_NO_TIMESYNC.
"""

from __future__ import annotations

import secrets
import threading
from dataclasses import dataclass, field

from bosdyn.api import time_sync_pb2

from robots.spot import sdk_conversions as cv

SAMPLES_FOR_ESTIMATE = 3    # round trips before STATUS_OK
WINDOW = 10                 # recent samples the best estimate is chosen from


@dataclass
class _Clock:
    """One client's time sync: its recent samples, (round trip time, clock skew, robot time it was
    measured at), in seconds."""

    samples: list[tuple[float, float, float]] = field(default_factory=list)


def _sample(round_trip: time_sync_pb2.TimeSyncRoundTrip) -> tuple[float, float, float] | None:
    """(round trip time, clock skew, robot receive time) from one reported round trip, or None
    when a stamp is missing or the stamps are impossible (a negative network delay)."""
    stamps = (round_trip.client_tx, round_trip.server_rx, round_trip.server_tx, round_trip.client_rx)
    if not all(round_trip.HasField(name) for name in ("client_tx", "server_rx", "server_tx", "client_rx")):
        return None
    client_tx, server_rx, server_tx, client_rx = (cv.timestamp_to_seconds(t) for t in stamps)
    if 0.0 in (client_tx, server_rx, server_tx, client_rx):
        return None
    delay = (client_rx - client_tx) - (server_tx - server_rx)
    if delay < 0.0 or server_tx < server_rx:
        return None
    return delay, ((server_rx - client_tx) + (server_tx - client_rx)) / 2.0, server_rx


def _estimate(sample: tuple[float, float, float]) -> time_sync_pb2.TimeSyncEstimate:
    return time_sync_pb2.TimeSyncEstimate(round_trip_time=cv.seconds_to_duration(sample[0]),
                                          clock_skew=cv.seconds_to_duration(sample[1]))


class InvalidTimeSyncRequest(ValueError):
    """A TimeSyncUpdate request the service refuses (answered with CODE_INVALID_REQUEST)."""


class TimeSyncService:
    """The clocks of the clients that time-sync with the fake, by clock identifier (thread-safe)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._clocks: dict[str, _Clock] = {}

    def update(self, request: time_sync_pb2.TimeSyncUpdateRequest) -> time_sync_pb2.TimeSyncUpdateResponse:
        """The answer to one TimeSyncUpdate (its header is the caller's to fill: the client
        reports the header's receive and send times back in its next request)."""
        if request.HasField("previous_round_trip") and not request.clock_identifier:
            raise InvalidTimeSyncRequest("a round trip without a clock identifier (send the one the robot assigned)")
        resp = time_sync_pb2.TimeSyncUpdateResponse()
        with self._lock:
            clock_id = request.clock_identifier
            clock = self._clocks.get(clock_id) if clock_id else None
            if clock is None:                    # first contact, or an identifier the robot forgot
                clock_id = "fake-clock-" + secrets.token_hex(4)
                clock = self._clocks[clock_id] = _Clock()
            else:
                sample = _sample(request.previous_round_trip)
                if sample is not None:
                    clock.samples = (clock.samples + [sample])[-WINDOW:]
                    resp.previous_estimate.CopyFrom(_estimate(sample))
            resp.clock_identifier = clock_id
            state = resp.state
            if len(clock.samples) < SAMPLES_FOR_ESTIMATE:
                state.status = time_sync_pb2.TimeSyncState.STATUS_MORE_SAMPLES_NEEDED
            else:
                state.status = time_sync_pb2.TimeSyncState.STATUS_OK
                best = min(clock.samples)
                state.best_estimate.CopyFrom(_estimate(best))
                state.measurement_time.CopyFrom(cv.seconds_to_timestamp(best[2]))
        return resp

    def established(self, clock_id: str) -> bool:
        """Whether ``clock_id`` is a client clock whose time sync the service has established."""
        with self._lock:
            clock = self._clocks.get(clock_id) if clock_id else None
            return clock is not None and len(clock.samples) >= SAMPLES_FOR_ESTIMATE

    def forget(self) -> None:
        """The service failed: every identifier is unknown from now on (clients start over)."""
        with self._lock:
            self._clocks.clear()
