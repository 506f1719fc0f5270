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
