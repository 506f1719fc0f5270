"""Where trial episodes run: in this process, in a pool of local worker processes, or on a Ray
cluster. Every executor runs ``fn(job)`` for each job and yields the outcomes as they finish; the
caller (``tasks.trials.run_batch``) is the only writer of the run folder, so workers never touch
``episodes.jsonl``.

Local workers are started with the ``spawn`` method (no forked PyBullet or torch state), pin their
native thread pools to one thread (``helios.runtime.configure_threads``), ignore Ctrl-C (the parent
stops them), and die with the parent: on Linux through ``PR_SET_PDEATHSIG``, elsewhere through a
watchdog thread, so a batch killed with SIGKILL leaves no orphans behind.

Outcomes: ``ok`` (the job's return value), ``error`` (``fn`` raised: the traceback text) and
``died`` (the worker process exited while running the job, e.g. on a segfault or the OOM killer).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
import traceback
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Sequence

from tasks.provenance import git_commit

EXECUTORS = ("local", "ray")
HEARTBEAT_S = 1.0            # executors yield None this often while nothing finishes (progress redraws)
RAY_OBJECT_STORE_BYTES = 100 * 1024 * 1024


class ExecutorError(RuntimeError):
    """The executor cannot be set up (bad name, Ray missing or unreachable)."""


@dataclass(frozen=True)
class Outcome:
    index: int                 # position of the job in the submitted sequence
    status: str                # "ok" | "error" | "died"
    value: Any                 # the result, the traceback text, or why the worker died


def worker_setup() -> None:
    """Per-process setup of every trial worker (local process or Ray task)."""
    from helios.runtime import configure_threads

    configure_threads(1)


def _call(fn: Callable, job) -> tuple[str, Any]:
    try:
        return "ok", fn(job)
    except Exception:  # any failure is reported to the caller, which decides; Ctrl-C propagates
        return "error", traceback.format_exc()


# ------------------------------------------------------------------------------------------------
# In this process
# ------------------------------------------------------------------------------------------------
class InlineExecutor:
    """Runs the jobs one after the other in the calling process (``--workers 1``)."""

    workers = 1

    def map_unordered(self, fn: Callable, jobs: Sequence) -> Iterator[Outcome | None]:
        for i, job in enumerate(jobs):
            status, value = _call(fn, job)
            yield Outcome(i, status, value)

    def close(self) -> None:
        pass


# ------------------------------------------------------------------------------------------------
# Local worker processes
# ------------------------------------------------------------------------------------------------
def _die_with_parent(parent_pid: int) -> None:
    """Make this worker exit as soon as its parent does (even if the parent was SIGKILLed)."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signal.SIGKILL, 0, 0, 0)   # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent_pid:                  # the parent died before prctl took effect
        os._exit(1)

    def watchdog() -> None:                         # portable fallback (macOS)
        while True:
            time.sleep(0.5)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watchdog, name="parent-watchdog", daemon=True).start()


def _worker_loop(conn, parent_pid: int) -> None:
    _die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)    # Ctrl-C reaches the whole group; the parent decides
    worker_setup()
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        index, fn, job = msg
        status, value = _call(fn, job)
        try:
            conn.send((index, status, value))
        except (BrokenPipeError, OSError):
            return


class _Worker:
    def __init__(self, ctx):
        self.conn, child = ctx.Pipe(duplex=True)
        self.process = ctx.Process(target=_worker_loop, args=(child, os.getpid()), daemon=True,
                                   name="helios-trial-worker")
        self.process.start()
        child.close()
        self.job: int | None = None


class ProcessExecutor:
    """A pool of ``workers`` spawned processes; one job per worker at a time, in submission order."""

    def __init__(self, workers: int):
        import multiprocessing as mp

        if workers < 1:
            raise ExecutorError(f"--workers must be >= 1, got {workers}")
        self.workers = workers
        self._ctx = mp.get_context("spawn")
        self._pool: list[_Worker] = []

    def map_unordered(self, fn: Callable, jobs: Sequence) -> Iterator[Outcome | None]:
        from multiprocessing.connection import wait

        pending = list(range(len(jobs)))[::-1]       # pop() takes the next job in order
        running = 0
        while pending and len(self._pool) < self.workers:
            self._pool.append(_Worker(self._ctx))

        def assign(w: _Worker) -> None:
            nonlocal running
            if pending and w.job is None:
                i = pending.pop()
                w.job = i
                w.conn.send((i, fn, jobs[i]))
                running += 1

        for w in self._pool:
            assign(w)
        while running:
            ready = wait([w.conn for w in self._pool if w.job is not None]
                         + [w.process.sentinel for w in self._pool if w.job is not None], timeout=HEARTBEAT_S)
            if not ready:
                yield None
                continue
            for w in list(self._pool):
                if w.job is None:
                    continue
                outcome = None
                if w.conn in ready or w.conn.poll():
                    try:
                        index, status, value = w.conn.recv()
                        outcome = Outcome(index, status, value)
                    except (EOFError, OSError):
                        w.process.join(timeout=1.0)     # the pipe closed: the process is exiting
                if outcome is None and not w.process.is_alive():
                    w.process.join(timeout=1.0)
                    outcome = Outcome(w.job, "died", _exit_text(w.process.exitcode))
                    self._pool.remove(w)
                    running -= 1
                    if pending:
                        nw = _Worker(self._ctx)
                        self._pool.append(nw)
                        assign(nw)
                    yield outcome
                    continue
                if outcome is not None:
                    w.job = None
                    running -= 1
                    assign(w)
                    yield outcome

    def close(self) -> None:
        """Stop the workers: ask politely, then terminate (only our own processes, by handle)."""
        for w in self._pool:
            try:
                w.conn.send(None)
            except (BrokenPipeError, OSError):
                pass
        deadline = time.monotonic() + 5.0
        for w in self._pool:
            if w.job is not None:             # still busy (interrupted batch): do not wait for it
                w.process.terminate()
            w.process.join(timeout=max(0.0, deadline - time.monotonic()))
            if w.process.is_alive():
                w.process.kill()
                w.process.join(timeout=1.0)
            w.conn.close()
        self._pool.clear()


