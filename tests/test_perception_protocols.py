"""Perception contracts: the value prompt, per-role thresholds, configs and input checks."""

from __future__ import annotations

import numpy as np
import pytest

from helios.schema import ConfigError, dump_yaml, from_dict, load_config, to_dict, with_overrides
from helios.perception import (
    Detection,
    DetectionThresholds,
    PerceptionConfig,
    apply_thresholds,
    parse_value_prompt,
    role_thresholds,
    value_prompt,
)
from helios.perception.errors import ImageInputError, PromptError, UnknownCategoryError
from helios.perception.inputs import check_class_names, check_rgb_depth
from helios.perception.prompts import check_prompts
from sim.perception.config import SimPerceptionConfig
from sim.perception.confusion import ConfusionTable
from sim.scenes.catalog import ALL_CATEGORIES, LOOKALIKES


def test_the_paper_prompt_round_trips_for_every_category():
    assert value_prompt("counter") == "Seems like there is a counter ahead"
    for c in ALL_CATEGORIES:
        assert parse_value_prompt(value_prompt(c)) == c
    assert parse_value_prompt("seems like there is an (Apple) ahead.") == "apple"
    assert parse_value_prompt("Seems like there is a filing_cabinet ahead") == "filing cabinet"
    for bad in ("counter", "Seems like there is ahead", "There is a mug ahead", ""):
        with pytest.raises(PromptError, match="cannot interpret prompt"):
            parse_value_prompt(bad)
    with pytest.raises(PromptError, match="empty"):
        check_prompts([])
    with pytest.raises(PromptError, match="single string"):
        check_prompts("Seems like there is a mug ahead")


def test_per_role_thresholds_are_the_papers_and_a_shared_class_gets_the_lower_one():
    t = DetectionThresholds()
    assert (t.od_start_receptacle, t.od_object, t.od_goal_receptacle) == (0.35, 0.25, 0.45)
    assert role_thresholds(t, "mug", "table", "counter") == {"mug": 0.25, "table": 0.35, "counter": 0.45}
    assert role_thresholds(t, "mug", "table", "table") == {"mug": 0.25, "table": 0.35}
    m = np.ones((4, 4), dtype=bool)
    dets = [Detection(m, "mug", 0.3), Detection(m, "table", 0.3), Detection(m, "counter", 0.5), Detection(m, "bed", 0.9)]
    kept = apply_thresholds(dets, role_thresholds(t, "mug", "table", "counter"))
    assert [(d.class_name, d.score) for d in kept] == [("mug", 0.3), ("counter", 0.5)]
    assert len(apply_thresholds(dets, {"mug": 0.25}, default=0.0)) == 4
    with pytest.raises(ValueError, match="od_object must be in"):
        DetectionThresholds(od_object=1.5)


def test_helios_config_detection_section_is_the_threshold_type_and_filters_like_the_agent():
    from helios.config import HeliosConfig

    assert HeliosConfig().detection == DetectionThresholds()
    thresholds = role_thresholds(HeliosConfig().detection, "mug", "table", "table")
    m = np.ones((4, 4), dtype=bool)
    dets = [Detection(m, "mug", 0.25), Detection(m, "mug", 0.2), Detection(m, "table", 0.35), Detection(m, "table", 0.3),
            Detection(m, "bed", 0.99), Detection(m, "bed", 1.0)]
    # the agent's filter: classes outside the task pass only with a score of 1 (default=1.0)
    assert apply_thresholds(dets, thresholds, default=1.0) == [d for d in dets if d.score >= thresholds.get(d.class_name, 1.0)]
    assert [(d.class_name, d.score) for d in apply_thresholds(dets, thresholds, default=1.0)] == [
        ("mug", 0.25), ("table", 0.35), ("bed", 1.0)]


def test_configs_load_from_yaml_and_overrides_with_clear_errors(tmp_path):
    cfg = with_overrides(SimPerceptionConfig(), ["mode=gt", "bad_view_object=0.3", "category_difficulty={glass: 2.0}"])
    assert cfg.mode == "gt" and cfg.bad_view_object == 0.3 and cfg.category_difficulty["glass"] == 2.0
    assert cfg.category_difficulty["phone"] == SimPerceptionConfig().category_difficulty["phone"]   # merged
    assert from_dict(SimPerceptionConfig, to_dict(cfg)) == cfg
    path = tmp_path / "p.yaml"
    path.write_text(dump_yaml(PerceptionConfig()))
    assert load_config(PerceptionConfig, path) == PerceptionConfig()
    with pytest.raises(ConfigError, match="mode"):
        with_overrides(SimPerceptionConfig(), ["mode=perfect"])
    with pytest.raises(ConfigError, match="bad_view_object must be in"):
        with_overrides(SimPerceptionConfig(), ["bad_view_object=1.5"])
    with pytest.raises(ConfigError, match="bad_view_distance_scale needs 3 values"):
        with_overrides(SimPerceptionConfig(), ["bad_view_distance_scale=[1.0, 2.0]"])
    with pytest.raises(ConfigError, match="unknown config key"):
        with_overrides(SimPerceptionConfig(), ["bad_veiw_object=0.2"])
    with pytest.raises(ConfigError, match="value_prompt needs exactly one"):
        with_overrides(PerceptionConfig(), ["value_prompt=Seems like there is something ahead"])


