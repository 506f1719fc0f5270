"""Runner limits and error handling; trial batch files (append + fsync, resume, torn lines);
the oracle end to end on smoke episodes; the trials/episodes command lines."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from cli_helpers import run_cli
from tasks.episodes import load_split
from tasks.registry import UnknownAgentError, make_agent
from tasks.run_folder import prepare_run_folder, read_results, RunFolderError
from tasks.runner import RunnerConfig, run_sim_episode
from tasks.trial_config import TrialConfig, episode_seed
from tasks.trials import run_batch


class _Looper:
    name = "looper"

    def reset(self, task, rng):
        self.rng = rng

    def act(self, robot):
        robot.observe()
        return False


class _Crasher:
    name = "crasher"

    def reset(self, task, rng):
        pass

    def act(self, robot):
        raise ZeroDivisionError("agent bug")


def test_command_budget_stops_an_endless_agent():
    ep = load_split("smoke")[0]
    result = run_sim_episode(lambda sim: _Looper(), ep, RunnerConfig(max_commands=5))
    assert result.limit_hit and result.commands == 5
    assert result.metrics.failure_reason in ("timeout", "not_found")


def test_an_agent_exception_is_recorded_not_raised():
    ep = load_split("smoke")[0]
    result = run_sim_episode(lambda sim: _Crasher(), ep)
    assert result.error.startswith("ZeroDivisionError: agent bug")
    assert result.metrics is not None and not result.success


def test_unknown_agent_lists_valid_ones():
    with pytest.raises(UnknownAgentError, match=r"unknown agent 'helio'; valid agents: (\S+, )*oracle\b"):
        make_agent("helio", None)


def test_episode_seeds_are_stable_and_distinct():
    assert episode_seed(0, "val-00001") == episode_seed(0, "val-00001")
    assert len({episode_seed(0, f"val-{i:05d}") for i in range(200)}) == 200
    assert episode_seed(1, "val-00001") != episode_seed(0, "val-00001")


def test_oracle_completes_smoke_episodes_and_batches_resume(tmp_path):
    episodes = load_split("smoke")[:2]
    cfg = TrialConfig(agent="oracle", split="smoke", episodes=2)
    out = tmp_path / "run"
    first = run_batch(cfg, episodes[:1], out)
    assert len(first) == 1 and first[0]["metrics"]["success"], first[0]
    lines = (out / "episodes.jsonl").read_text().splitlines()
    # a kill in the middle of writing the second line leaves a torn line: resume repairs and continues
    with (out / "episodes.jsonl").open("a") as fh:
        fh.write('{"episode_id": "smoke-00001", "trunc')
    records = run_batch(cfg, episodes, out)
    final = (out / "episodes.jsonl").read_text().splitlines()
    assert final[0] == lines[0] and len(final) == 2
    assert [json.loads(l)["episode_id"] for l in final] == [e.episode_id for e in episodes]
    assert all(r["metrics"]["success"] for r in records)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["episodes"] == 2 and summary["SR"]["percent"] == 100.0
    # re-running a finished batch runs nothing and changes nothing
    run_batch(cfg, episodes, out)
    assert (out / "episodes.jsonl").read_text().splitlines() == final


def test_a_run_folder_refuses_a_different_config(tmp_path):
    from tasks.run_folder import append_result
    from tasks.trial_config import FINGERPRINT_FIELD, config_fingerprint

    prepare_run_folder(tmp_path, TrialConfig(seed=0))
    record = {"episode_id": "smoke-00000", "metrics": None, "sim_time": 1.0, "wall_time": 1.0,
              FINGERPRINT_FIELD: config_fingerprint(TrialConfig(seed=0))}
    append_result(tmp_path / "episodes.jsonl", record)
    with pytest.raises(RunFolderError, match="different configuration .*seed"):
        prepare_run_folder(tmp_path, TrialConfig(seed=1))
    assert list(read_results(tmp_path / "episodes.jsonl")) == ["smoke-00000"]


def test_a_run_folder_without_results_takes_a_new_config(tmp_path):
    from tasks.run_folder import read_run_config

    prepare_run_folder(tmp_path, TrialConfig(seed=0))
    prepare_run_folder(tmp_path, TrialConfig(seed=1))     # e.g. a corrected command after a failed set-up
    assert read_run_config(tmp_path)[1] == TrialConfig(seed=1)


def test_a_run_can_be_extended_to_more_episodes_but_not_shortened(tmp_path):
    from tasks.run_folder import read_run_config

    episodes = load_split("smoke")[:2]
    first = run_batch(TrialConfig(agent="oracle", split="smoke", episodes=1), episodes[:1], tmp_path)
    extended = run_batch(TrialConfig(agent="oracle", split="smoke", episodes=2), episodes, tmp_path)
    assert read_run_config(tmp_path)[1].episodes == 2
    assert [r["episode_id"] for r in extended] == [e.episode_id for e in episodes]
    assert extended[0] == first[0]          # the finished episode was kept, not re-run
    fresh = run_batch(TrialConfig(agent="oracle", split="smoke", episodes=2), episodes, tmp_path / "fresh")
    strip = lambda r: {k: v for k, v in r.items() if k not in ("wall_time", "memory")}
    assert [strip(r) for r in extended] == [strip(r) for r in fresh]
    with pytest.raises(RunFolderError, match="extended but not shortened"):
        prepare_run_folder(tmp_path, TrialConfig(agent="oracle", split="smoke", episodes=1))
    with pytest.raises(RunFolderError, match="differs in: episodes, seed"):
        prepare_run_folder(tmp_path, TrialConfig(agent="oracle", split="smoke", episodes=3, seed=1))


def test_an_extension_stopped_before_its_first_new_episode_can_go_back_to_the_shorter_run(tmp_path):
    """`--episodes 12` on a finished 4-episode run, Ctrl-C before a new episode finished, once left
    config.yaml at 12 and refused the original `--episodes 4` command for good."""
    from tasks.run_folder import read_run_config

    episodes = load_split("smoke")[:3]
    first = run_batch(TrialConfig(agent="oracle", split="smoke", episodes=1), episodes[:1], tmp_path)
    prepare_run_folder(tmp_path, TrialConfig(agent="oracle", split="smoke", episodes=3))   # the stopped extension
    assert read_run_config(tmp_path)[1].episodes == 3
    ids = [e.episode_id for e in episodes]
    done = prepare_run_folder(tmp_path, TrialConfig(agent="oracle", split="smoke", episodes=1), episode_ids=ids[:1])
    assert read_run_config(tmp_path)[1].episodes == 1 and done == {ids[0]: first[0]}
    again = run_batch(TrialConfig(agent="oracle", split="smoke", episodes=1), episodes[:1], tmp_path)
    assert again == first                          # resumed, nothing re-run or lost
    run_batch(TrialConfig(agent="oracle", split="smoke", episodes=2), episodes[:2], tmp_path)
    with pytest.raises(RunFolderError, match="extended but not shortened"):   # a finished episode lies beyond 1
        prepare_run_folder(tmp_path, TrialConfig(agent="oracle", split="smoke", episodes=1), episode_ids=ids[:1])


def test_a_resume_refuses_episodes_that_changed_under_the_same_episode_file_name(tmp_path, monkeypatch):
    """A relative --episodes-file run again from another directory (or a regenerated file) once
    mixed two files' episodes in one folder under one fingerprint: the name is in the config, the
    contents are not. The finished records' tasks are now checked against the episodes."""
    smoke = load_split("smoke")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "eps.jsonl").write_text(smoke[0].to_json() + "\n" + smoke[2].to_json() + "\n")
    out = tmp_path / "run"
    rc, _, err = run_cli(["trials", "--agent", "oracle", "--episodes-file", "eps.jsonl", "--episodes", "1",
                          "--progress", "none", "--no-pictures", "--out", str(out), "runner.max_commands=3"])
    assert rc == 0, err
    other = json.loads(smoke[1].to_json())
    other["episode_id"] = smoke[0].episode_id              # the same id, another task: another file
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    (tmp_path / "elsewhere" / "eps.jsonl").write_text(json.dumps(other) + "\n" + smoke[2].to_json() + "\n")
    before = (out / "episodes.jsonl").read_bytes(), (out / "config.yaml").read_bytes()
    rc, _, err = run_cli(["trials", "--agent", "oracle", "--episodes-file", "eps.jsonl", "--episodes", "2",
                          "--progress", "none", "--no-pictures", "--out", str(out), "runner.max_commands=3"])
    assert rc == 2 and err.count("\n") == 1, err
    assert f"episode {smoke[0].episode_id} was run as {smoke[0].task!r}" in err and "the episodes changed" in err
    assert ((out / "episodes.jsonl").read_bytes(), (out / "config.yaml").read_bytes()) == before
    monkeypatch.chdir(tmp_path)                            # the file the run was made with: it extends
    rc, _, err = run_cli(["trials", "--agent", "oracle", "--episodes-file", "eps.jsonl", "--episodes", "2",
                          "--progress", "none", "--no-pictures", "--out", str(out), "runner.max_commands=3"])
    assert rc == 0, err
    assert [r for r in read_results(out / "episodes.jsonl")] == [smoke[0].episode_id, smoke[2].episode_id]


