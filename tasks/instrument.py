"""Per-episode instrumentation for trial batches: memory sampling and recordings, for any agent.

The trial code wraps the agent (:class:`InstrumentedAgent`) and the robot the agent drives
(:class:`InstrumentedRobot`); neither changes what the agent sees or does, so an instrumented or
recorded episode gives the same numbers as a bare one. Agents may offer two optional hooks:

``agent.memory_bytes() -> int | Mapping[str, int]``
    Bytes of the agent's map / world model (e.g. ``HierarchicalMap.memory_bytes()``), sampled
    after every robot command. Mappings are summed; the last breakdown is kept.
``agent.record(recorder: tasks.recording.EpisodeRecorder) -> None``
    Called after every ``act`` when the episode is recorded; log what the agent knows, e.g.
    ``recorder.log_map(self.map)`` (occupancy/value images, Gaussians, instances, frontiers),
    ``recorder.log_detections(dets, class_names)`` and ``recorder.log_path("plan", waypoints)``.
    The recorder's clock is already set to the simulation time; exceptions are caught, reported
    once on stderr and in the record's ``recording.errors``, and never change the episode.

A ``tracer`` (:class:`tasks.episode_trace.EpisodeTracer`) sees every observation and command too,
for the per-episode pictures of the trial report; its failures go to the trace's own ``errors``.

Memory per episode: peak resident set size (Linux: the kernel's high-water mark, reset at the
episode start; elsewhere the peak of the samples), map bytes, and CUDA memory allocated/reserved
(peak and per sample) when torch has initialised CUDA in this process. The time series has one
sample per robot command, thinned to at most ``MAX_SAMPLES`` (bin maxima, so peaks survive).
"""

from __future__ import annotations

import math
import sys
import traceback
from typing import Any, Callable, Mapping, Sequence

from robots.hal import CommandProxy

MB = 1024.0 * 1024.0
MAX_SAMPLES = 64


