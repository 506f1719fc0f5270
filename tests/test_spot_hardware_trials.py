"""HELIOS with real perception on a robot (here: the fake Spot over TLS), and hardware trial records.

* ``tools spot --fake --episode ID --agent helios --perception real`` with tiny random OWLv2/CLIP
  models saved locally: the SDK's images go through the real adapters into the agent's map, the
  agent acts on them, and the run folder is one ``tools report`` reads.
* ``tools spot HOST --agent helios --task ... --on-goal/--at-rest``: the real-robot path (a fake
  serving an episode's scene stands in for the robot): one record in the schema of simulated
  trials, operator answers, the robot's log, a rerun recording; reported next to a sim run.
* Missing weights, missing operator answers, a folder of another configuration: one line, before
  any robot is touched.
"""

from __future__ import annotations

import io
import json

import pytest

pytest.importorskip("bosdyn.client")
pytest.importorskip("transformers")

from robots.hal import CommandResult, GraspResult, NavigateResult, PlaceResult, Reason, SE2Pose  # noqa: E402
from tasks.episodes import load_split  # noqa: E402
from tasks.hardware import (  # noqa: E402
    HardwareJudge,
    OperatorVerdict,
    apply_verdict,
    ask_operator,
    verdict_from_flags,
    HardwareTrialError,
)
from tiny_models import save_tiny_models  # noqa: E402
from spot_fake_fixtures import TEST_PASSWORD, TEST_USER, credentials_env, session_pki  # noqa: E402

pytestmark = pytest.mark.timeout(120)

EPISODE = "smoke-00001"


@pytest.fixture(scope="module")
def tiny_models(tmp_path_factory):
    return save_tiny_models(tmp_path_factory.mktemp("tiny_models"))


@pytest.fixture(scope="module")
def episode():
    return next(e for e in load_split("smoke") if e.episode_id == EPISODE)


# ------------------------------------------------------------------------------------------ units
def test_hardware_judge_and_operator_verdict_give_the_sim_phases():
    now = iter([0.0, 1.5, 4.0, 9.25, 12.0, 20.0, 30.0])     # the judge's clock: start, then one per command
    judge = HardwareJudge(clock=lambda: next(now))
    judge.after_command("navigate_to", NavigateResult(False, Reason.COLLISION, "blocked", collided=True,
                                                      final_pose=SE2Pose(0, 0, 0)))
    judge.after_command("grasp", GraspResult(False, Reason.GRASP_MISSED, "missed"))
    assert judge.metrics.find_obj and not judge.metrics.pick and judge.metrics.pick_attempts == 1
    judge.after_command("grasp", GraspResult(True, Reason.OK, "ok", holding=True))
    judge.after_command("place", PlaceResult(True, Reason.OK, "released"))
    judge.after_command("place", PlaceResult(True, Reason.OK, "released again"))
    m = judge.finalize(False)
    assert (m.find_obj, m.pick, m.find_rec, m.collisions) == (True, True, True, 1)
    # first committed grasp, first held grasp, first place while holding: seconds from the start
    assert (m.find_obj_time, m.pick_time, m.find_rec_time) == (4.0, 9.25, 12.0)
    assert [e["command"] for e in judge.log] == ["navigate_to", "grasp", "grasp", "place", "place"]
    ok = apply_verdict(m, OperatorVerdict(True, True), judge.released, False)
    assert ok.place and not ok.success and ok.failure_reason == "collision"      # the collision costs SR
    fell = apply_verdict(m, OperatorVerdict(False, True), judge.released, False)
    assert not fell.place and fell.failure_reason == "fell_off"
    clean = HardwareJudge()
    clean.after_command("grasp", GraspResult(True, Reason.OK, "ok", holding=True))
    clean.after_command("place", PlaceResult(True, Reason.OK, "released"))
    assert apply_verdict(clean.finalize(False), OperatorVerdict(True, True), True, False).success
    assert apply_verdict(clean.finalize(False), OperatorVerdict(True, True, 2), True, False).failure_reason == \
        "collision"
    nothing = apply_verdict(HardwareJudge().finalize(True), OperatorVerdict(False, False), False, True)
    assert nothing.failure_reason == "timeout" and not nothing.find_obj
    assert HardwareJudge().after_command("stow_arm", CommandResult(True, Reason.OK)) is None


