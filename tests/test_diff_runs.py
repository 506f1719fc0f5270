"""`tools diff`: which episodes' records differ between two run folders, field by field."""

from __future__ import annotations

import json
import math

import pytest

from cli_helpers import run_cli
from tasks.run_folder import append_result, prepare_run_folder
from tasks.trial_config import FINGERPRINT_FIELD, TrialConfig, config_fingerprint
from tools.diff_runs import differences, parse_ignore


def _record(i: int, config: TrialConfig, **metrics) -> dict:
    m = {"find_obj": True, "pick": True, "find_rec": False, "place": False, "success": False, "collisions": 0,
         "failure_reason": "receptacle_not_found", "find_obj_time": 40.0 + i, "pick_time": 80.0 + i,
         "find_rec_time": None}
    m.update(metrics)
    return {"episode_id": f"val-{i:05d}", "agent": config.agent, "seed": i, "success": m["success"], "error": None,
            "commands": 100 + i, "limit_hit": False, "sim_time": 300.0 + i, "wall_time": 5.0 + i,
            "extra": {"decisions": {"gaze_point_visits": 7 + i}, "activity_time": {"exploration": 120.5}},
            "collision_events": [], "metrics": m, "memory": {"peak_rss_mb": 600.0 + i},
            FINGERPRINT_FIELD: config_fingerprint(config)}


def _run(path, n: int, config: TrialConfig | None = None, changes: dict | None = None, start: int = 0):
    """A synthetic run folder with episodes start..start+n-1; ``changes`` maps an episode index to
    a function that edits its record."""
    config = config or TrialConfig(agent="helios", split="val", episodes=start + n)
    prepare_run_folder(path, config)
    for i in range(start, start + n):
        rec = _record(i, config)
        if changes and i in changes:
            changes[i](rec)
        append_result(path / "episodes.jsonl", rec)
    return path


def test_differences_walk_nested_records_leaf_by_leaf():
    a = {"m": {"x": 1, "y": [1.0, 2.0], "b": True}, "t": 3.0, "n": float("nan"), "only_a": 1}
    b = {"m": {"x": 1.0, "y": [1.0, 2.5], "b": 1}, "t": 3.0, "n": float("nan"), "only_b": None}
    d = {p: (x, y) for p, x, y in differences(a, b)}
    # 1 and 1.0 are one number, NaN equals NaN; a bool is not the number 1; a list differs where it does
    assert set(d) == {"m.y[1]", "m.b", "only_a", "only_b"}
    assert d["m.y[1]"] == (2.0, 2.5) and d["m.b"] == (True, 1)
    assert differences(a, b, frozenset({"m", "only_a", "only_b"})) == []          # ignored with all below
    assert [p for p, _, _ in differences({"l": [1, 2]}, {"l": [1, 2, 3]})] == ["l"]   # lengths differ: as a whole
    assert differences({"x": {"y": 1}}, {"x": [1]}) == [("x", {"y": 1}, [1])]
    assert not differences(json.loads(json.dumps(a, allow_nan=True)), a)
    assert math.isnan(differences({"n": float("nan")}, {"n": 0.0})[0][1])


def test_a_tolerance_lets_last_bit_rounding_through_and_nothing_else():
    a = {"t": 512.25, "z": -1.0967893389286918e-05, "n": 600, "ok": True}
    b = {"t": 512.25 * (1 + 3e-13), "z": -1.0967893389286e-05, "n": 601, "ok": True}
    assert [p for p, _, _ in differences(a, b)] == ["n", "t", "z"]
    assert [p for p, _, _ in differences(a, b, tolerance=1e-9)] == ["n"]              # a count is never close
    assert [p for p, _, _ in differences({"z": 0.0}, {"z": 1e-7}, tolerance=1e-9)] == ["z"]   # near zero: absolute 1e-12
    assert differences({"ok": True}, {"ok": 1}, tolerance=0.5) == [("ok", True, 1)]


