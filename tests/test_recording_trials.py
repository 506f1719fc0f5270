"""Recordings of trial episodes: what an agent exposes through the optional hooks (its map, plans,
memory) ends up in the .rrd next to the robot, the camera and the scene, and recording never
changes an episode's numbers."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from helios.schema import with_overrides
from tasks import registry
from tasks.episodes import load_split
from tasks.oracle import OracleAgent
from tasks.trial_config import TrialConfig, deterministic_view
from tasks.trials import run_batch, run_one

RERUN = Path(sys.executable).with_name("rerun")


class MappingOracle:
    """The oracle, plus a ``HierarchicalMap`` fed with every observation it takes; exposes the
    optional trial hooks ``memory_bytes()`` and ``record(recorder)``."""

    name = "mapping-oracle"

    def __init__(self, context, **_options):   # registry factories take config options
        self._oracle = OracleAgent(context)
        self.map = None
        self.record_calls = 0

    def reset(self, task, rng):
        from helios.config import HeliosConfig
        from helios.schema import with_overrides
        from helios.maps.hierarchical import HierarchicalMap

        self._oracle.reset(task, rng)
        cfg = with_overrides(HeliosConfig(), ["occupancy.grid_size=800", "occupancy.cell_size=0.05"])
        self.map = HierarchicalMap(cfg, [task.object, task.start_receptacle, task.goal_receptacle],
                                   value_layers=[task.start_receptacle, task.goal_receptacle])
        # a few Gaussians with different certainty, so recordings have ellipsoids to draw
        self.map.objects.add_gaussians(np.array([[1.0, 1.0, 0.5], [1.1, 1.0, 0.5], [3.0, 2.0, 0.8]]), 0.05, 0.5,
                                       concentrations=np.array([[50.0, 1, 1, 1], [2, 1, 1, 1], [1, 1, 30, 1]]))

    def act(self, robot):
        agent = self

        class Tap:
            def __init__(self, r):
                self._r = r

            def observe(self):
                obs = self._r.observe()
                agent.map.update(obs, scores={name: 0.5 for name in agent.map.values.layers})
                return obs

            def __getattr__(self, name):
                return getattr(self._r, name)

        return self._oracle.act(Tap(robot))

    def memory_bytes(self):
        return self.map.memory_bytes()

    def record(self, recorder):
        from helios.perception.detection import Detection

        self.record_calls += 1
        recorder.log_map(self.map)
        mask = np.zeros((240, 320), dtype=bool)
        mask[100:140, 150:200] = True
        recorder.log_detections([Detection(mask, "mug", 0.8)], ["mug", "table"])
        recorder.log_path("plan", [(0.0, 0.0, 0.1), (1.0, 1.0, 0.1)])


@pytest.fixture
def mapping_agent(monkeypatch):
    monkeypatch.setitem(registry.AGENTS, "mapping-oracle",
                        registry.AgentEntry(MappingOracle, "test double: oracle + HELIOS map"))
    import rerun as rr

    rr.set_strict_mode(True)          # logging mistakes raise (and would show up as recording errors)
    yield with_overrides(TrialConfig(agent="mapping-oracle", episodes=1), ["runner.max_sim_time=45"])
    rr.set_strict_mode(False)


def _entities(path: Path) -> str:
    proc = subprocess.run([str(RERUN), "rrd", "stats", str(path)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def test_a_recorded_episode_holds_robot_camera_map_plans_and_metrics(mapping_agent, tmp_path):
    out = tmp_path / "run"
    ep = load_split("smoke")[0]
    records = run_batch(mapping_agent, [ep], out, record=1)
    rec = records[0]
    assert rec["recording"] == {"path": "recordings/smoke-00000.rrd", "errors": []}
    path = out / rec["recording"]["path"]
    assert path.stat().st_size > 200_000
    verify = subprocess.run([str(RERUN), "rrd", "verify", str(path)], capture_output=True, text=True, timeout=60)
    assert verify.returncode == 0, verify.stderr
    stats = _entities(path)
    value_layers = (f"/maps/value/{ep.start_receptacle_category}", f"/maps/value/{ep.goal_receptacle_category}")
    for entity in ("/world/hand_camera/rgb", "/world/hand_camera/depth", "/transforms",       # robot + camera
                   "/world/hand_camera/detections/boxes", "/world/hand_camera/detections/masks",
                   "/maps/occupancy", *value_layers,                                         # map layers as images
                   "/world/map/gaussians", "/world/map/obstacles", "/world/map/frontiers",    # map in 3D
                   "/world/plans/navigate_to", "/world/plans/plan",                          # planned paths
                   "/world/scene/target", "/world/scene/goal_receptacles", "/world/scene/walls",
                   "/metrics/memory/rss_mb", "/metrics/memory/map_mb", "/metrics/outcome/SR", "/log"):
        assert f"{entity}:" in stats, entity
    # the memory hook: the map's bytes, summed over its layers (occupancy: a few bytes per cell of the 800 x 800 grid)
    mem = rec["memory"]
    assert set(mem["map_bytes_final"]) == {"occupancy", "value_map", "gaussians"}
    assert mem["map_bytes_final"]["occupancy"] % (800 * 800) == 0 and mem["map_bytes_final"]["occupancy"] > 0
    assert mem["map_mb_peak"] == pytest.approx(sum(mem["map_bytes_final"].values()) / 2 ** 20, abs=1e-3)
    assert max(mem["series"]["map_mb"]) == pytest.approx(mem["map_mb_peak"], abs=1e-3)


def test_recording_does_not_change_the_numbers(mapping_agent, tmp_path):
    ep = load_split("smoke")[0]
    recorded = run_one(mapping_agent, ep, recording=tmp_path / "a.rrd")
    plain = run_one(mapping_agent, ep)
    assert deterministic_view(recorded) == deterministic_view(plain)
    assert "recording" not in plain and recorded["recording"]["path"].endswith("a.rrd")


def test_log_map_draws_gaussians_by_class_and_uncertainty(tmp_path):
    from helios.config import HeliosConfig
    from helios.schema import with_overrides as wo
    from helios.maps.hierarchical import HierarchicalMap
    from tasks.recording import BACKGROUND_RGB, PALETTE, EpisodeRecorder

    hmap = HierarchicalMap(wo(HeliosConfig(), ["occupancy.grid_size=64"]), ["mug", "table"], ["table"])
    hmap.objects.add_gaussians(np.zeros((2, 3)), 0.05, 0.5, concentrations=np.array([[1000.0, 1, 1], [1.0, 1, 1]]))
    logged = {}
    with EpisodeRecorder(tmp_path / "m.rrd") as rec:
        real_log = rec.rec.log
        rec.rec.log = lambda path, value, **kw: (logged.__setitem__(path, value), real_log(path, value, **kw))
        rec.set_time(1.0)
        rec.log_map(hmap)
    ell = logged["world/map/gaussians"]
    colors = ell.colors.as_arrow_array().to_numpy(zero_copy_only=False)
    rgb = [((int(c) >> 24) & 255, (int(c) >> 16) & 255, (int(c) >> 8) & 255) for c in colors]
    # a confident mug is (almost) the mug colour; a flat Dirichlet is background grey
    assert np.allclose(rgb[0], PALETTE[0], atol=8)
    assert np.allclose(rgb[1], BACKGROUND_RGB, atol=1)
    assert "maps/occupancy" in logged and "maps/value/table" in logged
