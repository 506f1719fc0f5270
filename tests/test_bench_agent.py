"""``tools bench agent``: the before/after report, the profiled phases and the worker protocol
(timings themselves are never asserted)."""

import cProfile
import json
from pathlib import Path

import numpy as np
import pytest

from tools import bench_agent
from tools.bench_agent_worker import PROFILE_PHASES, _profile_phases
from tools.cli import CliError


def _run(label, walls, sims, replan_ms):
    episodes = [{"episode": f"val-{i:05d}", "wall": w, "sim": s, "success": False, "plans": 3, "peak_rss_mb": 500.0,
                 "phases": {"simulator (HAL commands)": w / 4, "agent: map update": w / 2,
                            "scene build and judge": 1.0}} for i, (w, s) in enumerate(zip(walls, sims))]
    replans = [{"map": "home map", "times_ms": replan_ms, "ok": len(replan_ms)}]
    return {"label": label, "episodes": episodes, "replans": replans, **bench_agent._summary(episodes, replans)}


def test_report_puts_before_and_after_side_by_side_with_ratios_and_projection():
    before = _run("3f77267", [10.0, 20.0, 4.0], [600.0, 600.0, 139.0], [50.0, 300.0, 60.0])
    after = _run("this checkout", [5.0, 10.0, 2.0], [600.0, 600.0, 139.0], [20.0, 60.0, 25.0])
    text = bench_agent.format_report(after, before, "helios")
    assert "before: 3f77267" in text
    median_line = next(line for line in text.splitlines() if line.startswith("median"))
    assert "10.0" in median_line and "5.0" in median_line and "2.00x" in median_line
    assert "same simulated time and outcome on every episode: yes" in text
    per_sim = next(line for line in text.splitlines() if line.startswith("wall ms per simulated s"))
    assert per_sim.split()[-3:] == [f"{1e3 * 34 / 1339:.1f}", f"{1e3 * 17 / 1339:.1f}", "2.00x"]
    # the projection: 10 runs x 1000 episodes x mean(wall + scene build) / 2 workers
    hours = 10 * 1000 * np.mean([6.0, 11.0, 3.0]) / 2 / 3600
    assert f"{hours:10.1f}" in next(line for line in text.splitlines() if line.startswith("hours"))
    changed = _run("this checkout", [5.0, 10.0, 2.0], [600.0, 480.0, 139.0], [20.0])
    assert "NO (behaviour differs)" in bench_agent.format_report(changed, before, "helios")
    for e in before["episodes"]:
        e["task"] = "home 1|Move the cup"
    for e in changed["episodes"]:
        e["task"] = "home 2|Move the cup"                 # a baseline with its own splits
    assert "are other episodes" in bench_agent.format_report(changed, before, "helios")
    alone = bench_agent.format_report(after, None, "helios")
    assert "before" not in alone.split("\n", 2)[1] and "ratio" not in alone
    assert "hand-camera" not in alone                      # runs that did not time the camera


def test_the_report_nests_the_hand_cameras_share_under_the_simulator():
    before = _run("3f77267", [10.0, 20.0], [600.0, 600.0], [50.0])
    after = _run("this checkout", [5.0, 10.0], [600.0, 600.0], [20.0])
    for e, (seconds, frames) in zip(after["episodes"], ((1.2, 80), (1.8, 120))):
        e["camera"] = {"seconds": seconds, "frames": frames}
    lines = bench_agent.format_report(after, before, "helios").splitlines()
    share = next(line for line in lines if "of which hand-camera frames" in line)
    assert share.split()[-1] == "1.50" and " - " in f" {share} "      # mean s; the baseline did not time it
    assert next(line for line in lines if "frames per episode" in line).split()[-1] == "100"
    assert next(line for line in lines if "ms per hand-camera frame" in line).split()[-1] == "15.0"
    assert lines.index(share) == 1 + next(i for i, line in enumerate(lines) if line.startswith("simulator"))