# ------------------------------------------------------------------------------------------------
# Memory
# ------------------------------------------------------------------------------------------------
def _reset_peak_rss() -> bool:
    """Reset the kernel's peak-RSS counter of this process (Linux >= 4.0); False if unsupported."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def _peak_rss_kernel() -> int | None:
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _cuda():
    """torch.cuda if torch is loaded and CUDA is initialised in this process, else None."""
    torch = sys.modules.get("torch")
    if torch is None:
        return None
    try:
        return torch.cuda if torch.cuda.is_available() and torch.cuda.is_initialized() else None
    except Exception:  # noqa: BLE001 - a broken CUDA setup must not break the episode
        return None


def _total_bytes(value) -> tuple[int, dict[str, int] | None]:
    if isinstance(value, Mapping):
        parts = {str(k): int(v) for k, v in value.items()}
        return sum(parts.values()), parts
    return int(value), None


class MemoryProbe:
    """Samples RSS, agent map bytes and CUDA memory during one episode."""

    def __init__(self, map_bytes: Callable[[], Any] | None = None):
        import psutil

        self._proc = psutil.Process()
        self._map_bytes = map_bytes
        self._kernel_peak = _reset_peak_rss()
        cuda = _cuda()
        if cuda is not None:
            cuda.reset_peak_memory_stats()
        self._cuda_reset = cuda is not None
        self.samples: list[tuple[float, float, float | None, float | None, float | None]] = []
        self.map_breakdown: dict[str, int] | None = None
        self.map_error: str | None = None

    def sample(self, t: float) -> None:
        rss = self._proc.memory_info().rss / MB
        map_mb = None
        if self._map_bytes is not None and self.map_error is None:
            try:
                total, parts = _total_bytes(self._map_bytes())
                map_mb = total / MB
                self.map_breakdown = parts
            except Exception as exc:  # noqa: BLE001 - a faulty hook is reported, not fatal
                self.map_error = f"{type(exc).__name__}: {exc}"
        alloc = reserved = None
        cuda = _cuda()
        if cuda is not None:
            alloc, reserved = cuda.memory_allocated() / MB, cuda.memory_reserved() / MB
        self.samples.append((float(t), rss, map_mb, alloc, reserved))

    def summary(self) -> dict:
        """The ``memory`` field of an episode record (MB)."""
        s = self.samples
        rss = [x[1] for x in s]
        peak = _peak_rss_kernel() if self._kernel_peak else None
        if peak:
            rss.append(peak / MB)
        rss_peak = max(rss) if rss else self._proc.memory_info().rss / MB
        maps = [x[2] for x in s if x[2] is not None]
        out: dict = {"peak_rss_mb": round(rss_peak, 3),
                     "map_mb_peak": round(max(maps), 4) if maps else None,
                     "map_mb_final": round(maps[-1], 4) if maps else None,
                     "gpu_allocated_mb_peak": None, "gpu_reserved_mb_peak": None}
        if self.map_breakdown is not None:
            out["map_bytes_final"] = self.map_breakdown
        if self.map_error:
            out["map_error"] = self.map_error
        cuda = _cuda()
        if cuda is not None:
            allocs = [x[3] for x in s if x[3] is not None]
            res = [x[4] for x in s if x[4] is not None]
            if self._cuda_reset:
                allocs.append(cuda.max_memory_allocated() / MB)
                res.append(cuda.max_memory_reserved() / MB)
            out["gpu_allocated_mb_peak"] = round(max(allocs), 2) if allocs else None
            out["gpu_reserved_mb_peak"] = round(max(res), 2) if res else None
        out["series"] = _thin(s, MAX_SAMPLES)
        return out


def _thin(samples: Sequence[tuple], limit: int) -> dict[str, list]:
    """At most ``limit`` points: each bin keeps its last time and the maximum of every quantity."""
    keys = ("t", "rss_mb", "map_mb", "gpu_allocated_mb", "gpu_reserved_mb")
    n = len(samples)
    bins = [samples[int(math.floor(i * n / limit)):int(math.floor((i + 1) * n / limit))] for i in range(limit)] \
        if n > limit else [[x] for x in samples]
    out: dict[str, list] = {k: [] for k in keys}
    for b in bins:
        if not b:
            continue
        out["t"].append(round(b[-1][0], 2))
        for j, k in enumerate(keys[1:], 1):
            vals = [x[j] for x in b if x[j] is not None]
            out[k].append(round(max(vals), 3) if vals else None)
    return {k: v for k, v in out.items() if any(x is not None for x in v)}


# ------------------------------------------------------------------------------------------------
# Wrappers
# ------------------------------------------------------------------------------------------------
class InstrumentedRobot(CommandProxy):
    """The robot handed to the agent: forwards every call unchanged, then samples memory and, when
    recording, logs the observation or the command, its result and the robot's state."""

    def __init__(self, robot, owner: "InstrumentedAgent"):
        self._robot = robot
        self._owner = owner

    def observe(self):
        obs = self._robot.observe()
        self._owner.after_command("observe", (), obs)
        return obs

    def _command(self, name: str, *args, **kwargs):
        result = getattr(self._robot, name)(*args, **kwargs)
        self._owner.after_command(name, args, result, kwargs)
        return result

    def navigate_to(self, goal, via=()):
        self._owner.before_navigate(goal, via)
        return super().navigate_to(goal, via)

    def __getattr__(self, name: str):
        return getattr(self._robot, name)