def test_operator_prompt_repeats_until_answered_and_flags_are_all_or_nothing():
    answers = iter(["maybe", "y", "n", "two", "2"])
    out = io.StringIO()
    v = ask_operator("Move the cup from the stool to the chair", input_fn=lambda q: next(answers), out=out)
    assert v == OperatorVerdict(True, False, 2, source="prompt")
    assert out.getvalue().count("try again") == 2
    assert verdict_from_flags(None, None, None) is None
    assert verdict_from_flags("yes", "no", None) == OperatorVerdict(True, False, 0, source="flags")
    with pytest.raises(HardwareTrialError, match="both --on-goal and --at-rest"):
        verdict_from_flags("yes", None, None)
    with pytest.raises(HardwareTrialError, match="--on-goal must be yes or no"):
        verdict_from_flags("perhaps", "yes", None)


# ------------------------------------------------------------------------------------------ perception
class _Counting:
    def __init__(self, inner):
        self.inner, self.calls, self.shapes = inner, 0, []

    def __call__(self, rgb, *args):
        self.calls += 1
        self.shapes.append(rgb.shape)
        return self.inner(rgb, *args)


def test_sdk_images_flow_through_the_real_adapters_into_the_map_and_the_agent_acts(tiny_models, episode):
    from tasks.fake_sdk import run_fake_sdk_episode
    from tasks.hardware import load_robot_perception
    from tasks.runner import RunnerConfig
    from helios.perception import ModelConfig

    owl, clip = tiny_models
    detector, scorer = load_robot_perception(ModelConfig(detector_weights=str(owl), scorer_weights=str(clip)))
    det, sco = _Counting(detector), _Counting(scorer)
    holder = {}

    def wrap(agent, ep):
        holder["agent"], holder["shape"] = agent, (ep.fake.sim.intrinsics.height, ep.fake.sim.intrinsics.width)
        return agent

    with credentials_env():
        result = run_fake_sdk_episode("helios", episode, seed=0, pki=session_pki(), agent_options={"perception": (det, sco)},
                                      config=RunnerConfig(max_commands=40), wrap_agent=wrap)
    agent = holder["agent"]
    assert det.calls > 0 and sco.calls > 0
    assert set(det.shapes) == {(*holder["shape"], 3)}              # the SDK's hand-camera images
    assert len(agent.map.objects) > 0                              # detections reached the Gaussian map
    assert float(agent.map.values.confidence.max()) > 0            # scores reached the value map
    assert result.commands > det.calls                             # and the agent acted (walked, looked)
    assert result.metrics is not None and result.extra.get("transport") == "sdk-fake"


# ------------------------------------------------------------------------------------------ command line
def _spot(args, capsys):
    from tools.cli import main

    code = main(["spot", *args])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_fake_episode_with_real_perception_writes_a_run_folder_report_reads(tiny_models, tmp_path, capsys):
    owl, clip = tiny_models
    code, out, err = _spot(["--fake", "--episode", EPISODE, "--agent", "helios", "--perception", "real",
                            "--detector-weights", str(owl), "--scorer-weights", str(clip), "--max-time", "8",
                            "--out", str(tmp_path), "--name", "fake-real"], capsys)
    assert code in (0, 1), err
    run = tmp_path / "fake-real"
    (record,) = [json.loads(line) for line in (run / "episodes.jsonl").read_text().splitlines()]
    assert record["episode_id"] == EPISODE and record["agent"] == "helios" and record["metrics"] is not None
    assert record["hardware"]["setting"] == "fake" and record["hardware"]["perception"] == "real"
    assert (run / "robot.yaml").exists() and "detector_weights: " + str(owl) in (run / "config.yaml").read_text()
    assert list((run / "recordings").glob("*.rrd"))
    from tools.cli import main

    assert main(["report", str(run), "--out", str(tmp_path / "report")]) == 0
    assert "fake-real" in capsys.readouterr().out


@pytest.fixture
def episode_robot(episode):
    """A fake Spot serving the episode's scene, standing in for a real robot at 127.0.0.1:PORT."""
    from tasks.fake_sdk import start_episode_fake

    ep = start_episode_fake(session_pki(), episode, TEST_USER, TEST_PASSWORD)
    yield ep
    ep.stop()


def _robot_args(ep, *more):
    return ["127.0.0.1", "--port", str(ep.port), "--cert", str(session_pki().ca_cert), "--estop", "endpoint",
            "--set", "rpc_timeout=1.0", "connect_timeout=3.0", *more]


