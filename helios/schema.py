"""Configuration machinery (not a config tree itself): frozen dataclasses are the schema; YAML
files and ``key=value`` overrides fill them in; unknown keys and ill-typed values are errors that name the offending key.

Every config tree in the project (method hyper-parameters, simulator, robot motion limits, trial
settings) is a frozen dataclass built with these helpers, so a run's resolved configuration can be
saved as YAML and loaded back bit for bit (Drake ``yaml_load_typed`` style, without Drake).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
import types
import typing
from pathlib import Path
from types import MappingProxyType
from typing import Any, Iterable, Mapping, TypeVar

import yaml

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration value or key is invalid. The message names the key path."""


class ConfigValueError(ConfigError):
    """A value a config dataclass's own check refused (:func:`require`, :func:`require_range`); a
    ConfigError (so a command line reports it in one line) that :func:`from_dict` prefixes with the
    config section."""


def shorten(text: object, limit: int = 120) -> str:
    """``text`` as one line of at most ``limit`` characters: long user input (a 10,000-character
    task string, a binary file's first line) is cut in the middle so error messages stay readable."""
    s = " ".join(str(text).split("\n"))
    if len(s) <= limit:
        return s
    keep = max(8, limit - 30)
    return f"{s[:keep * 2 // 3]}...({len(s) - keep} more characters)...{s[len(s) - keep // 3:]}"


def short_repr(value: object, limit: int = 120) -> str:
    """``repr(value)`` shortened with :func:`shorten`."""
    return shorten(repr(value), limit)


def finite(*values: float) -> bool:
    """All values are finite numbers (for ``require`` in config checks)."""
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values)


def require_range(obj: object, names: str, lo: float | None = None, hi: float | None = None, *,
                  lo_open: bool = False, hi_open: bool = False) -> None:
    """Validation step of a config dataclass's ``__post_init__``: each field in ``names`` (space
    separated) is a finite number within [lo, hi] (``lo_open``/``hi_open``: the bound is excluded;
    None: unbounded); otherwise ``ValueError`` naming the field, its range and its value."""
    for name in names.split():
        v = getattr(obj, name)
        ok = finite(v) and (lo is None or (v > lo if lo_open else v >= lo)) and (
            hi is None or (v < hi if hi_open else v <= hi))
        if not ok:
            if lo is not None and hi is not None:
                rng = f"in {'(' if lo_open else '['}{_num(lo)}, {_num(hi)}{')' if hi_open else ']'}"
            elif lo is not None:
                rng = f"{'>' if lo_open else '>='} {_num(lo)}"
            else:
                rng = f"{'<' if hi_open else '<='} {_num(hi)}"
            raise ConfigValueError(f"{name} must be {rng}, got {short_repr(v, 40)}")


def _num(v: float) -> str:
    """A bound as people write it: 4294967295, 1000000, 0.001, 3.14159."""
    if isinstance(v, int) or (float(v).is_integer() and abs(v) < 1e16):
        return str(int(v))
    return f"{v:.6g}"


