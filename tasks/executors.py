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
WORKER_EPISODES = 10
"""Episodes a local trial worker process runs before a fresh one replaces it (``tasks.trials.
run_batch``): PyBullet keeps every mesh's Python objects alive (~11 MB per val episode), and a
fresh process costs a few seconds against ~100 s of episodes."""
HEARTBEAT_S = 1.0            # executors yield None this often while nothing finishes (progress redraws)
RAY_OBJECT_STORE_BYTES = 100 * 1024 * 1024
# Every wait on the network or another process is bounded (seconds):
RAY_CONNECT_TIMEOUT_S = 10.0    # for a Ray head at HOST:PORT to accept a connection
WORKER_START_TIMEOUT_S = 120.0  # for a spawned worker process to import the code and report ready


class ExecutorError(RuntimeError):
    """The executor cannot be set up (bad name, Ray missing or unreachable, a worker that does not start)."""


def parse_address(address: str) -> tuple[str, int] | None:
    """``local``/``auto`` -> None; ``HOST:PORT`` or ``ray://HOST:PORT`` -> (host, port); anything
    else is an ExecutorError saying what a valid address looks like."""
    import ipaddress
    import re

    from helios.schema import short_repr

    if address in ("local", "auto"):
        return None
    text = address[len("ray://"):] if address.startswith("ray://") else address
    bad = ExecutorError(f"--address {short_repr(address, 80)} is not 'local', 'auto' or HOST:PORT "
                        f"(e.g. 10.0.0.5:6379 or ray://head.example.org:10001)")
    m = re.fullmatch(r"\[(?P<v6>[0-9A-Fa-f:.]+)\]:(?P<port6>\d{1,5})|(?P<host>[^:\s/]+):(?P<port>\d{1,5})", text)
    if not m:
        raise bad
    host = m.group("v6") or m.group("host")
    port = int(m.group("port6") or m.group("port"))
    if not 1 <= port <= 65535:
        raise ExecutorError(f"--address {short_repr(address, 80)}: port {port} is outside 1..65535")
    if m.group("v6") or re.fullmatch(r"[\d.]+", host):
        try:
            ipaddress.ip_address(host)
        except ValueError:
            raise ExecutorError(f"--address {short_repr(address, 80)}: {host!r} is not a valid IP address") from None
    elif len(host) > 253 or not all(re.fullmatch(r"[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?", label)
                                    for label in host.rstrip(".").split(".")):
        raise ExecutorError(f"--address {short_repr(address, 80)}: {short_repr(host, 60)} is not a valid host name")
    return host, port


def _bounded(fn: Callable, timeout: float):
    """``fn()`` in a daemon thread: ("ok", value), ("error", exception) or ("timeout", None)."""
    box: dict = {}

    def target() -> None:
        try:
            box["ok"] = fn()
        except BaseException as exc:  # noqa: BLE001 - handed to the caller
            box["error"] = exc

    t = threading.Thread(target=target, name="helios-bounded-wait", daemon=True)
    t.start()
    t.join(timeout)
    if t.is_alive():
        return "timeout", None
    return ("ok", box["ok"]) if "ok" in box else ("error", box.get("error"))


def find_auto_address() -> tuple[str, int] | None:
    """What ``ray.init(address="auto")`` would join: ``RAY_ADDRESS`` if set, else the cluster a
    ``ray start`` on this machine recorded, else a running raylet's GCS address (Ray's own lookup,
    ``ray._private.services``). ExecutorError when there is none, before anything starts."""
    env = os.environ.get("RAY_ADDRESS", "").strip()
    if env:
        try:
            return parse_address(env)
        except ExecutorError as exc:
            raise ExecutorError(f"--address auto takes the address from RAY_ADDRESS: {exc}") from None
    try:        # private API (ray==2.60.0 is pinned); another Ray version: let ray.init do the lookup
        from ray._private.services import find_bootstrap_address, find_gcs_addresses

        found = find_bootstrap_address(None) or next(iter(sorted(find_gcs_addresses())), None)
    except (ImportError, AttributeError, TypeError):
        return None
    if not found:
        raise ExecutorError("--address auto: no running Ray cluster found on this machine (RAY_ADDRESS is not set "
                            "and no `ray start` cluster is running); start one with `ray start --head`, name its "
                            "head as HOST:PORT, or use --address local")
    try:
        return parse_address(found)
    except ExecutorError:
        return None                     # an address only Ray itself understands: let ray.init try it


