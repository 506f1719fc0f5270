"""``python -m tools calibrate-perception`` and ``python -m tools bench perception`` (smoke runs)."""

from __future__ import annotations

import argparse
import json

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


def test_calibrate_perception_bad_input_is_one_line(tmp_path, capsys):
    assert main(["calibrate-perception", "--views", "3", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip().startswith("error: --views (3) must be at least --group (5)")
    assert main(["calibrate-perception", "--views", "10", "--out", str(tmp_path), "bad_view_object=2"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "bad_view_object must be in [0, 1]" in err and len(err.splitlines()) == 1


def test_bench_perception_quick_reports_median_and_p90():
    from tools.bench_perception import run

    text = run(argparse.Namespace(quick=True, seed=0))
    assert "detector + scorer" in text and "median ms" in text and "p90 ms" in text and "target <= 10 ms" in text
