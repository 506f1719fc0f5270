"""Hardware trials: a task-episode agent (HELIOS, the trusting baseline, ...) on a real Spot with
real perception, recorded in the same run folders and the same record schema as simulated trials,
so ``python -m tools report`` puts the real-world table next to the simulated one.

One robot run is one episode: :func:`run_hardware_trial` drives the agent through
``tasks.runner.run_episode`` (the paper's 10-minute cap: ``RunnerConfig.max_sim_time``, robot
clock) with a :class:`HardwareJudge` in place of the simulator's judge, records the run (rerun
``.rrd``: hand camera, maps, plans, commands), asks the operator what the robot cannot judge
itself and appends one record to the folder's ``episodes.jsonl``.

What the robot judges itself (from the agent's HAL results): FindObj (the agent committed to a
target: it attempted a grasp), Pick (a grasp ended with the object held), FindRec (holding it, the
agent attempted a place on the goal receptacle), collisions (blocked walks and arm stalls the robot
reported). What only the operator can tell (:class:`OperatorVerdict`): the object rests on the goal
receptacle, it is at rest, and collisions the robot did not notice. Place = FindRec and a release
and both operator answers yes; SR = Place and no collision.
"""

from __future__ import annotations

import math
import re
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable

from helios.agents.config import AgentConfig
from helios.config import HeliosConfig
from helios.perception.config import ModelConfig
from helios.schema import require, require_range
from robots.hal import Reason
from tasks.metrics import EpisodeMetrics
from tasks.runner import EpisodeResult, RunnerConfig, run_episode
from tasks.spec import parse_task

SETTINGS = ("hardware", "fake")     # a real robot, or the fake Spot driven through the hardware path


class HardwareTrialError(ValueError):
    """A hardware run folder or operator answer that cannot be used (one line, before the robot moves)."""


@dataclass(frozen=True)
class HardwareConfig:
    """What determines a hardware trial's numbers (config.yaml of its run folder; every record
    carries its fingerprint). The robot's address, certificates and timeouts are not part of it
    (``robot.yaml`` next to it records them)."""

    agent: str = "helios"
    setting: str = "hardware"
    seed: int = 0
    runner: RunnerConfig = RunnerConfig()          # max_sim_time 600 s: the paper's 10-minute cap
    models: ModelConfig = field(default_factory=ModelConfig)
    agent_config: AgentConfig = field(default_factory=AgentConfig)
    helios: HeliosConfig = field(default_factory=HeliosConfig)

    def __post_init__(self) -> None:
        require(bool(self.agent.strip()), "agent must be a non-empty name")
        require(self.setting in SETTINGS, f"setting must be one of {', '.join(SETTINGS)}, got {self.setting!r}")
        require_range(self, "seed", 0, 2 ** 32 - 1)


@dataclass(frozen=True)
class RobotTask:
    """What ``run_episode`` needs of an episode, for a run on a robot: an id, the task in words,
    the agent's seed."""

    episode_id: str
    task: str
    seed: int = 0

    @property
    def spec(self):
        return parse_task(self.task)


def trial_id(task: str, when: float | None = None) -> str:
    """A hardware episode id: ``hw-YYYYmmdd-HHMMSS-<object>-to-<goal>``."""
    spec = parse_task(task)
    slug = re.sub(r"[^a-z0-9]+", "_", f"{spec.object}-to-{spec.goal_receptacle}".lower()).strip("_")
    return f"hw-{time.strftime('%Y%m%d-%H%M%S', time.localtime(when))}-{slug}"


def load_robot_perception(models: ModelConfig):
    """(detector, scorer) from local weight folders (OWLv2 and CLIP through
    ``helios.perception.adapters``). Missing weights or a missing ``transformers`` are one clear
    error (ModelWeightsMissingError / PerceptionDependencyError): call it before touching a robot."""
    from helios.perception.adapters import load_real_perception

    return load_real_perception(models)


