"""`python -m tools bench sim` builds its rows from working calls (it once crashed on an import
after a helper moved): the physics rates come from the demo scene at rest and with the mug held."""

from __future__ import annotations

from tools.bench_sim import _physics_rates


def test_physics_rates_measure_the_scene_at_rest_and_with_the_mug_held():
    rows = _physics_rates(seed=0, n_steps=20)
    names = [r[0] for r in rows]
    assert names == ["physics step, scene at rest", "physics step, holding the mug"], \
        "the grasp in the benchmark's set-up should succeed, or the holding rate is not measured"
    assert all(r[1] > 0 and r[2] == "steps/s" for r in rows)


def test_bench_scenes_times_no_column_that_is_always_zero():
    """(audit 2026-12-05) A "nav grids s" column timed the grids after the validation had built and
    cached them: 0.00 for every home. Every timing column now measures work."""
    import argparse

    from tools.bench_scenes import run

    text = run(argparse.Namespace(quick=True))
    lines = text.splitlines()
    header = lines[1].split("  ")
    assert "nav grids s" not in header
    rows = [line.split() for line in lines[3:] if line.strip() and line.split()[0].isdigit()]
    assert len(rows) == 5
    for col in (-4, -3, -2):                    # layout s, build (grids included) s, total s
        assert all(float(r[col]) > 0 for r in rows), col
    assert "(target <= 3 s: " in text
