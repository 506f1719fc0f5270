"""The bad-input corpus (issue 18): every command, fed what a new user (or a damaged disk) feeds it.

Part 1, ``CASES``: bad input over all commands. Each case must end with exit status 2, exactly one
line on stderr (``error: ...``), no traceback, and nothing changed anywhere in the workspace (which
holds valid and damaged run folders, episode and config files). The commands run in this process
through ``tools.cli.main`` (no simulation starts: every check happens at the boundary).

Part 2, ``DAMAGES``: run folders damaged after a clean run. For each: what ``report`` does (the
table from the valid records, every damaged line named FILE:LINE; or one error line), what a
resume does (repairs what it can prove, refuses what it cannot: one line, folder unchanged), and
after a valid command the records equal the clean run's, with every damaged line kept in
``episodes.damaged.jsonl``.

README "Reliability" lists the guarantees these cases check.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import pytest

from cli_helpers import run_cli
from tasks.episodes import load_split
from tasks.run_folder import DAMAGED_FILE, append_result, prepare_run_folder, read_results
from tasks.trial_config import FINGERPRINT_FIELD, TrialConfig, config_fingerprint, deterministic_view

TASK = "Move the mug from the stool to the table"
LONG = "x" * 10_000
UNWRITABLE = "/sys/helios-bad-input/out"        # mkdir there fails even for root
BUDGET = ["runner.max_commands=3"]              # damage corpus: episodes end after 3 HAL commands
RUN_ARGS = ["trials", "--agent", "oracle", "--split", "smoke", "--episodes", "3", "--progress", "none"]


def snapshot(root: Path) -> dict[str, bytes | None]:
    """Every file (bytes) and folder (None) under ``root``."""
    return {str(p.relative_to(root)): (None if p.is_dir() else p.read_bytes() if p.is_file() else b"<special file>")
            for p in sorted(root.rglob("*"))}      # (a FIFO is never read: that would wait for a writer)


# ------------------------------------------------------------------------------------------------
# The workspace: valid and damaged inputs, made once
# ------------------------------------------------------------------------------------------------
# smoke-00001's first goal receptacle, and one more of its category that its home does not have
GOAL_1 = load_split("smoke")[1].goal_receptacles[0]
GOAL_77 = GOAL_1.rsplit("_", 1)[0] + "_77"


def _episode(**changes) -> str:
    d = json.loads(load_split("smoke")[1].to_json())
    for key, value in changes.items():
        if key.startswith("scene."):
            d["scene"][key[6:]] = value
        else:
            d[key] = value
    return json.dumps(d)


def _synthetic_run(folder: Path, config: TrialConfig, ids=("smoke-00000", "smoke-00001"), fingerprint=True,
                   config_yaml=True) -> None:
    prepare_run_folder(folder, config)
    for eid in ids:
        rec = {"episode_id": eid, "agent": config.agent, "metrics": {
            "find_obj": True, "pick": False, "find_rec": False, "place": False, "success": False, "collisions": 0,
            "failure_reason": "pick_failed"}, "sim_time": 10.0, "wall_time": 1.0, "success": False, "memory": None}
        if fingerprint:
            rec[FINGERPRINT_FIELD] = config_fingerprint(config)
        append_result(folder / "episodes.jsonl", rec)
    (folder / ".lock").write_text("")
    if not config_yaml:
        (folder / "config.yaml").unlink()


@pytest.fixture(scope="module")
def ws(tmp_path_factory):
    root = tmp_path_factory.mktemp("bad-input")
    (root / "afile").write_text("not a folder\n")
    (root / "adir").mkdir()
    (root / "empty_dir").mkdir()
    (root / "rec.txt").write_text("not a recording\n")
    eps = root / "eps"
    eps.mkdir()
    files = {
        "nonutf8.jsonl": b"\xff\xfe\x00\x01 not text\n",
        "empty.jsonl": b"\n\n",
        "badjson.jsonl": b'{"episode_id": "smoke-00001", \n',
        "nested.jsonl": b"[" * 100_000 + b"\n",
        "scene_negative.jsonl": _episode(**{"scene.min_size": -5.0}).encode(),
        "scene_inverted.jsonl": _episode(**{"scene.min_size": 12.0, "scene.max_size": 9.0}).encode(),
        "scene_huge.jsonl": _episode(**{"scene.max_size": 1e9}).encode(),
        "scene_seed.jsonl": _episode(**{"scene.seed": -3}).encode(),
        "scene_seed_str.jsonl": _episode(**{"scene.seed": "abc"}).encode(),
        "target_missing.jsonl": _episode(target_object="cup_99").encode(),
        "target_category.jsonl": _episode(target_object="stool_2").encode(),
        "start_missing.jsonl": _episode(start_receptacle="stool_9").encode(),
        "goal_missing.jsonl": _episode(goal_receptacles=[GOAL_1, GOAL_77]).encode(),
        "start_1e308.jsonl": _episode(robot_start=[1e308, 4.2, 0.0]).encode(),
        "start_outside.jsonl": _episode(robot_start=[-5.0, -5.0, 0.0]).encode(),
        "start_nan.jsonl": _episode(robot_start=[float("nan"), 4.2, 0.0]).encode(),
        "long_task.jsonl": _episode(task=f"Move the {LONG} from the stool to the chair").encode(),
        "bad_id.jsonl": _episode(episode_id="smoke-../../etc").encode(),
        "long_id.jsonl": _episode(episode_id="smoke-" + LONG).encode(),
        "schema.jsonl": _episode(schema_version=1).encode(),
        "duplicate.jsonl": (_episode() + "\n" + _episode()).encode(),
        "start_overflow.jsonl": _episode(robot_start=[1.4, 2.3, 10 ** 400]).encode(),
        "start_bool.jsonl": _episode(robot_start=[True, 2.3, 1.4]).encode(),
        "scene_overflow.jsonl": _episode(**{"scene.min_size": 10 ** 400}).encode(),
        "seed_digits.jsonl": _episode(**{"scene.seed": 123454321}).replace("123454321", "9" * 5000).encode(),
    }
    for name, data in files.items():
        (eps / name).write_bytes(data)
    for name, data in QA_FILES.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_bytes(data)
    os.mkfifo(root / "fifo")                 # written to or read from, it must be refused, never replaced or waited on
    os.symlink("loop", root / "loop")        # a symbolic link loop: Path.resolve() raises RuntimeError
    (root / "ro_run").mkdir()                 # a run folder whose episodes/ takes no new file (/proc)
    os.symlink("/proc", root / "ro_run" / "episodes")
    cfg = root / "cfg"
    cfg.mkdir()
    configs = {
        "nonutf8.yaml": b"agent: oracle\nseed: \xff\xfe\n",
        "binary.yaml": bytes(range(256)) * 4,
        "list.yaml": b"- agent\n- oracle\n",
        "unknown.yaml": b"agent: oracle\nrunner:\n  max_sim_tme: 3\n",
        "syntax.yaml": b"agent: [oracle\n",
        "range.yaml": b"runner:\n  max_sim_time: -1\n",
        "camera.yaml": b"camera:\n  width: 0\n",
        "sdk.yaml": b"rpc_timeout: 0\n",
        "duplicate.yaml": b"runner: {max_sim_time: 10}\nrunner: {max_commands: 5}\n",
        "empty.yaml": b"",
        "bool_tag.yaml": b"agent: oracle\nrecord: !!bool x\n",
        "comments.yaml": b"# all defaults, I hope\n\n",
        "oracle_helios.yaml": b"agent: oracle\nhelios:\n  search:\n    cs_start_receptacle: 0.4\n",
        "trusting_local.yaml": b"agent: trusting\nagent_config:\n  local_search_views: all\n",
        "drop_top_band.yaml": b"agent: helios\nagent_config:\n  place:\n    top_band: 0.05\n",
    }
    for name, data in configs.items():
        (cfg / name).write_bytes(data)
    (cfg / "dir.yaml").mkdir()
    agents = root / "agents"                  # agents of your own (tasks.plugin_agents)
    agents.mkdir()
    for name, data in PLUGIN_FILES.items():
        (agents / name).write_bytes(data)
    (agents / "dir.py").mkdir()
    runs = root / "runs"
    _synthetic_run(runs / "valid", TrialConfig(agent="oracle", episodes=2))
    _synthetic_run(runs / "nocfg", TrialConfig(agent="oracle", episodes=2, seed=7), config_yaml=False)
    _synthetic_run(runs / "legacy_nocfg", TrialConfig(agent="oracle", episodes=2), fingerprint=False,
                   config_yaml=False)
    _synthetic_run(runs / "edited", TrialConfig(agent="oracle", episodes=2))
    text = (runs / "edited" / "config.yaml").read_text()
    (runs / "edited" / "config.yaml").write_text(text.replace("max_commands: 600", "max_commands: 400"))
    _synthetic_run(runs / "binary_cfg", TrialConfig(agent="oracle", episodes=2, seed=3))
    (runs / "binary_cfg" / "config.yaml").write_bytes(b"\x00\xff" * 50)
    for name in ("lockdir", "jsonldir", "summarydir", "cfgdir"):
        _synthetic_run(runs / name, TrialConfig(agent="oracle", episodes=2))
    (runs / "lockdir" / ".lock").unlink()
    (runs / "lockdir" / ".lock").mkdir()
    (runs / "jsonldir" / "episodes.jsonl").unlink()
    (runs / "jsonldir" / "episodes.jsonl").mkdir()
    (runs / "summarydir" / "summary.json").mkdir()
    (runs / "cfgdir" / "config.yaml").unlink()
    (runs / "cfgdir" / "config.yaml").mkdir()
    _synthetic_run(runs / "mixed", TrialConfig(agent="oracle", episodes=2))
    rec = json.loads((runs / "mixed" / "episodes.jsonl").read_text().splitlines()[0])
    append_result(runs / "mixed" / "episodes.jsonl", {**rec, "episode_id": "smoke-00002",
                                                     FINGERPRINT_FIELD: "0123456789abcdef"})
    (runs / "damaged_only").mkdir()
    (runs / "damaged_only" / "episodes.jsonl").write_bytes(b"{}\n[]\nnot json\n")
    _synthetic_run(runs / "other", TrialConfig(agent="oracle", episodes=6), ids=("smoke-00005",))
    return root


# ------------------------------------------------------------------------------------------------
# Part 1: bad input, one clear line each
# ------------------------------------------------------------------------------------------------
T = ["trials", "--episodes", "1", "--out", "{ws}/new_run"]          # a valid trials command but for one thing
E = "{ws}/eps/"
C = "{ws}/cfg/"
R = "{ws}/runs/"
SPOT = ["spot", "--fake", "--task", TASK]
REPORT = ["report", R + "valid"]
A = "{ws}/agents/"
PLUGIN_FILES = {
    "good.py": b"class Agent:\n    name = 'mine'\n    def reset(self, task, rng): pass\n"
               b"    def act(self, robot): return True\n\n\ndef make(context, **options):\n    return Agent()\n\n\n"
               b"LIMIT = 3\n",
    "syntax.py": b"def make(context:\n",
    "raises.py": b"import math\nx = 1 / 0\n",
    "reads_str.py": b"def make(context, **options):\n    pass\n\n\nmake.reads = 'perception'\n",
    "reads_sim.py": b"def make(context, **options):\n    pass\n\n\nmake.reads = ('perception', 'sim')\n",
    "reads_helios.py": b"def make(context, **options):\n    pass\n\n\nmake.reads = ('helios',)\n",
}

CASES: list[tuple[str, list[str], str]] = [
    # --- output paths: an existing file, a path inside a file, an unwritable folder (every command) ---
    ("trials-out-file", ["trials", "--episodes", "1", "--out", "{ws}/afile"], "is an existing file"),
    ("trials-out-in-file", ["trials", "--episodes", "1", "--out", "{ws}/afile/run"], "which is a file"),
    ("trials-out-unwritable", ["trials", "--episodes", "1", "--out", UNWRITABLE], "cannot write"),
    ("trials-out-in-proc", ["trials", "--episodes", "1", "--out", "/proc/helios-run"],
     "cannot write in '/proc' (no file or folder can be made there)"),
    ("trials-out-empty", ["trials", "--episodes", "1", "--out", " "], "must not be empty"),
    ("report-out-file", [*REPORT, "--out", "{ws}/afile"], "is an existing file"),
    ("report-out-in-file", [*REPORT, "--out", "{ws}/afile/rep"], "which is a file"),
    ("report-out-unwritable", [*REPORT, "--out", UNWRITABLE], "cannot write"),
    ("report-out-is-run", [*REPORT, "--out", R + "valid"], "is a run folder given to report"),
    ("tsdf-out-file", ["tsdf", "smoke-00001", "--out", "{ws}/afile"], "is an existing file"),
    ("tsdf-out-in-file", ["tsdf", "smoke-00001", "--out", "{ws}/afile/mesh"], "which is a file"),
    ("tsdf-out-unwritable", ["tsdf", "smoke-00001", "--out", UNWRITABLE], "cannot write"),
    ("episodes-out-dir", ["episodes", "generate", "--name", "x", "--seed", "1", "--count", "1", "--out", "{ws}/adir"],
     "is a folder"),
    ("episodes-out-in-file", ["episodes", "generate", "--name", "x", "--seed", "1", "--count", "1",
                              "--out", "{ws}/afile/e.jsonl"], "is an existing file"),
    ("episodes-out-unwritable", ["episodes", "generate", "--name", "x", "--seed", "1", "--count", "1",
                                 "--out", UNWRITABLE + "/e.jsonl"], "cannot write"),
    ("episodes-out-slash", ["episodes", "generate", "--name", "x", "--seed", "1", "--count", "1",
                            "--out", "{ws}/new/"], "ends with a slash"),
    ("spot-out-file", [*SPOT, "--out", "{ws}/afile"], "is an existing file"),
    ("spot-out-in-file", [*SPOT, "--out", "{ws}/afile/spot"], "which is a file"),
    ("spot-out-unwritable", [*SPOT, "--out", UNWRITABLE], "cannot write"),
    ("spot-name-is-file", [*SPOT, "--out", "{ws}", "--name", "afile"], "is an existing file"),
    # the scripted demo carries the layout's mug to its place table: another task was run as the demo, SUCCESS
    ("spot-demo-other-object", ["spot", "--fake", "--task", "Move the apple from the bed to the sofa", "--out",
                                "{ws}/new_spot"], "the task asks for the apple to the sofa"),
    ("spot-demo-other-goal-robot", ["spot", "127.0.0.1", "--task", "Move the mug from the stool to the shelf",
                                    "--out", "{ws}/new_spot"], "scripted-demo carries the demo layout's mug"),
    ("demo-out-file", ["demo", "--out", "{ws}/afile"], "is an existing file"),
    ("demo-out-unwritable", ["demo", "--out", UNWRITABLE], "cannot write"),
    ("arm-envelope-out-file", ["arm-envelope", "--quick", "--out", "{ws}/afile"], "is an existing file"),
    ("arm-envelope-out-in-file", ["arm-envelope", "--quick", "--out", "{ws}/afile/arm"], "which is a file"),
    ("arm-envelope-out-unwritable", ["arm-envelope", "--quick", "--out", UNWRITABLE], "cannot write"),
    ("calibrate-out-file", ["calibrate-perception", "--views", "5", "--out", "{ws}/afile"], "is an existing file"),
    ("calibrate-out-in-file", ["calibrate-perception", "--views", "5", "--out", "{ws}/afile/c"], "which is a file"),
    ("calibrate-out-unwritable", ["calibrate-perception", "--views", "5", "--out", UNWRITABLE], "cannot write"),
    # --- values that pass the type check but would break set-up or score nonsense ---
    ("seed-negative", ["trials", "--seed", "-1", "--episodes", "1", "--out", "{ws}/new_run"], "seed must be"),
    ("seed-huge", [*T, "seed=99999999999999"], "seed must be"),
    ("episodes-zero", ["trials", "--episodes", "0", "--out", "{ws}/new_run"], "episodes must be"),
    ("episodes-negative", ["trials", "--episodes", "-3", "--out", "{ws}/new_run"], "episodes must be"),
    ("episodes-too-many", ["trials", "--episodes", "21", "--out", "{ws}/new_run"], "fewer than the 21"),
    ("max-sim-time-zero", [*T, "runner.max_sim_time=0"], "max_sim_time must be"),
    ("max-sim-time-negative", [*T, "runner.max_sim_time=-1"], "max_sim_time must be"),
    ("max-sim-time-nan", [*T, "runner.max_sim_time=.nan"], "NaN"),
    ("max-sim-time-inf", [*T, "runner.max_sim_time=.inf"], "finite"),
    ("max-sim-time-overflow", [*T, "runner.max_sim_time=1.0e+400"], "finite"),
    ("max-sim-time-text", [*T, "runner.max_sim_time=abc"], "expected a number"),
    ("max-sim-time-list", [*T, "runner.max_sim_time=[1, 2]"], "expected a number"),
    ("max-sim-time-long", [*T, "runner.max_sim_time=" + LONG], "more characters"),
    ("max-commands-negative", [*T, "runner.max_commands=-5"], "max_commands must be"),
    ("max-commands-zero", [*T, "runner.max_commands=0"], "max_commands must be"),
    ("max-commands-float", [*T, "runner.max_commands=1.5"], "expected an integer"),
    ("max-commands-huge", [*T, "runner.max_commands=1" + "0" * 30], "max_commands must be"),
    ("metrics-radius", [*T, "runner.metrics.find_radius=0"], "find_radius must be"),
    ("metrics-coverage", [*T, "runner.metrics.min_coverage=2"], "min_coverage must be"),
    ("metrics-stability", [*T, "runner.metrics.stability_steps=0"], "stability_steps must be"),
    ("control-dt-zero", [*T, "sim.motion.control_dt=0"], "control_dt must be"),
    ("control-dt-negative", [*T, "sim.motion.control_dt=-0.05"], "control_dt must be"),
    ("base-velocity-zero", [*T, "sim.motion.base.linear_velocity=0"], "linear_velocity must be"),
    ("arm-jerk-negative", [*T, "sim.motion.arm.jerk=-1"], "jerk must be"),
    ("camera-width-zero", [*T, "sim.camera.width=0"], "width must be"),
    ("camera-height-huge", [*T, "sim.camera.height=100000"], "height must be"),
    ("camera-near-zero", [*T, "sim.camera.near=0"], "near must be"),
    ("camera-far-before-near", [*T, "sim.camera.far=0.01"], "must be < far"),
    ("camera-renderer", [*T, "sim.camera.renderer=opengl"], "is not one of"),
    ("hold-force-negative", [*T, "sim.grasp.hold_force=-1"], "hold_force must be"),
    ("hold-force-inf", [*T, "sim.grasp.hold_force=.inf"], "finite"),
    ("close-force-zero", [*T, "sim.grasp.close_force=0"], "close_force must be"),
    ("open-angle-positive", [*T, "sim.grasp.open_angle=1"], "open_angle must be"),
    ("timestep-zero", [*T, "sim.world.physics.timestep=0"], "timestep must be"),
    ("solver-iterations-zero", [*T, "sim.world.physics.solver_iterations=0"], "solver_iterations must be"),
    ("gravity-huge", [*T, "sim.world.physics.gravity=1000000000.0"], "gravity must be"),
    ("settle-time-negative", [*T, "sim.world.settle.max_time=-1"], "max_time must be"),
    ("stream-hz-negative", [*T, "sim.stream_hz=-1"], "stream_hz must be"),
    ("arm-tolerance-zero", [*T, "sim.arm_tolerance=0"], "arm_tolerance must be"),
    ("contact-check-zero", [*T, "sim.contact_check_every=0"], "contact_check_every must be"),
    ("hand-position-far", [*T, "sim.gaze_hand_position=[0, 0, 1000000000.0]"], "within 2 m"),
    ("hand-position-short", [*T, "sim.gaze_hand_position=[1, 2]"], "expected 3 values"),
    ("pick-attempts-negative", [*T, "agent_config.max_pick_attempts=-1"], "max_pick_attempts must be"),
    ("look-distance-zero", [*T, "agent_config.view.look_distance=0"], "look_distance must be"),
    ("look-yaws-empty", [*T, "agent_config.view.look_yaws_deg=[]"], "must not be empty"),
    ("reach-angles", [*T, "agent_config.reach.n_angles=1"], "invalid reach settings"),
    ("drop-height", [*T, "agent_config.place.drop_height=5"], "drop_height"),
    ("place-mode", [*T, "agent_config.place.mode=throw"], "is not one of"),
    ("plan-cell-zero", [*T, "agent_config.planner.plan_cell_size=0"], "must be > 0"),
    ("footprint-margin", [*T, "agent_config.planner.footprint.margin=-1"], "margin must be"),
    ("walk-chunks-zero", [*T, "agent_config.max_walk_chunks=0"], "max_walk_chunks must be"),
    ("gaze-hop-negative", [*T, "agent_config.gaze_hop=-1"], "gaze_hop must be"),
    ("local-search-views", [*T, "agent_config.local_search_views=some"], "is not one of"),
    ("local-search-min-gain", [*T, "agent_config.local_search_min_gain=2"], "local_search_min_gain must be"),
    ("occupancy-cell-zero", [*T, "helios.occupancy.cell_size=0"], "cell_size must be"),
    ("occupancy-grid-huge", [*T, "helios.occupancy.grid_size=1000000000"], "grid_size must be"),
    ("occupancy-stride-zero", [*T, "helios.occupancy.depth_stride=0"], "depth_stride must be"),
    ("gaussians-alpha-zero", [*T, "helios.gaussians.alpha_cpa=0"], "alpha_cpa must be"),
    ("gaussians-width-huge", [*T, "helios.gaussians.update_max_width=100000"], "update_max_width must be"),
    ("instances-voxel-zero", [*T, "helios.instances.voxel_size=0"], "voxel_size must be"),
    ("scoring-alpha-negative", [*T, "helios.scoring.alpha_cs=-1"], "alpha_cs must be"),
    ("frontier-radius-zero", [*T, "helios.frontiers.value_radius=0"], "value_radius must be"),
    ("search-alpha-huge", [*T, "helios.search.alpha_d=1000000000000"], "alpha_d must be"),
    ("decision-tau-increase-huge", [*T, "helios.decision.tau_increase=1000000000000"], "tau_increase must be"),
    ("render-near-zero", [*T, "helios.gaussians.render.near=0"], "near must be"),
    ("detection-threshold", [*T, "helios.detection.od_object=2"], "od_object must be"),
    ("device", [*T, "helios.device=tpu"], "is not one of"),
    ("perception-probability", [*T, "perception.p_detect_object=1.5"], "p_detect_object must be"),
    ("perception-bins", [*T, "perception.azimuth_bins=0"], "azimuth_bins must be"),
    ("agent-empty", [*T, "agent="], "agent must be"),
    ("agent-unknown", [*T, "agent=helio"], "unknown agent 'helio'"),
    ("agent-long", [*T, "agent=" + LONG], "more characters"),
    ("split-unknown", [*T, "split=vall"], "unknown split 'vall'"),
    ("key-unknown", [*T, "runner.max_sim_tme=3"], "unknown config key"),
    ("key-top-unknown", [*T, "nope=1"], "unknown config key"),
    ("key-long", [*T, LONG + "=1"], "unknown config key"),
    ("override-no-equals", [*T, "runner.max_sim_time"], "not of the form key=value"),
    ("override-empty-key", [*T, "=5"], "empty key"),
    ("override-section", [*T, "runner=5"], "expected a mapping"),
    ("override-value-section", [*T, "runner.max_sim_time.x=5"], "is a value, not a section"),
    ("override-bad-yaml", [*T, "runner.max_sim_time=[1,"], "cannot parse value"),
    # --- trials flags ---
    ("workers-zero", [*T, "--workers", "0"], "--workers must be"),
    ("workers-huge", [*T, "--workers", "100000"], "--workers must be"),
    ("workers-text", [*T, "--workers", "two"], "invalid int value"),
    ("record-negative", [*T, "--record", "-1"], "--record must be"),
    ("worker-episodes-negative", [*T, "--worker-episodes", "-1"], "--worker-episodes must be"),
    ("progress-choice", [*T, "--progress", "fancy"], "invalid choice"),
    ("executor-choice", [*T, "--executor", "slurm"], "invalid choice"),
    ("address-without-ray", [*T, "--address", "10.0.0.1:6379"], "only applies to --executor ray"),
    ("ray-address-bad-ip", [*T, "--executor", "ray", "--address", "256.1.1.1:1"], "not a valid IP address"),
    ("ray-address-no-port", [*T, "--executor", "ray", "--address", "headnode"], "HOST:PORT"),
    ("ray-address-port", [*T, "--executor", "ray", "--address", "head:99999"], "outside 1..65535"),
    ("ray-address-host", [*T, "--executor", "ray", "--address", "a..b:6379"], "not a valid host name"),
    ("ray-address-refused", [*T, "--executor", "ray", "--address", "127.0.0.1:1"], "cannot reach the Ray cluster"),
    ("episodes-flag-text", ["trials", "--episodes", "abc"], "invalid int value"),
    ("seed-flag-float", ["trials", "--seed", "1.5"], "invalid int value"),
    ("unknown-flag", [*T, "--wokers", "2"], "helios trials: unrecognized arguments: --wokers (see: helios trials --help)"),
    # --- episode files: encodings, damage, and episodes that do not fit their homes ---
    ("ep-nonutf8", [*T, "--episodes-file", E + "nonutf8.jsonl"], "not UTF-8"),
    ("ep-directory", [*T, "--episodes-file", "{ws}/adir"], "is a directory"),
    ("ep-missing", [*T, "--episodes-file", E + "nope.jsonl"], "does not exist"),
    ("ep-empty", [*T, "--episodes-file", E + "empty.jsonl"], "holds no episodes"),
    ("ep-bad-json", [*T, "--episodes-file", E + "badjson.jsonl"], "not valid JSON"),
    ("ep-nested", [*T, "--episodes-file", E + "nested.jsonl"], "not valid JSON"),
    ("ep-scene-negative", [*T, "--episodes-file", E + "scene_negative.jsonl"], "min_size"),
    ("ep-scene-inverted", [*T, "--episodes-file", E + "scene_inverted.jsonl"], "min_size"),
    ("ep-scene-huge", [*T, "--episodes-file", E + "scene_huge.jsonl"], "min_size"),
    ("ep-scene-seed", [*T, "--episodes-file", E + "scene_seed.jsonl"], "seed >= 0"),
    ("ep-scene-seed-text", [*T, "--episodes-file", E + "scene_seed_str.jsonl"], "field 'scene'"),
    ("ep-target-missing", [*T, "--episodes-file", E + "target_missing.jsonl"], "'cup_99' is not in its home"),
    ("ep-target-category", [*T, "--episodes-file", E + "target_category.jsonl"], "is not in its home"),
    ("ep-start-missing", [*T, "--episodes-file", E + "start_missing.jsonl"], "'stool_9' is not in its home"),
    ("ep-goal-missing", [*T, "--episodes-file", E + "goal_missing.jsonl"], f"{GOAL_77!r} is not in its home"),
    ("ep-start-1e308", [*T, "--episodes-file", E + "start_1e308.jsonl"], "outside its home"),
    ("ep-start-outside", [*T, "--episodes-file", E + "start_outside.jsonl"], "outside its home"),
    ("ep-start-nan", [*T, "--episodes-file", E + "start_nan.jsonl"], "3 finite numbers"),
    ("ep-long-task", [*T, "--episodes-file", E + "long_task.jsonl"], "unknown object"),
    ("ep-bad-id", [*T, "--episodes-file", E + "bad_id.jsonl"], "episode_id"),
    ("ep-long-id", [*T, "--episodes-file", E + "long_id.jsonl"], "episode_id"),
    ("ep-schema", [*T, "--episodes-file", E + "schema.jsonl"], "schema_version 1 is not supported"),
    ("ep-duplicate", [*T, "--episodes-file", E + "duplicate.jsonl"], "duplicate episode_id"),
    ("ep-tsdf-target-missing", ["tsdf", "smoke-00001", "--episodes-file", E + "target_missing.jsonl",
                                "--out", "{ws}/new_tsdf"], "is not in its home"),
    ("ep-tsdf-outside", ["tsdf", "smoke-00001", "--episodes-file", E + "start_outside.jsonl",
                         "--out", "{ws}/new_tsdf"], "outside its home"),
    ("ep-check-nonutf8", ["episodes", "check", E + "nonutf8.jsonl"], "not UTF-8"),
    ("ep-check-directory", ["episodes", "check", "{ws}/adir"], "is a directory"),
    ("ep-check-scene", ["episodes", "check", E + "scene_inverted.jsonl"], "min_size"),
    # --- scenario files ---
    ("cfg-nonutf8", ["trials", "--config", C + "nonutf8.yaml", "--out", "{ws}/new_run"], "not UTF-8"),
    ("cfg-binary", ["trials", "--config", C + "binary.yaml", "--out", "{ws}/new_run"], "config file"),
    ("cfg-list", ["trials", "--config", C + "list.yaml", "--out", "{ws}/new_run"], "must hold a mapping"),
    ("cfg-directory", ["trials", "--config", C + "dir.yaml", "--out", "{ws}/new_run"], "is a directory"),
    ("cfg-missing", ["trials", "--config", C + "nope.yaml", "--out", "{ws}/new_run"], "does not exist"),
    ("cfg-unknown-key", ["trials", "--config", C + "unknown.yaml", "--out", "{ws}/new_run"], "max_sim_tme"),
    ("cfg-syntax", ["trials", "--config", C + "syntax.yaml", "--out", "{ws}/new_run"], "not valid YAML (line"),
    ("cfg-range", ["trials", "--config", C + "range.yaml", "--out", "{ws}/new_run"], "max_sim_time must be"),
    ("cfg-run-binary", ["trials", "--config", R + "binary_cfg/config.yaml", "--out", "{ws}/new_run"], "config file"),
    ("demo-cfg-nonutf8", ["demo", "--no-record", "--config", C + "nonutf8.yaml"], "not UTF-8"),
    ("demo-cfg-camera", ["demo", "--no-record", "--config", C + "camera.yaml"], "width must be"),
    ("demo-cfg-directory", ["demo", "--no-record", "--config", C + "dir.yaml"], "is a directory"),
    ("spot-cfg-nonutf8", [*SPOT, "--config", C + "nonutf8.yaml", "--out", "{ws}/new_spot"], "not UTF-8"),
    ("spot-cfg-range", [*SPOT, "--config", C + "sdk.yaml", "--out", "{ws}/new_spot"], "rpc_timeout"),
    # --- run folders that must not be resumed with this configuration ---
    ("run-different-config", ["trials", "--episodes", "2", "--seed", "1", "--out", R + "valid"],
     "different configuration"),
    ("run-shortened", ["trials", "--episodes", "1", "--out", R + "valid"], "extended but not shortened"),
    ("run-no-config-other", ["trials", "--episodes", "2", "--out", R + "nocfg"], "config.yaml is missing"),
    ("run-no-config-legacy", ["trials", "--episodes", "2", "--out", R + "legacy_nocfg"], "no configuration fingerprint"),
    ("run-config-edited", ["trials", "--episodes", "2", "--out", R + "edited", "runner.max_commands=400"],
     "does not describe the records"),
    ("run-config-binary", ["trials", "--episodes", "2", "--out", R + "binary_cfg"], "cannot be resumed"),
    ("run-lock-directory", ["trials", "--episodes", "2", "--out", R + "lockdir"], ".lock is a directory"),
    ("run-results-directory", ["trials", "--episodes", "2", "--out", R + "jsonldir"], "episodes.jsonl is a directory"),
    ("run-summary-directory", ["trials", "--episodes", "2", "--out", R + "summarydir"], "summary.json is a directory"),
    ("run-config-directory", ["trials", "--episodes", "2", "--out", R + "cfgdir"], "config.yaml is a directory"),
    ("run-mixed", ["trials", "--episodes", "3", "--out", R + "mixed"], "mixes records of 2 configurations"),
    # --- report ---
    ("report-missing", ["report", R + "nope", "--out", "{ws}/new_rep"], "does not exist"),
    ("report-file", ["report", "{ws}/afile", "--out", "{ws}/new_rep"], "is a file"),
    ("report-empty", ["report", "{ws}/empty_dir", "--out", "{ws}/new_rep"], "no finished episodes"),
    ("report-damaged-only", ["report", R + "damaged_only", "--out", "{ws}/new_rep"], "only damaged lines"),
    ("report-results-directory", ["report", R + "jsonldir", "--out", "{ws}/new_rep"], "is a directory"),
    ("report-names-count", [*REPORT, R + "other", "--names", "a", "--out", "{ws}/new_rep"], "--names has 1"),
    ("report-names-empty", [*REPORT, R + "other", "--names", "a,", "--out", "{ws}/new_rep"], "empty name"),
    ("report-common-disjoint", [*REPORT, R + "other", "--common", "--out", "{ws}/new_rep"], "share no finished"),
    ("report-no-runs", ["report"], "the following arguments are required"),
    # --- unchanged ---
    ("unchanged-no-commit", ["unchanged", "no-such-commit-0123", "--out", "{ws}/unch"], "is not a commit"),
    ("unchanged-unknown-run", ["unchanged", "HEAD", "--runs", "helios,nope", "--out", "{ws}/unch"],
     "there is no configs/val_nope.yaml"),
    ("unchanged-runs-empty", ["unchanged", "HEAD", "--runs", "helios,", "--out", "{ws}/unch"], "separated by commas"),
    ("unchanged-runs-twice", ["unchanged", "HEAD", "--runs", "trusting,trusting", "--out", "{ws}/unch"],
     "more than once"),
    ("unchanged-runs-path", ["unchanged", "HEAD", "--runs", "../x", "--out", "{ws}/unch"], "is not a run name"),
    ("unchanged-episodes-zero", ["unchanged", "HEAD", "--episodes", "0", "--out", "{ws}/unch"], "--episodes must be"),
    ("unchanged-episodes-many", ["unchanged", "HEAD", "--episodes", "1001", "--out", "{ws}/unch"],
     "--episodes must be"),
    ("unchanged-workers-zero", ["unchanged", "HEAD", "--workers", "0", "--out", "{ws}/unch"], "--workers must be"),
    ("unchanged-out-file", ["unchanged", "HEAD", "--out", "{ws}/afile"], "is an existing file"),
    ("unchanged-out-foreign", ["unchanged", "HEAD", "--out", R + "valid"], "not an earlier `tools unchanged`"),
    ("unchanged-ignore-empty", ["unchanged", "HEAD", "--ignore", "a,,b", "--out", "{ws}/unch"], "empty field name"),
    ("unchanged-no-commit-given", ["unchanged"], "the following arguments are required"),
    # --- diff ---
    ("diff-missing", ["diff", R + "nope", R + "valid"], "does not exist"),
    ("diff-file", ["diff", R + "valid", "{ws}/afile"], "is a file"),
    ("diff-empty", ["diff", R + "valid", "{ws}/empty_dir"], "no finished episodes"),
    ("diff-damaged-only", ["diff", R + "damaged_only", R + "valid"], "only damaged lines"),
    ("diff-disjoint", ["diff", R + "valid", R + "other"], "share no finished episode"),
    ("diff-ignore-unknown", ["diff", R + "valid", R + "valid", "--ignore", "metrics.fnd_obj"], "names no field"),
    ("diff-ignore-empty", ["diff", R + "valid", R + "valid", "--ignore", "sim_time,,x"], "empty field name"),
    ("diff-ignore-spaces", ["diff", R + "valid", R + "valid", "--ignore", "metrics find_obj"], "not a dotted field"),
    ("diff-episodes-zero", ["diff", R + "valid", R + "valid", "--episodes", "0"], "--episodes must be"),
    ("diff-episodes-word", ["diff", R + "valid", R + "valid", "--episodes", "ten"], "invalid int value"),
    ("diff-show-negative", ["diff", R + "valid", R + "valid", "--show", "-1"], "--show must be"),
    ("diff-one-run", ["diff", R + "valid"], "the following arguments are required"),
    ("diff-tolerance-negative", ["diff", R + "valid", R + "valid", "--tolerance=-1e-9"], "--tolerance must be"),
    ("diff-tolerance-nan", ["diff", R + "valid", R + "valid", "--tolerance", "nan"], "--tolerance must be"),
    ("report-pick-limit-zero", [*REPORT, "--pick-limits", "0", "--out", "{ws}/new_rep"], "0 is outside [1, 1000]"),
    ("report-pick-limit-word", [*REPORT, "--pick-limits", "1,five", "--out", "{ws}/new_rep"], "'five' is not a whole"),
    ("report-pick-limit-twice", [*REPORT, "--pick-limits", "5,1,5", "--out", "{ws}/new_rep"], "5 is given twice"),
    ("report-budget-word", [*REPORT, "--budgets", "60,soon", "--out", "{ws}/new_rep"], "'soon' is not a number of seconds"),
    ("report-budget-negative", [*REPORT, "--budgets=-5", "--out", "{ws}/new_rep"], "-5 is not a positive number"),
    ("report-budget-nan", [*REPORT, "--budgets", "nan", "--out", "{ws}/new_rep"], "nan is not a positive number"),
    ("report-budget-twice", [*REPORT, "--budgets", "60,120,60", "--out", "{ws}/new_rep"], "60 is given twice"),
    ("report-budget-beyond-cap", [*REPORT, "--budgets", "1e6", "--out", "{ws}/new_rep"], "is beyond run 'valid''s cap"),
    # --- tsdf ---
    ("tsdf-hz-nan", ["tsdf", "smoke-00001", "--stream-hz", "nan", "--out", "{ws}/new_tsdf"], "finite"),
    ("tsdf-hz-inf", ["tsdf", "smoke-00001", "--stream-hz", "inf", "--out", "{ws}/new_tsdf"], "finite"),
    ("tsdf-hz-negative", ["tsdf", "smoke-00001", "--stream-hz", "-1", "--out", "{ws}/new_tsdf"], "positive"),
    ("tsdf-hz-zero", ["tsdf", "smoke-00001", "--stream-hz", "0", "--out", "{ws}/new_tsdf"], "positive"),
    ("tsdf-hz-huge", ["tsdf", "smoke-00001", "--stream-hz", "1e9", "--out", "{ws}/new_tsdf"], "at most 1000"),
    ("tsdf-unknown-episode", ["tsdf", "smoke-99999", "--out", "{ws}/new_tsdf"], "no episode 'smoke-99999'"),
    ("tsdf-long-episode", ["tsdf", "smoke-" + LONG, "--out", "{ws}/new_tsdf"], "more characters"),
    ("tsdf-unknown-split", ["tsdf", "smoke-00001", "--split", "nope", "--out", "{ws}/new_tsdf"], "unknown split"),
    ("tsdf-voxel-zero", ["tsdf", "smoke-00001", "voxel_size=0", "--out", "{ws}/new_tsdf"], "voxel_size must be"),
    ("tsdf-voxel-nan", ["tsdf", "smoke-00001", "voxel_size=.nan", "--out", "{ws}/new_tsdf"], "NaN"),
    ("tsdf-depth-negative", ["tsdf", "smoke-00001", "depth_max=-1", "--out", "{ws}/new_tsdf"], "depth_max must be"),
    ("tsdf-unknown-key", ["tsdf", "smoke-00001", "voxel=0.1", "--out", "{ws}/new_tsdf"], "unknown config key"),
    # --- episodes ---
    ("gen-count-zero", ["episodes", "generate", "--name", "x", "--seed", "1", "--count", "0", "--out", "{ws}/n.jsonl"],
     "--count must be positive"),
    ("gen-count-huge", ["episodes", "generate", "--name", "x", "--seed", "1", "--count", "1000000000",
                        "--out", "{ws}/n.jsonl"], "at most 100000"),
    ("gen-seed-negative", ["episodes", "generate", "--name", "x", "--seed", "-1", "--count", "1",
                           "--out", "{ws}/n.jsonl"], "--seed must be"),
    ("gen-name-slash", ["episodes", "generate", "--name", "a/b", "--seed", "1", "--count", "1",
                        "--out", "{ws}/n.jsonl"], "--name"),
    ("gen-name-long", ["episodes", "generate", "--name", LONG, "--seed", "1", "--count", "1", "--out", "{ws}/n.jsonl"],
     "more characters"),
    ("gen-difficulty", ["episodes", "generate", "--name", "x", "--seed", "1", "--count", "1", "--difficulty", "hard",
                        "--out", "{ws}/n.jsonl"], "invalid choice"),
    ("gen-missing-arg", ["episodes", "generate", "--name", "x"], "required"),
    ("episodes-no-action", ["episodes"], "required"),
    # --- demo ---
    ("demo-seed-negative", ["demo", "--no-record", "--seed", "-1"], "--seed must be"),
    ("demo-hold-force", ["demo", "--no-record", "grasp.hold_force=-1"], "hold_force must be"),
    ("demo-camera-width", ["demo", "--no-record", "camera.width=0"], "width must be"),
    ("demo-camera-text", ["demo", "--no-record", "camera.width=abc"], "expected an integer"),
    ("demo-control-dt", ["demo", "--no-record", "motion.control_dt=0"], "control_dt must be"),
    ("demo-stream-nan", ["demo", "--no-record", "stream_hz=.nan"], "NaN"),
    ("demo-timestep", ["demo", "--no-record", "world.physics.timestep=0"], "timestep must be"),
    ("demo-unknown-key", ["demo", "--no-record", "camera.widht=320"], "unknown config key"),
    # --- spot ---
    ("spot-fake-and-host", ["spot", "--fake", "10.0.0.3", "--task", TASK], "leave out the hostname"),
    ("spot-no-host", ["spot", "--task", TASK], "HOSTNAME is required"),
    ("spot-task-empty", ["spot", "--fake", "--task", "  "], "--task must not be empty"),
    ("spot-task-long", ["spot", "--fake", "--task", LONG], "malformed task"),
    ("spot-task-long-object", ["spot", "--fake", "--task", f"Move the {LONG} from the stool to the table"],
     "unknown object"),
    ("spot-task-unknown", ["spot", "--fake", "--task", "Move the unicorn from the stool to the table"],
     "unknown object 'unicorn'"),
    ("spot-port-zero", ["spot", "10.0.0.3", "--task", TASK, "--port", "0"], "--port must be"),
    ("spot-port-huge", ["spot", "10.0.0.3", "--task", TASK, "--port", "70000"], "--port must be"),
    ("spot-seed-negative", [*SPOT, "--seed", "-1"], "--seed must be"),
    ("spot-name-slash", [*SPOT, "--name", "../escape"], "--name"),
    ("spot-episode-no-fake", ["spot", "10.0.0.3", "--episode", "smoke-00001"], "--episode needs --fake"),
    ("spot-episode-and-task", ["spot", "--fake", "--episode", "smoke-00001", "--task", TASK], "leave out --task"),
    ("spot-episode-unknown", ["spot", "--fake", "--episode", "smoke-99999", "--out", "{ws}/new_spot"],
     "no episode 'smoke-99999'"),
    ("spot-episode-split", ["spot", "--fake", "--episode", "nope-00001", "--out", "{ws}/new_spot"], "unknown split"),
    # the oracle loaded the models and ignored them; a -gt agent was refused after the robot stood (audit)
    ("spot-episode-oracle-real", ["spot", "--fake", "--episode", "smoke-00000", "--agent", "oracle", "--perception",
                                  "real", "--detector-weights", "{ws}", "--scorer-weights", "{ws}", "--out",
                                  "{ws}/new_spot"], "agent 'oracle' reads the simulator's ground truth"),
    ("spot-episode-gt-real", ["spot", "--fake", "--episode", "smoke-00000", "--agent", "helios-gt", "--perception",
                              "real", "--models", "{ws}/m.yaml", "--out", "{ws}/new_spot"],
     "--perception real: agent 'helios-gt' reads the simulator's ground truth and uses no detector; agents that take "
     "real perception: helios, helios-5050, helios-no-global, helios-place, trusting"),
    ("spot-agent-unknown", [*SPOT, "--agent", "nope"], "unknown agent 'nope'"),
    ("spot-agent-wrong-kind", [*SPOT, "--agent", "helios"], "runs on"),
    ("spot-set-timeout-zero", [*SPOT, "--out", "{ws}/new_spot", "--set", "rpc_timeout=0"], "rpc_timeout must be"),
    ("spot-set-timeout-nan", [*SPOT, "--out", "{ws}/new_spot", "--set", "rpc_timeout=.nan"], "NaN"),
    ("spot-set-timeout-huge", [*SPOT, "--out", "{ws}/new_spot", "--set", "arm_move_timeout=1000000000000"],
     "arm_move_timeout must be at most 600 s"),
    ("spot-set-margin-huge", [*SPOT, "--out", "{ws}/new_spot", "--set", "command_margin=1000000000000"],
     "command_margin must be within"),
    ("spot-set-jpeg", [*SPOT, "--out", "{ws}/new_spot", "--set", "jpeg_quality=0"], "jpeg_quality must be"),
    ("spot-set-tolerance", [*SPOT, "--out", "{ws}/new_spot", "--set", "goal_tolerance=5"], "goal_tolerance must be"),
    ("spot-set-control-dt", [*SPOT, "--out", "{ws}/new_spot", "--set", "motion.control_dt=0"], "control_dt must be"),
    ("spot-set-unknown", [*SPOT, "--out", "{ws}/new_spot", "--set", "rpc_timout=2"], "unknown config key"),
    # --- view, bench, calibrate-perception, the command line itself ---
    ("view-missing", ["view", "{ws}/nope.rrd"], "does not exist"),
    ("view-directory", ["view", "{ws}/adir"], "is a folder"),
    ("view-not-rrd", ["view", "{ws}/rec.txt"], "not a rerun recording"),
    # spot/demo/tsdf/view: inputs that were silently ignored or named the wrong problem (audit)
    ("spot-fake-set-hostname", [*SPOT, "--set", "hostname=10.1.2.3"], "--set hostname=... is ignored with --fake"),
    ("spot-fake-set-port", [*SPOT, "--set", "port=1234"], "--set port=... is ignored with --fake"),
    ("spot-fake-set-cert", [*SPOT, "--set", "rpc_timeout=2", "cert_path=/x.pem"],
     "--set cert_path=... is ignored with --fake"),
    ("spot-episode-set-port", ["spot", "--fake", "--episode", "smoke-00001", "--set", "port=1234"],
     "--set port=... is ignored with --fake"),
    ("spot-host-is-setting", ["spot", "--task", TASK, "rpc_timeout=2"],
     "hostname 'rpc_timeout=2' looks like a setting; pass settings with --set KEY=VALUE"),
    ("spot-fake-host-is-setting", [*SPOT, "rpc_timeout=2"], "hostname 'rpc_timeout=2' looks like a setting"),
    ("demo-out-no-record", ["demo", "--no-record", "--out", "{ws}/new_demo"], "with --no-record"),
    ("demo-out-file-no-record", ["demo", "--no-record", "--out", "{ws}/afile"], "with --no-record"),
    ("demo-out-rrd", ["demo", "--out", "{ws}/x.rrd"], "is a folder, not the recording: the recording is named "
                                                      "demo_seed0.rrd inside it"),
    ("tsdf-split-and-file", ["tsdf", "smoke-00001", "--split", "bogus", "--episodes-file", E + "duplicate.jsonl",
                             "--out", "{ws}/new_tsdf"], "--split and --episodes-file"),
    ("tsdf-episode-not-in-split", ["tsdf", "smoke-00003", "--split", "val", "--out", "{ws}/new_tsdf"],
     "no episode 'smoke-00003' in split 'val'"),
    ("view-empty", ["view", ""], "recording path must not be empty"),
    ("bench-unknown", ["bench", "simulator"], "unknown benchmark suite"),
    # agents of your own (tasks.plugin_agents): checked before any work, the user's folder untouched
    ("trials-helios-mode-gt", [*T, "--agent", "helios", "perception.mode=gt"],
     "which sets perception.mode='noisy' itself; leave it out, or run agent 'helios-gt'"),
    ("agent-plugin-no-file", [*T, "--agent", A + "nope.py:make"], "no such file"),
    ("agent-plugin-folder", [*T, "--agent", A + "dir.py:make"], "(it is a folder)"),
    ("agent-plugin-syntax", [*T, "--agent", A + "syntax.py:make"], "raised SyntaxError (line 1)"),
    ("agent-plugin-raises", [*T, "--agent", A + "raises.py:make"], "raised ZeroDivisionError (line 2)"),
    ("agent-plugin-no-factory", [*T, "--agent", A + "good.py:mk"], "has no 'mk'; its functions and classes: Agent, make"),
    ("agent-plugin-not-callable", [*T, "--agent", A + "good.py:LIMIT"], "is a value of type int, not a factory"),
    ("agent-plugin-not-a-name", [*T, "--agent", A + "good.py:1x"], "is not a Python name"),
    ("agent-plugin-not-a-module", [*T, "--agent", "my agent:make"], "is neither a .py file nor a module name"),
    ("agent-plugin-no-module", [*T, "--agent", "no_such_pkg.agents:make"], "no module 'no_such_pkg.agents'"),
    ("agent-plugin-no-source", [*T, "--agent", ":make"], "give your own agent as FILE.py:FACTORY"),
    ("agent-plugin-no-factory-name", [*T, "--agent", A + "good.py:"], "give your own agent as FILE.py:FACTORY"),
    ("agent-plugin-reads-str", [*T, "--agent", A + "reads_str.py:make"], "its reads must be a tuple"),
    ("agent-plugin-reads-sim", [*T, "--agent", A + "reads_sim.py:make"], "its reads names 'sim'"),
    ("agent-plugin-unread-section", [*T, "--agent", A + "good.py:make", "perception.mode=gt"],
     "perception.mode: agent"),
    ("agent-plugin-ray", [*T, "--agent", A + "good.py:make", "--executor", "ray"], "runs on local workers"),
    ("agent-plugin-cuda", [*T, "--agent", A + "reads_helios.py:make", "helios.device=cuda"], "helios.device=cuda: "),
    ("spot-agent-plugin", ["spot", "--fake", "--episode", "smoke-00001", "--agent", A + "good.py:make", "--out",
                           "{ws}/new_spot"], "agents of your own run in simulated trials"),
    ("bench-agent-plugin", ["bench", "agent", "--agent-name", A + "good.py:make"], "the benchmarks time registered"),
    ("bench-seed", ["bench", "sim", "--seed", "-1"], "--seed must be"),
    ("bench-trials-workers", ["bench", "trials", "--trials-workers", "1,x"], "--trials-workers"),
    ("bench-trials-workers-zero", ["bench", "trials", "--trials-workers", "0"], "--trials-workers"),
    ("bench-agent-episodes", ["bench", "agent", "--agent-episodes", "0"], "--agent-episodes must be"),
    ("bench-agent-set-replaced", ["bench", "agent", "--agent-name", "helios-5050", "--agent-set",
                                  "helios.search.information_gain=optimistic"],
     "which sets helios.search.information_gain='fifty_fifty' itself"),
    ("bench-maps-recording", ["bench", "maps", "--maps-recording", "{ws}/nope.npz"], "is not a file"),
    ("bench-agent-baseline", ["bench", "agent", "--agent-baseline", "no-such-commit-or-file"],
     "neither a file nor a commit"),
    ("bench-agent-baseline-file", ["bench", "agent", "--agent-baseline", "{ws}/rec.txt"], "--agent-baseline"),
    ("bench-agent-save", ["bench", "agent", "--agent-save", "{ws}/nope/bench.json"], "does not exist"),
    ("bench-agent-seed", ["bench", "agent", "--agent-seed", "first"], "--agent-seed must be a master seed within"),
    ("bench-maps-device", ["bench", "agent", "maps", "--maps-device", "cuda"], "no CUDA device"),
    ("calibrate-views", ["calibrate-perception", "--views", "0", "--out", "{ws}/new_cal"], "--views"),
    ("calibrate-group", ["calibrate-perception", "--group", "0", "--out", "{ws}/new_cal"], "--group"),
    ("calibrate-scenes", ["calibrate-perception", "--scenes", "0", "--out", "{ws}/new_cal"], "--scenes"),
    ("calibrate-seed", ["calibrate-perception", "--seed", "-1", "--out", "{ws}/new_cal"], "--seed must be"),
    ("calibrate-split", ["calibrate-perception", "--split", "nope", "--out", "{ws}/new_cal"], "unknown split"),
    ("calibrate-pixels", ["calibrate-perception", "--min-pixels", "0", "--out", "{ws}/new_cal"], "--min-pixels"),
    ("calibrate-gt", ["calibrate-perception", "--out", "{ws}/new_cal", "mode=gt"], "mode=gt"),
    ("calibrate-probability", ["calibrate-perception", "--out", "{ws}/new_cal", "p_detect_object=2"],
     "p_detect_object must be"),
    # bench / calibrate-perception: options checked before the first suite or view, none ignored or capped (audit)
    ("bench-agent-repeats-before-scenes", ["bench", "scenes", "agent", "--quick", "--agent-repeats", "0"],
     "--agent-repeats must be within 1..20, got 0"),
    ("bench-agent-baseline-empty-file", ["bench", "scenes", "agent", "--quick", "--agent-baseline", "{ws}/empty.rrd"],
     "not a readable JSON file"),
    ("bench-agent-option-unselected", ["bench", "scenes", "--quick", "--agent-repeats", "0", "--agent-seed", "banana"],
     "--agent-repeats applies to the 'agent' suite, which is not selected"),
    ("bench-trials-option-unselected", ["bench", "sim", "--trials-episodes", "3"],
     "--trials-episodes applies to the 'trials' suite, which is not selected"),
    ("bench-maps-option-unselected", ["bench", "agent", "--maps-synthetic"],
     "--maps-synthetic applies to the 'maps' suite, which is not selected"),
    ("bench-agent-quick-explicit", ["bench", "agent", "--quick", "--agent-episodes", "1001"],
     "--agent-episodes 1001 is more than the 1000 val episodes"),
    ("bench-trials-quick-explicit", ["bench", "trials", "--quick", "--trials-episodes", "21"],
     "--trials-episodes must be in 1..20"),
    ("calibrate-baseline-not-calibration", ["calibrate-perception", "--out", "{ws}/new_cal", "--baseline",
                                            E + "schema.jsonl"], "not a calibration.json of this tool: "
                                                                 "['task_query'] is missing"),
    ("calibrate-baseline-empty", ["calibrate-perception", "--out", "{ws}/new_cal", "--baseline", ""],
     "--baseline must not be empty"),
    ("calibrate-scenes-more-than-split", ["calibrate-perception", "--split", "smoke", "--scenes", "500", "--views",
                                          "25", "--out", "{ws}/new_cal"],
     "--scenes 500 is more than the 20 distinct scenes of split 'smoke'"),
    ("no-command", [], "required"),
    ("unknown-command", ["trails"], "invalid choice"),
    # config values (QA 2026-12-04)
    ("override-date", [*T, "seed=2024-13-45"], "cannot parse value (month must be in 1..12)"),
    ("override-float-tag", [*T, "runner.max_sim_time=!!float abc"], "cannot parse value"),
    ("override-int-tag", [*T, "runner.max_commands=!!int abc"], "cannot parse value"),
    ("override-nested", [*T, "seed=" + "[" * 50_000], "cannot parse value"),
    ("override-nested-closed", [*T, "seed=" + "[" * 1500 + "]" * 1500], "cannot parse value"),
    # explicitly tagged text PyYAML's constructors crashed on (IndexError, KeyError, AttributeError)
    ("override-float-tag-empty", [*T, 'seed=!!float ""'], "cannot parse value ('' is not a number"),
    ("override-bool-tag", [*T, "seed=!!bool maybe"], "cannot parse value ('maybe' is not true or false)"),
    ("override-timestamp-tag", [*T, "seed=!!timestamp soon"], "cannot parse value ('soon' is not a date"),
    ("cfg-bool-tag", ["trials", "--config", C + "bool_tag.yaml", "--out", "{ws}/new_run"],
     "bool_tag.yaml' is not valid YAML (line 2, column 9): 'x' is not true or false"),
    ("override-duplicate-key", [*T, "agent_config={max_walk_chunks: 3, max_walk_chunks: 4}"],
     "found duplicate key 'max_walk_chunks'"),
    ("spot-set-date", [*SPOT, "--out", "{ws}/new_spot", "--set", "rpc_timeout=2024-13-45"], "cannot parse value"),
    ("demo-float-tag", ["demo", "--no-record", "stream_hz=!!float abc"], "cannot parse value"),
    ("tsdf-date", ["tsdf", "smoke-00001", "voxel_size=2024-13-45", "--out", "{ws}/new_tsdf"], "cannot parse value"),
    ("calibrate-int-tag", ["calibrate-perception", "--out", "{ws}/new_cal", "min_pixels=!!int abc"],
     "cannot parse value"),
    ("cfg-duplicate-key", ["trials", "--config", C + "duplicate.yaml", "--out", "{ws}/new_run"],
     "found duplicate key 'runner'"),
    ("perception-category-unknown", [*T, "--agent", "helios", "perception.category_difficulty={unicorn: 1.0}"],
     "unknown category ('unicorn')"),
    ("perception-category-oracle", [*T, "--agent", "oracle", "perception.category_difficulty={glas: 1.0}"],
     "did you mean 'glass'"),
    ("calibrate-category-unknown", ["calibrate-perception", "--views", "5", "--out", "{ws}/new_cal",
                                    "category_difficulty={unicorn: 1.0}"], "unknown category ('unicorn')"),
    ("background-class-task", [*T, "--agent", "helios", "helios.background_class=cup"],
     "background_class 'cup' is a category"),
    ("perception-morph-huge", [*T, "perception.mask_morph_px=1000000000000"], "mask_morph_px must be in [0, 64]"),
    ("calibrate-morph-huge", ["calibrate-perception", "--views", "5", "--group", "5", "--scenes", "1",
                              "--out", "{ws}/new_cal", "mask_morph_px=100000"], "mask_morph_px must be in [0, 64]"),
    ("perception-shift-huge", [*T, "perception.mask_shift_px=100000"], "mask_shift_px must be"),
    ("perception-bins-huge", [*T, "perception.azimuth_bins=1000000000000"], "azimuth_bins must be in [1, 360]"),
    ("perception-min-pixels-huge", [*T, "perception.min_pixels=1000000000000"], "min_pixels must be"),
    ("perception-gt-pixels-huge", [*T, "perception.gt_min_pixels=1000000000000"], "gt_min_pixels must be"),
    ("perception-distance-huge", [*T, "perception.distance_half_object=1.0e+12"], "distance_half_object must be"),
    ("perception-edges-huge", [*T, "perception.distance_edges=[1.5, 1.0e+12]"], "distance_edges must lie in"),
    ("tsdf-block-count-memory", ["tsdf", "smoke-00001", "block_count=10000000", "--out", "{ws}/new_tsdf"],
     "would preallocate 762.9 GiB"),
    ("tsdf-block-resolution-memory", ["tsdf", "smoke-00001", "block_resolution=64", "--out", "{ws}/new_tsdf"],
     "block_count <= 819 at this block_resolution"),
    # report and run folders (QA 2026-12-04)
    ("report-names-long", [*REPORT, "--names", "n" * 5000, "--out", "{ws}/new_rep"], "at most 100"),
    ("report-names-control", [*REPORT, "--names", "a\nb", "--out", "{ws}/new_rep"], "control character"),
    ("report-out-in-run", [*REPORT, "--out", R + "valid/episodes"], "is inside run folder"),
    ("report-out-deep-in-run", [*REPORT, "--out", R + "valid/episodes/sub/rep"], "own 'episodes'"),
    ("report-out-in-run-file", [*REPORT, "--out", R + "valid/episodes.jsonl/rep"], "own 'episodes.jsonl'"),
    ("report-out-not-utf8", [*REPORT, "--out", "{ws}/rep\udcff"], "not UTF-8"),
    ("report-run-not-utf8", ["report", R + "r\udcff", "--out", "{ws}/new_rep"], "not UTF-8"),
    ("diff-run-not-utf8", ["diff", R + "valid", R + "r\udcff"], "not UTF-8"),
    ("trials-out-not-utf8", [*T[:-2], "--out", "{ws}/run\udcff"], "not UTF-8"),      # report could not read it
    ("tsdf-out-not-utf8", ["tsdf", "smoke-00001", "--out", "{ws}/ts\udcff"], "not UTF-8"),
    # spot, bench, episodes, ray (QA 2026-12-04)
    ("spot-demo-on-goal", [*SPOT, "--on-goal", "maybe"], "--on-goal is for task-episode agents"),
    ("spot-demo-at-rest", [*SPOT, "--at-rest", "2"], "--at-rest is for task-episode agents"),
    ("spot-demo-trial-id", [*SPOT, "--trial-id", "../../etc"], "--trial-id is for task-episode agents"),
    ("spot-demo-models", [*SPOT, "--models", "/nonexistent.yaml"], "--models is for task-episode agents"),
    ("spot-demo-detector", [*SPOT, "--detector-weights", "/nonexistent"], "--detector-weights is for task-episode"),
    ("spot-demo-device", [*SPOT, "--device", "cuda"], "--device is for task-episode agents"),
    ("spot-demo-max-time", [*SPOT, "--max-time", "5"], "--max-time is for task-episode agents"),
    ("spot-demo-no-recording", [*SPOT, "--no-recording"], "--no-recording is for task-episode agents"),
    ("spot-demo-robot-on-goal", ["spot", "10.0.0.3", "--task", TASK, "--on-goal", "yes"], "--on-goal is for"),
    ("spot-fake-cert", [*SPOT, "--cert", "/nonexistent.pem"], "--cert is ignored with --fake"),
    ("spot-fake-port", [*SPOT, "--port", "443"], "--port is ignored with --fake"),
    ("spot-split-without-episode", [*SPOT, "--split", "smoke"], "without --episode it is ignored"),
    ("spot-robot-cert-missing", ["spot", "10.0.0.3", "--task", TASK, "--cert", "{ws}/nope.pem"], "does not exist"),
    ("spot-robot-cert-dev-null", ["spot", "10.0.0.3", "--task", TASK, "--cert", "/dev/null"], "is not a regular file"),
    ("spot-robot-trial-id", ["spot", "10.0.0.3", "--agent", "helios", "--task", TASK, "--detector-weights", "{ws}/adir",
                             "--scorer-weights", "{ws}/adir", "--trial-id", "../../etc"], "--trial-id '../../etc'"),
    ("spot-robot-on-goal-value", ["spot", "10.0.0.3", "--agent", "helios", "--task", TASK, "--detector-weights",
                                  "{ws}/adir", "--scorer-weights", "{ws}/adir", "--on-goal", "maybe", "--at-rest", "yes"],
     "--on-goal must be yes or no"),
    ("spot-episode-trial-id", ["spot", "--fake", "--episode", "smoke-00001", "--trial-id", "x"], "with --episode"),
    ("spot-episode-models-sim", ["spot", "--fake", "--episode", "smoke-00001", "--models", "/nonexistent.yaml"],
     "ignored with --perception sim"),
    ("spot-episode-extra-collisions", ["spot", "--fake", "--episode", "smoke-00001", "--extra-collisions", "1"],
     "ignored with --fake --episode"),
    ("spot-seed-huge", [*SPOT, "--seed", "99999999999999"], "--seed must be within 0..4294967295"),
    ("bench-seed-huge", ["bench", "sim", "--seed", "99999999999999"], "--seed must be within 0..4294967295"),
    ("calibrate-seed-huge", ["calibrate-perception", "--seed", "99999999999999", "--out", "{ws}/new_cal"],
     "--seed must be within 0..4294967295"),
    ("gen-seed-huge", ["episodes", "generate", "--name", "x", "--seed", "99999999999999", "--count", "1",
                       "--out", "{ws}/n.jsonl"], "--seed must be within 0..4294967295"),
    ("bench-trials-agent", ["bench", "trials", "--trials-agent", "nope"], "--trials-agent: unknown agent 'nope'"),
    ("bench-agent-name-late", ["bench", "sim", "agent", "--agent-name", "nope"], "--agent-name: unknown agent 'nope'"),
    ("bench-trials-split", ["bench", "sim", "trials", "--trials-split", "nope"], "unknown split 'nope'"),
    ("bench-trials-episodes-many", ["bench", "trials", "--trials-episodes", "21"], "--trials-episodes must be in 1..20"),
    ("bench-trials-workers-twice", ["bench", "trials", "--trials-workers", "1,1"], "--trials-workers: 1 is given twice"),
    ("bench-suite-twice", ["bench", "sim", "sim"], "suite 'sim' is given twice"),
    ("bench-maps-recording-not-npz", ["bench", "maps", "--maps-recording", "{ws}/rec.txt"], "not a trajectory .npz"),
    ("bench-maps-recording-no-arrays", ["bench", "maps", "--maps-recording", "{ws}/arrays.npz"], "lacks the arrays"),
    ("ep-check-target-missing", ["episodes", "check", E + "target_missing.jsonl"], "'cup_99' is not in its home"),
    ("ep-check-start-outside", ["episodes", "check", E + "start_outside.jsonl"], "outside its home"),
    ("ep-check-difficulty", ["episodes", "check", E + "difficulty.jsonl"],
     "difficulty.jsonl:1: difficulty 'insane' is not one of: easy, normal"),
    ("ep-difficulty", [*T, "--episodes-file", E + "difficulty.jsonl"], "difficulty.jsonl:1: difficulty 'insane'"),
    ("ep-check-duplicate-key", ["episodes", "check", E + "duplicate_key.jsonl"],
     "duplicate_key.jsonl:1: key 'difficulty' appears twice"),
    ("ep-duplicate-key", [*T, "--episodes-file", E + "duplicate_key.jsonl"], "key 'difficulty' appears twice"),
    ("ep-duplicate-key-nested", [*T, "--episodes-file", E + "duplicate_key_scene.jsonl"], "key 'seed' appears twice"),
    ("ep-check-goal-twice", ["episodes", "check", E + "goal_twice.jsonl"],
     f"goal_twice.jsonl:1: goal receptacle {GOAL_1!r} is listed twice"),
    ("ep-goal-twice", [*T, "--episodes-file", E + "goal_twice.jsonl"], "is listed twice"),
    ("ep-check-goal-is-start", ["episodes", "check", E + "goal_is_start.jsonl"],
     "goal_is_start.jsonl:1: the start receptacle"),
    ("ep-goal-is-start", [*T, "--episodes-file", E + "goal_is_start.jsonl"], "is also a goal receptacle"),
    ("ep-dev-null", [*T, "--episodes-file", "/dev/null"], "is not a regular file"),
    ("cfg-dev-null", ["trials", "--config", "/dev/null", "--out", "{ws}/new_run"], "is not a regular file"),
    ("spot-cfg-dev-null", [*SPOT, "--config", "/dev/null"], "is not a regular file"),
    ("view-dev-null", ["view", "/dev/null"], "is not a regular file"),
    ("view-random-bytes", ["view", "--print", "{ws}/random.rrd"], "does not start with a .rrd header"),
    ("view-empty-rrd", ["view", "--print", "{ws}/empty.rrd"], "does not start with a .rrd header"),
    # the audit of 2026-12-05: settings a run would record but not use, and inputs that passed unseen
    ("trials-split-and-file", [*T, "--split", "val", "--episodes-file", E + "duplicate.jsonl"],
     "--split and --episodes-file both name the episodes"),
    ("trials-bogus-split-in-cfg", [*T, "--episodes-file", E + "duplicate.jsonl", "split=vall"],
     "unknown split 'vall'"),
    ("oracle-agent-config", [*T, "--agent", "oracle", "agent_config.max_pick_attempts=1"],
     "agent 'oracle' reads no agent_config.* settings"),
    ("oracle-helios-cfg", ["trials", "--config", C + "oracle_helios.yaml", "--out", "{ws}/new_run"],
     "helios.*: agent 'oracle' reads no helios.* settings"),
    ("gt-noisy", [*T, "--agent", "helios-gt", "perception.mode=noisy"],
     "with agent 'helios-gt', which sets perception.mode='gt' itself"),
    ("5050-optimistic", [*T, "--agent", "helios-5050", "helios.search.information_gain=optimistic"],
     "which sets helios.search.information_gain='fifty_fifty' itself"),
    ("trusting-variant", [*T, "--agent", "trusting", "agent_config.variant=no_global"],
     "which sets agent_config.variant='trusting' itself"),
    ("place-variant-mode", [*T, "--agent", "helios-place-gt", "agent_config.place.mode=drop"],
     "which sets agent_config.place.mode='improved' itself"),
    ("cfg-empty", ["trials", "--config", C + "empty.yaml", "--out", "{ws}/new_run"], "holds no settings"),
    ("cfg-comments-only", ["trials", "--config", C + "comments.yaml", "--out", "{ws}/new_run"],
     "holds no settings"),
    ("demo-cfg-empty", ["demo", "--no-record", "--config", C + "empty.yaml"], "holds no settings"),
    ("diff-same-folder", ["diff", R + "valid", R + "valid/"], "are the same folder"),
    ("flag-twice", [*T, "--out", "{ws}/new_run2"], "helios trials: --out is given twice"),
    ("flag-twice-equals", ["report", R + "valid", "--out={ws}/rep", "--out", "{ws}/rep2"], "--out is given twice"),
    ("report-same-folder", ["report", R + "valid", R + "other", R + "valid/", "--out", "{ws}/rep"],
     "is given twice (also as"),
    ("diff-ignore-metric-typo", ["diff", R + "valid", R + "other", "--ignore", "metrics.findobj"],
     "'findobj' is not a field of metrics"),
    ("unchanged-ignore-typo", ["unchanged", "HEAD", "--ignore", "metrics.findobj", "--out", "{ws}/unch"],
     "'findobj' is not a field of metrics"),
    ("unchanged-ignore-top-typo", ["unchanged", "HEAD", "--ignore", "wall_tme", "--out", "{ws}/unch"],
     "'wall_tme' is not a field of an episode record"),
    # the audit of 2026-12-05 (session 35): inputs that were taken as something else, dropped, or a traceback
    ("flag-shortened", [*T, "--ou", "{ws}/new_run2"], "unrecognized arguments: --ou"),
    ("report-flag-shortened", ["report", R + "valid", "--nam", "x", "--out", "{ws}/rep"],
     "unrecognized arguments: --nam"),
    ("gen-two-values-twice", ["episodes", "generate", "--name", "x", "--seed", "1", "--count", "1", "--home-size", "8",
                              "9", "--home-size", "10", "12", "--out", "{ws}/n.jsonl"],
     "helios episodes generate: --home-size is given twice ('--home-size 8 9' and '--home-size 10 12')"),
    ("trials-flag-and-override", [*T, "episodes=3"], "--episodes and 'episodes=3' both set episodes; give one"),
    ("trials-agent-flag-and-override", [*T, "--agent", "helios", "agent=oracle"], "both set agent"),
    ("trials-split-flag-file-override", ["trials", "--split", "val", "episodes_file=" + E + "duplicate.jsonl",
                                         "--out", "{ws}/new_run"], "both name the episodes"),
    ("trials-out-empty-string", ["trials", "--episodes", "1", "--out="], "--out must not be empty"),
    ("trials-split-flag-empty", ["trials", "--episodes", "1", "--split=", "--out", "{ws}/new_run"],
     "--split must not be empty"),
    ("trials-agent-flag-empty", ["trials", "--episodes", "1", "--agent=", "--out", "{ws}/new_run"],
     "--agent must not be empty"),
    ("trials-config-empty", ["trials", "--config=", "--out", "{ws}/new_run"], "--config must not be empty"),
    ("trials-episodes-file-empty", [*T, "--episodes-file="], "--episodes-file must not be empty"),
    ("gen-out-fifo", ["episodes", "generate", "--name", "x", "--seed", "1", "--count", "1", "--out", "{ws}/fifo"],
     "is a device, FIFO or socket; it must name a regular file"),
    ("trials-seed-hex", [*T, "seed=0x10"], "seed: expected an integer, got '0x10'"),
    ("trials-time-base-60", [*T, "runner.max_sim_time=1:30"], "runner.max_sim_time: expected a number, got '1:30'"),
    ("trials-gt-noise", [*T, "--agent", "helios-gt", "perception.p_detect_object=0.5"],
     "perception.p_detect_object would change nothing with agent 'helios-gt': ground-truth semantics"),
    ("trials-gt-min-pixels-noisy", [*T, "--agent", "helios", "perception.gt_min_pixels=5"],
     "applies only with perception.gt_roles"),
    ("trials-arm-swing-measured", [*T, "--agent", "helios", "agent_config.view.arm_swing_radius=0.6"],
     "the measured arm model"),
    # the read tracer's session (tests/test_config_reads.py): what the trusting variant never reaches
    ("trusting-decision-tau", [*T, "--agent", "trusting", "helios.decision.tau_object=0.7"],
     "helios.decision.tau_object would change nothing with agent 'trusting': the trusting variant "
     "(agent_config.variant=trusting) keeps no object map"),
    ("trusting-gt-gaze-spacing", [*T, "--agent", "trusting-gt", "agent_config.gaze.spacing=0.4"],
     "agent_config.gaze.spacing would change nothing with agent 'trusting-gt': the trusting variant"),
    ("helios-as-trusting-support", [*T, "--agent", "helios", "agent_config.variant=trusting",
                                    "agent_config.support_radius=0.5"],
     "agent_config.support_radius would change nothing with agent 'helios': the trusting variant"),
    ("trusting-alpha-d", [*T, "--agent", "trusting", "helios.search.alpha_d=0.01"],
     "goes to the highest-value frontier (helios.search.frontier_choice=highest_value)"),
    ("trusting-cfg-local-search", ["trials", "--config", C + "trusting_local.yaml", "--out", "{ws}/new_run"],
     "agent_config.local_search_views (set in the scenario file) would change nothing with agent 'trusting'"),
    ("bench-agent-trusting-set", ["bench", "agent", "--agent-name", "trusting", "--agent-set",
                                  "helios.decision.cs_object=0.4"],
     "helios.decision.cs_object would change nothing with agent 'trusting'"),
    ("gt-scorer-object-saturation", [*T, "--agent", "helios-gt", "perception.scorer_saturation_object=0.01"],
     "the agents ask the image-text scorer only about receptacles"),
    # settings only a part of the agent reads that its switch turns off (tasks.registry.ONLY_WITH)
    ("trials-stall-radius-stall-off", [*T, "--agent", "helios", "agent_config.stall_steps=0",
                                       "agent_config.stall_radius=0.8"],
     "agent_config.stall_radius would change nothing with agent 'helios': exploration stall detection, which alone "
     "reads it, is off (agent_config.stall_steps=0; a count above 0 turns it on); leave it out"),
    ("trials-stall-area-stall-off", [*T, "--agent", "trusting", "agent_config.stall_steps=0",
                                     "agent_config.stall_new_area=1"],
     "agent_config.stall_new_area would change nothing with agent 'trusting': exploration stall detection"),
    ("trials-improved-height-drop", [*T, "--agent", "helios-gt", "agent_config.place.improved_height=0.05"],
     "the improved place, which alone reads it, is off (agent_config.place.mode=drop; improved turns it on)"),
    ("trials-cfg-top-band-drop", ["trials", "--config", C + "drop_top_band.yaml", "--out", "{ws}/new_run"],
     "agent_config.place.top_band (set in the scenario file) would change nothing with agent 'helios': the "
     "improved place"),
    ("trials-surface-cell-drop", [*T, "--agent", "helios-no-global", "agent_config.place.surface_cell=0.05"],
     "(agent_config.place.mode=drop; improved turns it on)"),
    ("trials-min-gain-all-views", [*T, "--agent", "helios", "agent_config.local_search_views=all",
                                   "agent_config.local_search_min_gain=0.2"],
     "local search's choice of informative gaze points, which alone reads it, is off "
     "(agent_config.local_search_views=all; informative turns it on)"),
    ("trials-revisit-spacing-no-revisits", [*T, "--agent", "helios-5050", "agent_config.max_revisits=0",
                                            "agent_config.revisit_spacing=2"],
     "revisiting the most promising seen places, which alone reads it, is off (agent_config.max_revisits=0"),
    ("trials-tau-increase-no-looks", [*T, "--agent", "helios-place-gt", "agent_config.max_looks_per_candidate=0",
                                      "helios.decision.tau_increase=0.1"],
     "helios.decision.tau_increase would change nothing with agent 'helios-place-gt': taking extra views of a "
     "candidate, which alone reads it, is off (agent_config.max_looks_per_candidate=0"),
    ("trials-fresh-view-no-looks", [*T, "--agent", "helios", "agent_config.max_looks_per_candidate=0",
                                    "agent_config.fresh_view_distance=0.3"],
     "agent_config.fresh_view_distance would change nothing with agent 'helios': taking extra views"),
    ("bench-agent-revisits-off-set", ["bench", "agent", "--agent-name", "helios", "--agent-set",
                                      "agent_config.max_revisits=0", "--agent-set", "agent_config.revisit_candidates=3"],
     "agent_config.revisit_candidates would change nothing with agent 'helios': revisiting"),
    ("trials-drop-height-improved-place", [*T, "--agent", "helios-place", "agent_config.place.drop_height=0.2"],
     "agent_config.place.drop_height would change nothing with agent 'helios-place': the paper's drop, which alone "
     "reads it, is off (agent_config.place.mode=improved; drop turns it on)"),
    ("trials-near-yaws-no-near-views", [*T, "--agent", "trusting", "agent_config.view.near_look_distance=0",
                                        "agent_config.view.start_near_yaws_deg=[-90,90]"],
     "agent_config.view.start_near_yaws_deg would change nothing with agent 'trusting': the views of the near "
     "floor, which alone reads it, is off (agent_config.view.near_look_distance=0.0; a distance above 0 turns it on)"),
    ("ep-robot-start-overflows", ["episodes", "check", E + "start_overflow.jsonl"],
     "robot_start must be 3 finite numbers"),
    ("ep-robot-start-bool", [*T, "--episodes-file", E + "start_bool.jsonl"], "robot_start must be 3 finite numbers"),
    ("ep-scene-size-overflows", ["episodes", "check", E + "scene_overflow.jsonl"], "field 'scene' needs"),
    ("ep-seed-5000-digits", [*T, "--episodes-file", E + "seed_digits.jsonl"], "not valid JSON (Exceeds the limit"),
    ("calibrate-baseline-fifo", ["calibrate-perception", "--views", "5", "--baseline", "{ws}/fifo",
                                 "--out", "{ws}/cal"], "is not a regular file"),
    ("report-symlink-loop", ["report", "{ws}/loop", "--out", "{ws}/rep"], "cannot be resolved (a symbolic link loop)"),
    ("diff-symlink-loop", ["diff", "{ws}/loop", R + "valid"], "cannot be resolved (a symbolic link loop)"),
    ("report-out-symlink-loop", ["report", R + "valid", "--out", "{ws}/loop"],
     "/loop' cannot be resolved (a symbolic link loop)"),
    ("trials-episodes-folder-unwritable", ["trials", "--episodes", "1", "--out", "{ws}/ro_run"],
     "ro_run': its episodes/ folder"),
    ("trials-map-smaller-than-homes", [*T, "--agent", "helios", "helios.occupancy.grid_size=64"],
     "helios.occupancy.grid_size=64 cells of 0.025 m is a 1.6 m map, narrower than these episodes' homes"),
    ("report-names-twice", ["report", R + "valid", R + "other", "--names", "x,x", "--out", "{ws}/rep"],
     "--names: the name 'x' is given twice"),
    ("trials-record-beyond", [*T, "--record", "1000000"], "--record 1000000 is more than the 1 episode(s)"),
    ("bench-seed-unread", ["bench", "scenes", "--quick", "--seed", "12345"],
     "--seed is read by the agent suite and by maps --maps-synthetic only"),
    ("bench-maps-recording-and-synthetic", ["bench", "maps", "--maps-recording", "{ws}/rec.txt", "--maps-synthetic"],
     "--maps-synthetic and --maps-recording both choose"),
    ("tsdf-episodes-file-empty", ["tsdf", "smoke-00000", "--episodes-file="], "--episodes-file must not be empty"),
    ("tsdf-split-empty", ["tsdf", "smoke-00000", "--split="], "--split must not be empty"),
    ("spot-split-empty", ["spot", "--fake", "--episode", "smoke-00000", "--split="], "--split must not be empty"),
    ("bench-agent-oracle", ["bench", "agent", "--agent-name", "oracle"], "the oracle keeps no timings"),
    ("bench-agent-save-folder", ["bench", "agent", "--agent-save", "{ws}/adir"], "is a folder; it must name a file"),
    ("bench-agent-save-empty", ["bench", "agent", "--agent-save="], "--agent-save must not be empty"),
    ("bench-agent-baseline-partial", ["bench", "agent", "--agent-baseline", "{ws}/bench_partial.json"],
     "a damaged `bench agent --agent-save` file: median_wall is missing"),
    ("spot-name-reused", [*SPOT, "--out", "{ws}/spotruns", "--name", "a"],
     "already holds a run (outcome.json); give another --name"),
    ("spot-seed-scripted-robot", ["spot", "127.0.0.1", "--task", TASK, "--seed", "7", "--out", "{ws}/spotruns"],
     "--seed is ignored by agent 'scripted-demo' on a robot"),
]
# Files the QA 2026-12-04 cases read, written into the workspace (path under it -> bytes)
QA_FILES: dict[str, bytes] = {
    "eps/difficulty.jsonl": _episode(difficulty="insane").encode(),
    "eps/duplicate_key.jsonl": ('{"difficulty": "easy", ' + _episode()[1:]).encode(),
    "eps/duplicate_key_scene.jsonl": _episode().replace('"scene": {', '"scene": {"seed": 1, ').encode(),
    "eps/goal_twice.jsonl": _episode(goal_receptacles=[GOAL_1, GOAL_1]).encode(),
    "eps/goal_is_start.jsonl": _episode(goal_receptacles=[GOAL_1, load_split("smoke")[1].start_receptacle]).encode(),
    "random.rrd": bytes(range(256)) * 4,
    "empty.rrd": b"",
    "arrays.npz": b"PK\x05\x06" + b"\0" * 18,         # an empty zip: a .npz without any array
    "bench_partial.json": b'{"format": "helios-bench-agent/1"}',
    "spotruns/a/outcome.json": b'{"agent": "scripted-demo"}',
}


@pytest.fixture
def in_ws(ws, monkeypatch):
    monkeypatch.chdir(ws)                  # default output folders (runs/...) land in the workspace too
    return ws


def _unwritable_works() -> bool:
    try:
        Path(UNWRITABLE).mkdir(parents=True)
    except OSError:
        return True
    return False


def test_the_corpus_is_big_and_covers_every_command():
    assert len(CASES) >= 150
    assert len({c[0] for c in CASES}) == len(CASES)
    from tools.cli import COMMANDS

    assert {argv[0] for _, argv, _ in CASES if argv} >= set(COMMANDS)
    # the README's counts are this corpus's (they were 5 cases behind: audit 2026-12-05)
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")
    assert f"{len(CASES)} bad inputs over all commands, {len(DAMAGES)} run-folder damages" in readme


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_bad_input_is_one_clear_line_and_changes_nothing(case, in_ws):
    name, argv, fragment = case
    if name in ("bench-maps-device", "agent-plugin-cuda"):
        import torch

        if torch.cuda.is_available():
            pytest.skip("this machine has a CUDA device")
    if UNWRITABLE in argv or any(UNWRITABLE in a for a in argv):
        if not _unwritable_works():
            pytest.skip("no unwritable folder on this machine")
    argv = [a.replace("{ws}", str(in_ws)) for a in argv]
    before = snapshot(in_ws)
    t0 = time.perf_counter()
    rc, out, err = run_cli(argv)
    assert time.perf_counter() - t0 < 15, "a bad input must fail fast"
    assert rc == 2, (rc, out[-2000:], err[-2000:])
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err[-3000:]
    assert "Traceback" not in err + out
    assert len(lines[0]) <= 1200, "long inputs are shortened"
    assert fragment in lines[0], lines[0]
    assert snapshot(in_ws) == before, "a bad input changed the workspace"


def test_every_numeric_config_field_has_a_range():
    """For every number in every config tree the command line can set, an absurd value (-1e12 or
    +1e12) is refused. Exempt: fields the realism helper's perception config owns that have no
    natural bound (logits, gains), and the agent's gaze settings (owned by helios/search)."""
    import dataclasses
    import typing

    from helios.schema import ConfigError, with_overrides
    from robots.spot.sdk_backend import SdkBackendConfig
    from tasks.tsdf import TsdfConfig

    exempt_prefixes = ()

    def numeric_fields(cls, prefix=""):
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            tp = hints[f.name]
            if dataclasses.is_dataclass(tp):
                yield from numeric_fields(tp, prefix + f.name + ".")
            elif tp in (int, float):
                yield prefix + f.name, tp

    unchecked = []
    for root in (TrialConfig, SdkBackendConfig, TsdfConfig):
        for key, tp in numeric_fields(root):
            if key.startswith(exempt_prefixes):
                continue
            refused = 0
            for value in (-10 ** 12, 10 ** 12):
                try:
                    with_overrides(root(), {key: tp(value)})
                except ConfigError:
                    refused += 1
            if not refused:
                unchecked.append(f"{root.__name__}.{key}")
    assert not unchecked, unchecked


