"""Trial machinery in isolation: executors (errors, dead workers), progress output, memory
sampling, command-line errors for trials/report/view."""

from __future__ import annotations

import io
import os
import signal

import pytest

from tasks.executors import ExecutorError, InlineExecutor, ProcessExecutor, make_executor
from tasks.instrument import MAX_SAMPLES, MemoryProbe, _thin
from tools.progress import Progress, format_duration


# ------------------------------------------------------------------ executors
def square_or_fail(job):
    """Job function for executor tests (module level: spawned workers import it by name)."""
    kind, x = job
    if kind == "raise":
        raise ValueError(f"bad job {x}")
    if kind == "die":
        os.kill(os.getpid(), signal.SIGKILL)
    if kind == "threads":
        return os.environ.get("OMP_NUM_THREADS")
    if kind == "pid":
        return os.getpid()
    return x * x


def _collect(executor, jobs):
    try:
        return {o.index: (o.status, o.value) for o in executor.map_unordered(square_or_fail, jobs) if o is not None}
    finally:
        executor.close()


def test_process_executor_reports_results_errors_and_dead_workers_and_goes_on():
    jobs = [("ok", 2), ("raise", 3), ("die", 0), ("ok", 5), ("threads", 0), ("ok", 7)]
    out = _collect(ProcessExecutor(2), jobs)
    assert out[0] == ("ok", 4) and out[3] == ("ok", 25) and out[5] == ("ok", 49)
    assert out[1][0] == "error" and "ValueError: bad job 3" in out[1][1]
    assert out[2] == ("died", "worker process died (SIGKILL)")
    assert out[4] == ("ok", "1")                 # workers pin native thread pools to one thread


def test_inline_executor_runs_in_order_and_make_executor_validates():
    out = _collect(InlineExecutor(), [("ok", 1), ("raise", 2), ("ok", 3)])
    assert out == {0: ("ok", 1), 1: (out[1][0], out[1][1]), 2: ("ok", 9)} and out[1][0] == "error"
    assert isinstance(make_executor("local", 1), InlineExecutor)
    with pytest.raises(ExecutorError, match="unknown executor 'dask'; valid executors: local, ray"):
        make_executor("dask", 2)
    with pytest.raises(ExecutorError, match="--workers must be >= 1"):
        make_executor("local", 0)


def test_a_worker_is_replaced_by_a_fresh_process_after_its_share_of_jobs():
    """``jobs_per_worker``: PyBullet leaks every mesh's Python objects, so trial workers are
    recycled; each process runs at most that many jobs, every job still runs once, in order."""
    out = _collect(ProcessExecutor(1, jobs_per_worker=2), [("pid", i) for i in range(5)])
    pids = [out[i][1] for i in range(5)]
    assert all(out[i][0] == "ok" for i in range(5))
    assert pids[0] == pids[1] != pids[2] == pids[3] != pids[4] and len(set(pids)) == 3
    assert os.getpid() not in pids
    kept = _collect(ProcessExecutor(2, jobs_per_worker=0), [("pid", i) for i in range(6)])
    assert len({v for _s, v in kept.values()}) <= 2                      # 0: never replaced
    # one worker: in this process unless the batch is longer than the share
    assert isinstance(make_executor("local", 1, jobs=10, jobs_per_worker=10), InlineExecutor)
    assert isinstance(make_executor("local", 1, jobs=11, jobs_per_worker=0), InlineExecutor)
    pool = make_executor("local", 1, jobs=11, jobs_per_worker=10)
    assert isinstance(pool, ProcessExecutor) and pool.workers == 1 and pool.jobs_per_worker == 10
    with pytest.raises(ExecutorError, match="jobs per worker must be >= 0"):
        ProcessExecutor(1, jobs_per_worker=-1)


# ------------------------------------------------------------------ progress
def _record(i, success=True, reason=None, error=None):
    return {"episode_id": f"val-{i:05d}", "success": success, "metrics": {"failure_reason": reason},
            "sim_time": 40.0, "wall_time": 2.5, "error": error}


def test_progress_lines_for_logs_with_running_success_rate():
    stream = io.StringIO()
    p = Progress(4, done=1, successes=1, mode="auto", stream=stream)
    assert p.mode == "lines"                     # not a terminal
    p.update(_record(1))
    p.update(_record(2, False, "pick_failed"))
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("[trials] 2/4 val-00001 success  (sim 40 s, wall 2.5 s)  SR 100.0%")
    assert lines[1].startswith("[trials] 3/4 val-00002 failed: pick_failed") and "SR 66.7%" in lines[1]
    assert "ETA 0:00:0" in lines[1]


class _Tty(io.StringIO):
    def isatty(self):
        return True