def require(condition: bool, message: str) -> None:
    """Validation step of a config dataclass's ``__post_init__``: raise ``ConfigValueError(message)``
    (a ValueError) unless ``condition`` holds (:func:`from_dict` reports it naming the section)."""
    if not condition:
        raise ConfigValueError(message)


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def finite_number(value: Any) -> bool:
    """A real number (not a bool) that is finite, also as a float: ``math.isfinite(10**400)``
    raises OverflowError, which reached users of episode files and run folders as a traceback."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


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
        raise ConfigError(f"{path}: {short_repr(value)} matches none of {[_type_name(a) for a in args]}")
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(f"{path}: {short_repr(value)} is not one of {list(args)}")
        return value
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, Mapping):
            raise ConfigError(f"{path}: expected a mapping for {tp.__name__}, got {type(value).__name__}")
        return from_dict(tp, value, path)
    if origin in (tuple, list):
        if isinstance(value, (str, bytes)) or not isinstance(value, Iterable):
            raise ConfigError(f"{path}: expected a list, got {short_repr(value)}")
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
            raise ConfigError(f"{path}: expected a mapping, got {short_repr(value)}")
        kt, vt = args if args else (Any, Any)
        return {_coerce(k, kt, path): _coerce(v, vt, f"{path}.{k}") for k, v in value.items()}
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{path}: expected true/false, got {short_repr(value)}")
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise ConfigError(f"{path}: expected an integer, got {short_repr(value)}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{path}: expected a number, got {short_repr(value)}")
        try:
            value = float(value)
        except OverflowError:                    # an int too large for a float
            raise ConfigError(f"{path}: {short_repr(value, 40)} is too large") from None
        if math.isnan(value):
            raise ConfigError(f"{path}: NaN is not a valid value")
        if math.isinf(value):
            raise ConfigError(f"{path}: {value} is not a valid value (numbers must be finite)")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{path}: expected a string, got {short_repr(value)}")
        return value
    if isinstance(tp, type) and isinstance(value, tp):
        return value
    raise ConfigError(f"{path}: cannot interpret {short_repr(value)} as {_type_name(tp)}")


@functools.lru_cache(maxsize=None)
def _field_types(cls: type) -> Mapping[str, Any]:
    """The init fields' resolved types (read-only). Cached per class: ``typing.get_type_hints``
    re-evaluates every annotation string each call, and a trial configuration's ~30 nested classes
    are built on every command, override and config read (10 of the bad-input corpus's 137 s)."""
    hints = typing.get_type_hints(cls)
    return MappingProxyType({f.name: hints[f.name] for f in dataclasses.fields(cls) if f.init})


def from_dict(cls: type[T], data: Mapping[str, Any] | None, path: str = "") -> T:
    """Build dataclass ``cls`` from a mapping; missing keys take defaults, unknown keys are errors."""
    data = dict(data or {})
    types_ = _field_types(cls)
    unknown = sorted(set(data) - set(types_))
    if unknown:
        where = f"{path}." if path else ""
        raise ConfigError(
            f"unknown config key{'s' if len(unknown) > 1 else ''} "
            f"{', '.join(short_repr(where + str(k), 60) for k in unknown[:5])}"
            f"{f' (and {len(unknown) - 5} more)' if len(unknown) > 5 else ''}; valid keys here: {', '.join(sorted(types_))}")
    kwargs = {}
    for name, tp in types_.items():
        if name in data:
            kwargs[name] = _coerce(data[name], tp, f"{path}.{name}" if path else name)
    try:
        return cls(**kwargs)
    except ConfigValueError as exc:
        raise ConfigError(f"{path or cls.__name__}: {shorten(exc, 300)}") from None
    except ConfigError:
        raise
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{path or cls.__name__}: {shorten(exc, 300)}") from None


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
            raise ConfigError(f"unknown config key {short_repr(dotted, 80)} (no {short_repr(key, 60)} under "
                              f"{shorten(here, 60)}; valid: {valid})")
        if i == len(keys) - 1:
            node[key] = value
        else:
            child_tp = types_[key]
            if not dataclasses.is_dataclass(child_tp):
                raise ConfigError(f"config key {short_repr('.'.join(keys[:i + 1]), 80)} is a value, not a section")
            node = node.setdefault(key, {})
            node_cls = child_tp


def parse_overrides(overrides: Iterable[str]) -> list[tuple[str, Any]]:
    """Parse ``key.sub=value`` strings; values are read as YAML scalars/lists (``[1, 2]``, ``true``)."""
    out = []
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"override {short_repr(item)} is not of the form key=value")
        key, raw = item.split("=", 1)
        key = key.strip()
        if not key:
            raise ConfigError(f"override {short_repr(item)} has an empty key")
        try:
            value = load_yaml(raw) if raw.strip() else ""
        except yaml.YAMLError as exc:
            raise ConfigError(f"override {short_repr(item)}: cannot parse value "
                              f"({shorten(getattr(exc, 'problem', None) or exc, 100)})") from None
        except YAML_VALUE_ERRORS as exc:      # seed=2024-13-45, seed='!!float abc', seed='!!float ""', deep nesting
            raise ConfigError(f"override {short_repr(item)}: cannot parse value "
                              f"({shorten(exc, 100) or type(exc).__name__})") from None
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
    """The top-level mapping of a YAML config file; errors name the file. An empty file is refused
    rather than read as "all defaults": an explicit `{}` says that."""
    p = Path(path)
    name = short_repr(str(p))
    if p.is_dir():
        raise ConfigError(f"config file {name} is a directory, not a YAML file")
    if not p.is_file():     # /dev/null, a FIFO (reading one would block), a socket: not a config file
        raise ConfigError(f"config file {name} {'is not a regular file' if p.exists() else 'does not exist'}")
    loaded = yaml_load_text(read_text(p, f"config file {name}"), f"config file {name}", ConfigError)
    if loaded is None:      # empty or comments only: most likely the wrong file, or a save that failed
        raise ConfigError(f"config file {name} holds no settings (empty or only comments); "
                          "write '{}' in it to mean all defaults, or do not give the file")
    if not isinstance(loaded, Mapping):
        raise ConfigError(f"config file {str(p)!r} must hold a mapping at the top level, "
                          f"not a {type(loaded).__name__}")
    return dict(loaded)