# ------------------------------------------------------------------------------------------------
# Part 2: damaged run folders
# ------------------------------------------------------------------------------------------------
def _lines(folder: Path) -> list[bytes]:
    """Its lines at b"\\n" only (a CR inside a line is not a line break, see cr-inside-a-string)."""
    parts = (folder / "episodes.jsonl").read_bytes().split(b"\n")
    return [p + b"\n" for p in parts[:-1]] + ([parts[-1]] if parts[-1] else [])


def _cr_in_line(i: int, inside_string: bool):
    """A CR byte in line ``i``: between two tokens (JSON whitespace: the record stays valid) or in
    the task string (a control character: not JSON). Once either dropped every later record."""
    def damage(folder: Path) -> None:
        lines = _lines(folder)
        line = bytearray(lines[i])
        at = line.index(b'"task": "') + (len(b'"task": "') + 2 if inside_string else len(b'"task":'))
        line[at] = 0x0D
        lines[i] = bytes(line)
        _set_lines(folder, lines)
    return damage


def _set_lines(folder: Path, lines: list[bytes]) -> None:
    (folder / "episodes.jsonl").write_bytes(b"".join(lines))


def _replace_line(i: int, new: bytes):
    def damage(folder: Path) -> None:
        lines = _lines(folder)
        lines[i] = new
        _set_lines(folder, lines)
    return damage


