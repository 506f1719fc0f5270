"""Perception contracts and settings: detectors and image-text scorers the map consumes
(``detection``), the value-map prompt (``prompts``), per-role thresholds and model settings
(``config``), input checks and errors, and real-model adapters (``adapters``, optional extra).
Simulated implementations live in ``sim.perception``; nothing here imports the simulator."""

from helios.perception.config import DetectionThresholds, ModelConfig, PerceptionConfig, apply_thresholds, role_thresholds
from helios.perception.detection import Detection, Detector, ImageTextScorer
from helios.perception.errors import (
    ImageInputError,
    ModelWeightsMissingError,
    PerceptionDependencyError,
    PerceptionError,
    PromptError,
    UnknownCategoryError,
)
from helios.perception.prompts import VALUE_PROMPT_TEMPLATE, parse_value_prompt, value_prompt

__all__ = ["Detection", "Detector", "ImageTextScorer", "DetectionThresholds", "ModelConfig", "PerceptionConfig",
           "apply_thresholds", "role_thresholds", "PerceptionError", "UnknownCategoryError", "PromptError",
           "ImageInputError", "ModelWeightsMissingError", "PerceptionDependencyError", "VALUE_PROMPT_TEMPLATE",
           "value_prompt", "parse_value_prompt"]
