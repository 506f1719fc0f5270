"""The simulated image-text scorer (BLIP-2 ITC in VLFM / HELIOS): one value in [0, 1] per prompt
"Seems like there is a (object) ahead" per frame.

score = base
      + evidence_gain x (1 - exp(-(f_c + lookalike_gain x sum_k w_k f_k) / saturation_c))
      + room_gain x sum_rooms (share of the view in the room) x prior(category, room kind)
      + N(0, noise)
clipped to [0, 1], where f_c is the fraction of the image showing instances of the prompt's
category and f_k that of its look-alikes (confusion weights w_k). The room the camera looks into
comes from the depth image (world points seen, assigned to the home's rooms) when the rooms are
given, else from the room tags of the visible furniture. Room priors come from the home generator
(``sim.scenes.layout.ROOM_FURNITURE``, ``TABLE_CHAIRS``): a kitchen always has a counter (prior 1),
a kitchen sometimes has a cabinet (0.65), a bed is never in a kitchen (0). Small objects are placed on any
surface in any room, so they get no room prior.

Ground-truth mode (:class:`GroundTruthScorer`): 1 - exp(-f_c / saturation_c), no priors, no noise.
"""

from __future__ import annotations

import math
import zlib
from typing import Sequence

import numpy as np

from helios.perception.errors import UnknownCategoryError
from helios.perception.inputs import check_rgb
from helios.perception.prompts import check_prompts, parse_value_prompt
from sim.perception.config import SimPerceptionConfig
from sim.perception.confusion import ConfusionTable, category_group
from sim.perception.frames import FrameAnalysis, FrameAnalyzer
from sim.perception.geometry import normal
from sim.scenes.catalog import ALL_CATEGORIES
from sim.scenes.layout import OPTIONAL_PROBABILITY, ROOM_FURNITURE, TABLE_CHAIRS

_NOISE = 201
_CAT_KEY = {c: zlib.crc32(c.encode()) for c in ALL_CATEGORIES}


def room_prior(category: str, room_kind: str) -> float:
    """How typical ``category`` is for a room kind, in [0, 1] (from the home generator's rules;
    chairs also come with the room's tables, ``TABLE_CHAIRS``)."""
    entries = ROOM_FURNITURE.get(room_kind, [])
    prior = 0.0
    for i, (c, _p, _n) in enumerate(entries):
        if c == category:
            prior = 1.0 if i == 0 else OPTIONAL_PROBABILITY
            break
    if category == "chair":
        lo, hi = TABLE_CHAIRS.get(room_kind, (0, 0))
        if hi > 0:
            prior = max(prior, room_prior("table", room_kind) * (1.0 if lo > 0 else 0.5))
    return prior


def parse_prompts(prompts: Sequence[str]) -> list[str]:
    """The catalogue category of each value prompt; one clear error for the first bad one."""
    cats = []
    for i, p in enumerate(check_prompts(prompts)):
        c = parse_value_prompt(p)
        if c not in _CAT_KEY:
            raise UnknownCategoryError(f"prompts[{i}] {p!r} names unknown category {c!r}; valid: "
                                       f"{', '.join(ALL_CATEGORIES)}")
        cats.append(c)
    return cats


