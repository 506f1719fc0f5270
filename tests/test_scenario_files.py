"""Scenario files (Drake style): ``--config FILE.yaml`` on trials, demo and spot, then flags, then
``key=value``; unknown keys name the file; a run folder's config.yaml reproduces (resumes) the run."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from helios.schema import ConfigError, dump_yaml, to_dict, with_overrides
from tasks.run_folder import prepare_run_folder, read_run_config
from tasks.trial_config import TrialConfig, load_trial_config
from tools.cli import build_parser, main
from tools.trials import resolve_config

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"


def _trial_args(*argv: str):
    return build_parser().parse_args(["trials", *argv])


def _compare_agents() -> list[str]:
    text = (ROOT / "Makefile").read_text()
    return re.search(r"^COMPARE \?= (.+)$", text, re.M).group(1).split()


def test_every_example_file_loads_and_says_what_it_is():
    from helios.schema import load_config
    from robots.spot.sdk_backend import SdkBackendConfig
    from robots.spot.sim_backend import SimBackendConfig

    files = sorted(CONFIGS.glob("*.yaml"))
    assert files
    for path in files:
        assert path.read_text().startswith("# Scenario"), f"{path.name} has no header saying what it is"
        if path.name == "demo.yaml":
            load_config(SimBackendConfig, path)
        elif path.name.startswith("spot"):
            load_config(SdkBackendConfig, path)
        else:       # as `tools trials --config` reads it: no setting its agent ignores or replaces
            resolve_config(_trial_args("--config", str(path)))


def test_the_ablation_set_is_one_file_per_agent_of_make_compare():
    for run in _compare_agents():
        header, cfg = load_trial_config(CONFIGS / f"val_{run}.yaml")
        assert header == {"helios_version": None, "git_commit": None}
        if run == "helios-earlier":      # HELIOS with the earlier readings switched back
            assert cfg.agent == "helios" and (cfg.split, cfg.episodes, cfg.seed) == ("val", 200, 0)
            assert cfg.helios.search.initial_frontier_calibration == "fixed_ratio"
            assert cfg.helios.search.frontier_choice == "value_minus_distance"
            assert cfg.helios.decision.candidate_class == "score_only"
            assert cfg.helios.decision.view_prediction == "optimistic"
            assert cfg.agent_config.gaze.outer_rings == "always"
            continue
        # exactly the config `make compare` used to build from flags
        assert cfg == TrialConfig(agent=run, split="val", episodes=200, seed=0)
    smoke = load_trial_config(CONFIGS / "smoke.yaml")[1]
    assert smoke == TrialConfig(agent="helios", split="smoke", episodes=20, seed=0)     # `make run`


def test_the_poor_receptacle_runs_differ_from_the_ablation_rows_only_in_the_detector():
    """The stress-test runs (README, "A poorer receptacle detector") must compare like with like:
    each file is its ablation row's config with the same three receptacle parameters changed."""
    from dataclasses import replace

    from sim.perception.config import SimPerceptionConfig

    poor = replace(SimPerceptionConfig(), receptacle_part_false_positive=1.0,
                   score_false_positive_logit_receptacle=0.3, bad_view_receptacle=0.3)
    for run in ("helios", "helios-no-global", "helios-5050"):
        _, cfg = load_trial_config(CONFIGS / f"val_{run}-poor-receptacles.yaml")
        _, row = load_trial_config(CONFIGS / f"val_{run}.yaml")
        assert cfg.perception == poor != row.perception
        assert replace(cfg, perception=row.perception) == row