def check_address(address: str, timeout: float | None = None) -> None:
    """A Ray address that names a head which answers: the syntax (:func:`parse_address`), Ray is
    installed, ``auto`` finds a cluster (:func:`find_auto_address`), then a TCP connection within
    ``timeout`` seconds (default :data:`RAY_CONNECT_TIMEOUT_S`, name lookup included), so an
    unreachable cluster is one clear error instead of a hang; all before a run folder is made."""
    import importlib.util
    import socket

    target = parse_address(address)                 # the syntax first: it needs no Ray
    if importlib.util.find_spec("ray") is None:
        raise ExecutorError("--executor ray needs Ray, an optional extra: pip install -e '.[ray]' (ray==2.60.0)")
    if address == "auto":
        target = find_auto_address()
    if target is None:
        return
    timeout = RAY_CONNECT_TIMEOUT_S if timeout is None else timeout
    host, port = target

    def connect() -> None:
        socket.create_connection((host, port), timeout=timeout).close()

    status, value = _bounded(connect, timeout)
    if status == "timeout" or isinstance(value, (socket.timeout, TimeoutError)):
        raise ExecutorError(f"no answer from the Ray cluster at {host}:{port} within {timeout:g} s; "
                            f"check the address and that the head node is running")
    if status == "error":
        why = getattr(value, "strerror", None) or str(value) or type(value).__name__
        raise ExecutorError(f"cannot reach the Ray cluster at {host}:{port}: {why}")
    if os.environ.get("RAY_USE_TLS", "0").strip().lower() in ("", "0", "false"):
        _check_grpc_handshake(host, port, timeout)


def _check_grpc_handshake(host: str, port: int, timeout: float) -> None:
    """Ray's head (GCS, or the Ray client server of ``ray://``) speaks gRPC: a port that accepts TCP
    but completes no gRPC handshake within ``timeout`` is something else (a web server, another
    service), where ``ray.init`` would retry for minutes and print Ray's own warnings. Skipped
    with ``RAY_USE_TLS`` (the head then wants TLS, which this insecure probe cannot speak)."""
    import grpc

    channel = grpc.insecure_channel(f"{host}:{port}")
    try:
        grpc.channel_ready_future(channel).result(timeout=timeout)
    except grpc.FutureTimeoutError:
        raise ExecutorError(f"{host}:{port} accepts connections but does not answer as a Ray head (no gRPC "
                            f"handshake within {timeout:g} s); check the port (the head's GCS port, 6379 by "
                            f"default, or the ray:// client port, 10001)") from None
    finally:
        channel.close()


@dataclass(frozen=True)
class Outcome:
    index: int                 # position of the job in the submitted sequence
    status: str                # "ok" | "error" | "died"
    value: Any                 # the result, the traceback text, or why the worker died


def cpu_pin_environment() -> dict[str, str]:
    """The variables of the CPU pin this process runs under (``helios.runtime``), for workers
    whose environment is not inherited from it (Ray)."""
    from helios.runtime import CPU_ENV_VAR, PIN_VARS

    return {k: os.environ[k] for k in (CPU_ENV_VAR, *PIN_VARS) if k in os.environ}


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
    if hasattr(signal, "pthread_sigmask"):           # ignored, and blocked, since the start (_start_quiet)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    worker_setup()
    try:
        conn.send(("ready",))                       # the parent bounds how long it waits for this
    except (BrokenPipeError, OSError):
        return
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


def _start_quiet(process) -> None:
    """Start a worker process that ignores SIGINT from its first instruction: a Ctrl-C (sent to the
    whole process group) while the new interpreter imported and unpickled its code printed the
    child's KeyboardInterrupt traceback above the batch's own line (reliability audit). SIG_IGN is
    kept across exec (a blocked mask alone is not: native libraries start threads of their own
    while the worker imports, and the kernel hands the signal to one of them). In this process
    the handler is put back right after the start; a Ctrl-C in those few milliseconds is dropped
    (press it again), the price of a clean line."""
    if not hasattr(signal, "pthread_sigmask") or threading.current_thread() is not threading.main_thread():
        process.start()                      # signal.signal() works only in the main thread
        return
    old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    old_handler = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        process.start()
    finally:
        signal.signal(signal.SIGINT, old_handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)