def test_the_report_names_the_cpu_code_paths_and_flags_a_baseline_on_other_ones():
    after = {**_run("this checkout", [5.0], [600.0], [20.0]), "cpu": "x86-64-v3, numpy X86_V3"}
    assert "CPU code paths: x86-64-v3, numpy X86_V3" in bench_agent.format_report(after, None, "helios")
    same = {**_run("3f77267", [6.0], [600.0], [20.0]), "cpu": "x86-64-v3, numpy X86_V3"}
    text = bench_agent.format_report(after, same, "helios")
    assert "CPU code paths: x86-64-v3, numpy X86_V3" in text and "OTHER" not in text
    other = {**same, "cpu": "native (HELIOS_CPU=native), numpy AVX512_ICL"}
    assert ("the baseline ran on OTHER code paths (native (HELIOS_CPU=native), numpy AVX512_ICL)"
            in bench_agent.format_report(after, other, "helios"))
    unknown = _run("old.json", [6.0], [600.0], [20.0])        # saved before runs said
    assert "the baseline does not say which it ran on" in bench_agent.format_report(after, unknown, "helios")


def test_saved_results_are_a_baseline_and_foreign_files_are_refused(tmp_path):
    after = _run("x", [5.0], [600.0], [20.0])
    saved = tmp_path / "bench.json"
    saved.write_text(json.dumps({"format": bench_agent.SAVE_FORMAT, **after}))
    label, commit, data = bench_agent._check_baseline(str(saved))
    assert commit is None and data["median_wall"] == 5.0
    (tmp_path / "other.json").write_text(json.dumps({"median_wall": 1}))
    with pytest.raises(CliError, match="not a file written by"):
        bench_agent._check_baseline(str(tmp_path / "other.json"))


def test_profiled_phases_add_up_the_planner_pieces():
    from helios.maps.grid import GridGeometry
    from helios.planning import FMMPlanner
    from robots.hal import SE2Pose

    geometry = GridGeometry(0.025, 400, -5.0, -5.0)
    obstacle = np.zeros(geometry.shape, dtype=bool)
    obstacle[190:210, 100:300] = True
    explored = np.ones(geometry.shape, dtype=bool)
    profiler = cProfile.Profile()
    profiler.enable()
    FMMPlanner().plan(geometry, obstacle, explored, SE2Pose(-2.0, -2.0, 0.0), np.array([2.0, 2.5]),
                      max_height=np.zeros(geometry.shape, np.float32))
    profiler.disable()
    phases, top = _profile_phases(profiler)
    assert set(phases) == {name for name, _ in PROFILE_PHASES}
    assert phases["planning: all"] > 0 and phases["planning: FMM solve"] > 0
    assert phases["planning: footprint checks"] > 0
    assert phases["planning: all"] >= phases["planning: FMM solve"]
    assert phases["simulator: camera rendering"] == 0.0
    assert top and all(isinstance(t, float) and ":" in name for t, name in top)


def test_profiled_map_phases_split_the_update_into_its_layers():
    """The whole map update is one phase and its occupancy, value and Gaussian layers three more
    (an earlier version booked the whole update as "occupancy and value layers")."""
    from helios.config import HeliosConfig
    from helios.maps.hierarchical import HierarchicalMap
    from helios.perception.detection import Detection
    from helios.schema import with_overrides
    from robots.hal import Observation
    from robots.transforms import look_at_camera
    from sim.synthetic_boxes import Box, pinhole, render_boxes

    cam, pose = pinhole(160, 120), look_at_camera([0.0, 0.0, 1.0], [3.0, 0.0, 0.6])
    rgb, depth, hit = render_boxes([Box((-1.0, -3.0, -0.02), (6.0, 3.0, 0.0), "floor"),
                                    Box((2.9, -0.1, 0.5), (3.1, 0.1, 0.7), "cup")], cam, pose)
    obs = Observation(rgb=rgb, depth=depth, intrinsics=cam, T_world_cam=pose, T_world_body=np.eye(4), stamp=0.0)
    hmap = HierarchicalMap(with_overrides(HeliosConfig(), ["occupancy.grid_size=400"]), ["cup", "table"], ["table"])
    profiler = cProfile.Profile()
    profiler.enable()
    for _ in range(3):
        hmap.update(obs, [Detection(hit == 1, "cup", 0.9)], {"table": 0.3})
    profiler.disable()
    phases, _ = _profile_phases(profiler)
    layers = [phases["map: occupancy layer"], phases["map: value layers"], phases["map: Gaussian update (all)"]]
    assert all(t > 0 for t in layers)
    assert phases["map: update (all layers)"] >= sum(layers)
    assert "map: occupancy and value layers" not in phases


