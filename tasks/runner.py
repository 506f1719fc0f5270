"""Running one episode: an agent drives a robot through the HAL until it declares the task done or
the episode's limits run out; in simulation a ground-truth judge scores it.

The agent receives a :class:`MonitoredBackend`, a HAL proxy that counts commands, enforces the
limits (raising :class:`EpisodeLimitReached` inside the agent when they run out) and tells the judge
what happened. It exposes nothing beyond the HAL, so agents cannot reach simulator state.
"""

from __future__ import annotations

import os
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from robots.hal import CommandProxy, Observation, RobotBackend, RobotFault
from tasks.episodes import Episode
from tasks.metrics import EpisodeMetrics, MetricsConfig
from tasks.spec import TaskSpec


@dataclass(frozen=True)
class RunnerConfig:
    max_commands: int = 600            # HAL commands (observe included) per episode
    max_sim_time: float = 600.0        # s of robot time per episode (the paper stops hardware runs at 10 min)
    metrics: MetricsConfig = MetricsConfig()

    def __post_init__(self) -> None:
        from helios.schema import require_range

        require_range(self, "max_commands", 1, 10_000_000)
        require_range(self, "max_sim_time", 0.0, 1e6, lo_open=True)     # s; 1e6 s is 11 days


class EpisodeLimitReached(Exception):
    """Raised inside the agent when the episode's command or time budget is used up."""


@runtime_checkable
class Agent(Protocol):
    """What the runner needs from an agent. ``act`` performs one decision (one or more HAL calls)
    and returns True once the agent considers the task finished (or given up)."""

    name: str

    def reset(self, task: TaskSpec, rng: np.random.Generator) -> None: ...

    def act(self, robot: RobotBackend) -> bool: ...


@dataclass
class EpisodeResult:
    episode_id: str
    task: str
    agent: str
    seed: int
    metrics: EpisodeMetrics | None      # None on a real robot (no ground truth)
    commands: int
    sim_time: float
    wall_time: float
    limit_hit: bool
    error: str | None = None            # agent or robot exception, if the episode ended on one
    extra: dict = field(default_factory=dict)

    @property
    def success(self) -> bool:
        return bool(self.metrics and self.metrics.success)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["success"] = self.success
        return d


class MonitoredBackend(CommandProxy):
    """HAL proxy handed to agents: counts commands, enforces limits, informs the judge."""

    def __init__(self, backend: RobotBackend, config: RunnerConfig, judge=None, start_time: float = 0.0):
        self._backend = backend
        self._config = config
        self._judge = judge
        self._t0 = start_time
        self._now = start_time
        self.commands = 0
        self.limit_hit = False

    def _before(self) -> None:
        if self.commands >= self._config.max_commands or self._now - self._t0 >= self._config.max_sim_time:
            self.limit_hit = True
            raise EpisodeLimitReached(f"episode budget used up ({self.commands} commands, "
                                      f"{self._now - self._t0:.0f} s)")
        self.commands += 1

    def _after(self, name: str, result) -> None:
        self._now += float(getattr(result, "duration", 0.0))
        if self._judge is not None:
            self._judge.after_command(name, result)

    @property
    def elapsed(self) -> float:
        return self._now - self._t0

    def observe(self) -> Observation:
        self._before()
        obs = self._backend.observe()
        self._now = max(self._now, obs.stamp)
        if self._judge is not None:
            self._judge.on_observation(obs)
        return obs

    def _command(self, name: str, *args, **kwargs):
        self._before()
        result = getattr(self._backend, name)(*args, **kwargs)
        self._after(name, result)
        return result

    def close(self) -> None:
        """Agents do not own the robot; closing is the runner's job."""


def run_episode(agent: Agent, backend: RobotBackend, episode: Episode, config: RunnerConfig = RunnerConfig(),
                judge=None, start_time: float = 0.0, seed: int | None = None) -> EpisodeResult:
    """Run ``agent`` on ``episode`` through ``backend`` until done or out of budget.

    ``seed`` seeds the agent's generator (default: the episode's own seed).
    """
    wall0 = time.perf_counter()
    robot = MonitoredBackend(backend, config, judge, start_time)
    seed = episode.seed if seed is None else seed
    rng = np.random.default_rng(seed)
    error = None
    clock = _ActivityClock(agent, robot)
    reset_done = False
    try:
        agent.reset(episode.spec, rng)
        reset_done = True
        done = False
        while not done:
            try:
                done = agent.act(robot)
            finally:                   # also an act cut short by the budget or an exception
                clock.tick()
    except EpisodeLimitReached:
        pass
    except RobotFault as exc:
        error = f"{type(exc).__name__}: {exc}"
    except Exception as exc:  # an agent bug must not take the batch down; keep the trace for the log
        error = f"{type(exc).__name__}: {exc}\n{_portable(traceback.format_exc(limit=8))}"
    metrics = judge.finalize(robot.limit_hit) if judge is not None else None
    extra: dict = {}
    if clock.totals is not None:
        extra["activity_time"] = clock.totals
    decision_stats = getattr(agent, "decision_stats", None)
    if reset_done and callable(decision_stats):
        try:
            stats = dict(decision_stats())
            choices = stats.pop("global_choices", None)
            extra["decisions"] = stats
            truth = getattr(judge, "start_receptacle_truth", None)
            if choices is not None and callable(truth):
                extra["start_receptacle"] = truth(choices)
        except Exception as exc:  # a faulty hook is reported with the episode, never fatal
            error = (error + "\n" if error else "") + f"decision_stats: {type(exc).__name__}: {exc}"
    return EpisodeResult(episode_id=episode.episode_id, task=episode.task, agent=agent.name, seed=seed,
                         metrics=metrics, commands=robot.commands, sim_time=robot.elapsed,
                         wall_time=time.perf_counter() - wall0, limit_hit=robot.limit_hit, error=error,
                         extra=extra)