def test_a_resume_refuses_an_episode_edited_under_the_same_task(tmp_path, monkeypatch):
    """(reliability audit 2026-12-05) An episode whose start pose was moved 0.3 m, its task kept,
    resumed into a mix: the record made from the old pose stood beside a new run's, and the
    finished run differed from a fresh one. The run folder now keeps each episode's digest."""
    from tasks.run_folder import DIGESTS_FILE

    smoke = load_split("smoke")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "eps.jsonl").write_text(smoke[0].to_json() + "\n" + smoke[2].to_json() + "\n")
    out = tmp_path / "run"
    args = ["trials", "--agent", "oracle", "--episodes-file", "eps.jsonl", "--progress", "none", "--no-pictures",
            "--out", str(out), "runner.max_commands=3"]
    rc, _, err = run_cli([*args, "--episodes", "1"])
    assert rc == 0, err
    assert json.loads((out / DIGESTS_FILE).read_text())[smoke[0].episode_id]
    moved = json.loads(smoke[0].to_json())
    moved["robot_start"][0] += 0.3                          # the same task, another start pose
    (tmp_path / "eps.jsonl").write_text(json.dumps(moved) + "\n" + smoke[2].to_json() + "\n")
    before = (out / "episodes.jsonl").read_bytes()
    rc, _, err = run_cli([*args, "--episodes", "2"])
    assert rc == 2 and err.count("\n") == 1, err
    assert f"episode {smoke[0].episode_id} changed since it was run (same task" in err
    assert (out / "episodes.jsonl").read_bytes() == before
    (tmp_path / "eps.jsonl").write_text(smoke[0].to_json() + "\n" + smoke[2].to_json() + "\n")
    rc, _, err = run_cli([*args, "--episodes", "2"])        # the file the run was made with: it extends
    assert rc == 0, err
    assert set(json.loads((out / DIGESTS_FILE).read_text())) == {smoke[0].episode_id, smoke[2].episode_id}


