"""Agents of your own in ``tools trials``, without editing this repository: ``--agent FILE.py:FACTORY``
(a Python file) or ``--agent package.module:FACTORY`` (a module on the Python path, e.g. one in the
folder the command runs from). Why: the benchmark is for ranking search policies, and the policy a
researcher wants ranked is usually their own; the run folder, the resumable batch, the judge and
``tools report``'s paired tests then treat it as they treat HELIOS and its ablations.

The factory is called as the registered ones are (``tasks.registry``): ``FACTORY(context,
**options)`` once per episode, with an ``AgentContext`` (the episode, the simulator's ground truth
for simulated perception, the episode's seed), and returns an agent with ``reset(task, rng)`` and
``act(robot) -> bool`` (``tasks.runner.Agent``; ``decision_stats()``, ``memory_bytes()`` and the
rest are optional); its ``name`` is set to the ``--agent`` given, which the records carry. The shortest one builds on a registered agent, e.g. HELIOS with a search
policy of its own (``examples/nearest_first.py``)::

    def make(context, **options):
        return make_agent("helios", context, search_policy=NearestFirst, **options)
    make.reads = ("agent_config", "helios", "perception")

``FACTORY.reads`` names the TrialConfig sections the agent takes (any of ``agent_config``,
``helios``, ``perception``; none when absent): they reach the factory as the options
``agent_config``, ``method_config`` and ``perception_config``, and a run that sets a section the
agent does not read is refused before it starts, as for the oracle (config.yaml never records a
setting that changed nothing).

Provenance: the agent's code is not in the repository's commit, so each ``tools trials``
invocation logs the sha256 of its source file (``agent_source`` in invocations.jsonl); a resume
with other source says that the folder's episodes come from two versions of the agent (as for a
changed commit), and ``--replace-stale`` moves such a folder aside.

Where it runs: local worker processes (spawned, in the working directory the command runs in).
Ray workers may run on other machines, which need not have the file: refused with one line.
Not on a robot: ``tools spot`` takes registered agents only.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import importlib.util
import sys
import traceback
from pathlib import Path
from typing import Callable

from helios.schema import short_repr

SECTION_OPTIONS = {"agent_config": "agent_config", "helios": "method_config", "perception": "perception_config"}
"""TrialConfig sections an agent may read (``FACTORY.reads``) -> the factory's option for it."""


class PluginAgentError(ValueError):
    """An ``--agent FILE.py:FACTORY`` that cannot be used (one line says why; bad input, as the
    registry's ``UnknownAgentError``)."""


def is_plugin_spec(name: str) -> bool:
    """Whether an agent name is a plugin (``SOURCE:FACTORY``); registered names hold no colon (the
    one test for it: every command asks this)."""
    return ":" in str(name)


def parse_spec(spec: str) -> tuple[str, str, bool]:
    """``(source, factory name, is_file)`` of ``SOURCE:FACTORY``; PluginAgentError when malformed."""
    source, _, attr = str(spec).rpartition(":")
    source = source.strip()
    shown = short_repr(spec, 80)
    if not source or not attr:
        raise PluginAgentError(f"agent {shown}: give your own agent as FILE.py:FACTORY or package.module:FACTORY "
                               f"(a file or module, a colon, the name of its factory function)")
    if not attr.isidentifier():
        raise PluginAgentError(f"agent {shown}: {short_repr(attr, 40)} is not a Python name; after the colon give the "
                               f"name of the factory function in {short_repr(source, 60)}")
    if source.endswith(".py"):
        return source, attr, True
    if not all(part.isidentifier() for part in source.split(".")):
        raise PluginAgentError(f"agent {shown}: {short_repr(source, 60)} is neither a .py file nor a module name "
                               f"(package.module)")
    return source, attr, False


def canonical_spec(spec: str) -> str:
    """One spelling of a plugin however its file is named (relative to the working directory when
    the file lies under it, else absolute: ``tasks.trial_config.canonical_episodes_file``), so
    that the same agent gives the same configuration fingerprint; a module spec stays as given."""
    from tasks.trial_config import canonical_episodes_file

    source, attr, is_file = parse_spec(spec)
    return f"{canonical_episodes_file(source)}:{attr}" if is_file else f"{source}:{attr}"


