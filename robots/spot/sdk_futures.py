"""Waiting on a bosdyn future with a bound of our own: the Spot SDK backend's commands and its
shutdown both send RPCs asynchronously and must never wait longer than they chose to."""

from __future__ import annotations


def future_result(fut, timeout: float):
    """The result of a bosdyn FutureWrapper, waiting at most ``timeout`` s (its own
    ``result(timeout=)`` waits for the RPC's full deadline before looking at the timeout)."""
    inner = getattr(fut, "original_future", fut)
    inner.exception(timeout=timeout)          # grpc.FutureTimeoutError while not done
    return fut.result()


def cancel_future(fut) -> None:
    try:
        getattr(fut, "original_future", fut).cancel()
    except Exception:  # noqa: BLE001
        pass