def _insert_line(i: int, new: bytes):
    def damage(folder: Path) -> None:
        lines = _lines(folder)
        lines.insert(i, new)
        _set_lines(folder, lines)
    return damage


def _edit_record(i: int, edit):
    def damage(folder: Path) -> None:
        lines = _lines(folder)
        rec = json.loads(lines[i])
        edit(rec)
        lines[i] = (json.dumps(rec, sort_keys=True) + "\n").encode()
        _set_lines(folder, lines)
    return damage


def _torn(folder: Path) -> None:
    data = (folder / "episodes.jsonl").read_bytes()
    (folder / "episodes.jsonl").write_bytes(data[:-40])


def _to_directory(name: str):
    def damage(folder: Path) -> None:
        p = folder / name
        if p.exists():
            p.unlink()
        p.mkdir()
        (p / "junk").write_text("x")
    return damage


def _undo_directory(name: str):
    def fix(folder: Path, clean: Path) -> None:
        shutil.rmtree(folder / name)
    return fix


def _to_fifo(name: str, keep: bool = True):
    def damage(folder: Path) -> None:
        p = folder / name
        if keep:
            shutil.move(p, folder / (name + ".saved"))
        else:
            p.unlink()
        os.mkfifo(p)
    return damage


def _undo_fifo(name: str):
    def fix(folder: Path, clean: Path) -> None:
        (folder / name).unlink()
        shutil.move(folder / (name + ".saved"), folder / name)
    return fix