def test_identical_runs_exit_0_and_wall_time_and_memory_do_not_count(tmp_path):
    a = _run(tmp_path / "a", 4)
    b = _run(tmp_path / "b", 4, changes={1: lambda r: r.update(wall_time=99.0, memory={"peak_rss_mb": 1.0})})
    rc, out, err = run_cli(["diff", str(a), str(b)])
    assert rc == 0, out + err
    assert "identical: 4 of 4" in out and "different" not in out
    assert "compared: the 4 episodes both runs have (val-00000 .. val-00003)" in out
    assert "configurations: the same" in out and "only in A: none; only in B: none" in out


def test_a_changed_outcome_is_named_with_both_values_and_exit_1(tmp_path):
    a = _run(tmp_path / "a", 5)

    def place(r):
        r["metrics"].update(place=True, success=True, failure_reason=None)
        r["success"] = True

    b = _run(tmp_path / "b", 5, changes={2: place, 4: lambda r: r["extra"]["decisions"].update(gaze_point_visits=3)})
    rc, out, err = run_cli(["diff", str(a), str(b)])
    assert rc == 1, out + err
    assert "identical: 3 of 5" in out and "different: 2 (A / B)" in out
    line = next(s for s in out.splitlines() if s.strip().startswith("val-00002:"))
    # outcomes first, both values, JSON spelling
    assert line.strip().startswith('val-00002: 4 field(s) differ: metrics.failure_reason: "receptacle_not_found" / null;')
    assert "metrics.place: false / true" in line and "success: false / true" in line
    assert "val-00004: 1 field(s) differ: extra.decisions.gaze_point_visits: 11 / 3" in out
    assert "fields that differ, in how many episodes: extra.decisions 1, metrics.failure_reason 1" in out
    # ignoring the fields that differ makes the runs identical
    rc, out, _ = run_cli(["diff", str(a), str(b), "--ignore",
                          "metrics.place,metrics.success,metrics.failure_reason,success,extra.decisions"])
    assert rc == 0 and "identical: 5 of 5" in out
    # a tolerance does not hide a changed outcome, and says it was used
    rc, out, _ = run_cli(["diff", str(a), str(b), "--tolerance", "1e-6"])
    assert rc == 1 and "numbers within 1e-06 (relative) count as equal" in out and "identical: 3 of 5" in out
    # only the first N shared episodes
    rc, out, _ = run_cli(["diff", str(a), str(b), "--episodes", "2"])
    assert rc == 0 and "compared: the first 2 of the 5 episodes both runs have (val-00000 .. val-00001)" in out


def test_episodes_only_one_run_has_and_configurations_that_differ(tmp_path):
    a = _run(tmp_path / "a", 6)
    cfg = TrialConfig(agent="helios", split="val", episodes=7, seed=3)
    b = _run(tmp_path / "b", 4, config=cfg, start=3)
    rc, out, err = run_cli(["diff", str(a), str(b), "--show", "1"])
    assert rc == 1, out + err            # the fingerprints differ in every record
    assert "configurations differ in 1 field(s) (A / B): seed: 0 / 3" in out
    assert "compared: the 3 episodes both runs have (val-00003 .. val-00005)" in out
    assert "only in A: 3 episodes, val-00000 .. val-00002; only in B: 1 episode, val-00006" in out
    assert "... and 2 more episode(s) (--show to list them)" in out
    assert f"config_fingerprint: \"{config_fingerprint(TrialConfig(agent='helios', split='val', episodes=6))}\"" in out
    rc, out, _ = run_cli(["diff", str(a), str(b), "--ignore", "config_fingerprint"])
    assert rc == 1 and "identical: 3 of 3" in out         # the episodes only one run has count
    assert "not the same episodes: 4 episodes in one run only count as a difference (only in A: val-00000, " \
           "val-00001, val-00002; only in B: val-00006); --common compares only the episodes both runs have" in out
    rc, out, _ = run_cli(["diff", str(a), str(b), "--ignore", "config_fingerprint", "--common"])
    assert rc == 0 and "identical: 3 of 3" in out and "not the same episodes" not in out
    assert "(--common: episodes only one run has do not count)" in out