class _ScorerBase:
    def __init__(self, backend, config: SimPerceptionConfig, analyzer: FrameAnalyzer | None, rooms=None):
        self.config = config
        self.analyzer = analyzer or FrameAnalyzer(backend, config)
        # rooms: objects with .kind and x0, y0, x1, y1 (sim.scenes.layout.Room)
        self.rooms = [(r.kind, float(r.x0), float(r.y0), float(r.x1), float(r.y1)) for r in (rooms or [])]

    def _saturation(self, category: str) -> float:
        cfg = self.config
        return cfg.scorer_saturation_object if category_group(category) == "object" else cfg.scorer_saturation_receptacle

    def evidence(self, frame: FrameAnalysis, category: str, lookalikes: dict[str, float] | None = None) -> float:
        """1 - exp(-(visible fraction of the category (+ weighted look-alikes)) / saturation)."""
        h, w = frame.shape
        pix = frame.category_pixels()
        f = pix.get(category, 0) / (h * w)
        if lookalikes:
            f += self.config.scorer_lookalike_gain * sum(wt * pix.get(o, 0) for o, wt in lookalikes.items()) / (h * w)
        return 1.0 - math.exp(-f / self._saturation(category))

    def room_weights(self, frame: FrameAnalysis) -> dict[str, float]:
        """Share of the view falling in each room kind (sums to 1, or empty when unknown)."""
        if frame._room_weights is not None:
            return frame._room_weights
        weights: dict[str, float] = {}
        if self.rooms:
            obs = frame.obs
            depth = obs.depth[::12, ::12]
            v, u = np.nonzero(depth > 0)
            if v.size:
                z = depth[v, u].astype(np.float64)
                intr = obs.intrinsics
                x = (u * 12 - intr.cx) / intr.fx * z
                y = (v * 12 - intr.cy) / intr.fy * z
                T = obs.T_world_cam
                wx = T[0, 0] * x + T[0, 1] * y + T[0, 2] * z + T[0, 3]
                wy = T[1, 0] * x + T[1, 1] * y + T[1, 2] * z + T[1, 3]
                total = 0
                for kind, x0, y0, x1, y1 in self.rooms:
                    n = int(np.count_nonzero((wx >= x0 - 0.1) & (wx <= x1 + 0.1) & (wy >= y0 - 0.1) & (wy <= y1 + 0.1)))
                    if n:
                        weights[kind] = weights.get(kind, 0) + n
                        total += n
                weights = {k: n / total for k, n in weights.items()} if total else {}
        else:
            total = 0
            for b, n in frame.pixels.items():
                room = frame.record(b).room
                if room:
                    weights[room] = weights.get(room, 0) + n
                    total += n
            weights = {k: n / total for k, n in weights.items()} if total else {}
        frame._room_weights = weights
        return weights


class SimImageTextScorer(_ScorerBase):
    """Noisy simulated image-text scorer (see the module docstring)."""

    def __init__(self, backend, seed: int = 0, config: SimPerceptionConfig = SimPerceptionConfig(),
                 analyzer: FrameAnalyzer | None = None, rooms=None):
        super().__init__(backend, config, analyzer, rooms)
        self.seed = int(seed)
        self.confusion = ConfusionTable(config.lookalike_weight_extra)

    def __call__(self, rgb: np.ndarray, prompts: Sequence[str]) -> np.ndarray:
        cats = parse_prompts(prompts)
        check_rgb(rgb)
        frame = self.analyzer.analyse(rgb)
        return self.score(frame, cats)

    def score(self, frame: FrameAnalysis, categories: Sequence[str]) -> np.ndarray:
        cfg = self.config
        rooms = self.room_weights(frame) if cfg.scorer_room_gain > 0 else {}
        out = np.empty(len(categories), dtype=np.float64)
        for i, c in enumerate(categories):
            ev = self.evidence(frame, c, self.confusion.weights(c))
            prior = sum(share * room_prior(c, kind) for kind, share in rooms.items())
            noise = cfg.scorer_noise * normal(self.seed, frame.frame_id, _CAT_KEY[c], _NOISE)
            out[i] = cfg.scorer_base + cfg.scorer_evidence_gain * ev + cfg.scorer_room_gain * prior + noise
        return np.clip(out, 0.0, 1.0)


class GroundTruthScorer(_ScorerBase):
    """Perfect scorer: the saturating visible fraction of the prompt's category, nothing else."""

    def __init__(self, backend, config: SimPerceptionConfig = SimPerceptionConfig(),
                 analyzer: FrameAnalyzer | None = None, rooms=None):
        super().__init__(backend, config, analyzer, rooms)

    def __call__(self, rgb: np.ndarray, prompts: Sequence[str]) -> np.ndarray:
        cats = parse_prompts(prompts)
        check_rgb(rgb)
        frame = self.analyzer.analyse(rgb)
        return np.array([self.evidence(frame, c) for c in cats], dtype=np.float64)
