"""Real open-vocabulary models behind the perception protocols, for the real Spot: OWLv2 as the
detector and CLIP as the image-text scorer, through Hugging Face ``transformers``.

``transformers`` is an optional extra (``pip install 'helios-testbed[perception]'``) imported
only when an adapter is built. Weights are read from local directories (the ``save_pretrained``
layout) given in :class:`helios.perception.config.ModelConfig`; nothing is downloaded at run
time, and a missing or incomplete directory is one clear :class:`ModelWeightsMissingError`.

* :class:`Owlv2Detector`: one text query per class ("a photo of a {class}"); boxes above
  ``detector_min_score`` become masks: the box's pixels whose depth lies within
  ``depth_mask_tolerance`` of the median depth of the box's central half (OWLv2 has no masks;
  the map needs the object's pixels, not the wall behind it).
* :class:`ClipImageTextScorer`: cosine similarity of CLIP's image and text embeddings, one value
  per prompt (the role BLIP-2's ITC score plays in VLFM/HELIOS).
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from helios.perception.config import ModelConfig
from helios.perception.detection import Detection
from helios.perception.errors import ModelWeightsMissingError, PerceptionDependencyError
from helios.perception.inputs import check_class_names, check_rgb, check_rgb_depth
from helios.perception.prompts import check_prompts

_WEIGHT_FILES = ("model.safetensors", "model.safetensors.index.json", "pytorch_model.bin", "pytorch_model.bin.index.json")


def _transformers():
    try:
        import transformers
    except ImportError as exc:
        raise PerceptionDependencyError(
            "the real-model perception adapters need the optional dependency 'transformers' "
            f"({exc}); install it with: pip install 'helios-testbed[perception]'") from None
    return transformers


def check_weights_dir(path: str | Path, what: str, setting: str, example: str) -> Path:
    """The local checkpoint directory, or ModelWeightsMissingError saying what is missing and how to fix it."""
    hint = (f"set {setting} to a local directory holding a save_pretrained() copy of {example} "
            f"(config.json, model weights, processor files); nothing is downloaded at run time")
    if not str(path).strip():
        raise ModelWeightsMissingError(f"no {what} weights configured: {hint}")
    p = Path(path).expanduser()
    if not p.is_dir():
        raise ModelWeightsMissingError(f"{what} weights directory {str(p)!r} does not exist: {hint}")
    if not (p / "config.json").is_file():
        raise ModelWeightsMissingError(f"{what} weights directory {str(p)!r} has no config.json: {hint}")
    if not any((p / f).is_file() for f in _WEIGHT_FILES):
        raise ModelWeightsMissingError(f"{what} weights directory {str(p)!r} has no weights "
                                       f"({' or '.join(_WEIGHT_FILES)}): {hint}")
    return p


def _device(name: str) -> str:
    import torch

    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    return name


class Owlv2Detector:
    """OWLv2 open-vocabulary detection; boxes turned into depth-consistent masks."""

    def __init__(self, weights_dir: str | Path, device: str = "cpu", min_score: float = 0.1,
                 depth_tolerance: float = 0.25, query_template: str = "a photo of a {}"):
        tf = _transformers()
        path = check_weights_dir(weights_dir, "OWLv2 detector", "perception.models.detector_weights",
                                 "google/owlv2-base-patch16-ensemble")
        self.device = _device(device)
        self.processor = tf.Owlv2Processor.from_pretrained(path, local_files_only=True)
        self.model = tf.Owlv2ForObjectDetection.from_pretrained(path, local_files_only=True).eval().to(self.device)
        self.min_score = float(min_score)
        self.depth_tolerance = float(depth_tolerance)
        self.query_template = query_template
        self._max_tokens = int(getattr(self.model.config.text_config, "max_position_embeddings", 16))

    def __call__(self, rgb: np.ndarray, depth: np.ndarray, class_names: Sequence[str]) -> list[Detection]:
        import torch

        names = check_class_names(class_names)
        h, w = check_rgb_depth(rgb, depth)
        queries = [self.query_template.format(n) for n in names]
        inputs = self.processor(text=[queries], images=rgb, return_tensors="pt", padding="max_length",
                                truncation=True, max_length=self._max_tokens)
        with torch.no_grad():
            outputs = self.model(**{k: v.to(self.device) for k, v in inputs.items()})
        side = max(h, w)   # OWLv2 pads the image to a square (bottom/right) before resizing
        result = self.processor.post_process_grounded_object_detection(
            outputs=outputs, threshold=self.min_score, target_sizes=[(side, side)])[0]
        out = []
        for box, score, label in zip(result["boxes"].cpu().numpy(), result["scores"].cpu().numpy(),
                                     result["labels"].cpu().numpy()):
            mask = box_mask(box, depth, self.depth_tolerance)
            if mask is not None:
                out.append(Detection(mask, names[int(label)], float(score)))
        return out


def box_mask(box: Sequence[float], depth: np.ndarray, tolerance: float) -> np.ndarray | None:
    """Pixels of an (x0, y0, x1, y1) box, kept where depth is near the box centre's median depth."""
    h, w = depth.shape
    x0, y0, x1, y1 = (float(v) for v in box)
    u0, v0 = max(0, int(np.floor(x0))), max(0, int(np.floor(y0)))
    u1, v1 = min(w, int(np.ceil(x1))), min(h, int(np.ceil(y1)))
    if u1 <= u0 or v1 <= v0:
        return None
    mask = np.zeros((h, w), dtype=bool)
    mask[v0:v1, u0:u1] = True
    if tolerance > 0:
        bw, bh = u1 - u0, v1 - v0
        centre = depth[v0 + bh // 4:v1 - bh // 4 or v1, u0 + bw // 4:u1 - bw // 4 or u1]
        valid = centre[centre > 0]
        if valid.size:
            med = float(np.median(valid))
            box_depth = depth[v0:v1, u0:u1]
            near = (box_depth > 0) & (np.abs(box_depth - med) <= tolerance)
            if near.sum() >= 0.1 * near.size:
                mask[v0:v1, u0:u1] = near
    return mask


class ClipImageTextScorer:
    """CLIP image-text cosine similarity, one value per prompt."""

    def __init__(self, weights_dir: str | Path, device: str = "cpu"):
        tf = _transformers()
        path = check_weights_dir(weights_dir, "CLIP scorer", "perception.models.scorer_weights",
                                 "openai/clip-vit-base-patch32")
        self.device = _device(device)
        self.processor = tf.CLIPProcessor.from_pretrained(path, local_files_only=True)
        self.model = tf.CLIPModel.from_pretrained(path, local_files_only=True).eval().to(self.device)
        self._max_tokens = int(getattr(self.model.config.text_config, "max_position_embeddings", 77))

    def __call__(self, rgb: np.ndarray, prompts: Sequence[str]) -> np.ndarray:
        import torch

        items = check_prompts(prompts)
        check_rgb(rgb)
        inputs = self.processor(text=items, images=rgb, return_tensors="pt", padding=True, truncation=True,
                                max_length=self._max_tokens)
        with torch.no_grad():
            out = self.model(**{k: v.to(self.device) for k, v in inputs.items()})
        img = torch.nn.functional.normalize(out.image_embeds, dim=-1)
        txt = torch.nn.functional.normalize(out.text_embeds, dim=-1)
        return (img @ txt.T)[0].cpu().numpy().astype(np.float64)


def load_real_perception(models: ModelConfig = ModelConfig()) -> tuple[Owlv2Detector, ClipImageTextScorer]:
    """(detector, scorer) for the real robot from the configured local weights."""
    detector = Owlv2Detector(models.detector_weights, models.device, models.detector_min_score,
                             models.depth_mask_tolerance)
    return detector, ClipImageTextScorer(models.scorer_weights, models.device)