def test_hardware_trials_folder_from_operator_answers_is_reported_next_to_a_sim_run(tiny_models, episode_robot,
                                                                                       episode, tmp_path, capsys):
    from tools.cli import main

    owl, clip = tiny_models
    models = tmp_path / "models.yaml"
    models.write_text(f"detector_weights: {owl}\nscorer_weights: {clip}\ndevice: cpu\n")
    with credentials_env():
        code, out, err = _spot(_robot_args(episode_robot, "--agent", "helios", "--task", episode.task, "--models",
                                           str(models), "--max-time", "6", "--on-goal", "no", "--at-rest", "yes",
                                           "--extra-collisions", "1", "--trial-id", "hw-test-1",
                                           "--out", str(tmp_path), "--name", "hw"), capsys)
    assert code == 1, err                                  # not on the goal: a failed trial, recorded
    run = tmp_path / "hw"
    (record,) = [json.loads(line) for line in (run / "episodes.jsonl").read_text().splitlines()]
    assert record["episode_id"] == "hw-test-1" and record["task"] == episode.task and record["agent"] == "helios"
    hw = record["hardware"]
    assert hw["setting"] == "hardware" and hw["operator"] == {"on_goal": False, "at_rest": True,
                                                              "extra_collisions": 1, "source": "flags"}
    assert hw["robot_log"] and hw["robot_log"][0]["command"] and hw["robot"]["serial"] == "FAKE-SPOT-0001"
    m = record["metrics"]
    assert not m["place"] and not record["success"] and m["collisions"] >= 1 and m["failure_reason"]
    for key in ("sim_time", "wall_time", "commands", "limit_hit", "config_fingerprint", "collision_events"):
        assert key in record
    assert record["sim_time"] <= 6 + 30                    # the cap (robot time; the last command may overrun)
    assert list((run / "recordings").glob("hw-test-1.rrd"))
    assert "session.log" in {p.name for p in run.iterdir()} and "robot.yaml" in {p.name for p in run.iterdir()}
    # The robot was shut down before the operator was asked: sitting, powered off, lease returned.
    fake = episode_robot.fake
    assert not fake.powered and fake.lease_owner is None and not fake._endpoints
    # A second trial appends to the same folder; a different configuration is refused before connecting.
    code, _, err = _spot(_robot_args(episode_robot, "--agent", "trusting", "--task", episode.task, "--models",
                                     str(models), "--on-goal", "no", "--at-rest", "no", "--out", str(tmp_path),
                                     "--name", "hw"), capsys)
    assert code == 2 and "another configuration" in err
    # Side by side with a simulated run.
    assert main(["trials", "--agent", "oracle", "--episodes", "1", "--out", str(tmp_path / "sim")]) == 0
    capsys.readouterr()
    assert main(["report", str(run), str(tmp_path / "sim"), "--out", str(tmp_path / "report")]) == 0
    table = capsys.readouterr().out
    assert "| hw |" in table and "| sim |" in table


def test_robot_runs_refuse_missing_weights_and_answers_before_touching_the_robot(episode_robot, episode, tmp_path,
                                                                                  capsys, monkeypatch):
    fake = episode_robot.fake
    with credentials_env():
        code, _, err = _spot(_robot_args(episode_robot, "--agent", "helios", "--task", episode.task,
                                         "--detector-weights", str(tmp_path / "none"), "--scorer-weights",
                                         str(tmp_path / "none"), "--on-goal", "yes", "--at-rest", "yes",
                                         "--out", str(tmp_path)), capsys)
        assert code == 2 and err.count("\n") == 1 and "does not exist" in err, err
        assert "set --detector-weights (or detector_weights in the --models file)" in err, err   # its own flags
        code, _, err = _spot(_robot_args(episode_robot, "--agent", "helios", "--task", episode.task,
                                         "--on-goal", "yes", "--at-rest", "yes", "--out", str(tmp_path)), capsys)
        assert code == 2 and "weight folders" in err
        monkeypatch.setattr("sys.stdin", io.StringIO(""))          # no terminal to ask the operator on
        code, _, err = _spot(_robot_args(episode_robot, "--agent", "helios", "--task", episode.task,
                                         "--detector-weights", "x", "--scorer-weights", "y", "--out", str(tmp_path)),
                             capsys)
        assert code == 2 and "--on-goal yes|no --at-rest yes|no" in err
        code, _, err = _spot(_robot_args(episode_robot, "--agent", "helios-gt", "--task", episode.task,
                                         "--out", str(tmp_path)), capsys)
        assert code == 2 and "cannot run on a real robot" in err
        code, _, err = _spot(_robot_args(episode_robot, "--agent", "helios", "--perception", "sim", "--task",
                                         episode.task, "--out", str(tmp_path)), capsys)
        assert code == 2 and "--perception sim needs the simulator" in err
    assert fake.rpc_log == [], fake.rpc_log                         # nothing reached the robot
    assert not any(tmp_path.glob("*/episodes.jsonl"))


@pytest.fixture
def recording_that_fails_to_close(monkeypatch):
    """The recorder's last write fails as on a full disk (rerun: "File-writer thread shut down
    prematurely"), after the real close (no file left open)."""
    from tasks.recording import EpisodeRecorder

    real_close = EpisodeRecorder.close

    def close(self):
        real_close(self)
        raise RuntimeError("File-writer thread shut down prematurely")

    monkeypatch.setattr(EpisodeRecorder, "close", close)


