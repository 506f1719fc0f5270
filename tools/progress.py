"""Progress of long batches: a one-line bar with ETA and running success rate on a terminal, one
log line per finished episode otherwise (CI logs, files, pipes). No dependencies.

    [trials] ███████░░░░░░░░░░░░░  37/200  18%  SR 62.2%  elapsed 0:12:31  ETA 0:45:10  (2 workers)
    [trials] 37/200 val-00036 success  (sim 41 s, wall 2.1 s)  SR 62.2%  elapsed 0:12:31  ETA 0:45:10
"""

from __future__ import annotations

import shutil
import sys
import time
from typing import TextIO

MODES = ("auto", "bar", "lines", "none")


def format_duration(seconds: float | None) -> str:
    if seconds is None or seconds != seconds or seconds == float("inf"):
        return "--:--"
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


class Progress:
    """Counts finished episodes (``update``) and redraws (``tick``) until ``close``.

    ``done`` episodes were already finished before this batch started; ETA uses only the rate of
    this batch. ``mode="auto"`` draws a bar when ``stream`` is a terminal, else prints lines.
    """

    def __init__(self, total: int, done: int = 0, successes: int = 0, workers: int = 1, mode: str = "auto",
                 stream: TextIO | None = None, prefix: str = "[trials]"):
        if mode not in MODES:
            raise ValueError(f"progress mode must be one of {', '.join(MODES)}, got {mode!r}")
        self.stream = stream or sys.stdout
        if mode == "auto":
            mode = "bar" if getattr(self.stream, "isatty", lambda: False)() else "lines"
        self.mode = mode
        self.total, self.done, self.successes, self.workers = total, done, successes, workers
        self.start_done = done
        self.prefix = prefix
        self.t0 = time.perf_counter()
        self._drawn = False

    # ------------------------------------------------------------------ numbers
    @property
    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def eta(self) -> float | None:
        ran = self.done - self.start_done
        if ran <= 0:
            return None
        return self.elapsed / ran * (self.total - self.done)

    def success_rate(self) -> float | None:
        return 100.0 * self.successes / self.done if self.done else None

    # ------------------------------------------------------------------ events
    def update(self, record: dict) -> None:
        self.done += 1
        self.successes += bool(record.get("success"))
        if self.mode == "lines":
            self._line(record)
        elif self.mode == "bar":
            if record.get("error"):
                self.message(f"{record['episode_id']}: error: {str(record['error']).splitlines()[0]}")
            self._bar()

    def tick(self) -> None:
        if self.mode == "bar":
            self._bar()

    def message(self, text: str) -> None:
        """A line that stays (above the bar on a terminal)."""
        if self.mode == "none":
            return
        if self.mode == "bar" and self._drawn:
            self.stream.write("\r\033[K")
        self.stream.write(f"{self.prefix} {text}\n")
        self.stream.flush()
        if self.mode == "bar" and self._drawn:
            self._bar()

    def close(self) -> None:
        if self.mode == "bar" and self._drawn:
            self._bar()
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False

    # ------------------------------------------------------------------ drawing
    def _stats(self) -> str:
        sr = self.success_rate()
        return (f"SR {sr:.1f}%  " if sr is not None else "") + \
            f"elapsed {format_duration(self.elapsed)}  ETA {format_duration(self.eta())}"

    def _line(self, record: dict) -> None:
        m = record.get("metrics") or {}
        status = "success" if record.get("success") else f"failed: {m.get('failure_reason')}"
        if record.get("error"):
            status += f" (error: {str(record['error']).splitlines()[0]})"
        self.stream.write(f"{self.prefix} {self.done}/{self.total} {record['episode_id']} {status}  "
                          f"(sim {record['sim_time']:.0f} s, wall {record['wall_time']:.1f} s)  {self._stats()}\n")
        self.stream.flush()

    def _bar(self) -> None:
        width = shutil.get_terminal_size((100, 20)).columns
        frac = self.done / self.total if self.total else 1.0
        tail = (f" {self.done}/{self.total}  {100 * frac:3.0f}%  {self._stats()}"
                + (f"  ({self.workers} workers)" if self.workers > 1 else ""))
        n = max(10, min(30, width - len(self.prefix) - len(tail) - 3))
        full = int(round(frac * n))
        line = f"{self.prefix} {'█' * full}{'░' * (n - full)}{tail}"
        self.stream.write("\r\033[K" + line[:max(20, width - 1)])
        self.stream.flush()
        self._drawn = True