# ------------------------------------------------------------------------------------------------
# What the robot can judge itself
# ------------------------------------------------------------------------------------------------
class HardwareJudge:
    """The runner's judge on a real robot: no ground truth, only the HAL results the agent got.
    Keeps the robot's command log (``log``) and the collisions it reported."""

    def __init__(self, clock: Callable[[], float] = time.monotonic):
        self.metrics = EpisodeMetrics()
        self.log: list[dict] = []
        self.collision_events: list[dict] = []
        self.released = False
        self.holding = False
        self._clock = clock
        self._t0 = clock()

    def on_observation(self, obs) -> None:
        self.holding = bool(getattr(obs, "holding", self.holding))

    def after_command(self, name: str, result=None) -> None:
        t = round(self._clock() - self._t0, 3)
        entry = {"t": t, "command": name}
        if result is not None and hasattr(result, "success"):
            entry.update(success=bool(result.success), reason=getattr(getattr(result, "reason", None), "value", None),
                         message=str(getattr(result, "message", ""))[:200],
                         duration=round(float(getattr(result, "duration", 0.0)), 3))
        self.log.append(entry)
        if result is None or not hasattr(result, "success"):
            return
        m = self.metrics
        if getattr(result, "collided", False) or getattr(result, "reason", None) is Reason.COLLISION:
            m.collisions += 1
            self.collision_events.append({"time": t, "command": name, "message": entry["message"]})
        if name == "grasp":
            m.pick_attempts += 1
            if not m.find_obj:
                m.find_obj, m.find_obj_time = True, t    # the agent committed to a target it had found
            if result.success and getattr(result, "holding", False):
                if not m.pick:
                    m.pick_time = t
                m.pick = True
                self.holding = True
        elif name == "place":
            if m.pick and self.holding and not m.find_rec:
                m.find_rec, m.find_rec_time = True, t  # holding it, the agent found a goal receptacle to place on
            if result.success:
                self.released = True
                self.holding = False

    def finalize(self, limit_hit: bool) -> EpisodeMetrics:
        """The robot's side of the metrics; Place and SR wait for :func:`apply_verdict`."""
        self.limit_hit = bool(limit_hit)
        return self.metrics


@dataclass(frozen=True)
class OperatorVerdict:
    """What the operator saw at the end of a run."""

    on_goal: bool                     # the object rests on (top of) a goal receptacle
    at_rest: bool                     # and does not move (not rolling, tipping or held)
    extra_collisions: int = 0         # robot-scene contacts the robot did not report
    source: str = "prompt"            # prompt | flags

    def __post_init__(self) -> None:
        require(isinstance(self.extra_collisions, int) and not isinstance(self.extra_collisions, bool)
                and 0 <= self.extra_collisions <= 1000, f"extra collisions must be a count within 0..1000, "
                                                        f"got {self.extra_collisions!r}")


def apply_verdict(metrics: EpisodeMetrics, verdict: OperatorVerdict, released: bool, limit_hit: bool,
                  error: str | None = None) -> EpisodeMetrics:
    """Place, SR and the failure reason from the robot's metrics and the operator's answers
    (same chain and reasons as ``tasks.metrics.EpisodeJudge``)."""
    m = replace(metrics)
    m.collisions += verdict.extra_collisions
    m.place = bool(m.find_rec and released and verdict.on_goal and verdict.at_rest)
    m.success = bool(m.place and m.collisions == 0)
    if m.success:
        m.failure_reason = None
    elif m.place:
        m.failure_reason = "collision"
    elif not m.find_obj:
        m.failure_reason = "timeout" if limit_hit else "not_found"
    elif not m.pick:
        m.failure_reason = "pick_failed"
    elif not m.find_rec:
        m.failure_reason = "timeout" if limit_hit else "receptacle_not_found"
    elif released and not verdict.on_goal:
        m.failure_reason = "fell_off"
    else:
        m.failure_reason = "timeout" if (limit_hit and not released) else "place_failed"
    m.released_on = "goal receptacle (operator)" if verdict.on_goal and released else None
    return m


_YES = {"y", "yes", "true", "1"}
_NO = {"n", "no", "false", "0"}


def parse_yes_no(text: str, what: str) -> bool:
    t = str(text).strip().lower()
    if t in _YES:
        return True
    if t in _NO:
        return False
    raise HardwareTrialError(f"{what} must be yes or no, got {text!r}")


def operator_questions(task: str) -> list[str]:
    spec = parse_task(task)
    return [f"Is the {spec.object} on the {spec.goal_receptacle}? [y/n] ",
            f"Is the {spec.object} at rest (not rolling, tipping or held by the robot)? [y/n] ",
            "Robot-scene collisions the robot did not report (a number) [0]: "]


def ask_operator(task: str, input_fn: Callable[[str], str] = input, out=sys.stdout) -> OperatorVerdict:
    """Ask the operator the questions the robot cannot answer; repeat a question until it gets a
    usable answer."""
    qs = operator_questions(task)
    answers: list = []
    for i, q in enumerate(qs):
        while True:
            raw = input_fn(q)
            try:
                if i < 2:
                    answers.append(parse_yes_no(raw, "the answer"))
                else:
                    raw = raw.strip() or "0"
                    if not re.fullmatch(r"\d{1,4}", raw):
                        raise HardwareTrialError(f"a number of collisions, got {raw!r}")
                    answers.append(int(raw))
                break
            except HardwareTrialError as exc:
                print(f"  ({exc}; try again)", file=out)
    return OperatorVerdict(answers[0], answers[1], answers[2], source="prompt")


