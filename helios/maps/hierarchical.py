"""HELIOS's hierarchical task-driven map: occupancy, value maps and object Gaussians in one place.

One ``update(observation, detections, scores)`` call per frame feeds all three layers:

- the occupancy grid (navigation, frontiers) from ground-projected depth,
- one value-map layer per search target from the frame's image-text scores,
- the Gaussian object layer from depth and the detections of the task's classes.

The caller passes detections of this episode's classes only (unknown names are an error) and may
configure per-class score thresholds; everything else is in :class:`helios.config.HeliosConfig`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
import torch

from helios.config import HeliosConfig
from helios.schema import ConfigError
from helios.maps.classes import ClassSet
from helios.maps.frontiers import Frontier, find_frontiers
from helios.maps.gaussians import GaussianMap, GaussianUpdate
from helios.maps.grid import GridGeometry
from helios.maps.inputs import MapInputError
from helios.maps.instances import Instance
from helios.maps.labels import label_detections
from helios.maps.occupancy import OccupancyGrid
from helios.maps.value_map import ValueMap
from helios.perception.detection import Detection
from robots.hal import Observation


def resolve_device(name: str) -> torch.device:
    """``cpu``, ``cuda`` (must be available) or ``auto`` (CUDA when available)."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ConfigError("device 'cuda' was configured but torch sees no CUDA device; use 'cpu' or 'auto'")
    return torch.device(name)


@dataclass(frozen=True)
class MapUpdate:
    """Summary of one ``HierarchicalMap.update`` call."""

    frame: int
    detections_used: int
    objects: GaussianUpdate
    seconds: dict[str, float] = field(default_factory=dict)
    """Wall time per layer: ``occupancy``, ``value_map``, ``gaussians``, ``total``."""


class HierarchicalMap:
    """The three map layers of HELIOS, updated together.

    Args:
        config: method configuration.
        task_classes: the episode's classes, e.g. (object, start receptacle, goal receptacle);
            duplicates are merged and ``config.background_class`` is appended.
        value_layers: one value-map layer per search target (e.g. the two receptacle classes).
        score_thresholds: optional minimum detection score per class name.
    """

    def __init__(self, config: HeliosConfig, task_classes: Sequence[str], value_layers: Sequence[str] = (),
                 score_thresholds: Mapping[str, float] | None = None):
        self.config = config
        self.classes = ClassSet.from_task(task_classes, config.background_class)
        self.score_thresholds = dict(score_thresholds or {})
        for name in self.score_thresholds:
            self.classes.index(name)
        self.occupancy = OccupancyGrid(config.occupancy)
        self.values = ValueMap(value_layers, self.occupancy.geometry, config.value_map)
        self.objects = GaussianMap(self.classes, config.gaussians, config.instances, config.scoring,
                                   self.occupancy.geometry, resolve_device(config.device))
        self.frame = 0

    @property
    def geometry(self) -> GridGeometry:
        """World <-> cell conversion shared by the occupancy grid and the value maps."""
        return self.occupancy.geometry

    def update(self, observation: Observation, detections: Sequence[Detection] = (),
               scores: Mapping[str, float] | Sequence[float] | None = None) -> MapUpdate:
        """Integrate one frame into every layer (``scores`` None skips the value maps)."""
        if not isinstance(observation, Observation):
            raise MapInputError(f"observation must be a robots.hal.Observation, got {type(observation).__name__}")
        t0 = time.perf_counter()
        depth = observation.depth
        labels = label_detections(detections, self.classes, depth.shape, self.score_thresholds)
        score_vec = None if scores is None else self.values.scores_vector(scores)
        seconds: dict[str, float] = {}

        t = time.perf_counter()
        view = self.occupancy.integrate_depth(depth, observation.intrinsics, observation.T_world_cam)
        seconds["occupancy"] = time.perf_counter() - t
        t = time.perf_counter()
        if score_vec is not None and self.values.layers:
            self.values.fuse(view, score_vec)
        seconds["value_map"] = time.perf_counter() - t
        t = time.perf_counter()
        objects = self.objects.update(depth, observation.intrinsics, observation.T_world_cam,
                                      labels.labels, labels.objects, observation.rgb)
        seconds["gaussians"] = time.perf_counter() - t
        seconds["total"] = time.perf_counter() - t0
        self.frame += 1
        return MapUpdate(frame=self.frame, detections_used=labels.n_used, objects=objects, seconds=seconds)

    def frontiers(self) -> list[Frontier]:
        """Frontiers (longest first) with the value of every value-map layer near each centre."""
        found = find_frontiers(self.occupancy, self.config.frontiers)
        values = self.values.frontier_values(found, self.config.frontiers)
        return [Frontier(f.x, f.y, f.size, f.cells, v) for f, v in zip(found, values)]

    def instances(self) -> list[Instance]:
        return self.objects.instances()

    def memory_bytes(self) -> dict[str, int]:
        return {"occupancy": self.occupancy.memory_bytes(), "value_map": self.values.memory_bytes(),
                "gaussians": self.objects.memory_bytes()}

    def world_to_cell(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.geometry.world_to_cell(xy)

    def cell_to_world(self, rows, cols) -> np.ndarray:
        return self.geometry.cell_to_world(rows, cols)