def test_progress_bar_on_a_terminal_redraws_one_line_with_eta(monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")     # the bar cuts its line to the terminal's width
    stream = _Tty()
    p = Progress(10, workers=2, stream=stream)
    assert p.mode == "bar"
    p.update(_record(0))
    p.update(_record(1, False, "timeout", error="RuntimeError: boom\ntrace"))
    p.tick()
    p.close()
    text = stream.getvalue()
    assert "\r\033[K" in text and "2/10" in text and "SR 50.0%" in text and "ETA" in text and "(2 workers)" in text
    assert "[trials] val-00001: error: RuntimeError: boom\n" in text
    assert text.endswith("\n")
    assert format_duration(3725) == "1:02:05" and format_duration(None) == "--:--"


def test_progress_bar_fits_a_narrow_terminal(monkeypatch):
    monkeypatch.setenv("COLUMNS", "60")
    stream = _Tty()
    p = Progress(10, workers=2, stream=stream)
    p.update(_record(0))
    p.tick()
    p.close()
    redraws = [seg.rstrip("\n") for seg in stream.getvalue().split("\r\033[K") if seg]
    assert redraws and all(len(seg) <= 59 for seg in redraws)      # never wraps onto a second line
    assert all(seg.startswith("[trials] ") for seg in redraws)


# ------------------------------------------------------------------ memory
def test_memory_series_is_thinned_keeping_peaks_and_map_hooks_are_summed():
    calls = []

    def map_bytes():
        calls.append(1)
        return {"occupancy": 1024 * 1024, "gaussians": 1024 * 1024 * len(calls)}

    probe = MemoryProbe(map_bytes)
    for t in range(300):
        probe.sample(float(t))
    s = probe.summary()
    assert len(s["series"]["t"]) == MAX_SAMPLES and s["series"]["t"][-1] == 299.0
    assert s["map_mb_peak"] == pytest.approx(301.0) and s["series"]["map_mb"][-1] == pytest.approx(301.0)
    assert s["map_bytes_final"] == {"occupancy": 1024 * 1024, "gaussians": 300 * 1024 * 1024}
    assert s["peak_rss_mb"] >= max(s["series"]["rss_mb"]) - 0.01
    assert s["gpu_allocated_mb_peak"] is None     # no CUDA here
    thin = _thin([(float(i), float(i % 7), None, None, None) for i in range(10)], 3)
    assert thin == {"t": [2.0, 5.0, 9.0], "rss_mb": [2.0, 5.0, 6.0]}


def test_a_failing_memory_hook_is_reported_not_raised():
    probe = MemoryProbe(lambda: 1 / 0)
    probe.sample(0.0)
    assert probe.summary()["map_error"] == "ZeroDivisionError: division by zero"


# ------------------------------------------------------------------ command line
@pytest.mark.parametrize("args,message", [
    (["trials", "--workers", "0"], "error: --workers must be >= 1, got 0"),
    (["trials", "--address", "auto"], "error: --address only applies to --executor ray"),
    (["trials", "--record", "-1"], "error: --record must be >= 0"),
    (["report", "/nonexistent/run"], "error: run folder '/nonexistent/run' does not exist"),
    (["view", "/nonexistent/x.rrd"], "error: recording '/nonexistent/x.rrd' does not exist"),
])
def test_cli_errors_are_one_line(args, message, capsys):
    from tools.cli import main

    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(message), err


def test_report_on_an_empty_run_folder_says_so(tmp_path, capsys):
    from tools.cli import main

    (tmp_path / "empty").mkdir()
    assert main(["report", str(tmp_path / "empty")]) == 2
    assert "has no finished episodes (episodes.jsonl missing or empty)" in capsys.readouterr().err


def test_view_prints_how_to_view_without_a_display(tmp_path, capsys, monkeypatch):
    from tools.cli import main

    f = tmp_path / "ep.rrd"
    f.write_bytes(b"RRF2" + b"\0" * 996)           # the header rerun-sdk 0.41 writes, then anything
    monkeypatch.setenv("CI", "true")
    assert main(["view", str(f)]) == 0
    out = capsys.readouterr().out
    assert "no viewer can be shown here" in out and f"rerun {f.name}" in out and "--web-viewer" in out
    (tmp_path / "x.txt").write_text("x")
    assert main(["view", str(tmp_path / "x.txt")]) == 2


def test_a_repair_killed_before_its_rename_does_not_copy_the_damaged_lines_again(tmp_path, monkeypatch):
    """(QA 2026-12-04) quarantine() appends the damaged lines to episodes.damaged.jsonl, then
    renames the cleaned episodes.jsonl into place; a resume killed between the two left the lines
    in both files, and every later repair appended them again (3 copies after 2 kills)."""
    from tasks import run_folder

    path = tmp_path / "episodes.jsonl"
    torn = b'{"episode_id": "smoke-00002", "succ'
    path.write_bytes(b"#not a record\n" + torn)
    side = tmp_path / run_folder.DAMAGED_FILE
    real_write = run_folder.write_bytes_atomic

    def killed(*_args, **_kwargs):
        raise KeyboardInterrupt("killed at the rename")

    monkeypatch.setattr(run_folder, "write_bytes_atomic", killed)
    for _ in range(2):                                  # two resumes killed at the same place
        with pytest.raises(KeyboardInterrupt):
            run_folder.quarantine(path, run_folder.scan_results(path))
    monkeypatch.setattr(run_folder, "write_bytes_atomic", real_write)
    run_folder.quarantine(path, run_folder.scan_results(path))
    assert side.read_bytes() == b"#not a record\n" + torn + b"\n"
    assert path.read_bytes() == b""
    # a later, different damage is still appended after it
    path.write_bytes(b"#garbage\n")
    run_folder.quarantine(path, run_folder.scan_results(path))
    assert side.read_bytes() == b"#not a record\n" + torn + b"\n#garbage\n"


def test_a_write_error_names_the_file(tmp_path, monkeypatch):
    """(QA 2026-12-04) A full disk while a record or a summary was written said only "error:
    [Errno 28] No space left on device"; the error now carries the file's name, which the CLI's
    one error line prints."""
    import errno

    from tasks import run_folder

    real_fsync = os.fsync

    def full(_fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(run_folder.os, "fsync", full)
    with pytest.raises(OSError) as info:
        run_folder.append_result(tmp_path / "episodes.jsonl", {"episode_id": "smoke-00000"})
    assert info.value.errno == errno.ENOSPC and info.value.filename == str(tmp_path / "episodes.jsonl")
    with pytest.raises(OSError) as info:
        run_folder.write_bytes_atomic(tmp_path / "summary.json", b"{}")
    assert info.value.filename == str(tmp_path / "summary.json.tmp")
    monkeypatch.setattr(run_folder.os, "fsync", real_fsync)


def test_a_records_error_compares_by_its_first_line_and_keeps_paths_relative():
    """(determinism audit 2026-12-05) An agent's error kept its traceback with absolute paths:
    `tools unchanged` (a commit's code in another folder) and a clone elsewhere called identical
    records different. The trace now names files relative to the checkout, and records compare
    by the error's first line (the exception and its message), not where in the code it was."""
    from tasks.runner import _ROOT, _portable
    from tasks.trial_config import deterministic_view

    trace = f'Traceback (most recent call last):\n  File "{_ROOT}helios/search/gaze_points.py", line 9, in f\n'
    assert _portable(trace) == 'Traceback (most recent call last):\n  File "helios/search/gaze_points.py", line 9, in f\n'
    a = {"episode_id": "x", "error": "error: boom\n  File \"a.py\", line 1", "wall_time": 1.0}
    b = {"episode_id": "x", "error": "error: boom\n  File \"b.py\", line 7", "wall_time": 2.0}
    assert deterministic_view(a) == deterministic_view(b) == {"episode_id": "x", "error": "error: boom"}
    assert deterministic_view({**b, "error": "error: bang\nsame"}) != deterministic_view(a)
    assert deterministic_view({"episode_id": "x", "error": None}) == {"episode_id": "x", "error": None}


def test_an_episode_file_has_one_spelling_however_it_is_named(tmp_path, monkeypatch):
    """``tasks.trial_config.canonical_episodes_file``: relative to the working directory when the
    file lies under it, absolute otherwise, also from a working directory reached through a link."""
    from tasks.trial_config import canonical_episodes_file, same_episodes_file

    (tmp_path / "proj" / "splits").mkdir(parents=True)
    (tmp_path / "link").symlink_to(tmp_path / "proj")
    monkeypatch.chdir(tmp_path / "proj")
    for name in ("splits/x.jsonl", "./splits/x.jsonl", "splits/../splits/x.jsonl",
                 str(tmp_path / "proj/splits/x.jsonl"), str(tmp_path / "link/splits/x.jsonl")):
        assert canonical_episodes_file(name) == "splits/x.jsonl", name
    assert canonical_episodes_file("../other/x.jsonl") == str(tmp_path / "other" / "x.jsonl")
    assert canonical_episodes_file("") == ""
    assert same_episodes_file("splits/x.jsonl", str(tmp_path / "proj/splits/x.jsonl"))
    assert not same_episodes_file("splits/x.jsonl", "x.jsonl") and not same_episodes_file("", "x.jsonl")
