"""Trial batches at scale: identical numbers for the same seed whatever the workers, the executor
(in-process, local processes, Ray), resumption after SIGKILL at random moments, or recording."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

from cli_helpers import run_cli
from helios.runtime import cpu_dispatch
from helios.schema import with_overrides
from tasks.episodes import load_split
from tasks.run_folder import read_results
from tasks.trial_config import NONDETERMINISTIC_FIELDS, TrialConfig, deterministic_view
from tasks.trials import run_batch, run_one

# Short episodes for the oracle: smoke-00000 succeeds within the limit, smoke-00001 runs out of time (mixed outcomes).
SHORT = ["runner.max_sim_time=45"]
N = 3
ROOT = Path(__file__).resolve().parents[1]


def _config(seed: int = 0) -> TrialConfig:
    return with_overrides(TrialConfig(agent="oracle", split="smoke", episodes=N, seed=seed), SHORT)


def _views(records) -> dict[str, dict]:
    return {r["episode_id"]: deterministic_view(r) for r in (records.values() if isinstance(records, dict) else records)}


def _file_views(out: Path) -> list[dict]:
    lines = (out / "episodes.jsonl").read_text().splitlines()
    return [deterministic_view(json.loads(line)) for line in lines]


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """An uninterrupted in-process batch (the numbers every other way of running must reproduce)."""
    out = tmp_path_factory.mktemp("reference") / "run"
    run_batch(_config(), load_split("smoke")[:N], out)
    return out


def test_reference_batch_has_mixed_outcomes_and_complete_records(reference):
    records = read_results(reference / "episodes.jsonl")
    assert list(records) == [f"smoke-0000{i}" for i in range(N)]
    outcomes = [r["success"] for r in records.values()]
    assert True in outcomes and False in outcomes, outcomes
    for r in records.values():
        mem = r["memory"]
        assert 50 < mem["peak_rss_mb"] < 8000
        series = mem["series"]
        assert len(series["t"]) == len(series["rss_mb"]) <= 64 and series["t"] == sorted(series["t"])
        assert max(series["rss_mb"]) <= mem["peak_rss_mb"] + 0.01
        assert mem["map_mb_peak"] is None          # the oracle keeps no map
    summary = json.loads((reference / "summary.json").read_text())
    assert summary["complete"] and summary["episodes"] == N
    assert summary["memory"]["peak_rss_mb"]["max"] > 50
    assert set(NONDETERMINISTIC_FIELDS) == {"wall_time", "memory", "recording"}


def test_same_seed_same_numbers_and_the_seed_matters():
    ep = load_split("smoke")[0]                                         # the oracle picks within 25 s
    config = with_overrides(_config(), ["runner.max_sim_time=25"])     # walk, look, grasp: physics included
    a, b = run_one(config, ep), run_one(config, ep)
    assert a["metrics"]["pick"] and a["commands"] > 5
    assert deterministic_view(a) == deterministic_view(b)
    assert a["metrics"]["object_final"] == b["metrics"]["object_final"]     # bit-identical physics
    c = run_one(with_overrides(config, ["seed=1"]), ep)
    assert c["seed"] != a["seed"]


def _children(pid: int) -> list[int]:
    """Child processes, without multiprocessing's resource tracker (it lives as long as its parent)."""
    out = []
    try:
        for p in psutil.Process(pid).children(recursive=True):
            try:
                if "resource_tracker" not in " ".join(p.cmdline()):
                    out.append(p.pid)
            except psutil.Error:
                pass
    except psutil.NoSuchProcess:
        pass
    return out