def _exit_text(code: int | None) -> str:
    if code is None:
        return "worker process vanished"
    if code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        return f"worker process died ({name})"
    return f"worker process exited with status {code}"


# ------------------------------------------------------------------------------------------------
# Ray
# ------------------------------------------------------------------------------------------------
def _ray_task(fn: Callable, job, driver_commit: str) -> tuple[str, Any]:
    worker_setup()
    commit = git_commit()
    if commit != driver_commit:
        return "error", (f"the Ray worker runs code at commit {commit}, the driver at {driver_commit}; "
                         f"install the same version on every node")
    return _call(fn, job)


class RayExecutor:
    """Runs jobs as Ray tasks (one CPU each). ``address``: ``local`` starts a private instance on
    this machine bound to the loopback interface (no dashboard, small object store) and stops it on
    close; ``auto`` joins the cluster this machine belongs to; ``HOST:PORT`` (or ``ray://...``) names
    the cluster's head. The package must be installed at the same commit on every node."""

    def __init__(self, address: str = "local", workers: int = 2):
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")   # never phone home
        if address == "local":
            # Ray resolves "localhost" to the machine's routable address unless clusters are off.
            os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
        try:
            import ray
        except ImportError:
            raise ExecutorError("--executor ray needs Ray, an optional extra: "
                                "pip install -e '.[ray]' (ray==2.60.0)") from None
        if address == "local":
            import ray._private.ray_constants as rc

            rc.ENABLE_RAY_CLUSTER = False        # in case ray was imported before the variable was set
        self._ray = ray
        self.workers = workers
        self._owned = False
        if ray.is_initialized():
            return
        kwargs: dict = {"log_to_driver": False, "configure_logging": True, "logging_level": "ERROR"}
        try:
            if address == "local":
                ray.init(address="local", num_cpus=workers, include_dashboard=False,
                         object_store_memory=RAY_OBJECT_STORE_BYTES, **kwargs)
            else:
                ray.init(address=address, **kwargs)
        except (ConnectionError, ValueError, RuntimeError) as exc:
            raise ExecutorError(f"cannot connect to the Ray cluster at {address!r}: {exc}") from None
        self._owned = True
        if address != "local":
            self.workers = int(ray.cluster_resources().get("CPU", workers))

    def map_unordered(self, fn: Callable, jobs: Sequence) -> Iterator[Outcome | None]:
        ray = self._ray
        remote = ray.remote(num_cpus=1, max_retries=0)(_ray_task)
        commit = git_commit()
        refs = {remote.remote(fn, job, commit): i for i, job in enumerate(jobs)}
        self._refs = refs
        while refs:
            done, _ = ray.wait(list(refs), num_returns=1, timeout=HEARTBEAT_S)
            if not done:
                yield None
                continue
            for ref in done:
                i = refs.pop(ref)
                try:
                    status, value = ray.get(ref)
                except ray.exceptions.RayError as exc:   # worker crash, node loss, ...
                    status, value = "died", f"Ray task failed: {type(exc).__name__}: {str(exc).splitlines()[0]}"
                yield Outcome(i, status, value)

    def close(self) -> None:
        for ref in getattr(self, "_refs", {}):
            try:
                self._ray.cancel(ref, force=True)
            except Exception:  # noqa: BLE001 - best effort on the way out
                pass
        if self._owned:
            self._ray.shutdown()
            self._owned = False


def make_executor(kind: str = "local", workers: int = 1, address: str = "local"):
    """``local`` with one worker runs in this process; more workers use spawned processes."""
    if kind not in EXECUTORS:
        raise ExecutorError(f"unknown executor {kind!r}; valid executors: {', '.join(EXECUTORS)}")
    if workers < 1:
        raise ExecutorError(f"--workers must be >= 1, got {workers}")
    if kind == "ray":
        return RayExecutor(address, workers)
    return InlineExecutor() if workers == 1 else ProcessExecutor(workers)
