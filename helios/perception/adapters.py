"""Real open-vocabulary models behind the perception protocols, for the real Spot: OWLv2 as the
detector and CLIP as the image-text scorer, through Hugging Face ``transformers``.

``transformers`` is an optional extra (``pip install -e '.[perception]'`` in the checkout) imported
only when an adapter is built. Weights are read from local directories (the ``save_pretrained``
layout) given in :class:`helios.perception.config.ModelConfig`; nothing is downloaded at run
time, and a missing or incomplete directory is one clear :class:`ModelWeightsMissingError`
(:class:`ModelWeightsInvalidError` for a folder of another model type, without tokenizer or
image-processor files, or whose weights do not load or leave part of the model unset: loaded as
they are, the robot would search with random layers and no error).

* :class:`Owlv2Detector`: one text query per class ("a photo of a {class}"); boxes above
  ``detector_min_score`` become masks: the box's pixels whose depth lies within
  ``depth_mask_tolerance`` of the median depth of the box's central half (OWLv2 has no masks;
  the map needs the object's pixels, not the wall behind it).
* :class:`ClipImageTextScorer`: cosine similarity of CLIP's image and text embeddings, one value
  per prompt (the role BLIP-2's ITC score plays in VLFM/HELIOS).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from helios.perception.config import ModelConfig
from helios.perception.detection import Detection
from helios.perception.errors import ModelWeightsInvalidError, ModelWeightsMissingError, PerceptionDependencyError
from helios.perception.inputs import check_class_names, check_rgb, check_rgb_depth
from helios.perception.prompts import check_prompts

_WEIGHT_FILES = ("model.safetensors", "model.safetensors.index.json", "pytorch_model.bin", "pytorch_model.bin.index.json")
# What a save_pretrained() folder needs besides config.json and weights: a tokenizer (one file or
# the BPE pair) and an image processor (transformers 4 names it preprocessor_config, 5 processor_config).
_TOKENIZER_FILES = (("tokenizer.json",), ("vocab.json", "merges.txt"))
_PROCESSOR_FILES = ("preprocessor_config.json", "processor_config.json")


def _transformers():
    try:
        import transformers
    except ImportError as exc:
        raise PerceptionDependencyError(
            "the real-model perception adapters need the optional dependency 'transformers' "
            f"({exc}); install it with: pip install -e '.[perception]' (in the checkout)") from None
    # one line per problem: no progress bars or load reports (a bad load is refused below instead)
    transformers.utils.logging.set_verbosity_error()
    transformers.utils.logging.disable_progress_bar()
    return transformers


def check_weights_dir(path: str | Path, what: str, setting: str, example: str, model_type: str | None = None) -> Path:
    """The local checkpoint directory, or ModelWeightsMissingError saying what is missing and how
    to fix it; with ``model_type``, config.json must name it (ModelWeightsInvalidError otherwise)."""
    hint = (f"set {setting} to a local directory holding a save_pretrained() copy of {example} "
            f"(config.json, model weights, tokenizer and processor files); nothing is downloaded at run time")
    if not str(path).strip():
        raise ModelWeightsMissingError(f"no {what} weights configured: {hint}")
    p = Path(path).expanduser()
    try:
        os.fsencode(p).decode("utf-8")
    except UnicodeDecodeError:
        raise ModelWeightsInvalidError(f"{what} weights directory {str(p)!r}: its name is not UTF-8 text, which "
                                       f"the weights loader cannot open; rename it") from None
    if not p.is_dir():
        raise ModelWeightsMissingError(f"{what} weights directory {str(p)!r} does not exist: {hint}")
    if not (p / "config.json").is_file():
        raise ModelWeightsMissingError(f"{what} weights directory {str(p)!r} has no config.json: {hint}")
    if not any((p / f).is_file() for f in _WEIGHT_FILES):
        raise ModelWeightsMissingError(f"{what} weights directory {str(p)!r} has no weights "
                                       f"({' or '.join(_WEIGHT_FILES)}): {hint}")
    if not any(all((p / f).is_file() for f in files) for files in _TOKENIZER_FILES):
        raise ModelWeightsInvalidError(f"{what} weights directory {str(p)!r} has no tokenizer (tokenizer.json, or "
                                       f"vocab.json and merges.txt): without it every query reads the same: {hint}")
    if not any((p / f).is_file() for f in _PROCESSOR_FILES):
        raise ModelWeightsInvalidError(f"{what} weights directory {str(p)!r} has no image processor "
                                       f"({' or '.join(_PROCESSOR_FILES)}): {hint}")
    if model_type is not None:
        try:
            found = json.loads((p / "config.json").read_text(encoding="utf-8")).get("model_type")
        except (OSError, UnicodeDecodeError, ValueError, AttributeError) as exc:
            raise ModelWeightsInvalidError(f"{what} weights directory {str(p)!r}: config.json cannot be read "
                                           f"({type(exc).__name__}: {str(exc)[:120]})") from None
        if found != model_type:
            raise ModelWeightsInvalidError(f"{what} weights directory {str(p)!r} holds a {found!r} model, not "
                                           f"{model_type!r}: {hint}")
    return p


def _load(loader, path: Path, what: str, model: bool = False):
    """``loader.from_pretrained(path)`` offline; any failure to load, and for a model any weight
    missing from the checkpoint or of the wrong shape (transformers would initialise it randomly and
    only warn), is one ModelWeightsInvalidError naming the folder."""
    try:
        if not model:
            return loader.from_pretrained(path, local_files_only=True)
        loaded, info = loader.from_pretrained(path, local_files_only=True, output_loading_info=True)
    except Exception as exc:  # noqa: BLE001 - safetensors, JSON, shape and OS errors alike: the folder is bad
        raise ModelWeightsInvalidError(f"{what} weights directory {str(path)!r} does not load: {type(exc).__name__}: "
                                       f"{str(exc).splitlines()[0][:200] if str(exc) else 'no message'}") from None
    missing = list(info.get("missing_keys") or []) + [str(k[0]) if isinstance(k, tuple) else str(k)
                                                      for k in info.get("mismatched_keys") or []]
    if missing:
        raise ModelWeightsInvalidError(f"{what} weights directory {str(path)!r} leaves {len(missing)} weight(s) of the "
                                       f"model unset or of another shape (e.g. {missing[0]}): not a checkpoint of "
                                       f"this model")
    return loaded


def _device(name: str) -> str:
    import torch

    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" and not torch.cuda.is_available():
        raise PerceptionDependencyError(f"device cuda: no CUDA device here (torch.cuda.is_available() is False; "
                                        f"torch {torch.__version__}); use cpu or auto")
    return name


class Owlv2Detector:
    """OWLv2 open-vocabulary detection; boxes turned into depth-consistent masks."""

    def __init__(self, weights_dir: str | Path, device: str = "cpu", min_score: float = 0.1,
                 depth_tolerance: float = 0.25, query_template: str = "a photo of a {}"):
        tf = _transformers()
        path = check_weights_dir(weights_dir, "OWLv2 detector", "ModelConfig.detector_weights",
                                 "google/owlv2-base-patch16-ensemble", model_type="owlv2")
        self.device = _device(device)
        self.processor = _load(tf.Owlv2Processor, path, "OWLv2 detector")
        self.model = _load(tf.Owlv2ForObjectDetection, path, "OWLv2 detector", model=True).eval().to(self.device)
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
                                truncation=True, max_length=self._max_tokens, input_data_format="channels_last")
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
        valid = centre[np.isfinite(centre) & (centre > 0)]       # no return (0, NaN) or out of range (inf)
        if valid.size:
            med = float(np.median(valid))
            box_depth = depth[v0:v1, u0:u1]
            near = np.isfinite(box_depth) & (box_depth > 0) & (np.abs(box_depth - med) <= tolerance)
            if near.sum() >= 0.1 * near.size:
                mask[v0:v1, u0:u1] = near
    return mask


class ClipImageTextScorer:
    """CLIP image-text cosine similarity, one value per prompt."""

    def __init__(self, weights_dir: str | Path, device: str = "cpu"):
        tf = _transformers()
        path = check_weights_dir(weights_dir, "CLIP scorer", "ModelConfig.scorer_weights",
                                 "openai/clip-vit-base-patch32", model_type="clip")
        self.device = _device(device)
        self.processor = _load(tf.CLIPProcessor, path, "CLIP scorer")
        self.model = _load(tf.CLIPModel, path, "CLIP scorer", model=True).eval().to(self.device)
        self._max_tokens = int(getattr(self.model.config.text_config, "max_position_embeddings", 77))

    def __call__(self, rgb: np.ndarray, prompts: Sequence[str]) -> np.ndarray:
        import torch

        items = check_prompts(prompts)
        check_rgb(rgb)
        inputs = self.processor(text=items, images=rgb, return_tensors="pt", padding=True, truncation=True,
                                max_length=self._max_tokens, input_data_format="channels_last")
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