_LOADED: dict[tuple[str, str], tuple[int, Callable]] = {}


def _source_path(spec: str) -> Path | None:
    source, _, is_file = parse_spec(spec)
    if is_file:
        return Path(source)
    found = importlib.util.find_spec(source) if _module_findable(source) else None
    return Path(found.origin) if found is not None and found.origin not in (None, "built-in", "frozen") else None


def _module_findable(name: str) -> bool:
    """Whether module ``name`` can be imported (finding ``pkg.mod`` imports ``pkg``)."""
    try:
        with _no_bytecode():
            return importlib.util.find_spec(name) is not None
    except Exception:  # noqa: BLE001 - ImportError, or whatever the package's __init__ raises
        return False


def _import_error(spec: str, where: str, exc: BaseException, doing: str = "importing it") -> PluginAgentError:
    """One line for an exception raised while importing the agent's source (or calling its
    factory: ``doing``): its type, message and the deepest line of the traceback that lies in
    ``where`` (the agent's file), if any."""
    line = ""
    for frame in reversed(traceback.extract_tb(exc.__traceback__)):
        if where and Path(frame.filename).resolve() == Path(where).resolve():
            line = f" (line {frame.lineno})"
            break
    if isinstance(exc, SyntaxError) and exc.lineno:
        line = f" (line {exc.lineno})"
    message = exc.msg if isinstance(exc, SyntaxError) and exc.msg else (str(exc).splitlines() or [""])[0]
    return PluginAgentError(f"agent {short_repr(spec, 80)}: {doing} raised {type(exc).__name__}{line}"
                            f"{': ' + short_repr(message, 120) if message else ''}")


@contextlib.contextmanager
def _no_bytecode():
    """Import the agent's code without writing ``__pycache__`` next to it: the command that checks
    (and refuses) an agent leaves the user's folder as it was."""
    before = sys.dont_write_bytecode
    sys.dont_write_bytecode = True
    try:
        yield
    finally:
        sys.dont_write_bytecode = before


def _import(spec: str):
    source, attr, is_file = parse_spec(spec)
    shown = short_repr(spec, 80)
    if is_file:
        path = Path(source)
        if not path.is_file():
            raise PluginAgentError(f"agent {shown}: no such file {short_repr(source, 80)}"
                                   + (" (it is a folder)" if path.is_dir() else ""))
        resolved = path.resolve()
        name = "helios_agent_plugin_" + hashlib.sha1(str(resolved).encode()).hexdigest()[:12]
        module_spec = importlib.util.spec_from_file_location(name, resolved)
        if module_spec is None or module_spec.loader is None:
            raise PluginAgentError(f"agent {shown}: {short_repr(source, 80)} cannot be imported as a Python file")
        module = importlib.util.module_from_spec(module_spec)
        sys.modules[name] = module          # dataclasses and pickling look their module up by name
        try:
            with _no_bytecode():
                module_spec.loader.exec_module(module)
        except BaseException as exc:  # noqa: BLE001 - whatever the file raises, one line
            sys.modules.pop(name, None)
            if isinstance(exc, KeyboardInterrupt):
                raise
            raise _import_error(spec, str(resolved), exc) from None
    else:
        if not _module_findable(source):
            raise PluginAgentError(f"agent {shown}: no module {short_repr(source, 60)} on the Python path (run from the "
                                   f"folder that holds it, set PYTHONPATH, or give FILE.py:FACTORY)")
        try:
            with _no_bytecode():
                loaded = sys.modules.get(source)       # imported before: its file changed since (load_factory)
                module = importlib.reload(loaded) if loaded is not None else importlib.import_module(source)
        except BaseException as exc:  # noqa: BLE001
            if isinstance(exc, KeyboardInterrupt):
                raise
            raise _import_error(spec, str(_source_path(spec) or ""), exc) from None
    factory = getattr(module, attr, None)
    if factory is None:
        names = sorted(n for n, v in vars(module).items() if callable(v) and not n.startswith("_")
                       and getattr(v, "__module__", None) == module.__name__)
        raise PluginAgentError(f"agent {shown}: {short_repr(source, 60)} has no {attr!r}"
                               + (f"; its functions and classes: {', '.join(names[:12])}" if names else ""))
    if not callable(factory):
        raise PluginAgentError(f"agent {shown}: {attr!r} in {short_repr(source, 60)} is a value of type "
                               f"{type(factory).__name__}, not a factory function")
    plugin_reads(spec, factory)         # checked now, not at the first episode
    return factory