def _strip_fingerprints(folder: Path) -> None:
    lines = []
    for line in _lines(folder):
        rec = json.loads(line)
        rec.pop(FINGERPRINT_FIELD)
        lines.append((json.dumps(rec, sort_keys=True) + "\n").encode())
    _set_lines(folder, lines)


def _combine(*fns):
    def damage(folder: Path) -> None:
        for fn in fns:
            fn(folder)
    return damage


def _delete(name: str):
    return lambda folder: (folder / name).unlink()


def _edit_config(folder: Path) -> None:
    p = folder / "config.yaml"
    p.write_text(p.read_text().replace("max_commands: 3", "max_commands: 4"))


def _other_config_record(folder: Path) -> None:
    lines = _lines(folder)
    rec = json.loads(lines[0])
    rec.update(episode_id="smoke-00004", **{FINGERPRINT_FIELD: "0123456789abcdef"})
    _set_lines(folder, lines + [(json.dumps(rec, sort_keys=True) + "\n").encode()])


def _append_record(i: int, **changes):
    """Append a copy of record ``i`` with ``changes`` (dotted keys reach into objects)."""
    def damage(folder: Path) -> None:
        lines = _lines(folder)
        rec = json.loads(lines[i])
        for key, value in changes.items():
            *path, last = key.split("__")
            target = rec
            for part in path:
                target = target[part]
            target[last] = value
        _set_lines(folder, lines + [(json.dumps(rec, sort_keys=True) + "\n").encode()])
    return damage


