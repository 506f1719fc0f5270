"""Configuration machinery (not a config tree itself): frozen dataclasses are the schema; YAML
files and ``key=value`` overrides fill them in; unknown keys and ill-typed values are errors that name the offending key.

Every config tree in the project (method hyper-parameters, simulator, robot motion limits, trial
settings) is a frozen dataclass built with these helpers, so a run's resolved configuration can be
saved as YAML and loaded back bit for bit (Drake ``yaml_load_typed`` style, without Drake).
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from pathlib import Path
from typing import Any, Iterable, Mapping, TypeVar

import yaml

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration value or key is invalid. The message names the key path."""


def require(condition: bool, message: str) -> None:
    """Validation step of a config dataclass's ``__post_init__``: raise ``ValueError(message)``
    unless ``condition`` holds (:func:`from_dict` reports it as a ConfigError naming the section)."""
    if not condition:
        raise ValueError(message)


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _coerce(value: Any, tp: Any, path: str) -> Any:
    """Convert a YAML/JSON value into the annotated type, or raise ConfigError naming ``path``."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(value, arg, path)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(f"{path}: {value!r} matches none of {[_type_name(a) for a in args]}")
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(f"{path}: {value!r} is not one of {list(args)}")
        return value
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, Mapping):
            raise ConfigError(f"{path}: expected a mapping for {tp.__name__}, got {type(value).__name__}")
        return from_dict(tp, value, path)
    if origin in (tuple, list):
        if isinstance(value, (str, bytes)) or not isinstance(value, Iterable):
            raise ConfigError(f"{path}: expected a list, got {value!r}")
        items = list(value)
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(items) != len(args):
                raise ConfigError(f"{path}: expected {len(args)} values, got {len(items)}")
            out = [_coerce(v, a, f"{path}[{i}]") for i, (v, a) in enumerate(zip(items, args))]
        else:
            elem = args[0] if args else Any
            out = [_coerce(v, elem, f"{path}[{i}]") for i, v in enumerate(items)]
        return tuple(out) if origin is tuple else out
    if origin in (dict, Mapping) or tp in (dict,):
        if not isinstance(value, Mapping):
            raise ConfigError(f"{path}: expected a mapping, got {value!r}")
        kt, vt = args if args else (Any, Any)
        return {_coerce(k, kt, path): _coerce(v, vt, f"{path}.{k}") for k, v in value.items()}
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{path}: expected true/false, got {value!r}")
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise ConfigError(f"{path}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{path}: expected a number, got {value!r}")
        value = float(value)
        if math.isnan(value):
            raise ConfigError(f"{path}: NaN is not a valid value")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{path}: expected a string, got {value!r}")
        return value
    if isinstance(tp, type) and isinstance(value, tp):
        return value
    raise ConfigError(f"{path}: cannot interpret {value!r} as {_type_name(tp)}")


def _field_types(cls: type) -> dict[str, Any]:
    hints = typing.get_type_hints(cls)
    return {f.name: hints[f.name] for f in dataclasses.fields(cls) if f.init}


def from_dict(cls: type[T], data: Mapping[str, Any] | None, path: str = "") -> T:
    """Build dataclass ``cls`` from a mapping; missing keys take defaults, unknown keys are errors."""
    data = dict(data or {})
    types_ = _field_types(cls)
    unknown = sorted(set(data) - set(types_))
    if unknown:
        where = f"{path}." if path else ""
        raise ConfigError(
            f"unknown config key{'s' if len(unknown) > 1 else ''} "
            f"{', '.join(repr(where + k) for k in unknown)}; valid keys here: {', '.join(sorted(types_))}")
    kwargs = {}
    for name, tp in types_.items():
        if name in data:
            kwargs[name] = _coerce(data[name], tp, f"{path}.{name}" if path else name)
    try:
        return cls(**kwargs)
    except ConfigError:
        raise
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{path or cls.__name__}: {exc}") from exc


def to_dict(cfg: Any) -> Any:
    """Dataclass tree to plain YAML/JSON-serialisable values (tuples become lists)."""
    if dataclasses.is_dataclass(cfg):
        return {f.name: to_dict(getattr(cfg, f.name)) for f in dataclasses.fields(cfg)}
    if isinstance(cfg, (list, tuple)):
        return [to_dict(v) for v in cfg]
    if isinstance(cfg, Mapping):
        return {k: to_dict(v) for k, v in cfg.items()}
    return cfg


def _set_path(tree: dict, dotted: str, value: Any, cls: type) -> None:
    keys = dotted.split(".")
    node, node_cls = tree, cls
    for i, key in enumerate(keys):
        types_ = _field_types(node_cls) if dataclasses.is_dataclass(node_cls) else None
        if types_ is None or key not in types_:
            here = ".".join(keys[:i]) or "<root>"
            valid = ", ".join(sorted(types_)) if types_ else "(none: not a config section)"
            raise ConfigError(f"unknown config key {dotted!r} (no {key!r} under {here}; valid: {valid})")
        if i == len(keys) - 1:
            node[key] = value
        else:
            child_tp = types_[key]
            if not dataclasses.is_dataclass(child_tp):
                raise ConfigError(f"config key {'.'.join(keys[:i + 1])!r} is a value, not a section")
            node = node.setdefault(key, {})
            node_cls = child_tp


def parse_overrides(overrides: Iterable[str]) -> list[tuple[str, Any]]:
    """Parse ``key.sub=value`` strings; values are read as YAML scalars/lists (``[1, 2]``, ``true``)."""
    out = []
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"override {item!r} is not of the form key=value")
        key, raw = item.split("=", 1)
        key = key.strip()
        if not key:
            raise ConfigError(f"override {item!r} has an empty key")
        try:
            value = yaml.safe_load(raw) if raw.strip() else ""
        except yaml.YAMLError as exc:
            raise ConfigError(f"override {item!r}: cannot parse value ({exc})") from exc
        out.append((key, value))
    return out


def merge(base: dict, update: Mapping) -> dict:
    """Deep-merge ``update`` into a copy of ``base``."""
    out = dict(base)
    for k, v in update.items():
        out[k] = merge(out[k], v) if isinstance(v, Mapping) and isinstance(out.get(k), dict) else v
    return out


def with_overrides(cfg: T, overrides: Iterable[str] | Mapping[str, Any]) -> T:
    """Return a new config with dotted-key overrides applied and re-validated."""
    pairs = list(overrides.items()) if isinstance(overrides, Mapping) else parse_overrides(overrides)
    patch: dict = {}
    for key, value in pairs:
        _set_path(patch, key, value, type(cfg))
    return from_dict(type(cfg), merge(to_dict(cfg), patch))


def read_config_file(path: str | Path) -> dict:
    """The top-level mapping of a YAML config file; errors name the file."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"config file {str(p)!r} does not exist")
    try:
        loaded = yaml.safe_load(p.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"config file {str(p)!r} is not valid YAML: {exc}") from exc
    if loaded is not None and not isinstance(loaded, Mapping):
        raise ConfigError(f"config file {str(p)!r} must hold a mapping at the top level, "
                          f"not a {type(loaded).__name__}")
    return dict(loaded or {})


def load_config(cls: type[T], path: str | Path | None = None, overrides: Iterable[str] = (),
                ignore: Iterable[str] = ()) -> T:
    """Defaults, then a YAML file (if given; a scenario file), then ``key=value`` overrides.

    ``ignore`` names top-level keys the file may hold that are not part of the schema (a run
    folder's provenance: version, git commit); they are dropped. Any other unknown key, or a bad
    value, is a ConfigError naming the file and the key."""
    data: dict = {}
    if path is not None:
        data = read_config_file(path)
        for key in ignore:
            data.pop(key, None)
        try:
            cfg = from_dict(cls, data)
        except ConfigError as exc:
            raise ConfigError(f"config file {str(path)!r}: {exc}") from None
    else:
        cfg = from_dict(cls, data)
    return with_overrides(cfg, overrides)


def dump_yaml(cfg: Any) -> str:
    return yaml.safe_dump(to_dict(cfg), sort_keys=False)
