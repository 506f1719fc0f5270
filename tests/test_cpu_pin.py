"""One CPU code path everywhere (helios.runtime): the pin's settings per CPU, that `python -m
tools` and its workers run under it, and that it never half-applies."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest

from helios.runtime import (CPU_ENV_VAR, PIN_VARS, PORTABLE_LEVEL, cpu_dispatch, cpu_flags, cpu_model,
                           cpu_pin_settings)
from tasks.executors import cpu_pin_environment
from tasks.trial_config import TrialConfig

ROOT = Path(__file__).resolve().parents[1]
AVX512 = {"avx", "avx2", "fma", "avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl"}
AVX2 = {"avx", "avx2", "fma"}
HERE = cpu_flags()
X86_AVX2 = platform.machine().lower() in ("x86_64", "amd64") and {"avx2", "fma"} <= HERE


def test_an_avx512_cpu_is_pinned_to_avx2_kernels_in_every_library():
    env, what = cpu_pin_settings(AVX512, {}, "x86_64", numpy_2_4=True)
    assert what == PORTABLE_LEVEL == "x86-64-v3"
    assert env == {"OPENBLAS_CORETYPE": "Haswell", "ATEN_CPU_CAPABILITY": "avx2", "MKL_CBWR": "AVX2",
                   "ONEDNN_MAX_CPU_ISA": "AVX2", "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
                   "OPENCV_CPU_DISABLE": "AVX512-SKX"}
    assert set(env) <= set(PIN_VARS)
    # NumPy before 2.4 names its AVX-512 targets differently; disabling one does not disable the others
    old, _ = cpu_pin_settings(AVX512, {}, "x86_64", numpy_2_4=False)
    assert old["NPY_DISABLE_CPU_FEATURES"] == "AVX512F AVX512_SKX AVX512_ICL AVX512_SPR"


def test_exclusions_already_in_the_environment_are_kept():
    env, _ = cpu_pin_settings(AVX512, {"NPY_DISABLE_CPU_FEATURES": "AVX512_SPR,X86_V3",
                                       "OPENCV_CPU_DISABLE": "AVX2"}, "x86_64")
    assert env["NPY_DISABLE_CPU_FEATURES"] == "AVX512_SPR X86_V3 X86_V4 AVX512_ICL"
    assert env["OPENCV_CPU_DISABLE"] == "AVX2,AVX512-SKX"


def test_an_avx2_cpu_needs_no_exclusions_and_older_or_other_cpus_are_left_alone():
    env, what = cpu_pin_settings(AVX2, {}, "x86_64")
    assert what == PORTABLE_LEVEL and "NPY_DISABLE_CPU_FEATURES" not in env and "OPENCV_CPU_DISABLE" not in env
    assert env["ATEN_CPU_CAPABILITY"] == "avx2" and env["OPENBLAS_CORETYPE"] == "Haswell"
    # the level's kernels would crash without AVX2/FMA: such CPUs keep their own paths, and say so
    env, what = cpu_pin_settings({"avx", "sse4_2"}, {}, "x86_64")
    assert env == {} and what.startswith("native") and "AVX2" in what
    env, what = cpu_pin_settings(set(), {}, "aarch64")
    assert env == {} and "aarch64" in what


def test_opting_out_and_conflicts():
    env, what = cpu_pin_settings(AVX512, {CPU_ENV_VAR: "native"}, "x86_64")
    assert env == {} and what == f"native ({CPU_ENV_VAR}=native)"
    env, what = cpu_pin_settings(AVX512, {"NPY_ENABLE_CPU_FEATURES": "X86_V4"}, "x86_64")
    assert env == {} and "NPY_ENABLE_CPU_FEATURES" in what       # NumPy refuses enable and disable together
    with pytest.raises(ValueError, match=f"{CPU_ENV_VAR} must be x86-64-v3 or native"):
        cpu_pin_settings(AVX512, {CPU_ENV_VAR: "avx512"}, "x86_64")


def test_cpu_flags_reads_the_flags_line():
    text = "processor\t: 0\nvendor_id\t: GenuineIntel\nflags\t\t: fpu sse2 avx2 fma avx512f\nbugs\t: x\n"
    assert cpu_flags(text) == {"fpu", "sse2", "avx2", "fma", "avx512f"}
    assert cpu_flags("no flags here") == set()


def test_cpu_model_reads_the_model_name_line():
    """The reference records name the CPU they were made on by this line (tests/test_reference_records.py)."""
    text = "processor\t: 0\nmodel name\t:  AMD EPYC   9R14 96-Core Processor\nflags\t: fpu\n"
    assert cpu_model(text) == "AMD EPYC 9R14 96-Core Processor"
    assert cpu_model("no model here") == "unknown"
    assert cpu_model() and "\n" not in cpu_model()


def _fresh_python(code: str, **extra) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in (*PIN_VARS, CPU_ENV_VAR)}
    env.update(extra)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT,
                          env=env)


PROBE = ("import json, tools, numpy, torch, cv2; from helios.runtime import cpu_dispatch; "
         "print(json.dumps(cpu_dispatch()))")


@pytest.mark.skipif(not X86_AVX2, reason="the pin applies to x86-64 CPUs with AVX2 and FMA only")
def test_importing_tools_pins_numpy_torch_and_opencv_before_they_load():
    proc = _fresh_python(PROBE)
    assert proc.returncode == 0, proc.stderr[-2000:]
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got["pin"] == PORTABLE_LEVEL
    assert got["numpy"] in ("X86_V3", "baseline") and got["torch"] == "AVX2"
    assert "AVX512-SKX" not in got["opencv"].replace("AVX512-SKX?", "")   # '?' marks a disabled feature
    assert "OPENCV:" not in proc.stderr            # no warning about features the CPU lacks


@pytest.mark.skipif(not {"avx512f", "avx512bw", "avx512dq", "avx512vl"} <= HERE,
                    reason="needs an AVX-512 CPU to see the native paths differ from the pinned ones")
def test_native_opt_out_takes_the_avx512_kernels():
    proc = _fresh_python(PROBE, **{CPU_ENV_VAR: "native"})
    assert proc.returncode == 0, proc.stderr[-2000:]
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got["pin"] == f"native ({CPU_ENV_VAR}=native)"
    assert got["torch"] == "AVX512" and got["numpy"] not in ("X86_V3", "baseline")


@pytest.mark.skipif(not X86_AVX2, reason="the pin applies to x86-64 CPUs with AVX2 and FMA only")
def test_a_pin_after_numpy_loaded_changes_nothing_and_says_so():
    proc = _fresh_python("import os, numpy; from helios.runtime import pin_cpu_dispatch, PIN_VARS; "
                         "print(pin_cpu_dispatch()); print(sorted(k for k in PIN_VARS if k in os.environ))")
    assert proc.returncode == 0, proc.stderr[-2000:]
    what, env = proc.stdout.strip().splitlines()[-2:]
    assert what == "native (numpy imported before the pin)" and env == "[]"


def test_this_test_process_and_ray_workers_share_the_pin(monkeypatch):
    """conftest pins before NumPy loads; Ray workers, which do not inherit the driver's
    environment, are given the same variables (tests/test_trials_batch.py runs them)."""
    if X86_AVX2:
        assert cpu_dispatch()["pin"] == PORTABLE_LEVEL
    monkeypatch.setenv("ATEN_CPU_CAPABILITY", "avx2")
    monkeypatch.setenv(CPU_ENV_VAR, "x86-64-v3")
    monkeypatch.setenv("UNRELATED_VAR", "1")
    got = cpu_pin_environment()
    assert got["ATEN_CPU_CAPABILITY"] == "avx2" and got[CPU_ENV_VAR] == "x86-64-v3" and "UNRELATED_VAR" not in got


# ------------------------------------------------------------------------------------------------
# Run folders say which code paths their episodes ran on
# ------------------------------------------------------------------------------------------------
PINNED = {"pin": "x86-64-v3", "numpy": "X86_V3", "opencv": "SSE *AVX2 *AVX512-SKX?"}
NATIVE = {"pin": "native (HELIOS_CPU=native)", "numpy": "AVX512_ICL", "torch": "AVX512"}


def _invocations(folder: Path, *cpus) -> None:
    lines = []
    for cpu in cpus:
        entry = {"episodes_to_run": 3, "git_commit": "abc"}
        if cpu is not None:
            entry["cpu"] = cpu
        lines.append(json.dumps(entry))
    lines.append('{"episodes_to_run": 2, "cpu": {"pin": "torn')          # a torn last line is ignored
    (folder / "invocations.jsonl").write_text("\n".join(lines) + "\n")


def test_run_cpu_paths_lists_the_distinct_code_paths_in_order(tmp_path):
    from tasks.run_folder import invocation_cpu, run_cpu_paths

    assert run_cpu_paths(tmp_path) == []
    _invocations(tmp_path, None, PINNED, PINNED, NATIVE)
    assert run_cpu_paths(tmp_path) == ["not recorded", "x86-64-v3, numpy X86_V3",
                                       "native (HELIOS_CPU=native), numpy AVX512_ICL, torch AVX512"]
    assert invocation_cpu({"cpu": cpu_dispatch()}).startswith(cpu_dispatch()["pin"])


def test_the_report_shows_each_runs_code_paths_and_warns_when_they_differ(tmp_path):
    from tests.test_report import _make_run
    from tools.report import make_report

    a = _make_run(tmp_path / "a", [(5, None), (0, "not_found")])
    b = _make_run(tmp_path / "b", [(0, "not_found"), (5, None)])
    _invocations(a, PINNED)
    _invocations(b, PINNED)
    result = make_report([a, b], tmp_path / "rep", episode_pages=False)
    assert "CPU code paths" in result["text"] and result["text"].count("x86-64-v3, numpy X86_V3") == 2
    assert not [w for w in result["warnings"] if "different CPU code paths" in w]
    assert any("invocations.jsonl:2: damaged line" in w for w in result["warnings"])   # _invocations' torn line
    _invocations(b, NATIVE)                           # the same experiment on another machine's fast paths
    result = make_report([a, b], tmp_path / "rep", episode_pages=False)
    assert any("runs compared ran on different CPU code paths" in w and "b: native (HELIOS_CPU=native)" in w
               for w in result["warnings"])
    _invocations(a, PINNED, NATIVE)                   # one folder resumed on other paths
    result = make_report([a], tmp_path / "rep", episode_pages=False)
    assert any(f"{a}: its episodes ran on 2 different CPU code paths" in w for w in result["warnings"])
    assert "x86-64-v3, numpy X86_V3 | native (HELIOS_CPU=native)" in result["text"]


def test_a_resume_on_other_code_paths_is_reported(tmp_path):
    from helios.schema import with_overrides
    from tasks.episodes import load_split
    from tasks.trials import BatchReport, run_batch

    config = with_overrides(TrialConfig(episodes=2), ["runner.max_sim_time=5"])
    run_batch(config, load_split("smoke")[:1], tmp_path)
    entry = json.loads((tmp_path / "invocations.jsonl").read_text().splitlines()[-1])
    assert entry["cpu"] == cpu_dispatch()
    report = BatchReport([])
    run_batch(config, load_split("smoke")[:2], tmp_path, report=report)
    assert report.cpu_changed is None and report.ran == 1             # same machine, same paths
    (tmp_path / "invocations.jsonl").write_text(json.dumps({"episodes_to_run": 1, "cpu": NATIVE}) + "\n")
    report = BatchReport([])
    run_batch(config, load_split("smoke")[:3], tmp_path, report=report)
    assert report.cpu_changed == "native (HELIOS_CPU=native), numpy AVX512_ICL, torch AVX512"


def test_a_bad_helios_cpu_is_one_error_line_for_every_command(monkeypatch, tmp_path):
    """HELIOS_CPU is read when `tools` is imported (before NumPy loads); a value that is neither
    x86-64-v3 nor native used to raise a ValueError traceback there, for every command, --help too.
    Now every command ends with one `error:` line naming the variable, exit status 2, before any work."""
    proc = _fresh_python("import runpy, sys; sys.argv = ['tools', 'trials', '--help']; "
                         "runpy.run_module('tools', run_name='__main__')", **{CPU_ENV_VAR: "bogus"})
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert proc.stderr.splitlines() == [f"error: {CPU_ENV_VAR} must be x86-64-v3 or native (or unset), got 'bogus'"]
    assert proc.stdout == ""

    from cli_helpers import run_cli

    monkeypatch.setenv(CPU_ENV_VAR, "avx512")
    rc, out, err = run_cli(["trials", "--episodes", "1", "--out", str(tmp_path / "run")])
    assert rc == 2 and err.splitlines() == [f"error: {CPU_ENV_VAR} must be x86-64-v3 or native (or unset), "
                                            f"got 'avx512'"]
    assert not (tmp_path / "run").exists()


def test_an_invocation_logged_after_a_torn_line_is_kept_and_the_torn_line_is_named(tmp_path):
    """A kill mid-write leaves a torn last line; the next invocation starts a line of its own (it
    was glued to the torn one and lost), and the report names the torn line."""
    from tasks.run_folder import append_result, read_invocations, run_cpu_paths
    from tools.report_runs import invocations_problem

    path = tmp_path / "invocations.jsonl"
    append_result(path, {"episodes_to_run": 1, "cpu": PINNED})
    with path.open("ab") as fh:
        fh.write(b'{"episodes_to_run": 2, "cpu": {"pin": "to')
    append_result(path, {"episodes_to_run": 3, "cpu": NATIVE})
    lines = path.read_text().splitlines()
    assert len(lines) == 3 and json.loads(lines[2])["episodes_to_run"] == 3
    assert read_invocations(tmp_path)[1] == [2]
    assert len(run_cpu_paths(tmp_path)) == 2
    problem = invocations_problem(tmp_path)
    assert problem.startswith(f"{path}:2: damaged line") and "\n" not in problem
    path.write_text(lines[0] + "\n")
    assert invocations_problem(tmp_path) is None
