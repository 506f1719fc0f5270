"""The simulated open-vocabulary detector, built on the renderer's instance segmentation.

It implements ``helios.perception.Detector``: ``detector(rgb, depth, class_names)`` returns
``Detection(mask, class_name, score)`` for instances labelled as one of ``class_names``. The frame
is found through the sim backend's ``frame_for`` port, so callers hand it images only.

Error model (all parameters in :class:`sim.perception.config.SimPerceptionConfig`):

* **Detection probability** of a visible instance = p_max x area factor x distance factor x
  occlusion factor x grazing factor (logistics in log pixel area, metres, visible fraction of the
  expected silhouette, and silhouette foreshortening). Drawn per frame.
* **View-dependent, persistent label errors.** Around every object the viewpoint is binned
  (azimuth in the object's frame, elevation, distance). A hash of (episode seed, object, bin)
  decides whether the bin is a *bad view* and ranks the object's look-alikes (confusion table);
  from a bad view the object is labelled as the first queried look-alike, every time. Another
  bin is usually a good view and gives the true label. Rare per-frame confusions come on top.
  An object whose category is not queried is reported only where it looks like a queried one.
* **False positives**: parts of furniture detected as a queried object class, distractor
  objects detected as one, and parts of furniture detected as a queried *receptacle* class it is
  not (a chair on a sofa's armrest, a counter on a cabinet top, a table on the end of a bed),
  each decided per (body, bin[, class]) so they too persist across frames.
* **Scores** are logit-normal with class-conditional means (correct > wrong label > false
  positive), lowered for poor views, so the per-role thresholds od_* matter. Furniture has its
  own means and spread: true and false receptacle detections overlap more than small objects'.
* **Masks** are the instance's pixels, eroded or dilated by a random 0-2 px, with boundary pixels
  flipped and a 1 px shift.

Every random draw is a hash of (seed, ...) or a generator seeded from one: the same seed and the
same frames give the same detections.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from helios.perception.detection import Detection
from helios.perception.inputs import check_class_names, check_rgb_depth
from sim.perception.config import SimPerceptionConfig
from sim.perception.confusion import ConfusionTable, category_group
from sim.perception.frames import FrameAnalysis, FrameAnalyzer
from sim.perception.geometry import BodyView, logistic, mix, normal, u01
from sim.scenes.catalog import ALL_CATEGORIES, OBJECT_CATEGORIES, RECEPTACLE_CATEGORIES
from sim.world import FURNITURE, OBJECT

# salts of the hashed draws
_DETECT, _BAD, _RANK, _BADTRUE, _FLIP, _FLIPPICK, _SCORE, _MASK, _PART, _PARTPOS, _DISTR, _DISTRPICK = range(101, 113)
_RPART, _RPARTDET = 113, 114
_CAT_KEY = {c: zlib.crc32(c.encode()) for c in ALL_CATEGORIES}
_OBJECT_SET = frozenset(OBJECT_CATEGORIES)
_RECEPTACLE_SET = frozenset(RECEPTACLE_CATEGORIES)
_KERNEL = np.ones((3, 3), np.uint8)


def _bin_key(b: tuple[int, int, int]) -> int:
    return b[0] * 10_000 + b[1] * 100 + b[2]


@dataclass(frozen=True)
class _GroupScores:
    """Score and slip parameters of one group (small objects or furniture)."""

    correct: float
    wrong: float
    false_positive: float
    std: float
    transient: float


class SimDetector:
    """Noisy simulated open-vocabulary detector (see the module docstring)."""

    known_classes = ALL_CATEGORIES

    def __init__(self, backend, seed: int = 0, config: SimPerceptionConfig = SimPerceptionConfig(),
                 analyzer: FrameAnalyzer | None = None):
        unknown = sorted(set(config.category_difficulty) - set(ALL_CATEGORIES))
        if unknown:
            raise ValueError(f"category_difficulty names unknown categories {unknown}")
        self.config = config
        self.seed = int(seed)
        self.analyzer = analyzer or FrameAnalyzer(backend, config)
        self.confusion = ConfusionTable(config.lookalike_weight_extra)
        c = config
        self._groups = {
            OBJECT: _GroupScores(c.score_correct_logit, c.score_wrong_logit, c.score_false_positive_logit,
                                 c.score_logit_std, c.transient_confusion),
            FURNITURE: _GroupScores(c.score_correct_logit_receptacle, c.score_wrong_logit_receptacle,
                                    c.score_false_positive_logit_receptacle, c.score_logit_std_receptacle,
                                    c.transient_confusion_receptacle),
        }

    # ------------------------------------------------------------------ protocol
    def __call__(self, rgb: np.ndarray, depth: np.ndarray, class_names: Sequence[str]) -> list[Detection]:
        names = check_class_names(class_names, ALL_CATEGORIES)
        check_rgb_depth(rgb, depth)
        frame = self.analyzer.analyse(rgb)
        return self.detect(frame, frozenset(names))

    # ------------------------------------------------------------------ model pieces (public for tests/tools)
    def detection_probability(self, frame: FrameAnalysis, body_id: int) -> tuple[float, float]:
        """(probability of detecting this visible body in this frame, view quality in [0, 1])."""
        cfg = self.config
        rec = frame.record(body_id)
        n = frame.pixels.get(body_id, 0)
        if n < cfg.min_pixels:
            return 0.0, 0.0
        v = frame.view(body_id)
        h, w = frame.shape
        is_obj = rec.kind == OBJECT
        f_area = logistic((math.log(n / (h * w)) - math.log(cfg.area_half)) / cfg.area_slope)
        d_half = cfg.distance_half_object if is_obj else cfg.distance_half_receptacle
        f_dist = logistic((d_half - v.distance) / cfg.distance_width)
        visible = min(1.0, n / max(frame.expected_pixels(body_id), 1.0))
        v_half = cfg.visible_half if is_obj else cfg.visible_half_receptacle
        f_vis = logistic((visible - v_half) / cfg.visible_width)
        f_fore = logistic((v.foreshortening - cfg.foreshortening_half) / cfg.foreshortening_width)
        quality = f_area * f_dist * f_vis * f_fore
        p_max = cfg.p_detect_object if is_obj else cfg.p_detect_receptacle
        return p_max * quality, quality

    def bad_view_probability(self, category: str, view: BodyView) -> float:
        cfg = self.config
        base = cfg.bad_view_object if category_group(category) == "object" else cfg.bad_view_receptacle
        p = base * cfg.bad_view_distance_scale[view.bin[2]] * cfg.bad_view_elevation_scale[view.bin[1]]
        return min(0.95, p * cfg.category_difficulty.get(category, 1.0))

    def is_bad_view(self, frame: FrameAnalysis, body_id: int) -> bool:
        """Whether this frame sees the body from one of its bad viewpoint bins (persistent)."""
        rec = frame.record(body_id)
        v = frame.view(body_id)
        return u01(self.seed, rec.key, _bin_key(v.bin), _BAD) < self.bad_view_probability(rec.category, v)

    def ranked_lookalikes(self, body_key: int, category: str, view_bin: tuple[int, int, int]) -> list[str]:
        """The body's look-alikes in the order it resembles them from this viewpoint bin."""
        keys = []
        bk = _bin_key(view_bin)
        for other, weight in self.confusion.weights(category).items():
            u = max(u01(self.seed, body_key, bk, _CAT_KEY[other], _RANK), 1e-12)
            keys.append((u ** (1.0 / weight), other))
        return [c for _, c in sorted(keys, reverse=True)]

    def _score(self, mean_logit: float, quality: float, *keys: int, std: float | None = None) -> float:
        cfg = self.config
        mu = mean_logit + cfg.score_quality_gain * (quality - 1.0)
        return logistic(mu + (cfg.score_logit_std if std is None else std) * normal(self.seed, *keys, _SCORE))

    # ------------------------------------------------------------------ the detector
    def detect(self, frame: FrameAnalysis, queried: frozenset[str]) -> list[Detection]:
        cfg = self.config
        fid = frame.frame_id
        queried_objects = sorted(queried & _OBJECT_SET)
        queried_receptacles = sorted(queried & _RECEPTACLE_SET)
        out: list[Detection] = []
        for body_id in sorted(frame.pixels):
            rec = frame.record(body_id)
            c = rec.category
            relevant = self.confusion.could_be_labelled(c, queried)
            if not relevant and not queried_objects and not (rec.kind == FURNITURE and queried_receptacles):
                continue
            if frame.pixels[body_id] < cfg.min_pixels:
                continue
            p_det, quality = self.detection_probability(frame, body_id)
            view = frame.view(body_id)
            bk = _bin_key(view.bin)
            if relevant:
                label = score = None
                if u01(self.seed, fid, rec.key, _DETECT) < p_det:
                    label, mean = self._label(frame, body_id, rec, view, queried)
                    if label is not None:
                        score = self._score(mean, quality, fid, rec.key, std=self._groups[rec.kind].std)
                if label is not None and score >= cfg.min_score:
                    out.append(Detection(self._noisy_mask(frame, body_id, rec.key), label, score))
            elif rec.kind == OBJECT:   # a distractor: nothing queried looks like it
                if (u01(self.seed, rec.key, bk, _DISTR) < cfg.distractor_false_positive
                        and u01(self.seed, fid, rec.key, _DETECT) < p_det):
                    label = queried_objects[int(u01(self.seed, rec.key, bk, _DISTRPICK) * len(queried_objects))]
                    score = self._score(cfg.score_false_positive_logit, 1.0, fid, rec.key)
                    if score >= cfg.min_score:
                        out.append(Detection(self._noisy_mask(frame, body_id, rec.key), label, score))
            if rec.kind == FURNITURE and queried_objects:
                out.extend(self._part_false_positives(frame, body_id, rec, bk, queried_objects))
            if rec.kind == FURNITURE and queried_receptacles and cfg.receptacle_part_false_positive > 0:
                out.extend(self._receptacle_part_false_positives(frame, body_id, rec, bk, p_det, queried_receptacles))
        return out

    def _label(self, frame: FrameAnalysis, body_id: int, rec, view: BodyView,
               queried: frozenset[str]) -> tuple[str | None, float]:
        """(label, mean score logit) of a detected relevant instance; label None: not reported."""
        cfg = self.config
        g = self._groups[rec.kind]
        c = rec.category
        fid = frame.frame_id
        if self.is_bad_view(frame, body_id):
            for other in self.ranked_lookalikes(rec.key, c, view.bin):
                if other in queried:
                    return other, g.wrong
            if c in queried and u01(self.seed, rec.key, _bin_key(view.bin), _BADTRUE) < cfg.bad_view_true_label:
                return c, g.wrong
            return None, 0.0
        lookalikes = [o for o in self.confusion.weights(c) if o in queried]
        if lookalikes and u01(self.seed, fid, rec.key, _FLIP) < g.transient:
            pick = lookalikes[int(u01(self.seed, fid, rec.key, _FLIPPICK) * len(lookalikes))]
            return pick, g.wrong
        if c in queried:
            return c, g.correct
        return None, 0.0

    # ------------------------------------------------------------------ false positives on furniture parts
    def _part_false_positives(self, frame: FrameAnalysis, body_id: int, rec, bk: int,
                              queried_objects: list[str]) -> list[Detection]:
        """Per (furniture, viewpoint bin): maybe one part of it detected as a queried object class."""
        cfg = self.config
        if u01(self.seed, rec.key, bk, _PART) >= cfg.part_false_positive:
            return []
        cls = queried_objects[int(u01(self.seed, rec.key, bk, _PART, 3) * len(queried_objects))]
        blob = self._part_blob(frame, body_id, cfg.part_size, rec.key, bk, _PARTPOS)
        if blob is None:
            return []
        score = self._score(cfg.score_false_positive_logit, 1.0, frame.frame_id, rec.key, _PART)
        return [Detection(blob, cls, score)] if score >= cfg.min_score else []

    def _receptacle_part_false_positives(self, frame: FrameAnalysis, body_id: int, rec, bk: int, p_det: float,
                                         queried_receptacles: list[str]) -> list[Detection]:
        """Per (furniture, viewpoint bin): maybe one part of it that looks like another receptacle
        class, fixed whatever is queried (``phantom_receptacle``); reported when that class is queried."""
        cfg = self.config
        cls = self.phantom_receptacle(rec.key, rec.category, bk)
        if cls is None or cls not in queried_receptacles:
            return []
        fid = frame.frame_id
        if u01(self.seed, fid, rec.key, _RPARTDET) >= p_det:
            return []
        blob = self._part_blob(frame, body_id, cfg.receptacle_part_size, rec.key, bk, _RPART)
        if blob is None:
            return []
        g = self._groups[FURNITURE]
        score = self._score(g.false_positive, 1.0, fid, rec.key, _RPART, std=g.std)
        return [Detection(blob, cls, score)] if score >= cfg.min_score else []

    def phantom_receptacle(self, body_key: int, category: str, bk: int) -> str | None:
        """The receptacle class a part of this piece of furniture looks like from viewpoint bin
        ``bk`` (None: no such part there): with probability ``receptacle_part_false_positive`` a
        class other than its own, drawn in proportion to the confusion weight (look-alikes) or
        ``receptacle_part_unrelated`` (any other receptacle class)."""
        cfg = self.config
        if u01(self.seed, body_key, bk, _RPART) >= cfg.receptacle_part_false_positive:
            return None
        weights = self.confusion.weights(category)
        best, best_key = None, -1.0
        for other in RECEPTACLE_CATEGORIES:
            if other == category:
                continue
            w = weights.get(other, cfg.receptacle_part_unrelated)
            if w <= 0:
                continue
            key = max(u01(self.seed, body_key, bk, _CAT_KEY[other], _RPART), 1e-12) ** (1.0 / w)
            if key > best_key:
                best, best_key = other, key
        return best

    def _part_blob(self, frame: FrameAnalysis, body_id: int, size: float, *keys: int) -> np.ndarray | None:
        """A disc of ``size`` metres (at the depth seen there) of the body's visible pixels around a
        spot fixed by ``keys`` (a handle, a leg, a corner): the mask of a phantom detection."""
        cfg = self.config
        mask, (v0, v1, u0, u1) = frame.mask(body_id)
        if v1 - v0 < 3 or u1 - u0 < 3:
            return None
        fv = v0 + u01(self.seed, *keys, 1) * (v1 - v0)
        fu = u0 + u01(self.seed, *keys, 2) * (u1 - u0)
        vs, us = np.nonzero(mask[v0:v1, u0:u1])
        k = int(np.argmin((vs + v0 - fv) ** 2 + (us + u0 - fu) ** 2))
        pv, pu = int(vs[k] + v0), int(us[k] + u0)
        depth = float(frame.obs.depth[pv, pu]) or frame.view(body_id).distance
        r = max(2, int(round(frame.obs.intrinsics.fx * size / 2 / max(depth, 0.1))))
        h, w = mask.shape
        a0, a1, b0, b1 = max(0, pv - r), min(h, pv + r + 1), max(0, pu - r), min(w, pu + r + 1)
        yy, xx = np.ogrid[a0 - pv:a1 - pv, b0 - pu:b1 - pu]
        blob = np.zeros(mask.shape, dtype=bool)
        blob[a0:a1, b0:b1] = (yy * yy + xx * xx <= r * r) & mask[a0:a1, b0:b1]
        if int(blob.sum()) < cfg.min_pixels:
            return None
        return blob

    # ------------------------------------------------------------------ masks
    def _noisy_mask(self, frame: FrameAnalysis, body_id: int, key: int) -> np.ndarray:
        cfg = self.config
        mask, (v0, v1, u0, u1) = frame.mask(body_id)
        morph, shift = cfg.mask_morph_px, cfg.mask_shift_px
        if morph == 0 and shift == 0 and cfg.mask_jitter == 0:
            return mask.copy()
        rng = np.random.Generator(np.random.PCG64(mix(self.seed, frame.frame_id, key, _MASK)))
        h, w = mask.shape
        pad = morph + shift + 2
        a0, a1, b0, b1 = max(0, v0 - pad), min(h, v1 + pad), max(0, u0 - pad), min(w, u1 + pad)
        crop = mask[a0:a1, b0:b1].astype(np.uint8)
        k = int(rng.integers(-morph, morph + 1)) if morph else 0
        if k > 0:
            crop = cv2.dilate(crop, _KERNEL, iterations=k)
        elif k < 0:
            eroded = cv2.erode(crop, _KERNEL, iterations=-k)
            if eroded.any():
                crop = eroded
        if cfg.mask_jitter > 0:
            band = (cv2.dilate(crop, _KERNEL) != cv2.erode(crop, _KERNEL))
            n = int(band.sum())
            if n:
                flip = np.zeros(band.shape, dtype=bool)
                flip[band] = rng.random(n) < cfg.mask_jitter
                crop = crop ^ flip.astype(np.uint8)
        if shift:
            dv, du = (int(x) for x in rng.integers(-shift, shift + 1, size=2))
            crop = np.roll(crop, (dv, du), axis=(0, 1))
        out = np.zeros((h, w), dtype=bool)
        out[a0:a1, b0:b1] = crop.astype(bool)
        if not out.any():
            return mask.copy()
        return out


class GroundTruthDetector:
    """Ground-truth semantics: the exact mask of every visible instance of a queried class, score 1."""

    known_classes = ALL_CATEGORIES

    def __init__(self, backend, config: SimPerceptionConfig = SimPerceptionConfig(),
                 analyzer: FrameAnalyzer | None = None):
        self.config = config
        self.analyzer = analyzer or FrameAnalyzer(backend, config)

    def __call__(self, rgb: np.ndarray, depth: np.ndarray, class_names: Sequence[str]) -> list[Detection]:
        names = frozenset(check_class_names(class_names, ALL_CATEGORIES))
        check_rgb_depth(rgb, depth)
        frame = self.analyzer.analyse(rgb)
        out = []
        for body_id in sorted(frame.pixels):
            rec = frame.record(body_id)
            if rec.category in names and frame.pixels[body_id] >= self.config.gt_min_pixels:
                out.append(Detection(frame.mask(body_id)[0].copy(), rec.category, 1.0))
        return out
