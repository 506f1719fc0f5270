"""What an open-vocabulary detector and an image-text scorer hand to the map.

Both real models (OWLv2/CLIP adapters) and the simulated detector in ``sim`` implement these
protocols, so the map and the agents never know which one they are talking to.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, Sequence, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class Detection:
    """One detected instance: a boolean pixel mask, the class name it was labelled with, a score."""

    mask: np.ndarray
    class_name: str
    score: float

    def __post_init__(self) -> None:
        if not isinstance(self.mask, np.ndarray) or self.mask.ndim != 2:
            raise ValueError(f"Detection mask must be a 2-D array, got {getattr(self.mask, 'shape', type(self.mask))}")
        if self.mask.dtype != np.bool_:
            object.__setattr__(self, "mask", self.mask.astype(bool))
        if not isinstance(self.class_name, str) or not self.class_name:
            raise ValueError(f"Detection class_name must be a non-empty string, got {self.class_name!r}")
        if not (isinstance(self.score, (int, float, np.floating)) and math.isfinite(float(self.score))):
            raise ValueError(f"Detection score must be a finite number, got {self.score!r}")
        object.__setattr__(self, "score", float(self.score))


@runtime_checkable
class Detector(Protocol):
    def __call__(self, rgb: np.ndarray, depth: np.ndarray, class_names: Sequence[str]) -> list[Detection]:
        """Detect instances of ``class_names`` in an RGB-D frame."""


@runtime_checkable
class ImageTextScorer(Protocol):
    def __call__(self, rgb: np.ndarray, prompts: Sequence[str]) -> np.ndarray:
        """One similarity score per prompt for the whole image (float array of len(prompts))."""