def _edit_trace(eid: str, edit):
    """Rewrite an episode's picture data (it still loads) after ``edit(meta, arrays)``."""
    import numpy as np

    def damage(folder: Path) -> None:
        path = folder / "episodes" / f"{eid}.npz"
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        meta = json.loads(str(arrays["meta"]))
        edit(meta, arrays)
        arrays["meta"] = np.array(json.dumps(meta))
        with path.open("wb") as fh:
            np.savez(fh, **arrays)
    return damage


def _set_map_3d(meta, arrays):
    arrays["map"] = arrays["map"][..., None]


def _set_path_1d(meta, arrays):
    arrays["path"] = arrays["path"].ravel()


# Picture data that loads but cannot be drawn, three episodes each (tests below check every one)
TRACE_DAMAGE_A = (("smoke-00000", lambda m, a: m.pop("grid"), "meta.grid"),
                  ("smoke-00001", lambda m, a: m["grid"].update(cell_size=0), "meta.grid.cell_size"),
                  ("smoke-00002", _set_path_1d, "path is not"))
TRACE_DAMAGE_B = (("smoke-00000", _set_map_3d, "map is not"),
                  ("smoke-00001", lambda m, a: m.update(events=[{"kind": "grasp"}]), "meta.events"),
                  ("smoke-00002", lambda m, a: m.pop("outcome"), "meta.outcome"))


