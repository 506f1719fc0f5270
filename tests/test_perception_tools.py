"""``python -m tools calibrate-perception`` and ``python -m tools bench perception`` (smoke runs)."""

from __future__ import annotations

import argparse
import json

import pytest

from tools.cli import main


def test_calibrate_perception_writes_a_table_json_and_plot(tmp_path, capsys):
    out = tmp_path / "cal"
    assert main(["calibrate-perception", "--views", "12", "--scenes", "1", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "scene 1/1" in text and "ALL small objects" in text and "5-view majority right %" in text
    result = json.loads((out / "calibration.json").read_text())
    assert result["views"] == 12
    assert set(result["pooled"]) == {"small objects", "receptacles"}
    assert (out / "calibration.png").stat().st_size > 10_000
    from sim.perception.config import SimPerceptionConfig

    assert result["config"]["bad_view_object"] == SimPerceptionConfig().bad_view_object   # the config is recorded
    from tools.calibrate_perception import load_baseline, receptacle_lines

    baseline = load_baseline(str(out / "calibration.json"))       # a run's own file is a valid --baseline
    assert "(before / after)" in receptacle_lines(result, baseline)


def test_calibrate_perception_bad_input_is_one_line(tmp_path, capsys):
    assert main(["calibrate-perception", "--views", "3", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip().startswith("error: --views (3) must be at least --group (5)")
    assert main(["calibrate-perception", "--views", "10", "--out", str(tmp_path), "bad_view_object=2"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "bad_view_object must be in [0, 1]" in err and len(err.splitlines()) == 1


ROW = {"precision": 0.5, "recall": None, "tp": 1, "fp": 1, "instances": 2}


@pytest.mark.parametrize("doc, fragment", [
    ({"task_query": {"start receptacle": 1}, "pooled": {"receptacles": 3}},
     "['task_query']['start receptacle'] is 1, not an object"),
    ({"task_query": {"start receptacle": ROW}, "pooled": {"receptacles": ROW}}, "['task_query']['goal receptacle'] is missing"),
    ({"task_query": {"start receptacle": ROW, "goal receptacle": ROW}, "pooled": {"receptacles": 3}},
     "['pooled']['receptacles'] is 3, not an object"),
    ({"task_query": {"start receptacle": ROW, "goal receptacle": {**ROW, "tp": "1"}}, "pooled": {"receptacles": ROW}},
     "['task_query']['goal receptacle']['tp'] is \"1\", not a whole number >= 0"),
    ({"task_query": {"start receptacle": {**ROW, "recall": 7}, "goal receptacle": ROW}, "pooled": {"receptacles": ROW}},
     "['task_query']['start receptacle']['recall'] is 7, not null or a number within 0..1"),
    ([], "it holds a list, not an object"),
    ("", "--baseline must not be empty"),
])
def test_calibrate_perception_refuses_a_wrong_baseline_before_any_view(doc, fragment, tmp_path, capsys, monkeypatch):
    """A parseable but wrong --baseline once failed with a traceback after the whole calibration."""
    import tasks.perception_calibration as pc

    monkeypatch.setattr(pc, "calibrate", lambda *a, **k: pytest.fail("the calibration ran"))
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps(doc))
    arg = "" if doc == "" else str(path)
    assert main(["calibrate-perception", "--views", "5", "--out", str(tmp_path / "out"), "--baseline", arg]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and fragment in err, err
    assert doc == "" or f"--baseline '{path}': not a calibration.json of this tool: " in err


def test_calibrate_perception_refuses_more_scenes_than_the_split_has(tmp_path, capsys, monkeypatch):
    """``--scenes 500`` of the 20 smoke homes was silently capped, and 500 recorded."""
    import tasks.perception_calibration as pc

    monkeypatch.setattr(pc, "SimEpisode", None)          # calibrate() must refuse before building a scene
    with pytest.raises(ValueError, match="scenes=21: split 'smoke' has 20 distinct scenes"):
        pc.calibrate(pc.CalibrationSettings(split="smoke", views=25, scenes=21))
    monkeypatch.setattr(pc, "calibrate", lambda *a, **k: pytest.fail("the calibration ran"))
    assert main(["calibrate-perception", "--split", "smoke", "--scenes", "21", "--views", "25",
                 "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.strip() == "error: --scenes 21 is more than the 20 distinct scenes of split 'smoke'"


def test_calibrate_perception_with_fewer_views_than_scenes_records_the_scenes_it_viewed(tmp_path, capsys,
                                                                                          monkeypatch):
    """``--views 5`` with the default 8 scenes once gave three scenes no view and recorded 8."""
    import tasks.perception_calibration as pc

    monkeypatch.setattr(pc, "SimEpisode", None)
    with pytest.raises(ValueError, match="views=5 < scenes=8"):
        pc.calibrate(pc.CalibrationSettings(split="smoke", views=5, group=1, scenes=8))
    seen = []

    def fake_calibrate(settings, config, progress=None):
        seen.append(settings)
        raise KeyboardInterrupt       # stop here: only the settings handed over are checked

    monkeypatch.setattr(pc, "calibrate", fake_calibrate)
    assert main(["calibrate-perception", "--split", "smoke", "--views", "5", "--group", "1",
                 "--out", str(tmp_path / "out")]) == 130
    assert seen[0].scenes == 5 and seen[0].views == 5
    assert "on 5 views of 5 smoke scenes (fewer views than --scenes 8)" in capsys.readouterr().out


def test_bench_perception_quick_reports_median_and_p90():
    from tools.bench_perception import run

    text = run(argparse.Namespace(quick=True, seed=0))
    assert "detector + scorer" in text and "median ms" in text and "p90 ms" in text and "target <= 10 ms" in text