@pytest.mark.parametrize("where", ["fake-episode", "robot"])
def test_a_recording_that_fails_to_close_loses_the_recording_never_the_record(
        where, recording_that_fails_to_close, tiny_models, episode, tmp_path, capsys, request):
    """A full disk at the recording's last write once ended the run in a traceback after the robot
    was shut down, with no record (and on a robot, before the operator was asked)."""
    if where == "fake-episode":
        code, out, err = _spot(["--fake", "--episode", EPISODE, "--agent", "oracle", "--max-time", "6",
                                "--out", str(tmp_path), "--name", "run"], capsys)
    else:
        owl, clip = tiny_models
        robot = request.getfixturevalue("episode_robot")
        with credentials_env():
            code, out, err = _spot(_robot_args(robot, "--agent", "helios", "--task", episode.task,
                                               "--detector-weights", str(owl), "--scorer-weights", str(clip),
                                               "--max-time", "4", "--on-goal", "no", "--at-rest", "yes",
                                               "--extra-collisions", "0", "--out", str(tmp_path), "--name", "run"),
                                   capsys)
    assert code in (0, 1) and "Traceback" not in out + err, err[-3000:]
    assert "may be incomplete (RuntimeError: File-writer thread shut down prematurely)" in out + err
    (record,) = [json.loads(line) for line in (tmp_path / "run" / "episodes.jsonl").read_text().splitlines()]
    assert "closing the recording: RuntimeError: File-writer thread shut down prematurely" in \
        record["recording"]["errors"]


def test_swapped_weight_folders_are_refused_naming_the_flag_before_any_robot(tiny_models, tmp_path):
    """(audit 2026-12-05) CLIP weights given as the detector loaded with a warning, the robot stood
    up, and the episode failed at its first frame (exit 1, a record written)."""
    from cli_helpers import run_cli

    owl, clip = tiny_models
    rc, out, err = run_cli(["spot", "--fake", "--episode", "smoke-00000", "--perception", "real",
                            "--detector-weights", str(clip), "--scorer-weights", str(clip), "--max-time", "5",
                            "--out", str(tmp_path / "run")])
    assert rc == 2 and err.count("\n") == 1, err
    assert "holds a 'clip' model, not 'owlv2': set --detector-weights (or detector_weights in the --models file)" in err
    assert "connecting" not in out and not (tmp_path / "run").exists()


def test_a_fake_episode_folder_seeded_the_old_way_is_refused_not_mixed(tmp_path):
    """Until 2026-12-06 `tools spot --fake --episode --seed S` gave the episode seed S itself; now
    `episode_seed(S, id)`, as `tools trials` does. The configuration is the same, so the folder's
    fingerprint cannot tell them apart: a record of the old seeding is refused, one of the new is not."""
    from tasks.hardware import HardwareConfig, HardwareTrialError, prepare_hardware_folder
    from tasks.run_folder import scan_results
    from tasks.trial_config import episode_seed

    config = HardwareConfig(agent="helios", setting="fake", seed=0)
    out = tmp_path / "fake"
    fingerprint = prepare_hardware_folder(out, config)

    def holding(seed):
        record = {"episode_id": "smoke-00001", "seed": seed, "config_fingerprint": fingerprint, "sim_time": 30.0,
                  "wall_time": 1.0, "success": False}
        (out / "episodes.jsonl").write_text(json.dumps(record) + "\n")

    holding(episode_seed(0, "smoke-00001"))
    assert prepare_hardware_folder(out, config, dry_run=True) == fingerprint
    holding(0)
    with pytest.raises(HardwareTrialError, match=r"its record of smoke-00001 was made with seed 0, not the seed "
                                                 rf"`tools trials --seed 0` gives that episode \({episode_seed(0, 'smoke-00001')}\)"):
        prepare_hardware_folder(out, config, dry_run=True)
    # a robot's folder keeps its own seeds (a robot task's seed is the one given)
    robot = HardwareConfig(agent="helios", setting="hardware", seed=0)
    prepare_hardware_folder(tmp_path / "robot", robot)
    (tmp_path / "robot" / "episodes.jsonl").write_text(json.dumps(
        {"episode_id": "hw-1", "seed": 0, "sim_time": 30.0, "wall_time": 1.0, "success": False,
         "config_fingerprint": prepare_hardware_folder(tmp_path / "robot", robot, dry_run=True)}) + "\n")
    prepare_hardware_folder(tmp_path / "robot", robot, dry_run=True)
    assert list(scan_results(tmp_path / "robot" / "episodes.jsonl").records) == ["hw-1"]    # read, not set aside