def _gone(pids, timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not any(psutil.pid_exists(p) and psutil.Process(p).status() != psutil.STATUS_ZOMBIE for p in pids):
            return True
        time.sleep(0.1)
    return False


def test_two_workers_give_the_same_records_as_one_and_leave_no_process(reference, tmp_path):
    out = tmp_path / "w2"
    records = run_batch(_config(), load_split("smoke")[:N], out, workers=2, record=1)
    assert _views(records) == _views(read_results(reference / "episodes.jsonl"))
    assert sorted(v["episode_id"] for v in _file_views(out)) == [f"smoke-0000{i}" for i in range(N)]
    # the recording of the first episode came back from its worker into the run folder
    rec = read_results(out / "episodes.jsonl")["smoke-00000"]["recording"]
    assert rec == {"path": "recordings/smoke-00000.rrd", "errors": []}
    assert (out / rec["path"]).stat().st_size > 100_000
    assert not list((out / "recordings").glob("*.tmp"))
    assert _gone(_children(os.getpid())), "trial workers outlived their batch"


def test_ray_local_instance_gives_the_same_records(reference, tmp_path):
    pytest.importorskip("ray")
    out = tmp_path / "ray"
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    proc = subprocess.run([sys.executable, "-m", "tools", "trials", "--episodes", str(N), "--workers", "2",
                           "--executor", "ray", "--address", "local", "--out", str(out), *SHORT],
                          capture_output=True, text=True, timeout=300, cwd=ROOT, env=env)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "on Ray (local)" in proc.stdout
    assert _views(read_results(out / "episodes.jsonl")) == _views(read_results(reference / "episodes.jsonl"))
    inv = [json.loads(l) for l in (out / "invocations.jsonl").read_text().splitlines()]
    assert inv[-1]["executor"] == "ray" and inv[-1]["workers"] == 2
    assert inv[-1]["cpu"]["pin"] == cpu_dispatch()["pin"]      # the CPU code paths it ran under


def _trials_cmd(out: Path, workers: int, n: int = N) -> list[str]:
    return [sys.executable, "-m", "tools", "trials", "--episodes", str(n), "--workers", str(workers),
            "--out", str(out), "--progress", "lines", *SHORT]


def _kill_and_resume(out: Path, workers: int, kills: int, seed: int, n: int = N) -> list[tuple[float, int]]:
    """Start the CLI, SIGKILL it at a random moment (only the parent: its workers must follow), several
    times; then run it to the end. Returns (kill time, finished episodes at the kill)."""
    rng = np.random.default_rng(seed)
    log = []
    for _ in range(kills):
        proc = subprocess.Popen(_trials_cmd(out, workers, n), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                cwd=ROOT)
        delay = float(rng.uniform(0.3, 4.5))
        t0 = time.monotonic()
        children: set[int] = set()
        while time.monotonic() - t0 < delay and proc.poll() is None:
            children.update(_children(proc.pid))
            time.sleep(0.05)
        if proc.poll() is None:
            children.update(_children(proc.pid))
            os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
        proc.stderr.close()
        assert _gone(children), f"worker processes outlived their killed parent: {children}"
        log.append((round(delay, 2), len(read_results(out / "episodes.jsonl"))))
    proc = subprocess.run(_trials_cmd(out, workers, n), capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return log


def test_sigkill_at_random_moments_then_resume_matches_an_uninterrupted_run(reference, tmp_path):
    out = tmp_path / "killed"
    log = _kill_and_resume(out, workers=2, kills=3, seed=7)
    lines = (out / "episodes.jsonl").read_text().splitlines()
    ids = [json.loads(l)["episode_id"] for l in lines]
    assert sorted(ids) == [f"smoke-0000{i}" for i in range(N)], (ids, log)     # nothing lost, nothing twice
    assert _views(read_results(out / "episodes.jsonl")) == _views(read_results(reference / "episodes.jsonl")), log
    assert json.loads((out / "summary.json").read_text())["complete"]


@pytest.mark.slow
def test_many_sigkills_with_one_worker_give_the_same_file_line_by_line(tmp_path):
    n = 4
    config = with_overrides(TrialConfig(agent="oracle", split="smoke", episodes=n), SHORT)
    ref = tmp_path / "ref"
    run_batch(config, load_split("smoke")[:n], ref)
    out = tmp_path / "killed"
    log = _kill_and_resume(out, workers=1, kills=6, seed=11, n=n)
    assert _file_views(out) == _file_views(ref), log       # one worker: same lines in the same order


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGHUP"])
def test_sigterm_and_sighup_stop_a_batch_like_ctrl_c_with_its_message(tmp_path, sig):
    """They once killed the batch without a word (the records were safe); now they take Ctrl-C's
    path: workers stopped, the message saying how to continue, exit 128 + the signal's number."""
    out = tmp_path / "run"
    proc = subprocess.Popen(_trials_cmd(out, 2), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            cwd=ROOT)
    deadline = time.monotonic() + 120
    children: set[int] = set()
    while not read_results(out / "episodes.jsonl"):      # one episode finished: the workers are busy
        assert time.monotonic() < deadline and proc.poll() is None, "the batch did not get going"
        children.update(_children(proc.pid))
        time.sleep(0.05)
    children.update(_children(proc.pid))
    proc.send_signal(getattr(signal, sig))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + getattr(signal, sig), err[-2000:]
    assert f"interrupted ({sig}); finished episodes are saved in" in err and "Traceback" not in err, err[-2000:]
    assert _gone(children), f"worker processes outlived the stopped batch: {children}"
    done = len(read_results(out / "episodes.jsonl"))
    proc = subprocess.run(_trials_cmd(out, 2), capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    ids = [json.loads(line)["episode_id"] for line in (out / "episodes.jsonl").read_text().splitlines()]
    assert sorted(ids) == [f"smoke-0000{i}" for i in range(N)] and done >= 1   # nothing lost, nothing twice


def test_a_sigterm_while_the_summary_prints_says_the_batch_had_finished(reference, tmp_path, monkeypatch):
    """The handler once ended with the batch, so a SIGTERM that came while the table printed killed
    the process without a word (exit 143, the run complete); now it takes the interrupt's path and
    says the results are all there."""
    import shutil

    import tools.trials

    out = tmp_path / "run"
    shutil.copytree(reference, out)               # finished: the batch only resumes, then prints
    printed = tools.trials._print_summary

    def terminated_while_printing(*args):
        os.kill(os.getpid(), signal.SIGTERM)      # a real signal, through the command's own handler
        return printed(*args)

    monkeypatch.setattr(tools.trials, "_print_summary", terminated_while_printing)
    before = signal.getsignal(signal.SIGTERM)
    rc, stdout, err = run_cli(["trials", "--agent", "oracle", "--split", "smoke", "--episodes", str(N),
                               "--out", str(out), "--progress", "none", *SHORT])
    assert signal.getsignal(signal.SIGTERM) == before         # the handler is put back
    assert rc == 128 + signal.SIGTERM, err
    assert f"resuming: {N} of {N}" in stdout and "Traceback" not in err
    assert re.fullmatch(r"interrupted \(SIGTERM\) after the batch finished, while printing its summary; results "
                        r"in .*summary\.json and .*episodes\.jsonl\n", err), err
    assert json.loads((out / "summary.json").read_text())["complete"]


@pytest.mark.parametrize("delay", [0.02, 0.05])
def test_ctrl_c_while_a_worker_process_starts_prints_no_traceback_of_the_worker(tmp_path, delay):
    """(reliability audit 2026-12-05) Ctrl-C reaches the whole process group; a worker still
    importing and unpickling its code (before its loop ignores SIGINT) printed a KeyboardInterrupt
    traceback, or 'Fatal Python error: init_import_site', above the batch's line (4 of 4 tries at
    the first spawn). Workers now start with SIGINT blocked until they ignore it."""
    proc = subprocess.Popen(_trials_cmd(tmp_path / "run", 2), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, cwd=ROOT, start_new_session=True)
    deadline = time.monotonic() + 60
    while True:
        assert time.monotonic() < deadline and proc.poll() is None, "no worker process started"
        starting = [c for c in psutil.Process(proc.pid).children()
                    if any("spawn_main" in part for part in _cmdline(c))]
        if starting:
            break
        time.sleep(0.005)
    time.sleep(delay)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err[-2000:]
    assert "Traceback" not in err and "Fatal Python error" not in err and "Exception ignored" not in err, err[-2000:]
    assert err.strip().splitlines()[-1].startswith("interrupted; finished episodes are saved in"), err[-2000:]


def _cmdline(process) -> list[str]:
    try:
        return process.cmdline()
    except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
        return []


def test_a_second_batch_on_the_same_folder_is_refused_while_the_first_runs(tmp_path):
    out = tmp_path / "busy"
    proc = subprocess.Popen(_trials_cmd(out, 1, 1), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT)
    try:
        deadline = time.monotonic() + 30
        while not (out / ".lock").exists() or not (out / ".lock").read_text():
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.05)
        from tasks.run_folder import RunFolderError

        with pytest.raises(RunFolderError, match=r"is in use by pid \d+"):
            run_batch(with_overrides(TrialConfig(episodes=1), SHORT), load_split("smoke")[:1], out)
        rc, stdout, err = run_cli(_trials_cmd(out, 1, 1)[3:])    # the CLI: refused before it says anything
        assert rc == 2 and stdout == "" and re.fullmatch(r"error: run folder .* is in use by pid \d+ .*\n", err), \
            (stdout, err)
    finally:
        proc.kill()
        proc.wait(timeout=30)
