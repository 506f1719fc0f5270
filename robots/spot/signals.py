"""Signals on a robot run: what Ctrl-C, SIGTERM and SIGHUP may interrupt and when.

Two hazards, each met once on the fake Spot (QA 2026-12-04): a signal during the shutdown cut it
short and left the robot powered and standing with our lease (:func:`signals_deferred` holds them
until it is done), and a KeyboardInterrupt raised inside a blocking gRPC call corrupted the heap or
left the channel's lock held, so the shutdown that followed crashed or hung (:func:`outside_grpc`
raises it once the call has returned). Main thread only, where Python runs signal handlers."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from typing import Callable, Sequence

DEFERRED_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")


@contextlib.contextmanager
def handling_signals(names: Sequence[str], handler: Callable):
    """``handler`` for the named signals while the block runs, the old handlers back after it. Only
    on the main thread (where Python runs signal handlers; elsewhere nothing changes); a signal the
    platform lacks, one that cannot be set here, and one the process ignores (SIG_IGN: SIGHUP
    under ``nohup``, SIGINT in a background job) are left alone."""
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for name in names:
            sig = getattr(signal, name, None)
            if sig is None or signal.getsignal(sig) == signal.SIG_IGN:
                continue
            try:
                previous[sig] = signal.signal(sig, handler)
            except (ValueError, OSError):     # e.g. an embedded interpreter
                pass
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def _grpc_code_prefix() -> str | None:
    """Folder of gRPC's Python package, once it is imported (no gRPC code can be running before)."""
    grpc = sys.modules.get("grpc")
    origin = getattr(grpc, "__file__", None)
    return os.path.dirname(os.path.abspath(origin)) + os.sep if origin else None


def grpc_entry_frame(frame):
    """The outermost frame of gRPC's Python code on the stack that ends in ``frame`` (a signal
    handler's), i.e. where the caller entered gRPC; None when the thread is not inside gRPC (its
    C extension calls back into Python, e.g. ``threading``, with gRPC's frames still below)."""
    prefix, entry = _grpc_code_prefix(), None
    while prefix is not None and frame is not None:
        if frame.f_code.co_filename.startswith(prefix):
            entry = frame
        frame = frame.f_back
    return entry


def outside_grpc(handler: Callable) -> Callable:
    """``handler`` (a signal handler that raises, e.g. KeyboardInterrupt) run only outside gRPC.

    A blocking RPC on the main thread waits in gRPC's C extension, which runs Python's signal
    handlers while it waits. An exception raised there abandons the call half way: the extension
    frees the call and destroys its completion queue while the call is still in flight (heap
    corruption: "malloc(): unsorted double linked list corrupted", SIGABRT in the next RPCs, i.e.
    the shutdown), or, raised in a callback that holds the channel's lock, leaves that lock held
    (every later RPC on the channel hangs, or fails at once and the shutdown is skipped). Measured
    on ``tools spot --fake`` interrupted mid-task under CPU load: 7 of 45 runs crashed or hung.

    Here a signal that lands inside gRPC is held, and ``handler`` runs (its exception raised in the
    caller) the moment the call returns to the code that made it: a profile function on this
    thread (``sys.setprofile``) watches for the return of gRPC's entry frame. Every RPC has a
    deadline, so the wait is bounded by it. While another profiler is active on the thread the
    handler runs at once, as before."""
    held = {"entry": None, "signals": []}

    def deliver(frame, event, _arg):
        if event != "return" or frame is not held["entry"]:
            return
        sys.setprofile(None)
        signum, held["entry"], held["signals"] = held["signals"][0], None, []
        handler(signum, frame.f_back)           # its exception leaves the call, in the caller

    def guarded(signum, frame):
        entry = grpc_entry_frame(frame)
        if entry is None or (held["entry"] is None and sys.getprofile() is not None):
            return handler(signum, frame)
        held["signals"].append(signum)
        if held["entry"] is None:
            held["entry"] = entry
            sys.setprofile(deliver)
        return None

    guarded.__wrapped__ = handler
    return guarded


@contextlib.contextmanager
def signals_deferred(names: Sequence[str] = DEFERRED_SIGNALS,
                     message: str = "shutting the robot down first (a few seconds)"):
    """Hold SIGINT, SIGTERM and SIGHUP while the robot is shut down, then deliver them.

    A second Ctrl-C from an impatient operator, a TERM from systemd or Docker, or a HUP from a
    dropped SSH session would otherwise cut ``close()`` short and leave the robot powered and
    standing, holding our lease (QA 2026-12-04: exit 130 after 1.2 s, robot still standing 12 s
    later). ``close()`` is bounded, so holding them costs at most a few seconds; each is delivered
    again (``signal.raise_signal``) once the old handlers are back, so Ctrl-C still ends the program,
    just after the robot is safe. The first one held prints ``[spot] SIGNAME: <message>`` to stderr.
    A signal ignored when the block starts (SIG_IGN, e.g. SIGHUP under ``nohup``) stays ignored.
    Only on the main thread (both: :func:`handling_signals`)."""
    held: list[int] = []

    def hold(signum, _frame) -> None:
        if not held:
            # os.write, not print: a handler that lands while the main thread is inside
            # sys.stderr's write raised "RuntimeError: reentrant call inside <_io.BufferedWriter>"
            text = f"[spot] {signal.Signals(signum).name}: {message}\n"
            try:
                os.write(2, text.encode(getattr(sys.stderr, "encoding", None) or "utf-8", errors="ignore"))
            except (OSError, LookupError):      # no stderr (closed, a broken pipe): hold the signal anyway
                pass
        held.append(signum)

    try:
        with handling_signals(names, hold):
            yield
    finally:
        for signum in dict.fromkeys(held):       # each once, in arrival order, to the old handlers
            signal.raise_signal(signum)