def test_an_episode_file_named_relative_or_absolute_is_one_configuration(tmp_path, monkeypatch):
    """(reliability audit 2026-12-06) ``--episodes-file splits/x.jsonl`` and the same file as
    ``/abs/.../splits/x.jsonl`` gave two configuration fingerprints: a run resumed or extended with
    the other spelling was refused as a different configuration, and two runs of one file compared
    as different. The file now has one spelling (relative to the working directory)."""
    from tasks.trial_config import FINGERPRINT_FIELD

    smoke = load_split("smoke")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "splits").mkdir()
    (tmp_path / "splits" / "x.jsonl").write_text(smoke[0].to_json() + "\n" + smoke[1].to_json() + "\n")
    spellings = ["splits/x.jsonl", str(tmp_path / "splits" / "x.jsonl"), "./splits/../splits/x.jsonl"]
    common = ["trials", "--agent", "oracle", "--progress", "none", "--no-pictures", "runner.max_commands=3"]
    for i, name in enumerate(spellings):
        rc, _, err = run_cli([*common, "--episodes-file", name, "--episodes", "1", "--out", f"run{i}"])
        assert rc == 0, err
        assert "episodes_file: splits/x.jsonl\n" in (tmp_path / f"run{i}" / "config.yaml").read_text()
    fps = {r[FINGERPRINT_FIELD] for i in range(3)
           for r in read_results(tmp_path / f"run{i}" / "episodes.jsonl").values()}
    assert len(fps) == 1, fps
    # extended with another spelling: resumed, not refused
    rc, out, err = run_cli([*common, "--episodes-file", spellings[1], "--episodes", "2", "--out", "run0"])
    assert rc == 0 and "resuming: 1 of 2" in out, out + err
    assert {r[FINGERPRINT_FIELD] for r in read_results(tmp_path / "run0" / "episodes.jsonl").values()} == fps
    rc, out, err = run_cli(["diff", "run0", "run1", "--common"])
    assert rc == 0 and "configurations: the same" in out, out + err
    # a file outside the working directory is named by its absolute path
    (tmp_path / "sub").mkdir()
    monkeypatch.chdir(tmp_path / "sub")
    rc, _, err = run_cli([*common, "--episodes-file", "../splits/x.jsonl", "--episodes", "1", "--out", "run3"])
    assert rc == 0, err
    saved = (tmp_path / "sub" / "run3" / "config.yaml").read_text()
    assert f"episodes_file: {tmp_path / 'splits' / 'x.jsonl'}\n" in saved


