"""Layered semantic value map (VLFM's BLIP-2 value map with one layer per search target).

Each frame brings one image-text score per layer (e.g. "Seems like there is a table ahead").
The score is spread over the cells the frame saw, weighted by a confidence that is 1 on the
optical axis and ``min_confidence`` at the edge of the field of view:
``c = c_min + (1 - c_min) * cos^2(pi/2 * min(|theta| / (fov/2), 1))``. Cells beyond the depth
return in their bearing are not seen and keep their values. Fusion per cell follows VLFM:
a new confidence below ``decision_threshold`` and below the stored one is dropped; then
``v <- (c v + c' v') / (c + c')`` and ``c <- (c^2 + c'^2) / (c + c')`` (or max-confidence
replacement). All layers share one confidence grid because every frame sees the same cone.
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from helios.config import FrontierConfig, ValueMapConfig
from helios.maps.frontiers import Frontier
from helios.maps.grid import GridGeometry
from helios.maps.ground_view import GroundView
from helios.maps.inputs import MapInputError


class ValueMap:
    """``values[layer]`` (float32 grids) and the shared ``confidence`` grid."""

    def __init__(self, layers: Sequence[str], geometry: GridGeometry, cfg: ValueMapConfig):
        layers = tuple(layers)
        if len(set(layers)) != len(layers) or any(not isinstance(n, str) or not n for n in layers):
            raise MapInputError(f"value-map layer names must be unique non-empty strings, got {layers!r}")
        self.layers = layers
        self.geometry = geometry
        self.cfg = cfg
        self.values = np.zeros((len(layers), *geometry.shape), dtype=np.float32)
        self.confidence = np.zeros(geometry.shape, dtype=np.float32)

    def layer(self, name: str) -> np.ndarray:
        return self.values[self._index(name)]

    def _index(self, name: str) -> int:
        try:
            return self.layers.index(name)
        except ValueError:
            raise MapInputError(f"unknown value-map layer {name!r}; layers are {', '.join(map(repr, self.layers))}") from None

    def scores_vector(self, scores: Mapping[str, float] | Sequence[float]) -> np.ndarray:
        """One finite score per layer, from a {layer: score} mapping or a sequence in layer order."""
        if isinstance(scores, Mapping):
            missing = [n for n in self.layers if n not in scores]
            extra = [n for n in scores if n not in self.layers]
            if missing or extra:
                raise MapInputError(
                    f"value-map scores must name exactly the layers {list(self.layers)}; "
                    f"missing {missing}, unknown {extra}")
            vec = np.array([scores[n] for n in self.layers], dtype=np.float64)
        else:
            vec = np.asarray(scores, dtype=np.float64).reshape(-1)
            if vec.size != len(self.layers):
                raise MapInputError(f"got {vec.size} value-map scores for {len(self.layers)} layers {list(self.layers)}")
        if not np.all(np.isfinite(vec)):
            raise MapInputError(f"value-map scores must be finite, got {vec.tolist()}")
        return vec.astype(np.float32)

    def cone_confidence(self, view: GroundView) -> np.ndarray:
        """VLFM confidence of every window cell for this frame (0 where not seen)."""
        theta = np.minimum(view.axis_offset / np.float32(max(view.half_fov, 1e-6)), np.float32(1.0))
        c_min = np.float32(self.cfg.min_confidence)
        conf = c_min + (np.float32(1.0) - c_min) * np.cos(theta * np.float32(math.pi / 2)) ** 2
        return np.where(view.visible, conf, np.float32(0.0)).astype(np.float32)

    def fuse(self, view: GroundView, scores: Mapping[str, float] | Sequence[float]) -> None:
        """Fuse one frame's per-layer scores over the cells it saw."""
        vec = self.scores_vector(scores)
        if view.is_empty:
            return
        r0, r1, c0, c1 = view.window
        c_new = self.cone_confidence(view)
        c_old = self.confidence[r0:r1, c0:c1]
        v_old = self.values[:, r0:r1, c0:c1]
        c_new[(c_new < self.cfg.decision_threshold) & (c_new < c_old)] = 0.0
        touched = c_new > 0
        if not touched.any():
            return
        if self.cfg.fusion == "max_confidence":
            better = c_new > c_old
            v_old[:, better] = vec[:, None]
            c_old[better] = c_new[better]
            return
        co, cn = c_old[touched], c_new[touched]
        denom = co + cn
        w_old, w_new = co / denom, cn / denom
        v_old[:, touched] = v_old[:, touched] * w_old + vec[:, None] * w_new
        c_old[touched] = co * w_old + cn * w_new

    def value_near(self, xy: np.ndarray, radius: float) -> np.ndarray:
        """Median value per layer of the seen cells within ``radius`` of world point ``xy``.

        (VLFM reads frontier values the same way.) NaN for a layer when no cell there was seen.
        """
        geo = self.geometry
        r = int(math.ceil(radius / geo.cell_size))
        row, col = (int(v) for v in geo.world_to_cell(np.asarray(xy, dtype=float)))
        r0, r1 = max(row - r, 0), min(row + r + 1, geo.size)
        c0, c1 = max(col - r, 0), min(col + r + 1, geo.size)
        out = np.full(len(self.layers), np.nan)
        if r1 <= r0 or c1 <= c0:
            return out
        centres = geo.cell_to_world(*np.mgrid[r0:r1, c0:c1])
        disk = np.hypot(centres[..., 0] - xy[0], centres[..., 1] - xy[1]) <= radius
        seen = disk & (self.confidence[r0:r1, c0:c1] > 0)
        if seen.any():
            out[:] = np.median(self.values[:, r0:r1, c0:c1][:, seen], axis=1)
        return out

    def frontier_values(self, frontiers: Sequence[Frontier], cfg: FrontierConfig) -> list[dict[str, float]]:
        """{layer: value} near each frontier centre (radius ``cfg.value_radius``)."""
        return [dict(zip(self.layers, self.value_near(f.xy, cfg.value_radius).tolist())) for f in frontiers]

    def memory_bytes(self) -> int:
        return self.values.nbytes + self.confidence.nbytes
