"""The trial configuration: everything that determines a batch's numbers (:class:`TrialConfig`,
saved as a run folder's config.yaml), its fingerprint (stamped on every record, so that results of
different configurations never mix), how two configurations differ (an extension, or not), and the
episodes and per-episode seeds it selects. Its own module so that what reads a configuration (a
scenario file, a run folder, the report, hardware trials) needs neither the run folder's rules nor
the batch runner.

Determinism: an episode's numbers depend only on the config and (master seed, episode id)
(:func:`episode_seed`), never on the order, the number of workers, the executor, resumption or
recording. The fields in :data:`NONDETERMINISTIC_FIELDS` (wall-clock time, memory, recording path)
vary between identical runs; everything else in a record is reproduced exactly
(:func:`deterministic_view`).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from helios.agents.config import AgentConfig
from helios.config import HeliosConfig
from helios.schema import (ConfigError, dump_yaml, load_config, read_config_file, require, require_range, short_repr,
                           to_dict)
from robots.spot.sim_backend import SimBackendConfig
from sim.perception.config import SimPerceptionConfig
from tasks.provenance import PROVENANCE_KEYS, provenance
from tasks.runner import RunnerConfig

NONDETERMINISTIC_FIELDS = ("wall_time", "memory", "recording")
FINGERPRINT_FIELD = "config_fingerprint"     # in every record: config_fingerprint() of the config that made it


@dataclass(frozen=True)
class TrialConfig:
    """Everything that determines a batch's numbers (saved as config.yaml in the run folder)."""

    agent: str = "oracle"
    split: str = "smoke"
    episodes_file: str = ""          # overrides ``split`` when set
    episodes: int = 20               # how many episodes of the split (from the start)
    seed: int = 0                    # master seed: each episode's RNG derives from (seed, episode id)
    sim: SimBackendConfig = field(default_factory=lambda: SimBackendConfig(stream_hz=0.0))
    runner: RunnerConfig = RunnerConfig()
    # HELIOS agents only (the oracle ignores them); a variant's own settings (helios.agents.variants)
    # and the "-gt" suffix (perception.mode) take precedence over these.
    agent_config: AgentConfig = field(default_factory=AgentConfig)
    helios: HeliosConfig = field(default_factory=HeliosConfig)
    perception: SimPerceptionConfig = field(default_factory=SimPerceptionConfig)

    def __post_init__(self) -> None:
        require(bool(self.agent.strip()), "agent must be a non-empty name")
        require_range(self, "episodes", 1, 10_000_000)
        require_range(self, "seed", 0, 2 ** 32 - 1)     # numpy seeds are non-negative
        # a "-gt" agent forces perception.mode=gt, with which gt_roles means nothing
        require(not (self.perception.gt_roles and self.agent.endswith("-gt")),
                f"perception.gt_roles={list(self.perception.gt_roles)} with agent {short_repr(self.agent, 40)}: a "
                f"'-gt' agent detects every role exactly already; use {short_repr(self.agent.removesuffix('-gt'), 40)}")
        from sim.scenes.catalog import ALL_CATEGORIES

        # A task's classes are categories of the simulator (tasks.spec); HELIOS's map refuses a
        # task class named like its background class (helios.maps.classes.ClassSet.from_task), so
        # such a background name would end every episode that names it on a MapInputError.
        require(self.helios.background_class not in ALL_CATEGORIES,
                f"helios.background_class {short_repr(self.helios.background_class, 40)} is a category of the "
                f"simulator, which clashes with the task classes of the episodes that name it; use a name that "
                f"is not a category (default 'other')")


def check_devices(config: TrialConfig) -> None:
    """ConfigError, before any work, when ``config`` asks for a torch device this machine lacks:
    ``helios.device=cuda`` for a HELIOS agent (the oracle ignores ``helios``) or an agent of your
    own (``FILE.py:FACTORY``; one that does not read ``helios`` was refused the setting already)
    without a CUDA device. Its episodes would otherwise each end on that ConfigError, counted as
    failures."""
    from helios.agents.variants import VARIANTS

    own = ":" in config.agent          # tasks.plugin_agents.is_plugin_spec (it imports this module)
    if config.helios.device != "cuda" or (config.agent.removesuffix("-gt") not in VARIANTS and not own):
        return
    from helios.maps.hierarchical import resolve_device

    try:
        resolve_device("cuda")
    except ConfigError as exc:
        raise ConfigError(f"helios.device=cuda: {exc}") from None


def episode_seed(master_seed: int, episode_id: str) -> int:
    """A stable per-episode seed: independent of order, workers and resumption."""
    state = np.random.SeedSequence([master_seed, *episode_id.encode()]).generate_state(1)[0]
    return int(state % (2 ** 31 - 1))


def deterministic_view(record: dict) -> dict:
    """A record without the fields that vary between identical runs (wall clock, memory, paths),
    and of an ``error`` its first line (the exception and its message): the traceback under it
    names files and line numbers of the code that ran, which a refactor moves (determinism audit)."""
    view = {k: v for k, v in record.items() if k not in NONDETERMINISTIC_FIELDS}
    if isinstance(view.get("error"), str):
        view["error"] = view["error"].split("\n", 1)[0]
    return view


def config_text(config: TrialConfig | dict) -> str:
    """A run folder's config.yaml: the provenance header, then the configuration."""
    return dump_yaml(provenance()) + dump_yaml(config)