def test_a_run_folder_made_with_an_absolute_episode_file_resumes_with_the_relative_name(tmp_path, monkeypatch):
    """A run folder written before episode files had one spelling holds the file as it was named
    (here absolute, as ``tools trials --episodes-file /abs/x.jsonl`` wrote it). Named relative now,
    it resumes and extends: config.yaml keeps its spelling and the new records its fingerprint."""
    from tasks.trial_config import FINGERPRINT_FIELD, config_fingerprint

    smoke = load_split("smoke")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "x.jsonl").write_text(smoke[0].to_json() + "\n" + smoke[1].to_json() + "\n")
    old = TrialConfig(agent="oracle", episodes_file=str(tmp_path / "x.jsonl"), episodes=1,
                      runner=RunnerConfig(max_commands=3))
    out = tmp_path / "run"
    run_batch(old, smoke[:1], out, pictures=False)         # the folder as the old command line made it
    rc, text, err = run_cli(["trials", "--agent", "oracle", "--episodes-file", "x.jsonl", "--episodes", "2",
                             "--progress", "none", "--no-pictures", "--out", str(out), "runner.max_commands=3"])
    assert rc == 0 and "resuming: 1 of 2" in text, text + err
    assert f"episodes_file: {tmp_path / 'x.jsonl'}\n" in (out / "config.yaml").read_text()
    records = read_results(out / "episodes.jsonl")
    assert list(records) == [smoke[0].episode_id, smoke[1].episode_id]
    assert {r[FINGERPRINT_FIELD] for r in records.values()} == {config_fingerprint(old)}
    # and another file of the same name elsewhere is still another configuration
    (tmp_path / "other").mkdir()
    monkeypatch.chdir(tmp_path / "other")
    (tmp_path / "other" / "x.jsonl").write_text(smoke[0].to_json() + "\n" + smoke[1].to_json() + "\n")
    rc, _, err = run_cli(["trials", "--agent", "oracle", "--episodes-file", "x.jsonl", "--episodes", "2",
                          "--progress", "none", "--no-pictures", "--out", str(out), "runner.max_commands=3"])
    assert rc == 2 and "different configuration (differs in: episodes_file)" in err, err