def test_a_worker_answers_in_turn_and_a_silent_one_is_one_error(tmp_path, monkeypatch):
    worker = bench_agent._WorkerProcess(bench_agent.ROOT, "helios", False, "this checkout")
    try:
        answer = worker.ask({"replans": 2, "seed": 0}, 60.0, "plan")
        assert answer == {"replans": []}          # no episode has built a map yet
    finally:
        worker.close()
    assert worker.proc.poll() is not None
    silent = tmp_path / "silent.py"
    silent.write_text("import time\ntime.sleep(60)\n")
    monkeypatch.setattr(bench_agent, "WORKER", silent)
    with pytest.raises(CliError, match="did not start up within 1 s"):
        bench_agent._WorkerProcess(bench_agent.ROOT, "helios", False, "silent", start_timeout=1.0)


def test_physics_stepping_is_booked_even_though_the_client_hook_makes_the_call():
    """PyBullet's stepSimulation runs inside World's client hook, where cProfile books it as the
    hook's own time; the phase counts World.step, so the time shows up."""
    from sim.world import World

    world = World()
    try:
        world.client.createMultiBody(baseMass=1.0, baseCollisionShapeIndex=world.client.createCollisionShape(
            world.client.GEOM_SPHERE, radius=0.1), basePosition=[0, 0, 1.0])
        profiler = cProfile.Profile()
        profiler.enable()
        world.step(200)
        profiler.disable()
    finally:
        world.close()
    phases, _ = _profile_phases(profiler)
    assert phases["simulator: physics stepping"] > 0.0
    assert phases["planning: all"] == 0.0


def test_repeats_keep_the_quickest_run_and_say_when_runs_disagree():
    runs = [{"episode": "val-00000", "wall": w, "sim": 600.0, "success": False, "phases": {"x": w}} for w in (9.0, 7.5, 8.0)]
    best = bench_agent.least_wall(runs)
    assert best["wall"] == 7.5 and best["phases"] == {"x": 7.5} and best["repeats"] == 3 and best["repeats_agree"]
    assert not bench_agent.least_wall(runs + [{**runs[0], "wall": 1.0, "sim": 480.0}])["repeats_agree"]
    after = _run("this checkout", [5.0, 10.0], [600.0, 600.0], [20.0])
    for e in after["episodes"]:
        e.update(repeats=3, repeats_agree=True)
    text = bench_agent.format_report(after, None, "helios")
    assert "wall seconds (the least of 3 runs of each episode)" in text and "NOT DETERMINISTIC" not in text
    after["episodes"][1]["repeats_agree"] = False
    assert "NOT DETERMINISTIC: the repeated runs of val-00001" in bench_agent.format_report(after, None, "helios")


def test_repeats_out_of_range_are_refused_before_any_episode_runs(capsys):
    from tools.cli import main

    assert main(["bench", "agent", "--agent-repeats", "0"]) == 2
    assert "--agent-repeats must be within 1..20, got 0" in capsys.readouterr().err


def test_a_repeated_episode_adds_no_second_replan_map():
    """Replans run on the maps of the first two *different* episodes: with ``--agent-repeats`` the
    second run of an episode must not stand in for another home. (val-00010 at its trial seed: a
    74 s success, 3 s of wall time; val-00001 at its own seed took 13 s.)"""
    from tools.bench_agent_worker import _Worker

    worker = _Worker("helios", 1, False)
    (request,) = bench_agent.episode_requests("0", 11)[10:]
    first = worker.episode(10, request["seed"], request["episode_id"])
    again = worker.episode(10, request["seed"], request["episode_id"])
    assert (first["sim"], first["success"]) == (again["sim"], again["success"])
    assert len(worker.maps) == 1
    # every observation is one hand-camera render, timed inside the simulator's HAL time
    assert first["camera"]["frames"] == again["camera"]["frames"] > 10
    assert 0 < first["camera"]["seconds"] < first["phases"]["simulator (HAL commands)"]