def _trace_damage(table):
    return _combine(*(_edit_trace(eid, edit) for eid, edit, _ in table))


def _record_shapes(folder: Path) -> None:
    _edit_record(0, lambda r: r.update(collision_events="boom"))(folder)
    _edit_record(2, lambda r: r.update(extra={"activity_time": {"explore": "x"}}))(folder)


# name, damage, report: (exit status, fragment in stderr), resume: (extra args, exit status, fragment),
# fix(folder, clean) applied after a refusal, before the valid command (None: the same command again)
DAMAGES = [
    ("torn-last-line", _torn, (0, "episodes.jsonl:3: torn last line"), ([], 0, "torn last line"), None),
    ("garbage-middle-line", _insert_line(1, b"#!garbage\n"), (0, "episodes.jsonl:2: not valid JSON"),
     ([], 0, "line 2: not valid JSON"), None),
    ("middle-line-overwritten", _replace_line(1, b'{"episode_id": "smoke-00001", "metr\n'),
     (0, "episodes.jsonl:2: not valid JSON"), ([], 0, "episodes without a valid record run again"), None),
    ("empty-object-line", _insert_line(1, b"{}\n"), (0, "episodes.jsonl:2: no episode_id"),
     ([], 0, "no episode_id"), None),
    ("list-line", _insert_line(2, b"[]\n"), (0, "episodes.jsonl:3: a JSON list"), ([], 0, "a JSON list"), None),
    ("metrics-not-object", _edit_record(1, lambda r: r.update(metrics="yes")),
     (0, "episodes.jsonl:2: metrics is not an object"), ([], 0, "metrics is not an object"), None),
    ("metrics-not-bool", _edit_record(0, lambda r: r["metrics"].update(success="maybe")),
     (0, "episodes.jsonl:1: metrics.success is not true/false"), ([], 0, "metrics.success"), None),
    ("metrics-missing-key", _edit_record(2, lambda r: r["metrics"].pop("pick")),
     (0, "episodes.jsonl:3: metrics.pick"), ([], 0, "metrics.pick"), None),
    ("phase-time-negative", _edit_record(0, lambda r: r["metrics"].update(find_obj_time=-3.0)),
     (0, "episodes.jsonl:1: metrics.find_obj_time is not a non-negative number"), ([], 0, "metrics.find_obj_time"),
     None),
    ("sim-time-nan", _edit_record(1, lambda r: r.update(sim_time=float("nan"))),
     (0, "episodes.jsonl:2: sim_time"), ([], 0, "sim_time"), None),
    ("non-utf8-line", _insert_line(0, b"\xff\xfe\xfd\n"), (0, "episodes.jsonl:1: not UTF-8"),
     ([], 0, "not UTF-8"), None),
    ("memory-malformed", _edit_record(0, lambda r: r.update(memory={"series": {"t": "abc"}})),
     (0, "episodes.jsonl:1: memory.series"), ([], 0, "memory.series"), None),
    ("binary-config", lambda f: (f / "config.yaml").write_bytes(bytes(range(256))),
     (0, "config.yaml is not UTF-8"), ([], 0, "config.yaml.damaged"), None),
    ("config-deleted", _delete("config.yaml"), (0, ""), ([], 0, "config.yaml was missing"), None),
    ("config-deleted-other-config", _delete("config.yaml"), (0, ""),
     (["runner.max_commands=4"], 2, "config.yaml is missing and the records"), None),
    ("config-edited", _edit_config, (0, "does not describe the records"),
     (["runner.max_commands=4"], 2, "does not describe the records"),
     lambda f, clean: shutil.copy(clean / "config.yaml", f / "config.yaml")),
    ("config-directory", _to_directory("config.yaml"), (0, "is a directory"), ([], 2, "config.yaml is a directory"),
     _undo_directory("config.yaml")),
    ("results-directory", _to_directory("episodes.jsonl"), (2, "is a directory"),
     ([], 2, "episodes.jsonl is a directory"), _undo_directory("episodes.jsonl")),
    ("lock-directory", _to_directory(".lock"), (0, ""), ([], 2, ".lock is a directory"), _undo_directory(".lock")),
    ("summary-directory", _to_directory("summary.json"), (0, ""), ([], 2, "summary.json is a directory"),
     _undo_directory("summary.json")),
    ("record-of-another-config", _other_config_record, (0, "2 different configurations"),
     ([], 2, "mixes records of 2 configurations"),
     lambda f, clean: _set_lines(f, _lines(f)[:-1])),
    ("legacy-records", _strip_fingerprints, (0, "without a configuration fingerprint"), ([], 0, ""), None),
    ("legacy-records-config-deleted", _combine(_strip_fingerprints, _delete("config.yaml")),
     (0, "without a configuration fingerprint"), ([], 2, "carry no configuration fingerprint"),
     lambda f, clean: shutil.copy(clean / "config.yaml", f / "config.yaml")),
    ("duplicate-record", lambda f: _set_lines(f, _lines(f) + _lines(f)[:1]), (0, ""), ([], 0, ""), None),
    # the audit of 2026-12-05 (session 35): a traceback, or a wait without end
    ("picture-data-deleted", _delete("episodes/smoke-00001.npz"),
     (0, "smoke-00001.npz: the picture data is missing (smoke-00001.npz; the run's other episodes have theirs"),
     ([], 0, ""), None),
    ("digests-directory", _to_directory("episode_digests.json"), (0, ""),
     ([], 2, "episode_digests.json is a directory"), _undo_directory("episode_digests.json")),
    ("digests-damaged", lambda f: (f / "episode_digests.json").write_text("[not json"), (0, ""),
     ([], 0, "episode_digests.json was unreadable; rewrote it"), None),
    ("cr-between-tokens", _cr_in_line(1, inside_string=False), (0, ""), ([], 0, ""), None),
    ("cr-inside-a-string", _cr_in_line(1, inside_string=True), (0, "episodes.jsonl:2: not valid JSON"),
     ([], 0, "line 2: not valid JSON"), None),
    ("sim-time-overflows-a-float", _edit_record(1, lambda r: r.update(sim_time=10 ** 400)),
     (0, "episodes.jsonl:2: sim_time"), ([], 0, "sim_time"), None),
    ("integer-of-5000-digits", _insert_line(1, b'{"episode_id": "smoke-00001", "sim_time": ' + b"9" * 5000 + b"}\n"),
     (0, "episodes.jsonl:2: not valid JSON (Exceeds the limit"), ([], 0, "line 2: not valid JSON"), None),
    ("results-fifo", _to_fifo("episodes.jsonl"), (2, "episodes.jsonl is not a regular file"),
     ([], 2, "episodes.jsonl is not a regular file"), _undo_fifo("episodes.jsonl")),
    ("config-fifo", _to_fifo("config.yaml", keep=False), (0, "config.yaml is not a regular file"),
     ([], 0, "config.yaml is not a regular file (a FIFO, device or socket); moved it to config.yaml.damaged"), None),
    # report and run folders (QA 2026-12-04)
    ("conflicting-duplicate", _append_record(0, success=True, metrics__success=True, metrics__failure_reason=None),
     (0, "episodes.jsonl:4: episode smoke-00000 has records that disagree (this one and line(s) 1, in metrics, "
         "success)"), ([], 0, "line 1: episode smoke-00000 has records that disagree"), None),
    ("record-of-another-episode", _append_record(0, episode_id="smoke-00015"),
     (0, "episodes.jsonl:4: episode smoke-00015 is not one of the run's 3 episodes (split smoke"),
     ([], 0, "smoke-00015 is not one of"), None),
    ("episode-id-not-a-name", _combine(_append_record(0, episode_id="../../../tmp/qa/pwned"),
                                       _append_record(1, episode_id="smoke-" + "x" * 5000)),
     (0, "episodes.jsonl:4: episode_id '../../../tmp/qa/pwned' is not an episode id"),
     ([], 0, "line 5: episode_id 'smoke-xxx"), None),
    ("record-fields-malformed", _record_shapes, (0, "episodes.jsonl:1: collision_events is not a list"),
     ([], 0, "line 3: extra.activity_time"), None),
    ("invocations-directory", _to_directory("invocations.jsonl"), (0, "invocations.jsonl is a directory"),
     ([], 2, "invocations.jsonl is a directory"), _undo_directory("invocations.jsonl")),
    ("invocations-torn-line", lambda f: (f / "invocations.jsonl").open("ab").write(b'{"episodes_to_run": 2, "cpu'),
     (0, "invocations.jsonl:2: damaged line of the run's invocation log"), ([], 0, ""), None),
    ("picture-data-content-a", _trace_damage(TRACE_DAMAGE_A),
     (0, "smoke-00000.npz: the picture data is damaged (meta.grid"), ([], 0, ""), None),
    ("picture-data-content-b", _trace_damage(TRACE_DAMAGE_B),
     (0, "smoke-00001.npz: the picture data is damaged (meta.events"), ([], 0, ""), None),
]


