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
from sim.perception.partial_gt import PartlyTrueDetector, role_classes_of, true_classes
from sim.perception.scorer import GroundTruthScorer, SimImageTextScorer


def make_sim_perception(backend, seed: int, config: SimPerceptionConfig = SimPerceptionConfig(), rooms=None,
                        role_classes=None):
    """(detector, scorer) for a simulated backend, seeded per episode; ``config.mode`` picks noisy
    or ground-truth semantics. ``rooms`` (``scene.layout.rooms``) lets the scorer tell which room
    the camera looks into; without it the room tags of visible furniture are used.
    ``role_classes`` (role -> class, ``partial_gt.role_classes_of(episode)``) is needed with
    ``config.gt_roles``: those roles' classes are then detected exactly."""
    analyzer = FrameAnalyzer(backend, config)
    if config.mode == "gt":
        return GroundTruthDetector(backend, config, analyzer), GroundTruthScorer(backend, config, analyzer, rooms)
    detector = SimDetector(backend, seed, config, analyzer)
    if config.gt_roles:
        detector = PartlyTrueDetector(detector, GroundTruthDetector(backend, config, analyzer),
                                      true_classes(config.gt_roles, role_classes))
    return detector, SimImageTextScorer(backend, seed, config, analyzer, rooms)


__all__ = ["SimPerceptionConfig", "SimDetector", "GroundTruthDetector", "SimImageTextScorer", "GroundTruthScorer",
           "FrameAnalyzer", "PartlyTrueDetector", "role_classes_of", "make_sim_perception"]
