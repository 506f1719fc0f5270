"""Real-model adapters (OWLv2, CLIP through transformers) on tiny randomly initialised models
saved to a temporary directory: no downloads. Also the errors for missing weights."""

from __future__ import annotations


import numpy as np
import pytest

from helios.perception import Detection, Detector, ImageTextScorer, ModelConfig
from helios.perception.adapters import box_mask, check_weights_dir, load_real_perception
from helios.perception.errors import ImageInputError, ModelWeightsMissingError, PerceptionDependencyError, PromptError


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
    with pytest.raises(PerceptionDependencyError, match=r"pip install 'helios-testbed\[perception\]'"):
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