class InstrumentedAgent:
    """Wraps any agent: same name, same decisions; adds memory samples and recording hooks.

    ``robot_state``: optional callable returning ``(world_time, T_world_body, joint_positions)``
    of the simulated robot, used only to draw the robot in recordings between observations.
    """

    def __init__(self, agent, recorder=None, robot_state: Callable[[], tuple] | None = None, tracer=None):
        self._agent = agent
        self.recorder = recorder
        self.tracer = tracer
        self._robot_state = robot_state
        hook = getattr(agent, "memory_bytes", None)
        self.probe = MemoryProbe(hook if callable(hook) else None)
        self._robot = None
        self.hook_errors: list[str] = []

    @property
    def name(self) -> str:
        return self._agent.name

    def reset(self, task, rng) -> None:
        self._agent.reset(task, rng)

    def act(self, robot) -> bool:
        self._robot = robot
        try:
            done = self._agent.act(InstrumentedRobot(robot, self))
        finally:
            if self.tracer is not None:
                self._trace(self.tracer.on_step, self._agent)
        self._call_record_hook()
        return done

    def __getattr__(self, name: str):
        return getattr(self._agent, name)

    # ------------------------------------------------------------------ callbacks
    def _elapsed(self) -> float:
        return float(getattr(self._robot, "elapsed", 0.0)) if self._robot is not None else 0.0

    def after_command(self, name: str, args: tuple, result, kwargs: dict | None = None) -> None:
        self.probe.sample(self._elapsed())
        if self.tracer is not None:
            self._trace(self.tracer.on_command, name, args, result, self._elapsed(), self._agent)
        rec = self.recorder
        if rec is None:
            return
        try:
            if name == "observe":
                rec.log_observation(result)
            else:
                self._log_state()
                rec.log_command(name, result)
            s = self.probe.samples[-1]
            rec.log_scalar("memory/rss_mb", s[1])
            if s[2] is not None:
                rec.log_scalar("memory/map_mb", s[2])
            if s[3] is not None:
                rec.log_scalar("memory/gpu_allocated_mb", s[3])
                rec.log_scalar("memory/gpu_reserved_mb", s[4])
            rec.log_scalar("commands", float(getattr(self._robot, "commands", 0)))
        except Exception:  # noqa: BLE001 - a recording problem must never change the episode
            self._hook_failed("recording")

    def before_navigate(self, goal, via) -> None:
        rec = self.recorder
        if rec is None or self._robot_state is None:
            return
        try:
            t, T, _ = self._robot_state()
            rec.set_time(t)
            pts = [(T[0, 3], T[1, 3])] + [(p.x, p.y) for p in (*via, goal)]
            rec.log_path("navigate_to", [(x, y, 0.05) for x, y in pts], color=(255, 120, 0))
        except Exception:  # noqa: BLE001
            self._hook_failed("recording")

    def _log_state(self) -> None:
        if self._robot_state is not None:
            t, T, joints = self._robot_state()
            self.recorder.set_time(t)
            self.recorder.log_robot_state(T, joints)

    def _call_record_hook(self) -> None:
        hook = getattr(self._agent, "record", None)
        if self.recorder is None or not callable(hook):
            return
        try:
            if self._robot_state is not None:
                self.recorder.set_time(self._robot_state()[0])
            hook(self.recorder)
        except Exception:  # noqa: BLE001
            self._hook_failed("agent.record")

    def _trace(self, fn, *args) -> None:
        try:
            fn(*args)
        except Exception as exc:  # noqa: BLE001 - a picture problem must never change the episode
            if not self.tracer.errors:
                print(f"[trials] warning: episode pictures failed (the episode goes on):\n"
                      f"{traceback.format_exc(limit=4)}", file=sys.stderr, flush=True)
            self.tracer.failed(f"{type(exc).__name__}: {exc}")

    def _hook_failed(self, what: str) -> None:
        text = traceback.format_exc(limit=4)
        if len(self.hook_errors) < 3:
            self.hook_errors.append(f"{what}: {text.strip().splitlines()[-1]}")
            print(f"[trials] warning: {what} failed (the episode goes on):\n{text}", file=sys.stderr, flush=True)
            try:
                if self.recorder is not None:
                    self.recorder.log_text(f"{what} failed: {text}", level="ERROR")
            except Exception:  # noqa: BLE001
                pass

