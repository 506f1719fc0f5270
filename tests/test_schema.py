"""Typed config machinery: strict keys, type checks, overrides, YAML round trip."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import pytest

from helios.schema import ConfigError, dump_yaml, from_dict, load_config, to_dict, with_overrides


@dataclass(frozen=True)
class Inner:
    rate: float = 1.5
    mode: Literal["a", "b"] = "a"


@dataclass(frozen=True)
class Outer:
    seed: int = 0
    name: str = "x"
    size: tuple[int, int] = (320, 240)
    inner: Inner = Inner()
    flag: bool = False


def test_defaults_and_nested_overrides():
    cfg = with_overrides(Outer(), ["seed=7", "inner.rate=2", "inner.mode=b", "size=[640, 480]", "flag=true"])
    assert cfg == Outer(seed=7, size=(640, 480), inner=Inner(rate=2.0, mode="b"), flag=True)


@pytest.mark.parametrize("override,match", [
    ("sead=1", "unknown config key 'sead'.*valid: flag, inner, name, seed, size"),
    ("inner.rat=1", "unknown config key 'inner.rat'"),
    ("seed=abc", "seed: expected an integer"),
    ("inner.mode=c", r"inner.mode: 'c' is not one of \['a', 'b'\]"),
    ("size=[1]", "size: expected 2 values"),
    ("inner=3", "not a config section|expected a mapping"),
    ("novalue", "not of the form key=value"),
    ("inner.rate=.nan", "NaN"),
])
def test_bad_overrides_name_the_key(override, match):
    with pytest.raises(ConfigError, match=match):
        with_overrides(Outer(), [override])


def test_unknown_keys_in_a_mapping_are_errors():
    with pytest.raises(ConfigError, match="unknown config key 'inner.extra'"):
        from_dict(Outer, {"inner": {"extra": 1}})


def test_yaml_round_trip(tmp_path):
    cfg = with_overrides(Outer(), ["seed=3", "inner.rate=0.25"])
    path = tmp_path / "cfg.yaml"
    path.write_text(dump_yaml(cfg))
    assert load_config(Outer, path) == cfg
    assert to_dict(cfg)["size"] == [320, 240]


def test_missing_or_broken_config_file(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(Outer, tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("seed: [unclosed")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(Outer, bad)
    top = tmp_path / "list.yaml"
    top.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="mapping at the top level"):
        load_config(Outer, top)


def test_sim_backend_config_is_a_valid_schema():
    from robots.spot.sim_backend import SimBackendConfig

    cfg = with_overrides(SimBackendConfig(), ["camera.width=640", "camera.height=480", "motion.base.linear_velocity=0.5"])
    assert cfg.camera.width == 640 and cfg.motion.base.linear_velocity == 0.5
    assert from_dict(SimBackendConfig, to_dict(cfg)) == cfg


def test_numbers_read_as_yaml_1_2_not_as_octal_hex_or_base_60(tmp_path):
    """PyYAML's YAML 1.1 made `seed=010` seed 8, `seed=0x10` 16 and `1:30` 90, and read `1e3` as
    text; the flags (`--seed 010`) read 10. Now an integer is decimal, a float has a dot or an
    exponent, and the other spellings are text that a numeric setting refuses."""
    assert with_overrides(Outer(), ["seed=010"]).seed == 10
    assert with_overrides(Outer(), ["inner.rate=1e3"]).inner.rate == 1000.0
    assert with_overrides(Outer(), ["inner.rate=-2.5e-3"]).inner.rate == -0.0025
    for text, value in ((".5", 0.5), ("-.5", -0.5), (".5e1", 5.0), ("+1.", 1.0)):
        assert with_overrides(Outer(), [f"inner.rate={text}"]).inner.rate == value, text
    for spelling in ("0x10", "0o7", "1:30", "1_000"):
        with pytest.raises(ConfigError, match="seed: expected an integer"):
            with_overrides(Outer(), [f"seed={spelling}"])
        with pytest.raises(ConfigError, match="inner.rate: expected a number"):
            with_overrides(Outer(), [f"inner.rate={spelling}"])
    with pytest.raises(ConfigError, match="not a decimal integer"):
        with_overrides(Outer(), ["seed=!!int 0x10"])
    path = tmp_path / "cfg.yaml"
    path.write_text("seed: 010\ninner: {rate: 1e-2}\n")
    assert load_config(Outer, path) == with_overrides(Outer(), ["seed=10", "inner.rate=0.01"])
    # what the config files are written with reads back the same: strings that look like numbers quoted
    for name in ("1e3", "010", "0x10", "1:30", "1_000", "1.0", ".inf", ".5", "-.5"):
        cfg = with_overrides(Outer(), {"name": name})
        path.write_text(dump_yaml(cfg))
        assert load_config(Outer, path) == cfg, (name, dump_yaml(cfg))


def test_configs_read_through_libyaml_exactly_as_through_the_python_loader(monkeypatch):
    """Every run folder's config.yaml, and every shipped scenario, is read by libyaml's parser when
    the text allows (7x faster; every resume, report and diff reads one): the same values as
    PyYAML's pure-Python loader, and a run folder's config.yaml does take that path."""
    import glob

    import yaml

    import helios.schema
    from helios.schema import _LIBYAML_SAFE, UniqueKeyLoader, _CParser, load_yaml
    from tasks.trial_config import TrialConfig

    if _CParser is None:
        pytest.skip("this PyYAML is built without libyaml (pip's wheels for Linux have it)")
    dumped = dump_yaml(TrialConfig(agent="helios", split="val", episodes=200))
    assert _LIBYAML_SAFE.match(dumped), "a run folder's config.yaml no longer takes the fast path"
    texts = [dumped] + [open(p, encoding="utf-8").read() for p in sorted(glob.glob("configs/*.yaml"))]
    assert len(texts) > 10
    for text in texts:
        assert load_yaml(text) == yaml.load(text, Loader=UniqueKeyLoader)
    # a duplicate key is refused on the fast path too, in the same words
    with pytest.raises(yaml.YAMLError, match=r"found duplicate key 'seed' \(first on line 1\)"):
        load_yaml("seed: 1\nagent: oracle\nseed: 2\n")
    # and libyaml did read it: with the pure-Python loader broken, the run folder's config still loads
    class Broken(UniqueKeyLoader):
        def __init__(self, stream):
            raise AssertionError("the pure-Python loader was used")

    monkeypatch.setattr(helios.schema, "UniqueKeyLoader", Broken)
    assert load_yaml(dumped)["agent"] == "helios"


@pytest.mark.parametrize("text", [
    "a\t",                            # a tab libyaml takes and PyYAML refuses
    "split:\tval\n",
    "|# a block scalar header libyaml reads differently\n",
    "8ee+d: 0\n\n\ufeff",             # a byte-order mark mid-text
    "[a?b]",                          # libyaml reads a '?' in a flow collection as part of the word
    "x: [1, 2?3]\n",
    "seed: " + "[" * 600 + "]" * 600,  # libyaml nests where the Python loader's recursion ends
])
def test_text_libyaml_reads_differently_gets_the_python_loaders_answer(text):
    """A differential fuzz (150,000 mutated configs) found libyaml taking text the pure-Python
    loader refuses; such text (tabs, non-ASCII, tags, block scalars) never takes the fast path."""
    import yaml

    from helios.schema import UniqueKeyLoader, load_yaml

    with pytest.raises((yaml.YAMLError, RecursionError)) as python:
        yaml.load(text, Loader=UniqueKeyLoader)
    with pytest.raises((yaml.YAMLError, RecursionError)) as ours:
        load_yaml(text)
    assert type(ours.value) is type(python.value) and str(ours.value) == str(python.value)


def test_deep_nesting_is_a_config_error_not_a_crash(tmp_path):
    """libyaml's parser recurses in C: 100,000 nested '[' killed the process with a segmentation
    fault. Text that could nest that deep takes the Python loader, whose RecursionError is a line."""
    from helios.schema import yaml_load_text

    for text in ("[" * 100_000, "- " * 100_000 + "x", "{a: " * 100_000):
        with pytest.raises(ConfigError, match="deep.yaml is not valid YAML"):
            yaml_load_text(text, "deep.yaml")


@pytest.mark.parametrize("value, says", [
    ('!!float ""', "'' is not a number"),
    ("!!float 1_000", "'1_000' is not a number"),
    ("!!bool maybe", "'maybe' is not true or false"),
    ("!!timestamp soon", "'soon' is not a date"),
])
def test_explicitly_tagged_text_pyyaml_could_not_read_is_refused_in_words(value, says):
    """PyYAML's constructors crashed on these (an IndexError, a KeyError, an AttributeError): a
    traceback instead of a line."""
    with pytest.raises(ConfigError, match=f"cannot parse value \\({says}"):
        with_overrides(Outer(), [f"seed={value}"])
    assert with_overrides(Outer(), ["flag=!!bool yes"]).flag is True
    assert with_overrides(Outer(), ["inner.rate=!!float 2"]).inner.rate == 2.0