def read_text(path: str | Path, what: str, error: type[Exception] = ConfigError) -> str:
    """A text file's contents, which must be UTF-8; otherwise ``error`` naming ``what`` and where
    the first bad byte is (never a UnicodeDecodeError traceback)."""
    p = Path(path)
    if p.exists() and not p.is_file() and not p.is_dir():     # reading a FIFO would wait for a writer
        raise error(f"{what} is not a regular file (a FIFO, device or socket)")
    try:
        data = p.read_bytes()
    except IsADirectoryError:
        raise error(f"{what} is a directory, not a file") from None
    except OSError as exc:
        raise error(f"cannot read {what}: {exc.strerror or exc}") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise error(f"{what} is not UTF-8 text (byte 0x{data[exc.start]:02x} on line {line}); "
                    f"is it the right file?") from None


class UniqueKeyLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses a mapping holding the same key twice (PyYAML keeps the last
    one silently: ``runner: {max_sim_time: 10}`` then ``runner: {max_commands: 5}`` would drop
    max_sim_time). Keys brought in by a merge (``<<: *base``) may be overridden, as YAML intends."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict = {}
            for key_node, _ in node.value:
                if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=deep)
                try:
                    first = seen.setdefault(key, key_node)
                except TypeError:                # an unhashable key: the base class says so
                    continue
                if first is not key_node:
                    raise yaml.constructor.ConstructorError(
                        "while constructing a mapping", node.start_mark,
                        f"found duplicate key {short_repr(key, 60)} (first on line {first.start_mark.line + 1})",
                        key_node.start_mark)
        return super().construct_mapping(node, deep=deep)


