"""Bad input the in-process corpus (``test_bad_input_corpus.CASES``) cannot express: environment
variables, a machine without a Ray cluster or a CUDA device, FIFOs. Same promise: exit status 2,
one ``error:`` line, no traceback, nothing written (README "Reliability")."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from cli_helpers import run_cli
from test_bad_input_corpus import TASK, snapshot


def _one_line(argv: list[str], fragment: str, root) -> str:
    before = snapshot(root)
    rc, out, err = run_cli(argv)
    assert rc == 2, (rc, out[-2000:], err[-2000:])
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err[-3000:]
    assert "Traceback" not in out + err
    assert fragment in lines[0], lines[0]
    assert snapshot(root) == before, "a bad input changed the workspace"
    return lines[0]


@pytest.fixture
def no_ray_cluster(monkeypatch):
    pytest.importorskip("ray")
    import ray._private.services as services

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setattr(services, "find_bootstrap_address", lambda temp_dir=None: None)
    monkeypatch.setattr(services, "find_gcs_addresses", lambda: frozenset())


def test_ray_auto_without_a_cluster_is_one_line_before_the_run_folder(no_ray_cluster, tmp_path):
    out = tmp_path / "X"
    _one_line(["trials", "--episodes", "1", "--workers", "1", "--out", str(out), "--executor", "ray",
               "--address", "auto"], "--address auto: no running Ray cluster found", tmp_path)
    assert not out.exists()


def test_ray_auto_takes_ray_address_and_checks_it(no_ray_cluster, tmp_path, monkeypatch):
    out = tmp_path / "X"
    args = ["trials", "--episodes", "1", "--out", str(out), "--executor", "ray", "--address", "auto"]
    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:1")
    _one_line(args, "cannot reach the Ray cluster at 127.0.0.1:1", tmp_path)
    monkeypatch.setenv("RAY_ADDRESS", "not an address")
    _one_line(args, "--address auto takes the address from RAY_ADDRESS", tmp_path)
    assert not out.exists()


@pytest.fixture
def tiny_trajectory(tmp_path_factory):
    from sim.synthetic_boxes import synthetic_frames
    from tools.bench_maps import save_trajectory

    return save_trajectory(tmp_path_factory.mktemp("traj") / "t.npz", synthetic_frames(3, 0),
                           ("cup", "table", "counter"), ("table", "counter"))


def test_a_valid_trajectory_passes_the_check(tiny_trajectory):
    from tools.bench_maps import check_trajectory

    check_trajectory(tiny_trajectory)


@pytest.mark.parametrize("value", ["abc", "-3", "0", "1.5"])
def test_bench_threads_env_is_checked_up_front(value, tiny_trajectory, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("HELIOS_BENCH_THREADS", value)
    _one_line(["bench", "maps", "--quick", "--maps-recording", str(tiny_trajectory)],
              f"HELIOS_BENCH_THREADS={value!r} must be a whole number", tmp_path)


def test_maps_recording_env_is_checked_up_front(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a recording\n")
    monkeypatch.setenv("HELIOS_MAPS_RECORDING", str(bad))
    _one_line(["bench", "maps", "--quick"], "HELIOS_MAPS_RECORDING", tmp_path)
    monkeypatch.setenv("HELIOS_MAPS_RECORDING", str(tmp_path / "nope.npz"))
    _one_line(["bench", "maps", "--quick"], "is not a file", tmp_path)


def test_a_trajectory_with_mismatched_arrays_is_one_line(tiny_trajectory, tmp_path, monkeypatch):
    import numpy as np

    monkeypatch.chdir(tmp_path)
    arrays = dict(np.load(tiny_trajectory))
    np.savez(tmp_path / "short.npz", **{**arrays, "rgb": arrays["rgb"][:1]})
    _one_line(["bench", "maps", "--quick", "--maps-recording", str(tmp_path / "short.npz")],
              "rgb has shape (1, ", tmp_path)


def test_fifos_are_not_regular_files(tmp_path, monkeypatch):
    work, fifos = tmp_path / "work", tmp_path / "fifos"       # the snapshot reads files: not the FIFOs
    work.mkdir()
    fifos.mkdir()
    monkeypatch.chdir(work)
    for name in ("c.yaml", "e.jsonl", "r.rrd"):
        os.mkfifo(fifos / name)                    # reading one would block: refused unread
    _one_line(["trials", "--config", str(fifos / "c.yaml"), "--out", str(work / "run")],
              "is not a regular file", work)
    _one_line(["trials", "--episodes-file", str(fifos / "e.jsonl"), "--out", str(work / "run")],
              "is not a regular file", work)
    _one_line(["episodes", "check", str(fifos / "e.jsonl")], "is not a regular file", work)
    _one_line(["view", "--print", str(fifos / "r.rrd")], "is not a regular file", work)


def test_spot_device_cuda_without_cuda_is_one_line(tmp_path, monkeypatch):
    import torch

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    weights = tmp_path / "w"
    weights.mkdir()
    _one_line(["spot", "10.0.0.3", "--agent", "helios", "--task", TASK, "--detector-weights", str(weights),
               "--scorer-weights", str(weights), "--device", "cuda", "--on-goal", "yes", "--at-rest", "yes",
               "--out", str(tmp_path / "spot")], "--device cuda: no CUDA device here", tmp_path)


def test_episodes_check_accepts_the_shipped_smoke_split(capsys):
    from tools.cli import main

    assert main(["episodes", "check", "tasks/data/smoke.jsonl"]) == 0
    assert "20 valid episodes in 20 homes" in capsys.readouterr().out


def test_episodes_check_counts_one_episode_in_the_singular(capsys, tmp_path):
    from tools.cli import main

    one = tmp_path / "one.jsonl"
    one.write_text(Path("tasks/data/smoke.jsonl").read_text().splitlines()[0] + "\n")
    assert main(["episodes", "check", str(one)]) == 0
    assert f"{one}: 1 valid episode in 1 home\n" in capsys.readouterr().out


def test_overrides_may_stand_among_the_flags_and_later_ones_win():
    from tools.cli import build_parser, parse_arguments

    parser = build_parser()
    args = parse_arguments(parser, ["trials", "runner.max_commands=3", "--out", "X", "--episodes", "2",
                                    "seed=4", "runner.max_commands=5"])
    assert args.overrides == ["runner.max_commands=3", "seed=4", "runner.max_commands=5"]
    assert (args.out, args.episodes) == ("X", 2)
    args = parse_arguments(parser, ["tsdf", "smoke-00001", "--out", "X", "voxel_size=0.02"])
    assert args.overrides == ["voxel_size=0.02"]


@pytest.mark.parametrize("argv, fragment", [
    (["trials", "a=1", "--out", "X", "--bogus"], "unrecognized arguments: --bogus"),
    (["trials", "a=1", "--out", "X", "notanoverride"], "unrecognized arguments: notanoverride"),
    (["diff", "A", "B", "a=1"], "unrecognized arguments: a=1"),       # a command without overrides
])
def test_a_stray_argument_is_still_one_line(argv, fragment, tmp_path):
    _one_line(argv, fragment, tmp_path)


@pytest.mark.parametrize("fault, rc", [("estop", 1), ("lease", 1), ("connect", 2)])
def test_a_robot_fault_during_bring_up_is_exit_1_and_not_reaching_the_robot_is_2(fault, rc, monkeypatch, tmp_path):
    """(QA 2026-12-04) An e-stop at power-on or a lease lost at stand is a robot fault (exit 1, as
    mid-run; it was 2, 'bad input'); a robot that cannot be reached stays bad input (2)."""
    import robots.spot.sdk_backend as sdk
    from robots.hal import EstopError, LeaseLostError

    error = {"estop": EstopError("the robot is e-stopped (hardware e-stop pressed)"),
             "lease": LeaseLostError("another client holds the body lease"),
             "connect": sdk.SpotConnectError("cannot reach 127.0.0.1:1: connection refused")}[fault]

    def fail(*_args, **_kwargs):
        raise error

    monkeypatch.setattr(sdk.SdkSpotBackend, "__init__", fail)
    got, out, err = run_cli(["spot", "--fake", "--task", TASK, "--out", str(tmp_path / "o")])
    assert got == rc, (got, out[-1500:], err[-1500:])
    lines = err.strip().splitlines()
    assert lines and lines[-1].startswith("error: ") and str(error) in lines[-1] and "Traceback" not in err


def test_an_agent_bug_on_the_demo_layout_is_one_line_after_a_full_shutdown(monkeypatch, tmp_path):
    """(QA 2026-12-04) A bug in the agent (not a robot fault) on `spot --fake --task` printed a
    traceback and wrote no outcome; now: the robot is shut down, one error line, exit 1, the
    traceback in session.log, outcome.json says what failed."""
    import json

    import tasks.scripted_demo as demo_agent

    def broken(*_args, **_kwargs):
        raise RuntimeError("mug_pixel exploded")

    monkeypatch.setattr(demo_agent.DemoHints, "mug_pixel", broken)
    rc, out, err = run_cli(["spot", "--fake", "--task", TASK, "--out", str(tmp_path / "o"), "--name", "bug"])
    assert rc == 1, (rc, out[-1500:], err[-1500:])
    assert "Traceback" not in err and "Traceback" not in out
    lines = err.strip().splitlines()
    assert lines[-1].startswith("error: the agent failed (RuntimeError: mug_pixel exploded); the robot was shut down")
    assert "shutting down: stop, stow, sit, power off, return the lease" in out
    run = tmp_path / "o" / "bug"
    assert json.loads((run / "outcome.json").read_text())["agent_error"] == "RuntimeError: mug_pixel exploded"
    log = (run / "session.log").read_text()
    assert "Traceback" in log and "sitting down and powering off" in log and "lease returned" in log


def test_ctrl_c_while_the_command_line_loads_is_one_line_and_130(monkeypatch, capsys):
    """(QA 2026-12-04) A Ctrl-C in the first few tenths of a second, while build_parser() imports
    every command's module, printed a KeyboardInterrupt traceback: it is now the same one line
    ("interrupted", exit 130) as a Ctrl-C during the command."""
    from tools import cli

    def interrupted_import():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted_import)
    assert cli.main(["trials", "--episodes", "1"]) == 130
    err = capsys.readouterr().err
    assert err.strip() == "interrupted" and "Traceback" not in err
