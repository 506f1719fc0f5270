"""Real-model adapters (OWLv2, CLIP through transformers) on tiny randomly initialised models
saved to a temporary directory: no downloads. Also the errors for missing weights."""

from __future__ import annotations


import numpy as np
import pytest

from helios.perception import Detection, Detector, ImageTextScorer, ModelConfig
from helios.perception.adapters import box_mask, check_weights_dir, load_real_perception
from helios.perception.errors import (ImageInputError, ModelWeightsInvalidError, ModelWeightsMissingError,
                                     PerceptionDependencyError, PromptError)


def test_missing_weights_are_one_clear_error(tmp_path):
    with pytest.raises(ModelWeightsMissingError, match="no OWLv2 detector weights configured: set "
                                                       "perception.models.detector_weights"):
        check_weights_dir("", "OWLv2 detector", "perception.models.detector_weights", "google/owlv2")
    with pytest.raises(ModelWeightsMissingError, match="does not exist"):
        check_weights_dir(tmp_path / "nope", "CLIP scorer", "perception.models.scorer_weights", "openai/clip")
    with pytest.raises(ModelWeightsMissingError, match="has no config.json"):
        check_weights_dir(tmp_path, "CLIP scorer", "perception.models.scorer_weights", "openai/clip")
    (tmp_path / "config.json").write_text("{}")
    with pytest.raises(ModelWeightsMissingError, match="has no weights"):
        check_weights_dir(tmp_path, "CLIP scorer", "perception.models.scorer_weights", "openai/clip")


def test_missing_transformers_is_one_clear_error(monkeypatch):
    import builtins

    real_import = builtins.__import__

    def fake_import(name, *args, **kwargs):
        if name == "transformers" or name.startswith("transformers."):
            raise ImportError("No module named 'transformers'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", fake_import)
    with pytest.raises(PerceptionDependencyError, match=r"pip install -e '\.\[perception\]' \(in the checkout\)"):
        load_real_perception(ModelConfig(detector_weights="/x", scorer_weights="/y"))


def test_box_masks_keep_the_object_and_drop_the_wall_behind_it():
    depth = np.full((100, 100), 4.0, np.float32)
    depth[40:60, 40:60] = 1.5                      # the object
    mask = box_mask((35, 35, 65, 65), depth, 0.25)
    assert mask.sum() == 400 and mask[50, 50] and not mask[36, 36]
    assert box_mask((35, 35, 65, 65), depth, 0.0).sum() == 900
    assert box_mask((120, 5, 130, 20), depth, 0.25) is None


@pytest.fixture(scope="module")
def tiny_models(tmp_path_factory):
    pytest.importorskip("transformers")
    from tiny_models import save_tiny_models

    return save_tiny_models(tmp_path_factory.mktemp("tiny_models"))


def test_owlv2_and_clip_adapters_run_offline_on_tiny_models(tiny_models):
    owl_dir, clip_dir = tiny_models
    detector, scorer = load_real_perception(ModelConfig(detector_weights=str(owl_dir), scorer_weights=str(clip_dir),
                                                        detector_min_score=0.0))
    assert isinstance(detector, Detector) and isinstance(scorer, ImageTextScorer)
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 255, (240, 320, 3), dtype=np.uint8)
    depth = rng.uniform(0.5, 4.0, (240, 320)).astype(np.float32)
    dets = detector(rgb, depth, ["mug", "kitchen counter"])
    assert dets and all(isinstance(d, Detection) and d.mask.shape == (240, 320) and d.mask.any() for d in dets)
    assert {d.class_name for d in dets} <= {"mug", "kitchen counter"}
    assert all(0.0 <= d.score <= 1.0 for d in dets)
    again = detector(rgb, depth, ["mug", "kitchen counter"])
    assert [(d.class_name, d.score) for d in again] == [(d.class_name, d.score) for d in dets]
    scores = scorer(rgb, ["Seems like there is a mug ahead", "Seems like there is a counter ahead"])
    assert scores.shape == (2,) and np.all(np.abs(scores) <= 1.0 + 1e-6)
    with pytest.raises(ImageInputError, match="sizes differ"):
        detector(rgb, depth[:100], ["mug"])
    with pytest.raises(PromptError, match="empty"):
        scorer(rgb, [])


# ------------------------------------------------------------------------------------------------
# Weight folders that load but would run blind, or do not load (audit 2026-12-05: each of these
# once loaded with a warning and ran a whole robot episode on random layers, or was a traceback)
# ------------------------------------------------------------------------------------------------
def _copy(folder, tmp_path, name):
    import shutil

    return shutil.copytree(folder, tmp_path / name)


def _load_both(owl, clip):
    return load_real_perception(ModelConfig(detector_weights=str(owl), scorer_weights=str(clip)))


