"""Which TrialConfig settings an agent reads while it runs: the evidence behind the refusal lists.

``tools trials`` refuses a setting its agent never reads (``tasks.registry.replaced_settings``,
``unread_settings``), so that config.yaml never records a setting that changed nothing. A list
made by reading the code alone can be wrong the other way, refusing a setting some rare branch
does read, which is worse than the gap it closes. :class:`ReadTracer` records, while real
episodes run, every read of a field of the ``agent_config``, ``helios`` and ``perception`` config
trees as its dotted key (``helios.decision.tau_object``), so a test can check that no refused
setting is read (tests/test_config_reads.py) and a session can see what an agent reads over
more episodes (:func:`traced_run`).

How: each dataclass of those trees gets a ``__getattribute__`` for the duration of the ``with``
block. The hook works per class, not per object: the agent derives configs with
``dataclasses.replace`` (the body's grown footprint, the coarser render config), and a read of
such a copy is a read of the setting it came from. Each class sits at one place in the trees
(checked by :func:`config_classes`). Reads that are not the agent's use are left out: a config
checking its own values (``__post_init__``, ``helios.schema``'s range checks), copying it
(``dataclasses``) or printing it (``__repr__``). A config's generated ``__eq__`` or ``__hash__``
(the config as a cache key) reads every field and counts as reading them all: the value then can
change what the agent does. Only this process is traced, so :func:`traced_run` runs its episodes
here (``tools trials --workers`` would run them in other processes).
"""

from __future__ import annotations

import dataclasses
import sys
from collections import defaultdict
from typing import Iterable

SECTIONS = ("agent_config", "helios", "perception")
"""The TrialConfig sections that configure the agent (the ones the refusal lists name)."""

NOT_A_USE_MODULES = frozenset({"dataclasses", "helios.schema"})
"""Modules whose reads copy or check a config rather than use it."""
NOT_A_USE_FUNCTIONS = frozenset({"__post_init__", "__repr__"})
"""Functions whose reads check or print a config rather than use it."""


def config_classes(config=None) -> dict[type, str]:
    """Each dataclass in the agent's sections of ``config`` (a TrialConfig; default: the defaults)
    -> its dotted path. A class found at two paths is an error: a read of it could not be told
    apart (and would have to count for both)."""
    from tasks.trial_config import TrialConfig

    config = config if config is not None else TrialConfig()
    out: dict[type, str] = {}

    def walk(obj, path: str) -> None:
        cls = type(obj)
        if cls in out and out[cls] != path:
            raise ValueError(f"{cls.__qualname__} sits at {out[cls]} and at {path}: its reads cannot be told apart")
        out[cls] = path
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            if dataclasses.is_dataclass(value) and not isinstance(value, type):
                walk(value, f"{path}.{f.name}")

    for section in SECTIONS:
        walk(getattr(config, section), section)
    return out


class ReadTracer:
    """Records the settings read inside a ``with`` block: ``reads`` maps each dotted key to the
    modules (``module:function``) that read it. Not thread-safe, not re-entrant; the hooks are
    removed on leaving the block, whatever happens inside."""

    def __init__(self, config=None):
        self.classes = config_classes(config)
        self.reads: dict[str, set[str]] = defaultdict(set)
        self._saved: dict[type, object] = {}

    def __enter__(self) -> "ReadTracer":
        for cls, path in self.classes.items():
            self._saved[cls] = cls.__dict__.get("__getattribute__")
            cls.__getattribute__ = self._hook(cls, path)
        return self

    def __exit__(self, *exc) -> None:
        for cls, own in self._saved.items():
            if own is None:
                del cls.__getattribute__
            else:
                cls.__getattribute__ = own
        self._saved.clear()

    def _hook(self, cls: type, path: str):
        fields = frozenset(f.name for f in dataclasses.fields(cls))
        plain = cls.__getattribute__          # the inherited one (object's), or the class's own
        reads = self.reads

        def getattribute(obj, name):
            if name in fields:
                frame = sys._getframe(1)
                module = frame.f_globals.get("__name__", "?")
                function = frame.f_code.co_name
                if module not in NOT_A_USE_MODULES and function not in NOT_A_USE_FUNCTIONS:
                    reads[f"{path}.{name}"].add(f"{module}:{function}")
            return plain(obj, name)

        return getattribute

    def read(self, key: str) -> bool:
        """Whether ``key`` (a setting or a whole section) or anything under it was read."""
        return any(r == key or r.startswith(key + ".") for r in self.reads)


def refused_as_unread(config) -> dict[str, str]:
    """The settings a run of ``config`` refuses because its agent never reads them -> why: the
    sections :func:`tasks.registry.replaced_settings` marks IGNORED and the keys of
    :func:`tasks.registry.unread_settings`. (Settings an agent forces are read, at its own value.)"""
    from tasks.registry import IGNORED, replaced_settings, unread_settings

    out = {key: "section ignored" for key, v in replaced_settings(config.agent).items() if v is IGNORED}
    out.update(unread_settings(config))
    return out


def traced_run(config, episodes: Iterable) -> ReadTracer:
    """Run ``episodes`` (``tasks.episodes.Episode``) with ``config`` as ``tools trials`` runs them
    (``tasks.trials.run_one``: the agent built from the config, then the episode, with the data of
    its pictures as by default, whose drawing reads the map), recording what is read. An episode
    that ends on an error raises it: a trace of a broken run proves nothing."""
    from tasks.trials import run_one

    tracer = ReadTracer(config)
    for episode in episodes:
        with tracer:
            record = run_one(config, episode, pictures=True)
        if record.get("error"):
            raise RuntimeError(f"{episode.episode_id} with {config.agent}: {record['error']}")
    return tracer