@pytest.fixture(scope="module")
def clean_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("damage")
    clean = root / "clean"
    rc, out, err = run_cli([*RUN_ARGS, "--out", str(clean), *BUDGET])
    assert rc == 0, err
    return clean


def _views(folder: Path) -> dict[str, dict]:
    return {k: {f: v for f, v in deterministic_view(r).items() if f != FINGERPRINT_FIELD}
            for k, r in read_results(folder / "episodes.jsonl").items()}


def _intact(folder: Path, clean: Path) -> set[str]:
    """Episodes of the clean run whose record is still in ``folder``'s episodes.jsonl, unchanged
    (fingerprints aside), found without the code under test. An episode with another, different
    record too is not intact (nothing says which of the two is right)."""
    def bare(rec: dict) -> dict:
        return {k: v for k, v in rec.items() if k != FINGERPRINT_FIELD}

    clean_records = {r["episode_id"]: bare(r) for r in map(json.loads, _lines(clean))}
    found, spoilt = set(), set()
    if not (folder / "episodes.jsonl").is_file():
        return found
    for line in _lines(folder):
        try:
            rec = json.loads(line)
        except ValueError:
            continue
        if not isinstance(rec, dict) or rec.get("episode_id") not in clean_records:
            continue
        if clean_records[rec["episode_id"]] == bare(rec):
            found.add(rec["episode_id"])
        elif isinstance(rec.get("metrics"), dict) and "success" in rec:      # a record, but another one
            spoilt.add(rec["episode_id"])
    return found - spoilt