class _ActivityClock:
    """Simulated seconds per activity, for agents that name what each ``act`` did in an optional
    ``activity`` attribute (HELIOS: ``helios.agents.activities.ACTIVITIES``). After every act,
    the robot time that act took (``MonitoredBackend.elapsed`` before and after, so the sim clock
    only) goes to the activity the agent names then; time before the first act (the agent's
    ``reset``) goes to the first. ``totals`` stays None for agents without ``activity``; otherwise
    its values sum to the episode's ``sim_time``."""

    def __init__(self, agent, robot: MonitoredBackend):
        self._agent = agent
        self._robot = robot
        self._last = 0.0                   # elapsed at the end of the previous act
        self.totals: dict[str, float] | None = None

    def tick(self) -> None:
        activity = getattr(self._agent, "activity", None)
        if not isinstance(activity, str):
            return
        now = self._robot.elapsed
        if self.totals is None:
            self.totals = {}
        self.totals[activity] = self.totals.get(activity, 0.0) + (now - self._last)
        self._last = now


# ------------------------------------------------------------------------------------------------
# Simulated episodes
# ------------------------------------------------------------------------------------------------
def build_episode_scene(world, episode: Episode):
    """Build ``episode``'s procedural home in ``world`` and check that it has the named instances.
    Shared by the sim backend's episodes and the fake Spot's (``robots.spot.fake_spot.launch``),
    so both run on the very same scene."""
    from sim.scenes.home import build_home
    from sim.scenes.layout import generate_layout

    scene = build_home(world, generate_layout(episode.scene.seed, episode.scene.layout_config()))
    missing = [n for n in (episode.target_object, episode.start_receptacle, *episode.goal_receptacles)
               if n not in scene.object_ids and n not in scene.receptacle_ids]
    if missing:
        raise ValueError(f"episode {episode.episode_id} names {missing}, absent from scene {episode.scene.seed}; "
                         f"the episode file does not match this version of the scene generator")
    return scene


def build_episode_world(episode: Episode, sim_config):
    """A world holding ``episode``'s home with Spot at its start pose: (world, scene, spot). The
    simulated episode and the fake Spot both start here; the world is closed if building fails."""
    from sim.spot import SpotBody
    from sim.world import World

    world = World(sim_config.world)
    try:
        scene = build_episode_scene(world, episode)
        spot = SpotBody(world, episode.start_pose)
    except Exception:
        world.close()
        raise
    return world, scene, spot


@dataclass
class SimEpisode:
    """Everything a simulated episode needs: world, scene, Spot, the HAL backend and the judge."""

    episode: Episode
    world: object
    scene: object
    backend: object
    judge: object

    @classmethod
    def create(cls, episode: Episode, sim_config=None, metrics: MetricsConfig = MetricsConfig()) -> "SimEpisode":
        from robots.spot.sim_backend import SimBackendConfig, SimSpotBackend
        from tasks.metrics import EpisodeJudge

        sim_config = sim_config or SimBackendConfig()
        world, scene, spot = build_episode_world(episode, sim_config)
        try:
            backend = SimSpotBackend(world, spot, sim_config)
            judge = EpisodeJudge(backend, scene, episode, metrics)
        except Exception:
            world.close()
            raise
        return cls(episode, world, scene, backend, judge)

    def close(self) -> None:
        self.backend.close()


def run_sim_episode(agent_factory, episode: Episode, config: RunnerConfig = RunnerConfig(),
                    sim_config=None, seed: int | None = None) -> EpisodeResult:
    """Build the episode's scene, run a fresh agent from ``agent_factory(sim_episode)`` and score it."""
    sim = SimEpisode.create(episode, sim_config, config.metrics)
    try:
        agent = agent_factory(sim)
        result = run_episode(agent, sim.backend, episode, config, sim.judge, start_time=sim.world.time, seed=seed)
        result.extra["collision_events"] = [asdict(e) for e in sim.backend.collision_events]
        return result
    finally:
        sim.close()


_ROOT = str(Path(__file__).resolve().parents[1]) + os.sep


def _portable(trace: str) -> str:
    """A traceback with this checkout's paths relative to it: a record is the same wherever the
    checkout sits (`tools unchanged` runs a commit's code from another folder; the absolute paths
    made every record with an error differ: determinism audit)."""
    return trace.replace(_ROOT, "")
