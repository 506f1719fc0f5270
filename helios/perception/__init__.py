"""Perception contracts: detectors and image-text scorers the map consumes (``detection``)."""

from helios.perception.detection import Detection, Detector, ImageTextScorer

__all__ = ["Detection", "Detector", "ImageTextScorer"]
