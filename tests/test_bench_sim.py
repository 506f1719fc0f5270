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