def test_episodes_only_one_run_has_set_the_exit_status_unless_common(tmp_path):
    """(reliability audit 2026-12-06) The exit status covered only the compared records: a run cut
    short, or one of another episode set, compared as the same as the full run (exit 0) where they
    overlapped. Episodes in one run only now count, named on one line (the first ten), unless
    ``--common`` asks for the episodes both runs have, as ``tools report --common`` does."""
    a = _run(tmp_path / "a", 30)
    b = _run(tmp_path / "b", 14, config=TrialConfig(agent="helios", split="val", episodes=30))   # cut short
    rc, out, err = run_cli(["diff", str(a), str(b)])
    assert rc == 1, out + err
    assert "identical: 14 of 14" in out and "different:" not in out
    line = next(s for s in out.splitlines() if s.startswith("not the same episodes:"))
    assert line == ("not the same episodes: 16 episodes in one run only count as a difference (only in A: "
                    + ", ".join(f"val-{i:05d}" for i in range(14, 24)) + " and 6 more); --common compares only "
                    "the episodes both runs have")
    rc, out, err = run_cli(["diff", str(b), str(a), "--common"])
    assert rc == 0 and "identical: 14 of 14" in out, out + err
    # --episodes N: the first N by id of either run, so a missing one among them counts ...
    rc, out, _ = run_cli(["diff", str(a), str(b), "--episodes", "16"])
    assert rc == 1 and "identical: 14 of 14" in out
    assert "16 episodes in one run only" not in out and "2 episodes in one run only count as a difference " \
        "(only in A: val-00014, val-00015)" in out
    rc, out, _ = run_cli(["diff", str(a), str(b), "--episodes", "14"])       # ... and none beyond them
    assert rc == 0 and "identical: 14 of 14" in out and "not the same episodes" not in out
    rc, out, _ = run_cli(["diff", str(a), str(b), "--episodes", "16", "--common"])   # the first 16 both have
    assert rc == 0 and "compared: the 14 episodes both runs have" in out


def test_a_damaged_line_is_named_and_the_rest_compared(tmp_path):
    a = _run(tmp_path / "a", 3)
    b = _run(tmp_path / "b", 3)
    lines = (b / "episodes.jsonl").read_bytes().splitlines(keepends=True)
    lines[1] = b'{"episode_id": "val-00001", "broken\n'
    (b / "episodes.jsonl").write_bytes(b"".join(lines))
    rc, out, err = run_cli(["diff", str(a), str(b)])
    assert rc == 1, out + err                    # B lacks a valid record of val-00001
    assert f"warning: {b / 'episodes.jsonl'}:2: not valid JSON" in err
    assert "identical: 2 of 2" in out and "only in A: 1 episode, val-00001" in out
    assert "not the same episodes: 1 episode in one run only counts as a difference (only in A: val-00001)" in out
    rc, out, err = run_cli(["diff", str(a), str(b), "--common"])
    assert rc == 0 and "identical: 2 of 2" in out, out + err


def test_the_cpu_code_paths_of_the_two_runs_are_compared(tmp_path):
    from tools.diff_runs import diff_runs, report_lines
    from tools.report_runs import load_run

    a, b = load_run(_run(tmp_path / "a", 2)), load_run(_run(tmp_path / "b", 2))
    a.cpu, b.cpu = ("x86-64-v3, numpy X86_V3",), ("x86-64-v4, numpy AVX512_SKX",)
    text = "\n".join(report_lines(a, b, diff_runs(a, b)))
    assert "CPU code paths differ between the runs" in text and "x86-64-v4, numpy AVX512_SKX" in text
    b.cpu = a.cpu
    assert "CPU code paths differ" not in "\n".join(report_lines(a, b, diff_runs(a, b)))