def config_fingerprint(config: TrialConfig | dict) -> str:
    """A short hash of a trial configuration (a TrialConfig, or a run folder's config.yaml as
    loaded), without its provenance (version, commit) and without ``episodes`` (extending a run
    keeps its fingerprint). Every record carries the fingerprint of the configuration that made
    it, so a folder whose records disagree with its config.yaml (edited, replaced or deleted) is
    recognised.

    A hash of the text as written, and so of ``episodes_file`` as spelt: ``tools trials`` spells
    it one way for a file however it was named (:func:`canonical_episodes_file`), and a run folder
    resumed with another spelling of its file keeps its own (:func:`config_difference`). It is not
    the file's contents: a fingerprint is computed from config.yaml alone (``tools report`` and
    ``tools diff`` check folders whose episode file may be gone), and the contents are checked
    episode by episode when a run resumes (``tasks.run_folder.prepare_run_folder``)."""
    d = dict(to_dict(config)) if not isinstance(config, dict) else dict(config)
    for key in (*PROVENANCE_KEYS, "episodes"):
        d.pop(key, None)
    text = json.dumps(d, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def load_trial_config(path: str | Path) -> tuple[dict, TrialConfig]:
    """A scenario file (``configs/*.yaml``) or a run folder's ``config.yaml``: its provenance
    (``helios_version``, ``git_commit``; None where absent, as in a hand-written scenario) and the
    trial config. Any other unknown key is a ConfigError naming the file and the key."""
    data = read_config_file(path)
    header = {k: data.get(k) for k in PROVENANCE_KEYS}
    return header, load_config(TrialConfig, path, ignore=PROVENANCE_KEYS)


def canonical_episodes_file(path: str) -> str:
    """One spelling of an episode file however it is named (the identity of ``episodes_file``):
    relative to the working directory when the file lies under it (``splits/x.jsonl``,
    ``./splits/x.jsonl`` and ``/abs/project/splits/x.jsonl`` run from ``/abs/project`` are all
    ``splits/x.jsonl``), else absolute; ``..`` and ``.`` are resolved, a symbolic link to the
    file is not (the link is a name of its own). "" (no file: the split) stays "".

    Why the path, and relative: the commands are run from the project folder, so the same file
    has the same spelling, and its runs the same fingerprint, in every clone and on every machine
    (an absolute path would differ between clones, and ``tools unchanged`` runs the commit's side
    in a tree of its own); it is the spelling a relative name always had, so run folders made
    with one keep their fingerprints; and it names what ``load_episodes`` opens from here. Not
    the contents: see :func:`config_fingerprint`."""
    import os

    if not path:
        return path
    absolute = Path(os.path.abspath(path))
    cwd = Path(os.getcwd())
    for base, target in ((cwd, absolute), (Path(os.path.realpath(cwd)), Path(os.path.realpath(absolute.parent)) /
                                           absolute.name)):      # a working directory reached through a link
        try:
            rel = target.relative_to(base)
        except ValueError:
            continue
        if rel.parts:
            return rel.as_posix()
    return str(absolute)


def same_episodes_file(a: str, b: str) -> bool:
    """Whether two spellings of ``episodes_file`` name the same file from this working directory
    (two empty ones: both the split)."""
    return a == b or (bool(a) and bool(b) and canonical_episodes_file(a) == canonical_episodes_file(b))


def config_difference(saved: TrialConfig, config: TrialConfig) -> list[str]:
    """The top-level keys where ``config`` differs from a run folder's ``saved`` configuration.
    ``episodes_file`` spelt another way for the same file (relative against absolute, as a run
    folder made before :func:`canonical_episodes_file` may hold it) is no difference: the run
    resumes, and keeps the spelling and the fingerprint it was made with."""
    if saved == config:
        return []
    old = to_dict(saved)
    return [k for k, v in to_dict(config).items() if old.get(k) != v and
            not (k == "episodes_file" and same_episodes_file(old.get(k), v))]


def is_extension(diff: list[str], saved: TrialConfig, config: TrialConfig) -> bool:
    """Whether the only difference is more episodes: a run may be extended, never shortened."""
    return diff == ["episodes"] and config.episodes > saved.episodes


def run_episode_ids(config: "TrialConfig | dict") -> tuple[list[str], str] | None:
    """The episodes a run folder of trial configuration ``config`` (a TrialConfig, or its
    config.yaml as loaded) holds records of: the first ``episodes`` of its split or episode file,
    and a description of them; None when that cannot be told (not a trial configuration, e.g. a
    hardware run's; an episode file that cannot be read)."""
    from tasks.episodes import DatasetError, load_episodes, load_split

    d = to_dict(config) if isinstance(config, TrialConfig) else config
    if not isinstance(d, dict):
        return None
    split, source, count = d.get("split"), d.get("episodes_file") or "", d.get("episodes")
    if not isinstance(count, int) or isinstance(count, bool) or count < 1 or not isinstance(source, str) or \
            (not source and not isinstance(split, str)):
        return None
    try:
        episodes = load_episodes(source) if source else load_split(split)
    except (DatasetError, OSError, ValueError):
        return None
    where = f"episode file {source}" if source else f"split {split}"
    return [e.episode_id for e in episodes[:count]], f"the run's {min(count, len(episodes))} episodes ({where}, " \
                                                     f"config.yaml)"