def test_the_bench_times_the_tables_episodes_with_their_trial_seeds(monkeypatch):
    """By default an episode gets the agent seed ``tools trials --seed 0`` gives it, so the bench
    times the very episodes of the tables: same simulated time, outcome and end as the record.
    With ``--agent-seed own`` the perception and the runner get the episode's own seed instead."""
    from tasks.episodes import load_split
    from tasks.trial_config import TrialConfig, episode_seed
    from tasks.trials import run_one
    from tools.bench_agent_worker import _Worker

    requests = bench_agent.episode_requests("0", 2)
    episodes = load_split("val")
    assert requests[1] == {"episode": 1, "episode_id": episodes[1].episode_id,
                           "seed": episode_seed(0, episodes[1].episode_id)}
    assert bench_agent.episode_requests("own", 2) == [{"episode": 0}, {"episode": 1}]
    assert bench_agent.episode_requests("7", 1)[0]["seed"] == episode_seed(7, episodes[0].episode_id) != requests[0]["seed"]
    worker = _Worker("helios", 1, False)
    (ten,) = bench_agent.episode_requests("0", 11)[10:]      # val-00010: a short episode at its trial seed
    timed = worker.episode(10, ten["seed"], ten["episode_id"])
    record = run_one(TrialConfig(agent="helios", split="val", episodes=11), episodes[10])
    assert timed["seed"] == record["seed"] == ten["seed"]
    assert (timed["sim"], timed["success"]) == (record["sim_time"], record["success"])
    # The episode's own seed: another course. Its first 20 s show the seeds it was given (the whole
    # course took 17 s of test time: 439 s of robot time against the trial seed's 74 s).
    import sim.perception as sim_perception
    import tasks.runner as runner

    seen = {}
    real_perception, real_run = sim_perception.make_sim_perception, runner.run_sim_episode

    def perception(*args, seed, **kwargs):
        seen["perception"] = seed
        return real_perception(*args, seed=seed, **kwargs)

    def first_seconds(make, episode, seed=None):
        result = real_run(make, episode, runner.RunnerConfig(max_sim_time=20.0), seed=seed)
        seen["runner"] = result.seed
        return result

    monkeypatch.setattr(sim_perception, "make_sim_perception", perception)
    monkeypatch.setattr(runner, "run_sim_episode", first_seconds)
    own = worker.episode(10)
    assert own["seed"] is None and own["sim"] < 30.0
    assert seen == {"perception": episodes[10].seed, "runner": episodes[10].seed} and episodes[10].seed != ten["seed"]
    with pytest.raises(ValueError, match="splits differ"):
        worker.episode(1, 5, "val-09999")


@pytest.mark.parametrize("seed", ["-1", "x", str(2 ** 32)])
def test_a_bad_agent_seed_is_refused_before_any_episode_runs(capsys, seed):
    from tools.cli import main

    assert main(["bench", "agent", "--agent-seed", seed]) == 2
    assert f"--agent-seed must be a master seed within 0..{2 ** 32 - 1} or 'own', got {seed!r}" in capsys.readouterr().err


def test_the_report_names_the_workload_and_flags_a_baseline_with_other_seeds():
    before = _run("saved", [10.0, 20.0], [600.0, 600.0], [50.0])          # a file saved before the seeds
    after = _run("this checkout", [5.0, 10.0], [400.0, 600.0], [20.0])
    after["agent_seed"] = "0"
    for i, e in enumerate(after["episodes"]):
        e["seed"] = 100 + i
    text = bench_agent.format_report(after, before, "helios")
    assert "episodes: the trial seeds of master seed 0, as `tools trials --seed 0` runs them" in text
    assert "the baseline's episodes: each episode's own seed (not the tables' episodes): OTHER WORKLOADS" in text
    assert "are other episodes (its own splits or seeds)" in text
    same = {**before, "agent_seed": "0", "episodes": [dict(e, seed=100 + i) for i, e in enumerate(before["episodes"])]}
    text = bench_agent.format_report(after, same, "helios")
    assert "OTHER WORKLOADS" not in text and "are other episodes" not in text


def _root_commit() -> str:
    """This checkout's first commit (it has no tasks/runner.py); skips where git is not usable."""
    import subprocess

    try:
        done = subprocess.run(["git", "rev-list", "--max-parents=0", "HEAD"], capture_output=True, text=True,
                              timeout=30, cwd=Path(bench_agent.__file__).parents[1])
    except (OSError, subprocess.TimeoutExpired) as exc:
        pytest.skip(f"git is not usable here ({exc})")
    if done.returncode != 0 or not done.stdout.strip():
        pytest.skip("this checkout has no git history")
    return done.stdout.split()[-1]