def test_runs_on_different_cpus_on_the_same_code_path_are_said(tmp_path):
    """The same code on the same pinned path still moved a record on another CPU (2026-12-05), so
    the diff names the CPUs the runs ran on and says when they differ."""
    from tasks.run_folder import append_result, run_cpu_models
    from tools.diff_runs import diff_runs, report_lines
    from tools.report_runs import load_run

    folders = {name: _run(tmp_path / name, 2) for name in ("a", "b")}
    for name, model in (("a", "Intel(R) Xeon(R) Processor"), ("b", "AMD EPYC 9R14 96-Core Processor")):
        append_result(folders[name] / "invocations.jsonl", {"episodes_to_run": 2, "cpu_model": model})
        append_result(folders[name] / "invocations.jsonl", {"episodes_to_run": 0, "cpu_model": "not counted"})
    assert run_cpu_models(folders["b"]) == ["AMD EPYC 9R14 96-Core Processor"]
    a, b = load_run(folders["a"]), load_run(folders["b"])
    text = "\n".join(report_lines(a, b, diff_runs(a, b)))
    assert "on Intel(R) Xeon(R) Processor" in text and "on AMD EPYC 9R14 96-Core Processor" in text
    assert "the runs ran on different CPUs" in text
    b = load_run(folders["a"])
    assert "different CPUs" not in "\n".join(report_lines(a, b, diff_runs(a, b)))


def test_an_invocation_records_the_cpu_model(tmp_path):
    from helios.runtime import cpu_model
    from tasks.run_folder import log_invocation, read_invocations

    log_invocation(tmp_path, 1, "local", "", 3, "abc")
    assert read_invocations(tmp_path)[0][0]["cpu_model"] == cpu_model()


@pytest.mark.parametrize("text,fragment", [("a,,b", "empty field name"), ("a b", "not a dotted field path"),
                                           (".a", "not a dotted field path"), ("a..b", "not a dotted field path")])
def test_bad_ignore_lists_are_refused(text, fragment):
    from tools.cli import CliError

    with pytest.raises(CliError, match=fragment):
        parse_ignore(text)
    assert parse_ignore(" metrics.place , sim_time") == frozenset({"metrics.place", "sim_time"})


def test_two_real_runs_of_the_same_config_are_identical(tmp_path):
    """End to end: one smoke episode run twice (oracle, short budget) gives identical records."""
    from helios.schema import with_overrides
    from tasks.episodes import load_split
    from tasks.trials import run_batch

    config = with_overrides(TrialConfig(episodes=2), ["runner.max_sim_time=20"])
    for name in ("a", "b"):
        run_batch(config, load_split("smoke")[:2], tmp_path / name)
    rc, out, err = run_cli(["diff", str(tmp_path / "a"), str(tmp_path / "b")])
    assert rc == 0, out + err
    assert "identical: 2 of 2" in out and "configurations: the same" in out


def test_two_long_values_that_differ_in_the_middle_are_shown_where_they_differ():
    """(determinism audit 2026-12-05) Shortened in the middle, two different texts of one length
    printed as the same value."""
    from tools.diff_runs import _shown_pair, show_value

    x = "A" * 100 + "path/one" + "B" * 100
    y = "A" * 100 + "path/two" + "B" * 100
    assert show_value(x) == show_value(y)
    sx, sy = _shown_pair(x, y)
    assert sx != sy and "one" in sx and "two" in sy and "from character 90" in sx
    assert _shown_pair(1, 2) == ("1", "2")


def test_records_that_differ_only_below_the_errors_first_line_are_identical(tmp_path):
    """(mutation audit 2026-12-05) The same exception raised from another line, or from the code in
    another folder (`tools unchanged`), is the same outcome; another exception is not."""
    def error(where):
        def edit(rec):
            rec["error"] = f"RuntimeError: boom\n  File \"{where}\", line 3, in f\n"
        return edit

    a = _run(tmp_path / "a", 2, changes={1: error("/x/helios/a.py")})
    b = _run(tmp_path / "b", 2, changes={1: error("/y/base-tree/helios/a.py")})
    rc, out, err = run_cli(["diff", str(a), str(b)])
    assert rc == 0 and "identical: 2 of 2" in out, out + err
    c = _run(tmp_path / "c", 2, changes={1: lambda rec: rec.update(error="ValueError: bang\n  File \"a.py\"")})
    rc, out, _ = run_cli(["diff", str(a), str(c)])
    assert rc == 1 and "error: \"RuntimeError: boom\" / \"ValueError: bang\"" in out, out
