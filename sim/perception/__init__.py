"""Simulated open-vocabulary perception: a detector and an image-text scorer built on the
renderer's ground-truth instance segmentation, with realistic, view-dependent errors (``noisy``)
or perfect semantics (``gt``), behind the ``helios.perception`` protocols.

    detector, scorer = make_sim_perception(sim.backend, seed=episode.seed, config=SimPerceptionConfig(),
                                           rooms=sim.scene.layout.rooms)
    obs = backend.observe()
    detections = detector(obs.rgb, obs.depth, ["mug", "table", "counter"])
    values = scorer(obs.rgb, ["Seems like there is a table ahead", "Seems like there is a counter ahead"])
"""

from __future__ import annotations

from sim.perception.config import SimPerceptionConfig
from sim.perception.detector import GroundTruthDetector, SimDetector
from sim.perception.frames import FrameAnalyzer
from sim.perception.scorer import GroundTruthScorer, SimImageTextScorer


def make_sim_perception(backend, seed: int, config: SimPerceptionConfig = SimPerceptionConfig(), rooms=None):
    """(detector, scorer) for a simulated backend, seeded per episode; ``config.mode`` picks noisy
    or ground-truth semantics. ``rooms`` (``scene.layout.rooms``) lets the scorer tell which room
    the camera looks into; without it the room tags of visible furniture are used."""
    analyzer = FrameAnalyzer(backend, config)
    if config.mode == "gt":
        return GroundTruthDetector(backend, config, analyzer), GroundTruthScorer(backend, config, analyzer, rooms)
    return SimDetector(backend, seed, config, analyzer), SimImageTextScorer(backend, seed, config, analyzer, rooms)


__all__ = ["SimPerceptionConfig", "SimDetector", "GroundTruthDetector", "SimImageTextScorer", "GroundTruthScorer",
           "FrameAnalyzer", "make_sim_perception"]