# Numbers as YAML 1.2 reads them, not PyYAML's YAML 1.1: `seed=010` was seed 8 (octal), `1:30` was 90
# (base 60), `0x10` 16, while `1e3` was the text '1e3'. Integers are decimal only; floats are written
# with a dot or an exponent (or .inf/.nan); anything else is text, which a numeric setting refuses.
_INT_TAG, _FLOAT_TAG = "tag:yaml.org,2002:int", "tag:yaml.org,2002:float"
_DECIMAL_INT = re.compile(r"^[-+]?[0-9]+$")
_FLOAT_12 = re.compile(r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
                       r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$")


def _numbers_as_yaml_1_2(cls: type) -> None:
    """Give a PyYAML loader or dumper class the YAML 1.2 number resolvers (the dumper's decide
    which strings it must quote, so what it writes reads back the same)."""
    cls.yaml_implicit_resolvers = {
        first: [(tag, rx) for tag, rx in resolvers if tag not in (_INT_TAG, _FLOAT_TAG)]
        for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}
    cls.add_implicit_resolver(_INT_TAG, _DECIMAL_INT, list("-+0123456789"))
    cls.add_implicit_resolver(_FLOAT_TAG, _FLOAT_12, list("-+0123456789."))


def _decimal_int(loader, node) -> int:
    text = loader.construct_scalar(node)
    if not _DECIMAL_INT.match(text):                  # an explicit `!!int 0x10`
        raise yaml.constructor.ConstructorError(None, None, f"{short_repr(text, 40)} is not a decimal integer",
                                                node.start_mark)
    return int(text)


def _explicit_scalar(tag: str, what: str, valid) -> None:
    """Check the text of an explicitly tagged scalar before PyYAML's constructor reads it: given
    text it cannot read, it crashed (``seed=!!float ""`` an IndexError, ``!!bool x`` a KeyError,
    ``!!timestamp x`` an AttributeError) instead of refusing it."""
    construct = yaml.SafeLoader.yaml_constructors[tag]

    def checked(loader, node):
        text = loader.construct_scalar(node)
        if not valid(text):
            raise yaml.constructor.ConstructorError(None, None, f"{short_repr(text, 40)} is not {what}",
                                                    node.start_mark)
        return construct(loader, node)
    UniqueKeyLoader.add_constructor(tag, checked)


_numbers_as_yaml_1_2(UniqueKeyLoader)
UniqueKeyLoader.add_constructor(_INT_TAG, _decimal_int)
_explicit_scalar(_FLOAT_TAG, "a number (YAML 1.2: digits with a dot or an exponent, .inf, .nan)",
                 lambda t: bool(_FLOAT_12.match(t) or _DECIMAL_INT.match(t)))
_explicit_scalar("tag:yaml.org,2002:bool", "true or false",
                 lambda t: t.lower() in yaml.constructor.SafeConstructor.bool_values)
_explicit_scalar("tag:yaml.org,2002:timestamp", "a date (YYYY-MM-DD, optionally with a time)",
                 lambda t: bool(yaml.constructor.SafeConstructor.timestamp_regexp.match(t)))


class _ConfigDumper(yaml.SafeDumper):
    """``yaml.SafeDumper`` that quotes what :class:`UniqueKeyLoader` would read as a number."""


_numbers_as_yaml_1_2(_ConfigDumper)


# What PyYAML's safe constructors raise, besides YAMLError, for a value they cannot build: ValueError
# (a date out of range: seed=2024-13-45), TypeError, RecursionError (deep nesting); IndexError,
# KeyError and AttributeError are what they raised on tagged text :func:`_explicit_scalar` now
# refuses first, kept so that any other such text is one line too.
YAML_VALUE_ERRORS = (ValueError, TypeError, IndexError, KeyError, AttributeError, RecursionError)

try:
    from yaml.cyaml import CParser as _CParser
except ImportError:                      # a PyYAML built without libyaml: the pure-Python loader only
    _CParser = None

if _CParser is not None:
    class _LibyamlUniqueKeyLoader(_CParser, UniqueKeyLoader):
        """:class:`UniqueKeyLoader` with libyaml's scanner and parser (the composer, resolver and
        constructor stay PyYAML's own Python, so the same nodes, tags and values): 7x faster on a
        run folder's config.yaml (3.6 against 27 ms), which every resume, report and diff reads."""

        def __init__(self, stream):
            _CParser.__init__(self, stream)
            yaml.constructor.SafeConstructor.__init__(self)
            yaml.resolver.Resolver.__init__(self)

# Text libyaml reads exactly as PyYAML's pure-Python scanner does (differential fuzzes of 150,000
# and 60,000 mutated configs found no difference within it): printable ASCII and newlines, no tag
# ('!'), no block scalar ('|', '>') and no '?'. Outside it the two differ (libyaml takes tabs and a
# BOM mid-text that PyYAML refuses, and a '?' inside a flow collection as part of a word: '[a?b]';
# tags and block-scalar headers are read differently), so such text takes the Python loader, as
# does text that could nest deeper than libyaml's C recursion survives (100,000 nested '[' crash
# the process; every nesting level needs one of '[{-:'), and a value libyaml read nested deeper
# than the Python loader's recursion reaches for certain (it refuses from about 500 levels).
_LIBYAML_SAFE = re.compile(r"[\n\x20\x22-\x3d\x40-\x7b\x7d\x7e]*\Z")
_LIBYAML_MAX_NESTING_MARKS = 2000
_LIBYAML_MAX_DEPTH = 100


def _deeper_than(value, limit: int) -> bool:
    """Whether lists and mappings nest more than ``limit`` deep in ``value`` (iterative: a YAML
    anchor can make a list that holds itself)."""
    stack, seen = [(value, 0)], set()
    while stack:
        v, depth = stack.pop()
        if isinstance(v, (dict, list)) and id(v) not in seen:
            if depth >= limit:
                return True
            seen.add(id(v))
            stack.extend((c, depth + 1) for c in (v.values() if isinstance(v, dict) else v))
    return False


def load_yaml(text: str):
    """``yaml.load`` with :class:`UniqueKeyLoader` (the YAML 1.2 numbers, duplicate keys refused),
    through libyaml where the text allows (:data:`_LIBYAML_SAFE`); its errors, and those of text
    libyaml refuses, are always the pure-Python loader's own (the messages name its wording)."""
    if (_CParser is not None and _LIBYAML_SAFE.match(text)
            and sum(map(text.count, "[{-:")) < _LIBYAML_MAX_NESTING_MARKS):
        try:
            value = yaml.load(text, Loader=_LibyamlUniqueKeyLoader)
        except (yaml.YAMLError, *YAML_VALUE_ERRORS):
            pass
        else:
            if not _deeper_than(value, _LIBYAML_MAX_DEPTH):
                return value
    return yaml.load(text, Loader=UniqueKeyLoader)


def yaml_load_text(text: str, what: str, error: type[Exception] = ConfigError):
    """``yaml.safe_load`` (refusing duplicate keys: :class:`UniqueKeyLoader`) whose errors are one
    line naming ``what`` and the line."""
    try:
        return load_yaml(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or type(exc).__name__
        raise error(f"{what} is not valid YAML{where}: {shorten(problem, 100)}") from None
    except YAML_VALUE_ERRORS as exc:     # e.g. a date out of range, an empty `!!float`
        raise error(f"{what} is not valid YAML: {shorten(exc, 100) or type(exc).__name__}") from None


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
            raise ConfigError(f"config file {short_repr(str(path))}: {exc}") from None
    else:
        cfg = from_dict(cls, data)
    return with_overrides(cfg, overrides)


def dump_yaml(cfg: Any) -> str:
    return yaml.dump(to_dict(cfg), Dumper=_ConfigDumper, sort_keys=False)