@pytest.mark.slow
def test_oracle_reaches_90_percent_on_the_smoke_split(tmp_path):
    records = run_batch(TrialConfig(agent="oracle", split="smoke", episodes=20), load_split("smoke"), tmp_path)
    sr = sum(r["metrics"]["success"] for r in records) / len(records)
    assert sr >= 0.9
    for r in records:   # failures are physical, each with a reason
        assert r["error"] is None
        assert r["metrics"]["success"] or r["metrics"]["failure_reason"] in ("collision", "fell_off", "pick_failed",
                                                                              "place_failed")


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "tools", *args], capture_output=True, text=True, timeout=600)


@pytest.mark.parametrize("args,message", [
    (["trials", "--agent", "helio"], "error: unknown agent 'helio'; valid agents: "),
    (["trials", "--split", "vall"], "error: unknown split 'vall'; valid splits: smoke, val, train, large"),
    (["trials", "--episodes", "21"], "error: split 'smoke' has 20 episodes, fewer than the 21 requested"),
    (["trials", "runner.max_sim_tme=3"], "error: unknown config key 'runner.max_sim_tme'"),
    (["trials", "--episodes-file", "nope.jsonl"], "error: episode file 'nope.jsonl' does not exist"),
    (["episodes", "generate", "--name", "x", "--seed", "1", "--count", "0", "--out", "/tmp/x.jsonl"],
     "error: --count must be positive, got 0"),
    (["tsdf", "smoke-99999"], "error: no episode 'smoke-99999'"),
])
def test_cli_bad_input_is_one_clear_line(args, message):
    rc, out, err = run_cli(args)          # in-process; the entry point itself: the test below
    assert rc == 2, out + err
    assert err.strip().splitlines()[-1].startswith(message)
    assert "Traceback" not in err


def test_the_entry_point_exits_2_with_one_line_on_bad_input():
    proc = _cli("trials", "--agent", "helio")
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert proc.stderr.strip().splitlines() == [proc.stderr.strip().splitlines()[-1]]
    assert proc.stderr.startswith("error: unknown agent 'helio'; valid agents: ")


def test_cli_trials_and_episodes_commands(tmp_path):
    proc = _cli("trials", "--agent", "oracle", "--split", "smoke", "--episodes", "1", "--out", str(tmp_path / "r"))
    assert proc.returncode == 0, proc.stderr
    assert "| run | FindObj | Pick | FindRec | Place | SR |" in proc.stdout
    assert "1/1 smoke-00000 success" in proc.stdout
    assert (tmp_path / "r" / "config.yaml").read_text().startswith("helios_version:")
    out = tmp_path / "mine.jsonl"
    rc, _, _ = run_cli(["episodes", "generate", "--name", "mine", "--seed", "3", "--count", "2", "--difficulty",
                        "easy", "--out", str(out)])
    assert rc == 0 and len(out.read_text().splitlines()) == 2
    _, stdout, _ = run_cli(["episodes", "check", str(out)])
    assert "2 valid episodes" in stdout


def test_every_command_help_describes_it_in_whole_sentences():
    from tools.cli import COMMANDS, build_parser

    parser = build_parser()
    subparsers = next(a for a in parser._actions if a.dest == "command").choices
    assert set(subparsers) == set(COMMANDS)
    for name, p in subparsers.items():
        assert p.description and p.description.rstrip().endswith((".", ")")), (name, p.description)
        assert "\n" not in p.description


def _folder_with_one_record(out, config):
    from tasks.run_folder import append_result
    from tasks.trial_config import FINGERPRINT_FIELD, config_fingerprint

    prepare_run_folder(out, config)
    append_result(out / "episodes.jsonl", {"episode_id": "smoke-00000", "metrics": None, "sim_time": 1.0,
                                           "wall_time": 1.0, FINGERPRINT_FIELD: config_fingerprint(config)})


