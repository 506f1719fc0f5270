"""Detections to a per-pixel class-label image and an object-of-interest mask.

Every pixel gets exactly one label y_i (one-hot in the paper's update): the class of the most
confident detection covering it, else the background class. Background-class detections label
their pixels but never create Gaussians: only objects of interest are modelled.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from helios.maps.classes import ClassSet
from helios.maps.inputs import MapInputError, check_image_mask
from helios.perception.config import passes_threshold
from helios.perception.detection import Detection


@dataclass(frozen=True)
class DetectionLabels:
    labels: np.ndarray
    """(H, W) int64 class index per pixel (background where nothing was detected)."""
    objects: np.ndarray
    """(H, W) bool: pixels detected as one of the task's (non-background) classes."""
    n_used: int
    """Detections that passed the score thresholds and were painted."""


def label_detections(detections: Sequence[Detection], classes: ClassSet, shape: tuple[int, int],
                     score_thresholds: Mapping[str, float] | None = None) -> DetectionLabels:
    """Paint detections (lowest score first, so the most confident wins overlaps) into labels.

    Raises UnknownClassError for a class outside ``classes`` and MapInputError for a mask whose
    shape differs from ``shape``, checking every detection before painting any.
    """
    thresholds = score_thresholds or {}
    checked = []
    for k, det in enumerate(detections):
        if not isinstance(det, Detection):
            raise MapInputError(f"detections[{k}] is a {type(det).__name__}, not a Detection")
        cls = classes.index(det.class_name)
        mask = check_image_mask(det.mask, shape, f"detections[{k}].mask ({det.class_name!r})")
        if passes_threshold(det, thresholds, default=-np.inf) and mask.any():
            checked.append((det.score, cls, mask))
    labels = np.full(shape, classes.background_index, dtype=np.int64)
    objects = np.zeros(shape, dtype=bool)
    for _, cls, mask in sorted(checked, key=lambda item: item[0]):
        labels[mask] = cls
    objects[:] = labels != classes.background_index
    return DetectionLabels(labels=labels, objects=objects, n_used=len(checked))