@pytest.mark.parametrize("option, fragment", [
    (["--agent-repeats", "0"], "--agent-repeats must be within 1..20, got 0"),
    (["--agent-seed", "banana"], "--agent-seed must be a master seed"),
    (["--agent-set", "foo=1"], "--agent-set 'foo=1': give KEY=VALUE"),
    (["--agent-save", "/nonexistent-helios-dir/x.json"], "does not exist"),
    (["--agent-baseline", "{empty}"], "not a readable JSON file"),
    # a commit from before tasks/runner.py was found only after `git archive`, inside the agent suite
    (["--agent-baseline", "{root}"], "has no tasks/runner.py: too old to bench"),
])
def test_agent_options_are_checked_before_the_first_suite_runs(option, fragment, tmp_path, monkeypatch, capsys):
    """``bench scenes agent --agent-repeats 0`` once ran the whole scenes suite before refusing."""
    from tools import bench_scenes
    from tools.cli import main

    (tmp_path / "empty.json").write_text("")
    ran = []
    monkeypatch.setattr(bench_scenes, "run", lambda args: ran.append("scenes") or "")
    if "{root}" in option:
        option = [o.replace("{root}", _root_commit()) for o in option]
    option = [o.replace("{empty}", str(tmp_path / "empty.json")) for o in option]
    assert main(["bench", "scenes", "agent", "--quick", *option]) == 2
    err = capsys.readouterr().err
    assert fragment in err and len(err.splitlines()) == 1
    assert ran == [], "the scenes suite ran before the agent suite's options were checked"


def test_options_of_a_suite_not_selected_are_refused_not_ignored(capsys):
    from tools import bench
    from tools.cli import build_parser, main, parse_arguments

    assert main(["bench", "scenes", "--quick", "--agent-repeats", "0", "--agent-seed", "banana"]) == 2
    assert capsys.readouterr().err.strip() == \
        "error: --agent-repeats applies to the 'agent' suite, which is not selected"
    owned = bench.suite_options()
    # the message names the flag by its dest: every suite option is --<suite>-..., of its suite
    assert all(dest.startswith(suite + "_") for dest, (suite, _) in owned.items())
    assert {suite for suite, _ in owned.values()} == {"agent", "maps", "trials"}
    # an option at its default changes nothing, so it is no reason to refuse
    args = parse_arguments(build_parser(), ["bench", "sim", "--agent-name", "helios", "--maps-device", "cpu"])
    bench._check_unselected(args)


def test_quick_only_changes_the_defaults_an_explicit_count_wins():
    import argparse

    from tools.bench_trials import episode_count

    def ns(quick, episodes=None, replans=None):
        return argparse.Namespace(quick=quick, agent_episodes=episodes, agent_replans=replans,
                                  trials_episodes=episodes)

    assert bench_agent.episode_counts(ns(False)) == (6, 40)
    assert bench_agent.episode_counts(ns(True)) == (2, 10)
    assert bench_agent.episode_counts(ns(True, 5, 7)) == (5, 7)
    assert (episode_count(ns(False)), episode_count(ns(True)), episode_count(ns(True, 5))) == (12, 3, 5)


def test_bench_trials_with_no_more_episodes_than_workers_prints_no_steady_rate(monkeypatch):
    """`bench trials --trials-episodes 1` (or as many episodes as workers) has no episode after every
    worker's first: its steady rate is "-", not a ValueError from round(nan) after the whole run."""
    import argparse

    import tasks.trials
    from tools import bench_trials

    def fake_batch(config, episodes, out, workers, on_episode):
        records = [{"episode_id": e.episode_id, "success": True, "wall_time": 0.5} for e in episodes]
        for r in records:
            on_episode(r, None, None)
        return records

    monkeypatch.setattr(tasks.trials, "run_batch", fake_batch)
    args = argparse.Namespace(quick=False, trials_episodes=1, trials_agent="oracle", trials_split="smoke",
                              trials_workers="1", seed=0)
    text = bench_trials.run(args)
    row = next(line for line in text.splitlines() if line.split()[:2] == ["1", "1"])
    assert row.split()[4] == "-" and row.split()[-1] == "-"
    assert "identical records across worker counts: yes" in text


def test_a_run_with_agent_set_and_no_baseline_names_its_options():
    """`bench agent --agent-set KEY=VALUE` alone: the numbers are of the agent with that option, and
    the report says so (it printed the label only beside a baseline)."""
    text = bench_agent.format_report(_run("this checkout (agent_config.face_unseen=false)", [5.0], [600.0], [20.0]),
                                     None, "helios")
    assert "after: this checkout (agent_config.face_unseen=false)" in text
    plain = bench_agent.format_report(_run("this checkout", [5.0], [600.0], [20.0]), None, "helios")
    assert "after: " not in plain