class _Worker:
    def __init__(self, ctx):
        self.conn, child = ctx.Pipe(duplex=True)
        self.process = ctx.Process(target=_worker_loop, args=(child, os.getpid()), daemon=True,
                                   name="helios-trial-worker")
        _start_quiet(self.process)
        child.close()
        self.job: int | None = None
        self.jobs_done = 0
        self.started_at = time.monotonic()
        self.ready = False

    def ask_to_exit(self) -> None:
        try:
            self.conn.send(None)
        except (BrokenPipeError, OSError):
            pass

    def reap(self, timeout: float) -> None:
        """Wait up to ``timeout`` s for the process to exit (after ``ask_to_exit``), then kill it."""
        self.process.join(timeout=max(0.0, timeout))
        if self.process.is_alive():
            self.process.kill()
            self.process.join(timeout=1.0)
        self.conn.close()

    def receive(self):
        """The next message, with the ready handshake consumed: an outcome tuple, or None."""
        msg = self.conn.recv()
        if isinstance(msg, tuple) and msg == ("ready",):
            self.ready = True
            return None
        return msg


class ProcessExecutor:
    """A pool of ``workers`` spawned processes; one job per worker at a time, in submission order.

    ``jobs_per_worker`` (0 = no limit): a worker that has run this many jobs is replaced by a
    fresh process before it takes another. PyBullet keeps a reference to every Python object a
    mesh is passed in (``createVisualShape``'s vertices, normals, uvs and indices; measured with
    ``sys.getrefcount``), so a long-lived trial worker grows by ~11 MB per episode: from ~370 MB to
    ~1.5 GB over 100 val episodes. A fresh process per few episodes bounds that; results do not
    depend on which process runs an episode (every episode builds its own world and seeds).
    """

    def __init__(self, workers: int, jobs_per_worker: int = 0):
        import multiprocessing as mp

        if workers < 1:
            raise ExecutorError(f"--workers must be >= 1, got {workers}")
        if jobs_per_worker < 0:
            raise ExecutorError(f"jobs per worker must be >= 0 (0 = no limit), got {jobs_per_worker}")
        self.workers = workers
        self.jobs_per_worker = jobs_per_worker
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
            late = [w for w in self._pool if not w.ready and w.process.is_alive()
                    and time.monotonic() - w.started_at > WORKER_START_TIMEOUT_S and not w.conn.poll()]
            if late:
                raise ExecutorError(f"a worker process did not start within {WORKER_START_TIMEOUT_S:g} s (it never "
                                    f"reported ready); is the machine overloaded? try fewer --workers")
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
                        msg = w.receive()
                        if msg is not None:
                            index, status, value = msg
                            outcome = Outcome(index, status, value)
                        elif w.process.is_alive():
                            continue
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
                    w.jobs_done += 1
                    running -= 1
                    if self.jobs_per_worker and w.jobs_done >= self.jobs_per_worker and pending:
                        self._pool.remove(w)          # a fresh process for the next jobs
                        w.ask_to_exit()
                        w.reap(5.0)
                        w = _Worker(self._ctx)
                        self._pool.append(w)
                    assign(w)
                    yield outcome

    def close(self) -> None:
        """Stop the workers: ask politely, then terminate (only our own processes, by handle)."""
        for w in self._pool:
            w.ask_to_exit()
        deadline = time.monotonic() + 5.0
        for w in self._pool:
            if w.job is not None:             # still busy (interrupted batch): do not wait for it
                w.process.terminate()
            w.reap(deadline - time.monotonic())
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
        check_address(address)          # before importing Ray: a bad or dead address fails fast
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
        kwargs: dict = {"log_to_driver": False, "configure_logging": True, "logging_level": "ERROR",
                        # the driver's CPU code paths (helios.runtime.pin_cpu_dispatch) for the workers too
                        "runtime_env": {"env_vars": cpu_pin_environment()}}
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
            self.workers = int(ray.cluster_resources().get("CPU", 0))
            if self.workers < 1:
                self.close()
                raise ExecutorError(f"the Ray cluster at {address!r} has no CPUs to run episodes on; "
                                    f"start worker nodes first")

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


def make_executor(kind: str = "local", workers: int = 1, address: str = "local", jobs: int = 0,
                  jobs_per_worker: int = 0):
    """``local`` with one worker runs in this process, unless the batch has more than
    ``jobs_per_worker`` jobs (then one spawned process, replaced every ``jobs_per_worker`` jobs,
    see :class:`ProcessExecutor`); more workers use spawned processes."""
    if kind not in EXECUTORS:
        raise ExecutorError(f"unknown executor {kind!r}; valid executors: {', '.join(EXECUTORS)}")
    if workers < 1:
        raise ExecutorError(f"--workers must be >= 1, got {workers}")
    if kind == "ray":
        return RayExecutor(address, workers)
    if workers == 1 and not (jobs_per_worker and jobs > jobs_per_worker):
        return InlineExecutor()
    return ProcessExecutor(workers, jobs_per_worker)