def test_every_simulated_perception_number_has_both_bounds():
    """Not only -1e12 but also +1e12 is refused for every number of the simulated detector's
    config (mask_morph_px=100000 used to reach OpenCV and run it out of memory; azimuth_bins,
    min_pixels, gt_min_pixels took 1e12), and so for the elements of its lists and maps; category
    names must be the simulator's (a typo was silently ignored by the oracle and failed HELIOS
    episodes after the run folder was written)."""
    import dataclasses
    import typing

    hints = typing.get_type_hints(SimPerceptionConfig)
    numbers = [f.name for f in dataclasses.fields(SimPerceptionConfig) if hints[f.name] in (int, float)]
    assert len(numbers) > 40
    accepted = []
    for name in numbers:
        for value in (-10 ** 12, 10 ** 12):
            try:
                with_overrides(SimPerceptionConfig(), {name: hints[name](value)})
                accepted.append((name, value))
            except ConfigError:
                pass
    for name, value in (("elevation_edges_deg", [20.0, 1e12]), ("distance_edges", [1.5, 1e12]),
                        ("bad_view_distance_scale", [0.8, 1.0, 1e12]), ("bad_view_elevation_scale", [1e12, 1.0, 0.9]),
                        ("category_difficulty", {"glass": 1e12}), ("elevation_edges_deg", [-1e12, 45.0])):
        try:
            with_overrides(SimPerceptionConfig(), {name: value})
            accepted.append((name, value))
        except ConfigError:
            pass
    assert not accepted, accepted
    with pytest.raises(ConfigError, match=r"mask_morph_px must be in \[0, 64\], got 100000"):
        with_overrides(SimPerceptionConfig(), ["mask_morph_px=100000"])
    with pytest.raises(ConfigError, match=r"unknown category \('unicorn'\)"):
        with_overrides(SimPerceptionConfig(), ["category_difficulty={unicorn: 1.0}"])
    with pytest.raises(ConfigError, match="did you mean 'glass'"):
        with_overrides(SimPerceptionConfig(), ["category_difficulty={glas: 1.0}"])
    # the defaults and the values the scenario files and the README use stay valid
    with_overrides(SimPerceptionConfig(), ["mask_morph_px=64", "mask_shift_px=0", "azimuth_bins=360",
                                           "category_difficulty={glass: 2.0, mug: 0.0}", "receptacle_part_false_positive=1.0",
                                           "score_false_positive_logit_receptacle=0.3", "bad_view_receptacle=0.3"])


def test_confusion_table_extends_the_catalogue_families_symmetrically():
    table = ConfusionTable(0.5)
    for fam in LOOKALIKES:
        for a in fam:
            assert all(table.weights(a).get(b) == 1.0 for b in fam if b != a)
    assert table.weights("banana") == {"toy": 0.5, "remote": 0.5}     # no catalogue family: extras only
    for a in ALL_CATEGORIES:
        assert a not in table.weights(a)
        assert all(table.weights(b)[a] == w for b, w in table.weights(a).items())
    assert table.could_be_labelled("cup", frozenset({"mug"})) and not table.could_be_labelled("bed", frozenset({"mug"}))
    assert "toy" not in ConfusionTable(0.0).weights("banana")


def test_input_checks_name_the_problem():
    rgb = np.zeros((240, 320, 3), np.uint8)
    assert check_rgb_depth(rgb, np.zeros((240, 320), np.float32)) == (240, 320)
    with pytest.raises(ImageInputError, match=r"rgb is 320x240 \(W x H\), depth is 320x200"):
        check_rgb_depth(rgb, np.zeros((200, 320), np.float32))
    with pytest.raises(ImageInputError, match="depth must be an"):
        check_rgb_depth(rgb, np.zeros((240, 320), np.uint16))
    with pytest.raises(ImageInputError, match="uint8"):
        check_rgb_depth(rgb.astype(np.float32), np.zeros((240, 320), np.float32))
    assert check_class_names(["anything goes"]) == ["anything goes"]      # open vocabulary without a catalogue
    with pytest.raises(UnknownCategoryError, match="more than once"):
        check_class_names(["mug", "mug"])
    with pytest.raises(UnknownCategoryError, match=r"unknown class names 'spoon', 'fork'; valid: a, b"):
        check_class_names(["spoon", "fork"], ["a", "b"])