def test_a_folder_without_tokenizer_or_image_processor_is_refused(tiny_models, tmp_path):
    owl, clip = tiny_models
    no_tok = _copy(owl, tmp_path, "no_tok")
    (no_tok / "tokenizer.json").unlink()
    with pytest.raises(ModelWeightsInvalidError, match=r"no_tok' has no tokenizer \(tokenizer.json, or vocab.json "
                                                       r"and merges.txt\): without it every query reads the same"):
        _load_both(no_tok, clip)
    no_proc = _copy(clip, tmp_path, "no_proc")
    (no_proc / "processor_config.json").unlink()
    with pytest.raises(ModelWeightsInvalidError, match=r"no_proc' has no image processor"):
        _load_both(owl, no_proc)


def test_weights_of_the_other_model_are_refused_by_their_type(tiny_models):
    owl, clip = tiny_models
    with pytest.raises(ModelWeightsInvalidError, match=r"OWLv2 detector weights directory .* holds a 'clip' model, "
                                                       r"not 'owlv2'"):
        _load_both(clip, clip)
    with pytest.raises(ModelWeightsInvalidError, match=r"CLIP scorer weights directory .* holds a 'owlv2' model, "
                                                       r"not 'clip'"):
        _load_both(owl, owl)


def test_damaged_weights_or_config_are_one_error_not_a_traceback(tiny_models, tmp_path):
    owl, clip = tiny_models
    cut = _copy(owl, tmp_path, "cut")
    weights = cut / "model.safetensors"
    weights.write_bytes(weights.read_bytes()[: weights.stat().st_size // 2])
    with pytest.raises(ModelWeightsInvalidError, match=r"cut' does not load: "):
        _load_both(cut, clip)
    bad_cfg = _copy(clip, tmp_path, "bad_cfg")
    (bad_cfg / "config.json").write_text("{ not json")
    with pytest.raises(ModelWeightsInvalidError, match=r"bad_cfg': config.json cannot be read \(JSONDecodeError"):
        _load_both(owl, bad_cfg)


def test_a_checkpoint_that_leaves_weights_unset_is_refused(tiny_models, tmp_path):
    """transformers fills weights a checkpoint lacks with random values and only warns."""
    from safetensors.numpy import load_file, save_file

    owl, clip = tiny_models
    partial = _copy(clip, tmp_path, "partial")
    tensors = load_file(partial / "model.safetensors")
    dropped = sorted(k for k in tensors if "visual_projection" in k)
    assert dropped
    save_file({k: v for k, v in tensors.items() if k not in dropped}, partial / "model.safetensors",
              metadata={"format": "pt"})
    with pytest.raises(ModelWeightsInvalidError, match=r"partial' leaves 1 weight\(s\) of the model unset or of "
                                                       r"another shape \(e.g. visual_projection"):
        _load_both(owl, partial)


def test_a_weights_folder_whose_name_is_not_utf8_is_one_error(tiny_models, tmp_path):
    import os
    import shutil

    owl, clip = tiny_models
    odd = os.fsdecode(os.fsencode(tmp_path) + b"/w\xff")
    shutil.copytree(owl, odd)
    with pytest.raises(ModelWeightsInvalidError, match="its name is not UTF-8 text"):
        _load_both(odd, clip)


def test_cuda_without_cuda_is_one_error_from_the_library_too(tiny_models):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    owl, clip = tiny_models
    with pytest.raises(PerceptionDependencyError, match="device cuda: no CUDA device here"):
        load_real_perception(ModelConfig(detector_weights=str(owl), scorer_weights=str(clip), device="cuda"))
    with pytest.raises(ValueError, match="device must be cpu, cuda or auto, got 'gpu'"):
        ModelConfig(device="gpu")


def test_infinite_depth_in_a_box_is_no_return_not_the_median():
    """+inf (out of range) in the box centre made the median inf: the whole box, wall included."""
    depth = np.full((100, 100), 4.0, np.float32)
    depth[40:60, 40:60] = 1.5
    depth[45:50, 45:55] = np.inf
    mask = box_mask((35, 35, 65, 65), depth, 0.25)
    assert mask.sum() == 400 - 50 and mask[42, 42] and not mask[36, 36] and not mask[47, 50]


def test_a_three_pixel_high_image_is_read_channels_last(tiny_models):
    """An image 3 pixels high (or wide) is ambiguous to the processors; they are told HWC."""
    owl, clip = tiny_models
    detector, scorer = load_real_perception(ModelConfig(detector_weights=str(owl), scorer_weights=str(clip)))
    rgb = np.random.default_rng(0).integers(0, 255, (3, 64, 3), dtype=np.uint8)
    depth = np.full((3, 64), 2.0, np.float32)
    detector(rgb, depth, ["mug"])
    assert scorer(rgb, ["Seems like there is a mug ahead"]).shape == (1,)
    last = scorer.processor(images=rgb, return_tensors="np", input_data_format="channels_last")["pixel_values"]
    first = scorer.processor(images=rgb, return_tensors="np", input_data_format="channels_first")["pixel_values"]
    seen = {}
    real = scorer.processor.__call__

    def spy(*args, **kwargs):
        out = real(*args, **kwargs)
        seen["pixels"] = out["pixel_values"].numpy()
        return out

    scorer.processor = type("Spy", (), {"__call__": staticmethod(spy)})()
    scorer(rgb, ["Seems like there is a mug ahead"])
    assert np.array_equal(seen["pixels"], last) and not np.array_equal(last, first)
