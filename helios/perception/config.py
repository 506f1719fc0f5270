"""Perception settings of the method: per-role detection thresholds, the value-map prompt, and
where the real models' weights live. Simulator-side parameters (how the simulated detector errs)
are in ``sim.perception.config``; nothing here knows about the simulator.

:class:`DetectionThresholds` is the one threshold type of the project: it is also the
``detection`` section of :class:`helios.config.HeliosConfig` (YAML keys ``helios.detection.*``).
:func:`role_thresholds` turns it into per-class thresholds of one task and :func:`apply_thresholds`
is the one place detections are filtered by score.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Literal, Mapping

from helios.perception.detection import Detection
from helios.perception.prompts import VALUE_PROMPT_TEMPLATE
from helios.schema import require


@dataclass(frozen=True)
class DetectionThresholds:
    """Per-role detector confidence thresholds (the paper's od_a, od_g, od_b)."""

    od_start_receptacle: float = 0.35
    """*paper* od_a: minimum detector score for the start (pick) receptacle class."""
    od_object: float = 0.25
    """*paper* od_g: minimum score for the target object class (low: HELIOS filters false positives
    by multi-view consistency but cannot recover missed detections)."""
    od_goal_receptacle: float = 0.45
    """*paper* od_b: minimum score for the goal (place) receptacle class."""

    def __post_init__(self) -> None:
        for name in ("od_start_receptacle", "od_object", "od_goal_receptacle"):
            value = getattr(self, name)
            require(isinstance(value, (int, float)) and 0.0 <= value <= 1.0, f"{name} must be in [0, 1], got {value}")


def role_thresholds(thresholds: DetectionThresholds, object_class: str, start_receptacle: str,
                    goal_receptacle: str) -> dict[str, float]:
    """Class name -> threshold for one task; a class filling two roles gets the lower threshold
    (HELIOS filters false positives itself but cannot recover missed detections)."""
    out: dict[str, float] = {}
    for name, value in ((object_class, thresholds.od_object), (start_receptacle, thresholds.od_start_receptacle),
                        (goal_receptacle, thresholds.od_goal_receptacle)):
        out[name] = min(float(value), out.get(name, float(value)))
    return out


def passes_threshold(detection: Detection, thresholds: Mapping[str, float], default: float | None = None) -> bool:
    """Whether ``detection.score`` reaches its class's threshold (``default`` for classes missing
    from ``thresholds``; with ``default=None`` such a class never passes)."""
    t = thresholds.get(detection.class_name, default)
    return t is not None and detection.score >= t


def apply_thresholds(detections: Iterable[Detection], thresholds: Mapping[str, float],
                     default: float | None = None) -> list[Detection]:
    """The detections, in order, that pass :func:`passes_threshold`. The agent keeps only the
    task's classes: ``apply_thresholds(dets, role_thresholds(...), default=1.0)``."""
    return [det for det in detections if passes_threshold(det, thresholds, default)]


@dataclass(frozen=True)
class ModelConfig:
    """Real open-vocabulary models for the real Spot (optional extra ``perception``: transformers).

    Weights are read from local directories only (``save_pretrained`` layout: ``config.json`` plus
    weights and processor files); nothing is downloaded at run time.
    """

    detector_weights: str = ""
    """Directory of an OWLv2 checkpoint (e.g. a local copy of google/owlv2-base-patch16-ensemble)."""
    scorer_weights: str = ""
    """Directory of a CLIP checkpoint (e.g. a local copy of openai/clip-vit-base-patch32)."""
    device: Literal["cpu", "cuda", "auto"] = "cpu"
    """Torch device for both models (``auto``: CUDA when available)."""
    detector_min_score: float = 0.1
    """Boxes below this OWLv2 score are not reported (the per-role thresholds apply afterwards)."""
    depth_mask_tolerance: float = 0.25
    """m; a box becomes a mask of its pixels within this depth of the box's median central depth
    (OWLv2 gives boxes, the map wants masks). 0 = use the whole box."""

    def __post_init__(self) -> None:
        require(self.device in ("cpu", "cuda", "auto"), f"device must be cpu, cuda or auto, got {self.device!r}")
        require(0.0 <= self.detector_min_score <= 1.0, f"detector_min_score must be in [0, 1], got {self.detector_min_score}")
        require(math.isfinite(self.depth_mask_tolerance) and self.depth_mask_tolerance >= 0,
                f"depth_mask_tolerance must be >= 0 m, got {self.depth_mask_tolerance}")


@dataclass(frozen=True)
class PerceptionConfig:
    """What the method needs to know about perception, independent of where images come from."""

    thresholds: DetectionThresholds = field(default_factory=DetectionThresholds)
    value_prompt: str = VALUE_PROMPT_TEMPLATE
    """*paper* Template of the value-map prompt; ``{}`` is replaced by the target category."""
    models: ModelConfig = field(default_factory=ModelConfig)

    def __post_init__(self) -> None:
        require(self.value_prompt.count("{}") == 1,
                f"value_prompt needs exactly one '{{}}' for the category, got {self.value_prompt!r}")