# ------------------------------------------------------------------------------------------------
# The run folder
# ------------------------------------------------------------------------------------------------
def prepare_hardware_folder(out: Path, config: HardwareConfig, dry_run: bool = False) -> str:
    """Create or reopen a hardware-trials run folder for ``config``; returns its configuration
    fingerprint. A folder holding trials of another configuration is refused (one line): results
    of different configurations never mix. ``dry_run``: only the checks."""
    from tasks.run_folder import RunFolderError, check_folder_layout, read_config_body, scan_results, write_atomic
    from tasks.trial_config import config_fingerprint, config_text

    out = Path(out)
    try:
        check_folder_layout(out)
        current = config_fingerprint(config)
        cfg_path = out / "config.yaml"
        scan = scan_results(out / "episodes.jsonl")
        known = {r.get("config_fingerprint") for r in scan.records.values()} - {None}
        if cfg_path.exists() and config_fingerprint(read_config_body(cfg_path)[1]) != current:
            raise HardwareTrialError(f"run folder {str(out)!r} holds trials of another configuration (agent, models, "
                                     f"limits or setting differ); use another --name or --out")
        if known and known != {current}:
            raise HardwareTrialError(f"run folder {str(out)!r} holds records of another configuration; use another "
                                     f"--name or --out")
        if config.setting == "fake":
            _check_fake_episode_seeds(out, config, scan.records.values())
        if dry_run:
            return current
        out.mkdir(parents=True, exist_ok=True)
        if not cfg_path.exists():
            write_atomic(cfg_path, config_text(config))
    except RunFolderError as exc:
        raise HardwareTrialError(str(exc)) from None
    except OSError as exc:
        raise HardwareTrialError(f"cannot use run folder {str(out)!r}: {exc.strerror or exc}") from None
    return current


def _check_fake_episode_seeds(out: Path, config: HardwareConfig, records) -> None:
    """A fake-Spot task-episode folder whose records were seeded otherwise is refused: until
    2026-12-06 ``tools spot --fake --episode --seed S`` gave the episode seed S itself (and the
    simulated perception the episode's own seed), since then ``episode_seed(S, id)`` as ``tools
    trials --seed S`` does. The configuration did not change, so the fingerprint cannot tell the
    two apart, and their perception draws differ: mixed in one folder, they would not compare."""
    from tasks.trial_config import episode_seed

    other = sorted({(r["episode_id"], r.get("seed")) for r in records
                    if r.get("seed") != episode_seed(config.seed, r["episode_id"])})
    if other:
        (eid, seed), more = other[0], len(other) - 1
        raise HardwareTrialError(
            f"run folder {str(out)!r}: its record of {eid}{f' (and {more} more)' if more else ''} was made with seed "
            f"{seed}, not the seed `tools trials --seed {config.seed}` gives that episode "
            f"({episode_seed(config.seed, eid)}): made before --fake --episode seeded episodes as trials do "
            f"(2026-12-06), its perception draws differ; use another --name or --out")


def hardware_record(result: EpisodeResult, metrics: EpisodeMetrics, fingerprint: str, *, setting: str,
                    judge: HardwareJudge | None, verdict: OperatorVerdict | None, robot: dict,
                    recording: dict | None = None, memory: dict | None = None) -> dict:
    """One line of episodes.jsonl, in the schema of simulated trials (``tasks.trials.run_one``)
    plus a ``hardware`` section: the operator's answers, the robot, the robot's command log."""
    record = result.as_dict()
    record["metrics"] = metrics.as_dict()
    record["success"] = bool(metrics.success)
    record["config_fingerprint"] = fingerprint
    record["collision_events"] = record["extra"].pop("collision_events", None) or \
        (judge.collision_events if judge is not None else [])
    record["memory"] = memory
    record["hardware"] = {"setting": setting, "operator": asdict(verdict) if verdict is not None else None,
                          "robot": robot, "robot_log": judge.log if judge is not None else [],
                          "log_file": "session.log"}
    if recording is not None:
        record["recording"] = recording
    return record


