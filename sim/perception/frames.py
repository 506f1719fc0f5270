"""What the simulated perception knows about a frame: the ground-truth instance segmentation of
the image (through the sim backend's ``frame_for`` port, so detectors keep the image-only
protocol), pixel counts per body, and per-body view geometry computed on demand.

One :class:`FrameAnalyzer` is shared by a simulated detector and scorer; it keeps the analysis of
the last few frames, so scoring a frame that was just run through the detector costs little.
"""

from __future__ import annotations

import zlib
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from helios.perception.errors import ImageInputError, PerceptionError
from sim.camera import decode_body_ids
from sim.perception.config import SimPerceptionConfig
from sim.perception.geometry import BodyShape, BodyView, body_shape, view_of
from sim.world import FURNITURE, OBJECT


@dataclass(frozen=True)
class BodyRecord:
    body_id: int
    name: str
    category: str
    kind: str                  # object | furniture
    key: int                   # stable hash of the name (for per-object random draws)
    shape: BodyShape
    room: str | None           # room kind for furniture


@dataclass
class FrameAnalysis:
    """One frame: observation, decoded body ids, pixel counts, lazily computed views and masks."""

    obs: object
    ids: np.ndarray                          # (H, W) int32 body id per pixel, -1 background
    pixels: dict[int, int]                   # body id -> visible pixels (objects and furniture only)
    cam_pos: tuple[float, float, float]
    analyzer: "FrameAnalyzer"
    _views: dict[int, BodyView] = field(default_factory=dict)
    _masks: dict[int, tuple[np.ndarray, tuple[int, int, int, int]]] = field(default_factory=dict)
    _room_weights: dict[str, float] | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.ids.shape

    @property
    def frame_id(self) -> int:
        return int(self.obs.frame_id)

    def record(self, body_id: int) -> BodyRecord:
        return self.analyzer.record(body_id)

    def view(self, body_id: int) -> BodyView:
        v = self._views.get(body_id)
        if v is None:
            rec = self.record(body_id)
            cfg = self.analyzer.config
            v = view_of(rec.shape, self.analyzer.pose(body_id), self.cam_pos, cfg.azimuth_bins,
                        cfg.elevation_edges_deg, cfg.distance_edges)
            self._views[body_id] = v
        return v

    def mask(self, body_id: int) -> tuple[np.ndarray, tuple[int, int, int, int]]:
        """(full-size bool mask, bbox (v0, v1, u0, u1) exclusive ends) of a body's visible pixels."""
        m = self._masks.get(body_id)
        if m is None:
            full = self.ids == body_id
            rows = np.flatnonzero(full.any(axis=1))
            cols = np.flatnonzero(full.any(axis=0))
            bbox = (int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1) if rows.size else (0, 0, 0, 0)
            m = (full, bbox)
            self._masks[body_id] = m
        return m

    def expected_pixels(self, body_id: int) -> float:
        v = self.view(body_id)
        intr = self.obs.intrinsics
        return v.expected_area * intr.fx * intr.fy / max(v.distance, 0.05) ** 2

    def category_pixels(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for b, n in self.pixels.items():
            c = self.record(b).category
            out[c] = out.get(c, 0) + n
        return out


class FrameAnalyzer:
    """Looks up frames of a simulated backend and caches per-body data (shapes, static poses)."""

    def __init__(self, backend, config: SimPerceptionConfig = SimPerceptionConfig(), keep: int = 4):
        self.backend = backend
        self.world = backend.world
        self.config = config
        self._keep = keep
        self._records: dict[int, BodyRecord | None] = {}
        self._static_poses: dict[int, np.ndarray] = {}
        self._cache: OrderedDict[int, FrameAnalysis] = OrderedDict()
        self._lut = np.zeros(0, dtype=bool)   # body id -> "is an object or furniture"

    # ------------------------------------------------------------------ bodies
    def record(self, body_id: int) -> BodyRecord:
        rec = self._records.get(body_id)
        if rec is None:
            rec = self._make_record(body_id)
        if rec is None:
            raise KeyError(f"body {body_id} is not an object or a piece of furniture")
        return rec

    def _make_record(self, body_id: int) -> BodyRecord | None:
        info = self.world.bodies.get(body_id)
        if info is None or info.kind not in (OBJECT, FURNITURE):
            self._records[body_id] = None
            return None
        shape = body_shape(self.world.client.getCollisionShapeData(body_id, -1))
        rec = BodyRecord(body_id, info.name, info.category, info.kind, zlib.crc32(info.name.encode()), shape,
                         info.extra.get("room") if info.kind == FURNITURE else None)
        self._records[body_id] = rec
        return rec

    def pose(self, body_id: int):
        """Body pose as nested lists (furniture is static: cached)."""
        T = self._static_poses.get(body_id)
        if T is not None:
            return T
        T = self.world.pose(body_id).tolist()
        if self.world.bodies[body_id].kind == FURNITURE:
            self._static_poses[body_id] = T
        return T

    def _relevant_lut(self, n: int) -> np.ndarray:
        if self._lut.size < n or len(self._records) < len(self.world.bodies):
            size = max(n, max(self.world.bodies) + 1 if self.world.bodies else 0)
            lut = np.zeros(size, dtype=bool)
            for b, info in self.world.bodies.items():
                if info.kind in (OBJECT, FURNITURE):
                    lut[b] = True
                    if b not in self._records:
                        self._make_record(b)
            self._lut = lut
        return self._lut

    # ------------------------------------------------------------------ frames
    def analyse(self, rgb: np.ndarray) -> FrameAnalysis:
        """The analysis of a frame this backend captured (``rgb`` must be the observation's array)."""
        try:
            obs, seg = self.backend.frame_for(rgb)
        except KeyError:
            raise PerceptionError("this image is not one of the recent frames of the simulated robot the perception "
                                  "was built on; pass the Observation's own rgb array (not a copy) soon after "
                                  "capturing it") from None
        hit = self._cache.get(obs.frame_id)
        if hit is not None and hit.obs is obs:
            self._cache.move_to_end(obs.frame_id)
            return hit
        if seg.shape != rgb.shape[:2]:
            raise ImageInputError(f"segmentation {seg.shape} and rgb {rgb.shape[:2]} sizes differ")
        ids = decode_body_ids(seg)
        counts = np.bincount(ids.ravel() + 1)
        lut = self._relevant_lut(counts.size - 1)
        present = np.flatnonzero(counts[1:]) if counts.size > 1 else np.zeros(0, dtype=np.int64)
        present = present[present < lut.size]
        present = present[lut[present]]
        pixels = {int(b): int(counts[b + 1]) for b in present}
        T = obs.T_world_cam
        analysis = FrameAnalysis(obs, ids, pixels, (float(T[0, 3]), float(T[1, 3]), float(T[2, 3])), self)
        self._cache[obs.frame_id] = analysis
        while len(self._cache) > self._keep:
            self._cache.popitem(last=False)
        return analysis