def test_a_config_left_by_a_failed_start_does_not_block_the_corrected_command(tmp_path):
    """A folder with only a config.yaml (a start that failed before any episode finished) takes the
    corrected command's configuration instead of refusing it as "a different configuration"."""
    folder = tmp_path / "run"
    prepare_run_folder(folder, TrialConfig(agent="oracle", episodes=1, seed=5))
    rc, out, err = run_cli(["trials", "--episodes", "1", "--progress", "none", "--out", str(folder), *BUDGET])
    assert rc == 0, err
    assert "replaced by this configuration" in err
    assert list(read_results(folder / "episodes.jsonl")) == ["smoke-00000"]


def test_the_damage_corpus_is_big_enough():
    assert len(DAMAGES) >= 15


@pytest.mark.parametrize("damage", DAMAGES, ids=[d[0] for d in DAMAGES])
def test_a_damaged_run_folder(damage, clean_run, tmp_path, monkeypatch):
    name, fn, (report_rc, report_says), (resume_extra, resume_rc, resume_says), fix = damage
    # The report as drawn without matplotlib (an install without the viz extra): the tables, each
    # damaged line named, and a warning instead of the PNGs. The plots read only the validated
    # records, the same few valid ones in every case here, and drawing them was half of each case's
    # time; tests/test_report.py draws them.
    monkeypatch.setattr("tools.report._pyplot", lambda: None)
    folder = tmp_path / "run"
    shutil.copytree(clean_run, folder)
    fn(folder)
    damaged_lines = _lines(folder) if (folder / "episodes.jsonl").is_file() else []

    # report: the table from the valid records, each damaged line named; or one error line
    before = snapshot(folder)
    rc, out, err = run_cli(["report", str(folder), "--out", str(tmp_path / "report")])
    assert "Traceback" not in err
    assert rc == report_rc, err
    assert report_says in err, err
    if rc == 2:
        assert len(err.splitlines()) == 1
    else:
        assert "| run | FindObj" in out
        assert "warning: plots need matplotlib (pip install -e '.[viz]'); wrote the tables only" in err, err
        assert not list((tmp_path / "report").glob("*.png")) and (tmp_path / "report" / "index.html").is_file()
        shown = json.loads((tmp_path / "report" / "report.json").read_text())["run"]["summary"]["episodes"]
        if name != "record-of-another-config":            # (that one adds a fourth, valid record)
            assert shown == len(_intact(folder, clean_run)), "report must count every valid record"
    assert snapshot(folder) == before, "report changed the run folder"

    # resume: repairs what it can prove, or refuses in one line and changes nothing
    rc, out, err = run_cli([*RUN_ARGS, "--out", str(folder), *BUDGET, *resume_extra])
    assert "Traceback" not in err
    assert rc == resume_rc, err
    assert resume_says in err, err
    if rc == 2:
        assert len(err.splitlines()) == 1 and err.startswith("error: ")
        assert snapshot(folder) == before, "a refused resume changed the run folder"
        if fix is not None:
            fix(folder, clean_run)
            damaged_lines = _lines(folder) if (folder / "episodes.jsonl").is_file() else []
        rc, out, err = run_cli([*RUN_ARGS, "--out", str(folder), *BUDGET])     # the valid command
        assert rc == 0, err

    # after a valid command: the records equal the clean run's, nothing valid was lost
    assert _views(folder) == _views(clean_run)
    kept = (folder / "episodes.jsonl").read_bytes()
    side = (folder / DAMAGED_FILE).read_bytes() if (folder / DAMAGED_FILE).exists() else b""
    for line in damaged_lines:
        assert line in kept or line.rstrip(b"\n") in side, line
    from tasks.run_folder import read_run_config

    fps = {r.get(FINGERPRINT_FIELD) for r in read_results(folder / "episodes.jsonl").values()}
    assert fps <= {config_fingerprint(read_run_config(clean_run)[1]), None}


@pytest.mark.parametrize("field, value, says", [
    ("collision_events", "boom", "collision_events is not a list of objects"),
    ("collision_events", [{"time": "soon"}], "collision_events: a time"),
    ("extra", {"decisions": "x"}, "extra.decisions is not an object"),
    ("extra", {"decisions": {"global_with_candidates": "many"}}, "extra.decisions.global_with_candidates"),
    ("extra", {"decisions": {"local_search_sizes": [1, "x"]}}, "extra.decisions.local_search_sizes"),
    ("extra", {"activity_time": "x"}, "extra.activity_time"),
    ("extra", {"activity_time": {"explore": -1}}, "extra.activity_time"),
    ("episode_id", "a/b", "is not an episode id"),
    ("episode_id", "x" * 101, "is not an episode id"),
])
def test_record_fields_the_pages_use_are_checked(clean_run, field, value, says):
    """(QA 2026-12-04) The line checks cover what the episode pages draw and what names files."""
    from tasks.run_folder import record_problem

    rec = json.loads(_lines(clean_run)[0])
    assert record_problem(rec) is None
    rec[field] = value
    assert says in (record_problem(rec) or "")


@pytest.mark.parametrize("table", [TRACE_DAMAGE_A, TRACE_DAMAGE_B], ids=["a", "b"])
def test_picture_data_that_loads_but_is_damaged_is_named(table, clean_run, tmp_path):
    """(QA 2026-12-04) Each damaged picture file is named on stderr and on its episode page; the
    report finishes; the other pages are drawn."""
    from tools.episode_pages import write_episode_pages
    from tools.report_runs import load_run

    folder = tmp_path / "run"
    shutil.copytree(clean_run, folder)
    _trace_damage(table)(folder)
    pages = write_episode_pages(tmp_path / "rep", 0, load_run(folder))
    for (eid, _, says), page in zip(table, pages):
        assert page.episode_id == eid and page.thumb is None
        assert page.damaged.startswith("is damaged (") and says in page.damaged, page.damaged
        assert f"{eid}.npz is damaged" in (tmp_path / "rep" / page.page).read_text()


def test_report_prints_nothing_from_matplotlib(clean_run, tmp_path):
    """(QA 2026-12-04) A long row name made matplotlib warn (tight layout) on stderr. (pytest
    catches Python warnings before they reach stderr: they are recorded here instead.)"""
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rc, out, err = run_cli(["report", str(clean_run), "--names", "n" * 100, "--out", str(tmp_path / "rep")])
    assert rc == 0, err
    assert not [str(w.message) for w in caught]
    assert all(line.startswith("warning: ") for line in err.splitlines()), err


def test_diff_names_damage_report_names(clean_run, tmp_path):
    """(QA 2026-12-04) diff reads run folders as report does: records that disagree are named
    FILE:LINE (not "identical"), and a damaged invocations.jsonl is said in one line."""
    folder = tmp_path / "run"
    shutil.copytree(clean_run, folder)
    DAMAGES[[d[0] for d in DAMAGES].index("conflicting-duplicate")][1](folder)
    _to_directory("invocations.jsonl")(folder)
    rc, out, err = run_cli(["diff", str(clean_run), str(folder)])
    assert rc == 1, err              # smoke-00000 has no valid record in B: one run only, which counts
    assert "episodes.jsonl:1: episode smoke-00000 has records that disagree" in err
    assert "episodes.jsonl:4: episode smoke-00000 has records that disagree" in err
    assert "invocations.jsonl is a directory" in err
    assert "only in A: 1 episode, smoke-00000" in out
    assert "not the same episodes: 1 episode in one run only counts as a difference (only in A: smoke-00000)" in out
    rc, out, err = run_cli(["diff", str(clean_run), str(folder), "--common"])
    assert rc == 0, out + err


def test_repeated_robot_runs_of_one_episode_are_not_a_disagreement(clean_run, tmp_path):
    """`tools spot --fake --episode ID` appends a record per run to one folder; robot runs differ by
    nature (robot clock), so they are not damaged lines: the first is used and report says so."""
    from tasks.run_folder import scan_results

    folder = tmp_path / "robot"
    shutil.copytree(clean_run, folder)
    path = folder / "episodes.jsonl"
    records = [json.loads(line) for line in path.read_text().splitlines()]
    for r in records:
        r["hardware"] = {"setting": "fake"}
    again = dict(records[0], sim_time=records[0]["sim_time"] + 7.5, success=not records[0]["success"])
    path.write_text("".join(json.dumps(r) + "\n" for r in [*records, again]))
    scan = scan_results(path)
    assert not scan.damaged and scan.repeated_runs == {records[0]["episode_id"]: 2}
    assert scan.records[records[0]["episode_id"]]["sim_time"] == records[0]["sim_time"]   # the first run
    rc, out, err = run_cli(["report", str(folder), "--out", str(tmp_path / "rep"), "--no-episode-pages"])
    assert rc == 0, err
    assert f"{records[0]['episode_id']} (2 runs)" in err and "damaged" not in err


def test_a_report_folder_of_its_own_inside_the_run_folder_is_fine(clean_run, tmp_path):
    """`make run` writes runs/smoke/report (README): only the run folder's own parts are refused."""
    folder = tmp_path / "run"
    shutil.copytree(clean_run, folder)
    rc, out, err = run_cli(["report", str(folder), "--out", str(folder / "report"), "--no-episode-pages"])
    assert rc == 0, err
    assert (folder / "report" / "table.txt").is_file()


def test_a_run_folder_whose_name_is_not_utf8_is_refused_before_writing(clean_run, tmp_path):
    """(QA 2026-12-04) report wrote table.txt, then failed on the path in its HTML."""
    import os

    folder = Path(os.fsdecode(bytes(tmp_path) + b"/r\xff"))
    shutil.copytree(clean_run, folder)
    rc, out, err = run_cli(["report", str(folder), "--out", str(tmp_path / "rep")])
    assert rc == 2 and err.count("\n") == 1 and "r\\xff': its name is not UTF-8 text" in err, err
    assert not (tmp_path / "rep").exists()


# ------------------------------------------------------------------------------------------------
# Every wait on the network or another process is bounded, with a clear message
# ------------------------------------------------------------------------------------------------
def test_a_ray_head_that_does_not_answer_is_one_error_within_the_timeout(monkeypatch):
    import socket

    from tasks.executors import ExecutorError, check_address

    def silent(*args, **kwargs):
        time.sleep(5)                       # a black-holed address: the SYN is never answered
        raise TimeoutError

    monkeypatch.setattr(socket, "create_connection", silent)
    t0 = time.perf_counter()
    with pytest.raises(ExecutorError, match=r"no answer from the Ray cluster at 10\.1\.2\.3:6379 within 0\.3 s"):
        check_address("10.1.2.3:6379", timeout=0.3)
    assert time.perf_counter() - t0 < 2


def test_a_port_that_answers_but_is_no_ray_head_is_one_error_before_any_run_folder(tmp_path, monkeypatch):
    """(audit 2026-12-05) A web server at --address: ray.init retried for minutes (killed at 164 s)
    after the run folder was made; the gRPC handshake Ray's head would complete refuses it first."""
    import socket
    import threading

    pytest.importorskip("ray")
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    port = server.getsockname()[1]

    def answer_http() -> None:            # accepts, answers like an HTTP/1.1 server, hangs up
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            with conn:
                conn.settimeout(1.0)
                try:
                    conn.recv(1024)
                    conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")
                except OSError:
                    pass

    threading.Thread(target=answer_http, daemon=True).start()
    try:
        import tasks.executors
        from tasks.executors import ExecutorError, check_address

        monkeypatch.setattr(tasks.executors, "RAY_CONNECT_TIMEOUT_S", 1.0)     # the CLI's wait, shortened
        t0 = time.perf_counter()
        with pytest.raises(ExecutorError, match=rf"127\.0\.0\.1:{port} accepts connections but does not answer as "
                                                r"a Ray head \(no gRPC handshake within 1 s\)"):
            check_address(f"127.0.0.1:{port}", timeout=1.0)
        assert time.perf_counter() - t0 < 5
        rc, out, err = run_cli(["trials", "--agent", "oracle", "--episodes", "1", "--executor", "ray",
                                "--address", f"127.0.0.1:{port}", "--out", str(tmp_path / "run")])
        assert rc == 2 and err.count("\n") == 1 and "no gRPC handshake within 1 s" in err, err
        assert not (tmp_path / "run").exists()
    finally:
        server.close()


def test_a_worker_process_that_does_not_start_is_one_error(monkeypatch):
    import tasks.executors as ex

    monkeypatch.setattr(ex, "WORKER_START_TIMEOUT_S", 0.0)    # no spawned interpreter is that fast
    pool = ex.ProcessExecutor(1)
    try:
        with pytest.raises(ex.ExecutorError, match="did not start within 0 s"):
            list(pool.map_unordered(abs, [-1]))
    finally:
        pool.close()


def test_a_fake_spot_that_does_not_listen_is_one_error():
    import socket
    from types import SimpleNamespace

    pytest.importorskip("bosdyn.client")
    from robots.spot.fake_spot.server import FakeSpot, FakeSpotStartError

    with socket.socket() as s:               # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(FakeSpotStartError, match=f"did not accept connections on 127.0.0.1:{port} within 0.2 s"):
        FakeSpot._wait_listening(SimpleNamespace(port=port), 0.2)