def test_stale_results_name_a_different_configuration_or_commit_and_nothing_else(tmp_path):
    from tasks.provenance import git_commit
    from tasks.run_folder import stale_results

    cfg = TrialConfig(agent="oracle", split="smoke", episodes=2)
    assert stale_results(tmp_path / "none", cfg) is None                   # no folder
    prepare_run_folder(tmp_path / "empty", cfg)
    assert stale_results(tmp_path / "empty", TrialConfig(seed=5)) is None  # no results: it takes any config
    out = tmp_path / "run"
    _folder_with_one_record(out, cfg)
    here = git_commit()
    assert stale_results(out, cfg, commit=here) is None                    # a resume
    assert stale_results(out, TrialConfig(agent="oracle", split="smoke", episodes=5), commit=here) is None  # an extension
    assert stale_results(out, TrialConfig(agent="oracle", split="smoke", episodes=1), commit=here) == \
        "results of a different configuration (differs in: episodes)"    # shortening is a difference
    assert stale_results(out, TrialConfig(agent="helios", split="smoke", episodes=2, seed=3), commit=here) == \
        "results of a different configuration (differs in: agent, seed)"
    if here != "unknown":
        assert stale_results(out, cfg, commit="0" * 40) == \
            f"results of commit {here[:10]} (this checkout is 0000000000)"
    # config.yaml damaged or missing: the records' fingerprints decide (reliability audit: another
    # configuration's folder was refused, not moved aside, by --replace-stale and so by `make run`)
    (out / "config.yaml").write_text("[1, 2]\n")
    assert stale_results(out, cfg, commit=here) is None                    # this configuration's: a resume
    assert stale_results(out, TrialConfig(seed=9), commit=here).startswith(
        "results of a different configuration (config.yaml unreadable; the records' fingerprint is")
    (out / "config.yaml").unlink()
    assert stale_results(out, cfg, commit=here) is None
    assert "config.yaml missing" in stale_results(out, TrialConfig(seed=9), commit=here)


def test_move_aside_keeps_the_folder_under_a_dated_name_and_never_moves_one_in_use(tmp_path):
    from tasks.run_folder import RunFolderError, FolderLock, move_aside

    out = tmp_path / "run"
    _folder_with_one_record(out, TrialConfig())
    kept = (out / "episodes.jsonl").read_bytes()
    first = move_aside(out, stamp="20261202-030000")
    assert first == tmp_path / "run.20261202-030000" and not out.exists()
    assert (first / "episodes.jsonl").read_bytes() == kept
    _folder_with_one_record(out, TrialConfig())
    assert move_aside(out, stamp="20261202-030000") == tmp_path / "run.20261202-030000.2"
    _folder_with_one_record(out, TrialConfig())
    with FolderLock(out):                     # a batch is writing there
        with pytest.raises(RunFolderError, match="in use by pid"):
            move_aside(out)
    assert (out / "episodes.jsonl").is_file()


def test_cli_replace_stale_moves_another_configurations_results_aside_and_runs_afresh(tmp_path):
    out = tmp_path / "r"
    _folder_with_one_record(out, TrialConfig(agent="oracle", split="smoke", episodes=1, seed=7))
    old = (out / "episodes.jsonl").read_text()
    args = ("trials", "--agent", "oracle", "--split", "smoke", "--episodes", "1", "--out", str(out))
    rc, _, err = run_cli([*args])             # without the flag: one clear line, nothing touched
    assert rc == 2 and "different configuration (differs in: seed)" in err
    assert err.rstrip().endswith("use another --out to start a new run, or --replace-stale to move it aside and "
                                 "start a new run in it"), err          # the way out this command has
    rc, out_text, err = run_cli([*args, "--replace-stale"])
    assert rc == 0, err
    moved = [p for p in tmp_path.iterdir() if p.name.startswith("r.")]
    assert len(moved) == 1 and (moved[0] / "episodes.jsonl").read_text() == old
    assert (f"[trials] {out} held results of a different configuration (differs in: seed); "
            f"moved it to {moved[0]} and starting a new run") in out_text
    assert "1/1 smoke-00000 success" in out_text
    assert [r["seed"] for r in read_results(out / "episodes.jsonl").values()] == [episode_seed(0, "smoke-00000")]
    rc, out_text, _ = run_cli([*args, "--replace-stale"])     # the same configuration at the same commit: a resume
    assert rc == 0 and "moved it" not in out_text
    assert len([p for p in tmp_path.iterdir() if p.name.startswith("r.")]) == 1