def load_factory(spec: str) -> Callable:
    """The factory ``spec`` names, imported once per process (again if its file changed since)."""
    source, attr, _ = parse_spec(spec)
    path = _source_path(spec)
    try:
        stamp = path.stat().st_mtime_ns if path is not None else 0
    except OSError:
        stamp = -1
    cached = _LOADED.get((source, attr))
    if cached is not None and cached[0] == stamp:
        return cached[1]
    factory = _import(spec)
    _LOADED[(source, attr)] = (stamp, factory)
    return factory


def plugin_reads(spec: str, factory: Callable | None = None) -> tuple[str, ...]:
    """The TrialConfig sections the plugin's agent reads (``FACTORY.reads``), checked."""
    factory = factory if factory is not None else load_factory(spec)
    reads = getattr(factory, "reads", ())
    if isinstance(reads, str) or not isinstance(reads, (tuple, list, set, frozenset)):
        raise PluginAgentError(f"agent {short_repr(spec, 80)}: its reads must be a tuple of section names "
                               f"({', '.join(SECTION_OPTIONS)}), got {short_repr(reads, 60)}")
    unknown = [r for r in reads if r not in SECTION_OPTIONS]
    if unknown:
        raise PluginAgentError(f"agent {short_repr(spec, 80)}: its reads names {short_repr(unknown[0], 40)}, not a "
                               f"section an agent can read ({', '.join(SECTION_OPTIONS)})")
    return tuple(s for s in SECTION_OPTIONS if s in reads)


def source_digest(spec: str) -> str | None:
    """sha256 (16 hex digits) of the plugin's source file; None when it has none to read."""
    path = _source_path(spec)
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()[:16] if path is not None else None
    except OSError:
        return None


def make_plugin_factory(spec: str) -> Callable:
    """A registry factory for ``spec``: calls the plugin's factory with the options of the sections
    it reads and checks that what it returns can run an episode."""
    load_factory(spec)                  # errors now, in the process that checks the command line

    def factory(context, **options):
        user = load_factory(spec)
        reads = plugin_reads(spec, user)
        given = {option: options[option] for section, option in SECTION_OPTIONS.items()
                 if section in reads and options.get(option) is not None}
        try:
            agent = user(context, **given)
        except Exception as exc:  # noqa: BLE001 - the batch stops on it with one line naming the file's line
            path = _source_path(spec)
            raise _import_error(spec, str(path or ""), exc, f"{parse_spec(spec)[1]}()") from None
        missing = [m for m in ("reset", "act") if not callable(getattr(agent, m, None))]
        if missing:
            raise PluginAgentError(f"agent {short_repr(spec, 80)}: {parse_spec(spec)[1]}() returned an object of type "
                                   f"{type(agent).__name__} without {' and '.join(m + '()' for m in missing)}; an "
                                   f"agent needs reset(task, rng) and act(robot) -> bool (tasks.runner.Agent)")
        try:                            # records name the run's agent, not what it was built from
            agent.name = spec
        except AttributeError:
            agent = _Named(agent, spec)
        return agent

    return factory


class _Named:
    """An agent whose ``name`` cannot be set (a property, slots), under the run's name."""

    def __init__(self, agent, name: str):
        self._agent, self.name = agent, name

    def __getattr__(self, attr):
        return getattr(self._agent, attr)