# ------------------------------------------------------------------------------------------------
# One hardware trial
# ------------------------------------------------------------------------------------------------
class _LastObservation:
    """The robot's pose for recordings, from the latest observation (a robot has no sim clock)."""

    def __init__(self, t0: float):
        self.obs = None
        self.t0 = t0

    def on_observation(self, obs) -> None:
        self.obs = obs

    def __call__(self):
        import numpy as np

        obs = self.obs
        t = max(0.0, time.time() - self.t0)
        if obs is None:
            return t, np.eye(4), {}
        return t, obs.T_world_body, dict(obs.joint_positions)


class _ChainedJudge:
    def __init__(self, judge: HardwareJudge, tracker: _LastObservation):
        self.judge, self.tracker = judge, tracker

    def on_observation(self, obs) -> None:
        self.tracker.on_observation(obs)
        self.judge.on_observation(obs)

    def after_command(self, name: str, result=None) -> None:
        self.judge.after_command(name, result)

    def finalize(self, limit_hit: bool):
        return self.judge.finalize(limit_hit)


def run_hardware_trial(backend, config: HardwareConfig, task: RobotTask, perception, out: Path, *,
                       verdict: Callable[[], OperatorVerdict], robot_info: dict | None = None,
                       fingerprint: str | None = None, record_rrd: bool = True, say=print,
                       close_robot: Callable[[], None] | None = None) -> dict:
    """Run ``config.agent`` (``tasks.registry``) with real ``perception`` on ``backend`` for
    ``task``; close the robot (``close_robot``, before the operator is asked: the robot is safe
    while they look), get the operator's ``verdict()`` and append the record to
    ``out/episodes.jsonl``; returns the record."""
    from tasks.instrument import InstrumentedAgent
    from tasks.registry import RunContext, make_agent
    from tasks.run_folder import append_result

    out = Path(out)
    fingerprint = fingerprint or prepare_hardware_folder(out, config)
    agent = make_agent(config.agent, RunContext(task=task.task, seed=task.seed, say=say), perception=perception,
                       agent_config=config.agent_config, method_config=config.helios)
    t0 = time.time()
    tracker = _LastObservation(t0)
    judge = HardwareJudge()
    recorder, rrd = None, None
    if record_rrd:
        from tasks.recording import EpisodeRecorder

        rrd = out / "recordings" / f"{task.episode_id}.rrd"
        rrd.parent.mkdir(parents=True, exist_ok=True)
        recorder = EpisodeRecorder(rrd, recording_id=f"{config.agent}-{task.episode_id}")
    wrapped = InstrumentedAgent(agent, recorder, tracker)
    try:
        result = run_episode(wrapped, backend, task, config.runner, _ChainedJudge(judge, tracker), start_time=t0,
                             seed=task.seed)
    finally:
        if close_robot is not None:
            close_robot()
    recording = None
    if recorder is not None:
        from tasks.recording import close_recording

        failed = close_recording(recorder, rrd, say,
                                 final_text=f"episode {task.episode_id}: {task.task}; agent {config.agent}")
        recording = {"path": str(rrd), "errors": list(wrapped.hook_errors) + ([failed] if failed else [])}
    answer = verdict()
    metrics = apply_verdict(judge.metrics, answer, judge.released, result.limit_hit, result.error)
    record = hardware_record(result, metrics, fingerprint, setting=config.setting, judge=judge, verdict=answer,
                             robot=robot_info or {}, recording=recording, memory=wrapped.probe.summary())
    return append_result(out / "episodes.jsonl", record)


def verdict_from_flags(on_goal: str | None, at_rest: str | None, collisions: int | None) -> OperatorVerdict | None:
    """The operator's answers given on the command line (None when none was given); a partial set
    is one error."""
    given = [v is not None for v in (on_goal, at_rest)]
    if not any(given) and collisions is None:
        return None
    if not all(given):
        raise HardwareTrialError("give both --on-goal and --at-rest (the operator's answers), or neither to be asked "
                                 "at the end of the run")
    n = 0 if collisions is None else collisions
    if isinstance(n, float) and not math.isfinite(n):
        raise HardwareTrialError("--extra-collisions must be a count")
    return OperatorVerdict(parse_yes_no(on_goal, "--on-goal"), parse_yes_no(at_rest, "--at-rest"), int(n),
                           source="flags")


__all__ = ["HardwareConfig", "HardwareJudge", "HardwareTrialError", "OperatorVerdict", "RobotTask", "apply_verdict",
           "ask_operator", "hardware_record", "load_robot_perception", "operator_questions",
           "prepare_hardware_folder", "run_hardware_trial", "trial_id", "verdict_from_flags"]
