"""Scripted Spot pick-and-place in a small scene: walk to a table, look with the arm camera, grasp
the mug by pixel, carry it, drop it on the other table; print the physical outcome, write a .rrd.

The script is the scripted demo agent of ``tasks.scripted_demo`` (the one ``tools spot`` runs);
it only calls the HAL. Here it is given the simulator's ground truth (``GroundTruthHints``): where
the tables are, and the mug's pixels from the segmentation instead of a detector.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tasks.scripted_demo import AgentStep


@dataclass
class DemoOutcome:
    seed: int
    success: bool
    resting_on: str | None
    settled: bool
    lifted_by: float            # m the mug rose above its start during the grasp
    final_position: tuple[float, float, float]
    object_poses: dict[str, tuple[float, ...]]   # every movable object: (x, y, z, qx, qy, qz, qw)
    offset_from_target: float   # m between the mug and the commanded release point (xy)
    collisions: int
    sim_time: float             # simulated seconds of the episode (scene building excluded)
    wall_time: float            # wall seconds of the episode
    setup_time: float           # wall seconds to build the world, the scene and the robot
    frames: int
    steps: list[AgentStep] = field(default_factory=list)
    recording: str | None = None

    @property
    def real_time_factor(self) -> float:
        return self.sim_time / max(self.wall_time, 1e-9)


def run_demo(seed: int = 0, overrides: list[str] | tuple[str, ...] = (), record_path: str | Path | None = None,
             verbose: bool = True, config_file: str | Path | None = None) -> DemoOutcome:
    """Build the demo scene, run the scripted pick-and-place through the HAL, measure the outcome.
    ``config_file``: a simulator scenario file (``SimBackendConfig``); ``overrides`` apply on top."""
    from helios.schema import load_config
    from robots.spot.sim_backend import SimBackendConfig, SimSpotBackend
    from sim.scenes.demo import build_demo_scene
    from sim.spot import SpotBody
    from sim.world import World
    from tasks.scripted_demo import GroundTruthHints, ScriptedDemo, physical_outcome

    config = load_config(SimBackendConfig, config_file, list(overrides))
    say = print if verbose else (lambda *a, **k: None)
    wall0 = time.perf_counter()
    world = World(config.world)
    rng = np.random.default_rng(seed)
    scene = build_demo_scene(world, rng)
    spot = SpotBody(world, scene["robot_start"])
    backend = SimSpotBackend(world, spot, config)
    recorder = None
    frames = [0]
    if record_path is not None:
        from tasks.recording import EpisodeRecorder

        recorder = EpisodeRecorder(record_path, recording_id=f"demo-seed{seed}")
        for b in world.bodies.values():
            if b.kind in ("furniture", "object"):
                lo, hi = world.aabb(b.body_id)
                recorder.log_boxes(b.name, [(lo + hi) / 2], [(hi - lo) / 2], labels=[b.category], static=True)

    def on_frame(obs) -> None:
        frames[0] += 1
        if recorder is not None:
            recorder.log_observation(obs)

    backend.add_frame_listener(on_frame)
    setup_wall = time.perf_counter() - wall0
    sim0, wall0 = world.time, time.perf_counter()
    mug = scene["mug"]
    hints = GroundTruthHints(world, scene, backend, say)
    mug_start = hints.mug_position
    lifted = [0.0]

    def on_step(step: AgentStep) -> None:
        if recorder is not None:
            recorder.log_text(f"{step.name}: {step.detail}", "INFO" if step.ok else "WARN")
        if step.ok and step.name.startswith("grasp"):
            lifted[0] = float(world.position(mug)[2] - mug_start[2])

    say(f"[demo] seed {seed}: mug on {scene['pick_table']} at ({mug_start[0]:.2f}, {mug_start[1]:.2f}); "
        f"Spot at the origin; goal: put it on {scene['place_table']}")
    agent = ScriptedDemo(hints, say=say, tag="demo", decimals=1, on_step=on_step).run(backend)
    # Judge the physical outcome only once everything has come to rest (a failed grasp may still
    # be tumbling).
    physical = physical_outcome(world, scene, agent.place_target)
    backend.drain_frames()  # streamed frames render in a worker process; collect the last ones
    outcome = DemoOutcome(
        seed=seed, success=bool(physical["success"] and not backend.holding),
        resting_on=physical["resting_on"], settled=physical["settled"], lifted_by=lifted[0],
        final_position=tuple(physical["final_position"]),
        object_poses={b.name: tuple(map(float, np.concatenate(world.client.getBasePositionAndOrientation(b.body_id))))
                      for b in world.bodies_of_kind("object")},
        offset_from_target=physical.get("offset_from_target", math.nan), collisions=len(backend.collision_events),
        sim_time=world.time - sim0, wall_time=time.perf_counter() - wall0, setup_time=setup_wall, frames=frames[0],
        steps=agent.steps, recording=str(record_path) if record_path else None)
    if recorder is not None:
        recorder.set_time(world.time)
        recorder.log_scalar("success", float(outcome.success))
        recorder.log_text(f"outcome: mug resting on {outcome.resting_on}, settled={outcome.settled}")
        recorder.close()
    backend.close()
    return outcome


def format_outcome(o: DemoOutcome) -> str:
    from tools.tables import format_table

    rows = [
        ("result", "SUCCESS" if o.success else "FAILED"),
        ("mug resting on", o.resting_on or "nothing (in the air or on the floor)"),
        ("mug settled", "yes" if o.settled else "no"),
        ("lifted during grasp", f"{100 * o.lifted_by:.1f} cm"),
        ("final mug position", "(" + ", ".join(f"{v:.3f}" for v in o.final_position) + ") m"),
        ("offset from release point", f"{100 * o.offset_from_target:.1f} cm" if not math.isnan(o.offset_from_target) else "-"),
        ("robot-scene collisions", str(o.collisions)),
        ("simulated time", f"{o.sim_time:.1f} s"),
        ("wall time (episode)", f"{o.wall_time:.2f} s  (+{o.setup_time:.2f} s to build the scene)"),
        ("real-time factor", f"{o.real_time_factor:.1f}x"),
        ("hand-camera frames streamed", str(o.frames)),
    ]
    if o.recording:
        rows.append(("recording", f"{o.recording}  (view: rerun {o.recording})"))
    return format_table(["outcome", "value"], rows, title="Physical outcome")


DEFAULT_OUT = "runs/demo"       # --out: the folder the recording demo_seed<SEED>.rrd is written in


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seed", type=int, default=0, help="scene seed (mug placement)")
    parser.add_argument("--out", default=None, metavar="DIR",
                        help=f"folder for the .rrd recording, written as {DEFAULT_OUT}/demo_seed<SEED>.rrd by "
                             f"default (not with --no-record)")
    parser.add_argument("--no-record", action="store_true", help="do not write a rerun recording")
    parser.add_argument("--config", default=None, metavar="FILE.yaml",
                        help="simulator scenario file (schema: robots/spot/sim_backend.py SimBackendConfig, "
                             "e.g. configs/demo.yaml); KEY=VALUE overrides apply on top")
    parser.add_argument("overrides", nargs="*", metavar="KEY=VALUE",
                        help="simulator config overrides, e.g. camera.width=640 camera.height=480 stream_hz=5")


def _check_out(args: argparse.Namespace) -> None:
    """``--out`` is a folder (README: ``runs/demo/demo_seed0.rrd``). One that names the recording
    itself (``--out x.rrd``) would become a folder ``x.rrd/`` holding ``demo_seed0.rrd``, and one
    given with ``--no-record`` would be silently ignored: both are one error instead
    (``--out`` defaults to None so that an explicit one can be told apart)."""
    from helios.schema import short_repr
    from tools.cli import CliError

    if args.out is None:
        return
    if args.no_record:
        raise CliError("--out is where the recording goes; with --no-record nothing is written and --out would be "
                       "ignored: give one of them")
    if str(args.out).rstrip("/").lower().endswith(".rrd"):
        raise CliError(f"--out {short_repr(str(args.out), 80)} is a folder, not the recording: the recording is "
                       f"named demo_seed{args.seed}.rrd inside it (e.g. --out {DEFAULT_OUT})")


def run(args: argparse.Namespace) -> int:
    from helios.schema import load_config
    from robots.spot.sim_backend import SimBackendConfig
    from tools.cli import check_output_file, check_seed

    check_seed(args.seed)
    load_config(SimBackendConfig, getattr(args, "config", None), list(args.overrides))   # bad config: fail first
    _check_out(args)
    out = DEFAULT_OUT if args.out is None else args.out
    record = None if args.no_record else check_output_file(Path(out) / f"demo_seed{args.seed}.rrd", "--out")
    outcome = run_demo(args.seed, args.overrides, record, config_file=getattr(args, "config", None))
    print()
    print(format_outcome(outcome))
    return 0 if outcome.success else 1