def test_precedence_defaults_file_flags_then_key_value(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text("agent: helios\nsplit: val\nepisodes: 50\nseed: 3\nrunner:\n  max_sim_time: 120\n"
                    "helios:\n  detection:\n    od_object: 0.3\n")
    cfg = resolve_config(_trial_args("--config", str(path)))
    assert (cfg.agent, cfg.split, cfg.episodes, cfg.seed) == ("helios", "val", 50, 3)
    assert cfg.runner.max_sim_time == 120.0 and cfg.helios.detection.od_object == 0.3
    assert cfg.helios.detection.od_goal_receptacle == 0.45            # untouched keys keep their defaults
    # flags override the file only where given
    cfg = resolve_config(_trial_args("--config", str(path), "--episodes", "7"))
    assert (cfg.agent, cfg.episodes, cfg.seed) == ("helios", 7, 3)
    cfg = resolve_config(_trial_args("--config", str(path), "--agent", "helios-no-global", "--seed", "0"))
    assert (cfg.agent, cfg.split, cfg.seed) == ("helios-no-global", "val", 0)
    # ... but not into settings the agent never reads (the oracle has no detector to tune)
    with pytest.raises(ConfigError, match="agent 'oracle' reads no helios"):
        resolve_config(_trial_args("--config", str(path), "--agent", "oracle"))
    # key=value overrides come last
    cfg = resolve_config(_trial_args("--config", str(path), "--episodes", "7", "seed=9",
                                     "runner.max_sim_time=60", "helios.detection.od_object=0.5"))
    assert (cfg.episodes, cfg.seed, cfg.runner.max_sim_time, cfg.helios.detection.od_object) == (7, 9, 60.0, 0.5)
    # ... and a flag and an override of the same setting are refused: one of them would be dropped
    with pytest.raises(ConfigError, match="--episodes and 'episodes=9' both set episodes; give one"):
        resolve_config(_trial_args("--config", str(path), "--episodes", "7", "episodes=9"))
    # without a file: the TrialConfig defaults, as before
    assert resolve_config(_trial_args()) == TrialConfig()
    assert resolve_config(_trial_args("--agent", "helios", "runner.max_sim_time=300")) == with_overrides(
        TrialConfig(agent="helios"), ["runner.max_sim_time=300"])


def test_unknown_key_in_a_file_is_one_line_naming_the_file_and_the_key(tmp_path, capsys):
    path = tmp_path / "typo.yaml"
    path.write_text("agent: oracle\nrunner:\n  max_sim_tme: 10\n")
    with pytest.raises(ConfigError, match=r"typo\.yaml.*'runner\.max_sim_tme'"):
        load_trial_config(path)
    for argv in (["trials", "--config", str(path), "--out", str(tmp_path / "run")],
                 ["demo", "--config", str(path), "--no-record"],
                 ["spot", "--fake", "--task", "Move the mug from the stool to the table", "--config", str(path),
                  "--out", str(tmp_path / "spot")]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err, err
        assert str(path) in err
        assert ("max_sim_tme" if argv[0] == "trials" else "'agent'") in err      # demo/spot: not their schema
    assert not (tmp_path / "run").exists()


def test_a_file_that_is_not_a_mapping_or_missing_is_an_error(tmp_path, capsys):
    path = tmp_path / "list.yaml"
    path.write_text("- agent\n- oracle\n")
    with pytest.raises(ConfigError, match=r"list\.yaml.*must hold a mapping at the top level, not a list"):
        load_trial_config(path)
    assert main(["trials", "--config", str(tmp_path / "nope.yaml")]) == 2
    assert "nope.yaml" in capsys.readouterr().err


def test_run_folder_config_written_by_trials_reads_back_as_a_scenario(tmp_path):
    cfg = with_overrides(TrialConfig(agent="helios-gt", split="val", episodes=3, seed=5),
                         ["runner.max_sim_time=200", "agent_config.max_pick_attempts=1", "helios.search.alpha_d=0.002"])
    prepare_run_folder(tmp_path, cfg)                 # the code path `tools trials` writes config.yaml with
    text = (tmp_path / "config.yaml").read_text()
    assert text.startswith("helios_version:") and "git_commit:" in text          # provenance header
    header, loaded = load_trial_config(tmp_path / "config.yaml")
    assert loaded == cfg and header == read_run_config(tmp_path)[0]
    assert resolve_config(_trial_args("--config", str(tmp_path / "config.yaml"))) == cfg
    assert to_dict(loaded) == to_dict(cfg)


def test_a_run_folder_config_reproduces_and_resumes_the_run(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["trials", "--agent", "oracle", "--episodes", "1", "--out", str(out), "--progress", "none"]) == 0
    lines = (out / "episodes.jsonl").read_text().splitlines()
    capsys.readouterr()
    # same folder: resumes (nothing to run, no "different configuration" complaint)
    assert main(["trials", "--config", str(out / "config.yaml"), "--out", str(out), "--progress", "none"]) == 0
    printed = capsys.readouterr()
    assert "resuming: 1 of 1" in printed.out and "warning" not in printed.err
    assert (out / "episodes.jsonl").read_text().splitlines() == lines
    # a flag overrides the file: a different seed is a different run, refused in this folder
    assert main(["trials", "--config", str(out / "config.yaml"), "--out", str(out), "--seed", "1"]) == 2
    assert "differs in: seed" in capsys.readouterr().err


def test_a_config_from_another_commit_is_flagged(tmp_path, capsys):
    path = tmp_path / "config.yaml"
    path.write_text("helios_version: 0.0.1\ngit_commit: 0123456789abcdef\n" + dump_yaml(TrialConfig(episodes=1)))
    assert resolve_config(_trial_args("--config", str(path))) == TrialConfig(episodes=1)
    assert "was written by helios 0.0.1 at commit 0123456789" in capsys.readouterr().err


def test_demo_and_spot_resolve_their_backend_config_from_the_file(tmp_path, monkeypatch):
    from helios.schema import load_config
    from robots.spot.sdk_backend import SdkBackendConfig
    from robots.spot.sim_backend import SimBackendConfig

    demo = load_config(SimBackendConfig, CONFIGS / "demo.yaml", ["camera.height=240"])
    assert (demo.camera.width, demo.camera.height) == (640, 240)
    spot = load_config(SdkBackendConfig, CONFIGS / "spot_fake.yaml", ["rpc_timeout=3"])
    assert (spot.rpc_timeout, spot.image_rpc_timeout) == (3.0, 4.0)
    # a real-robot run needs a hostname: from the command line or from the file
    assert main(["spot", "--config", str(CONFIGS / "spot_fake.yaml"), "--task", "Move the mug from the stool "
                 "to the table", "--out", str(tmp_path)]) == 2


def test_make_compare_checks_its_variables_before_the_first_run(tmp_path, capsys):
    """COMPARE and PICK_LIMITS were first read by `tools report`, after every run had finished."""
    from tools.cli import CliError
    from tools.compare_check import check, main as check_main

    text = (ROOT / "Makefile").read_text()
    recipe = text[text.index("\ncompare: setup"):]
    assert recipe.index("tools.compare_check") < recipe.index("tools trials"), "the check runs first"
    assert check(" ".join(_compare_agents()), "1,5") == _compare_agents()     # the defaults pass
    for compare, limits, message in [("", "1,5", "COMPARE is empty"), ("helios typo", "", "configs/val_typo.yaml"),
                                     ("helios trusting helios", "", "names 'helios' twice"),
                                     ("helios", "abc", "PICK_LIMITS: --pick-limits: 'abc' is not a whole number")]:
        with pytest.raises(CliError, match=re.escape(message)):
            check(compare, limits)
    assert check_main(["helios typo", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: COMPARE names 'typo'") and "helios-gt" in err
    # SPLIT=large runs the scenarios on the split of large homes; a misspelt split fails first
    assert "--split $(SPLIT)" in recipe and "--out runs/$(SPLIT)/$$a" in recipe
    assert check("helios trusting", "1", "large") == ["helios", "trusting"]
    assert check_main(["helios", "1", "larg"]) == 2
    assert capsys.readouterr().err == "error: SPLIT 'larg' is not a split; valid splits: smoke, val, train, large\n"


def test_make_sensitivity_checks_its_settings_before_the_first_run(capsys):
    """The paper's sensitivity grid (appendix): one run per setting, each checked as `tools trials`
    would check it before any episode runs, and the report reads every run against the paper's."""
    from tools.cli import CliError
    from tools.compare_check import check_sensitivity, main as check_main

    text = (ROOT / "Makefile").read_text()
    recipe = text[text.index("\nsensitivity: setup"):].split("\n\n")[0]
    assert recipe.index("tools.compare_check") < recipe.index("tools trials"), "the check runs first"
    assert '"$(SENSITIVITY)"' in recipe.splitlines()[2]
    # the paper's values first (the report pairs every run with the first), then one run per setting
    # (its own run: make compare's runs/<SPLIT>/helios may be longer, and a run is never shortened)
    assert recipe.index("--out runs/$(SPLIT)/sensitivity/helios ") < recipe.index('--out "runs/$(SPLIT)/sensitivity/$$s"')
    assert "tools report $(addprefix runs/$(SPLIT)/sensitivity/,helios $(SENSITIVITY))" in recipe
    default = text[text.index("SENSITIVITY ?="):text.index("\nsensitivity: setup")]
    settings = default.partition("?=")[2].replace("\\\n", " ").split()
    # the paper's grid (Tables "Sensitivity analysis"): alpha_cs 0.1, 2; alpha_d 1e-4, 1e-2; tau_g 0.3, 0.7; tau_inc 0.1
    assert check_sensitivity(" ".join(settings)) == settings and len(settings) == 7
    for given, message in [("", "SENSITIVITY is empty"),
                           ("helios.decision.tau_object=0.3 helios.decision.tau_object=0.3", "names 'helios.decision.tau_object=0.3' twice"),
                           ("helios.decision.tau_objet=0.3", "unknown config key 'helios.decision.tau_objet'"),
                           ("helios.decision.tau_object=3", "tau_object must be in [0, 1], got 3"),
                           ("episodes=10", "sets episodes, which is the same for every run (N= gives it)"),
                           ("split=train", "sets split, which is the same for every run (SPLIT= gives it)"),
                           ("agent=trusting", "(every run is HELIOS; make compare compares agents)"),
                           ("perception.gt_roles=[object/x]", "holds a '/'")]:
        with pytest.raises(CliError, match=re.escape(message)):
            check_sensitivity(given)
    assert check_main(["helios", "1,5", "train", "helios.scoring.alpha_c=2"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: SENSITIVITY: unknown config key 'helios.scoring.alpha_c'")
    assert check_main(["helios", "1,5", "train", "helios.scoring.alpha_cs=2"]) == 0


@pytest.mark.parametrize("workers, ok", [("auto", True), ("logical", True), ("0", True), ("2", True),
                                         ("-1", False), ("two", False), ("", False), ("1.5", False)])
def test_make_test_checks_test_workers_before_set_up(workers, ok):
    """`make test TEST_WORKERS=-1` ran the suite in one process unannounced (xdist's parser takes -1)."""
    import shutil
    import subprocess

    if shutil.which("make") is None:
        pytest.skip("no make here")
    text = (ROOT / "Makefile").read_text()
    assert "\ntest: test-workers setup" in text and "\ntest-all: test-workers setup" in text
    done = subprocess.run(["make", "-s", "-C", str(ROOT), "test-workers", f"TEST_WORKERS={workers}"],
                          capture_output=True, text=True, timeout=60)
    assert (done.returncode == 0) == ok, done.stderr
    if not ok:
        assert done.stderr.splitlines()[0] == ("error: TEST_WORKERS must be auto, logical or a number of test "
                                                f"processes (0: in this process), got '{workers}'")
