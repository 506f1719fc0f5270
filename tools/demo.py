"""Scripted Spot pick-and-place in a small scene: walk to a table, look with the arm camera, grasp
the mug by pixel, carry it, drop it on the other table; print the physical outcome, write a .rrd.

The script only calls the HAL (``navigate_to``, ``gaze_at``, ``observe``, ``grasp``, ``stow_arm``,
``place``). It is allowed one shortcut an agent never gets: it knows where the tables are and reads
the mug's pixels from the simulator's segmentation instead of running a detector.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from robots.hal import SE2Pose


@dataclass
class StepLog:
    name: str
    ok: bool
    detail: str
    sim_seconds: float


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
    steps: list[StepLog] = field(default_factory=list)
    recording: str | None = None

    @property
    def real_time_factor(self) -> float:
        return self.sim_time / max(self.wall_time, 1e-9)


def _table_extent(world, name: str, direction: np.ndarray) -> float:
    """Half-width of a table's top along a unit direction (support function of its rectangle)."""
    info = world.body(name)
    hx, hy = info.extra["top_half_extents"]
    T = world.pose(info.body_id)
    u, v = T[:2, 0], T[:2, 1]
    return abs(float(direction @ u)) * hx + abs(float(direction @ v)) * hy


def _approach_pose(world, table: str, target_xy: np.ndarray, robot_xy: np.ndarray, clearance: float) -> SE2Pose:
    """A pose facing ``target_xy`` from the robot's side, ``clearance`` in front of the table edge."""
    info = world.body(table)
    centre = world.position(info.body_id)[:2]
    d = target_xy - robot_xy
    d /= np.linalg.norm(d)
    body_front = 0.45  # m from Spot's body centre to its front (body box + hips)
    stand_off = _table_extent(world, table, d) + body_front + clearance
    p = centre - d * stand_off
    # Shift sideways so the target lies on the robot's forward axis.
    perp = np.array([-d[1], d[0]])
    p += perp * float((target_xy - centre) @ perp)
    return SE2Pose(p[0], p[1], math.atan2(d[1], d[0]))


def run_demo(seed: int = 0, overrides: list[str] | tuple[str, ...] = (), record_path: str | Path | None = None,
             verbose: bool = True) -> DemoOutcome:
    """Build the demo scene, run the scripted pick-and-place through the HAL, measure the outcome."""
    from helios.configuration import with_overrides
    from robots.spot.sim_backend import SimBackendConfig, SimSpotBackend
    from sim.camera import decode_body_ids
    from sim.grasping import support_body
    from sim.scenes.demo import build_demo_scene
    from sim.spot import SpotBody
    from sim.world import World

    config = with_overrides(SimBackendConfig(), list(overrides))
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
        from tools.recording import EpisodeRecorder

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
    steps: list[StepLog] = []
    setup_wall = time.perf_counter() - wall0
    sim0, wall0 = world.time, time.perf_counter()

    def step(name: str, result) -> bool:
        ok = bool(result)
        detail = result.message or result.reason.value
        steps.append(StepLog(name, ok, detail, float(result.duration)))
        say(f"[demo] {len(steps)}. {name:<34} {'ok' if ok else 'FAILED':<6} {detail}  [{result.duration:.1f} s]")
        if recorder is not None:
            recorder.log_text(f"{name}: {detail}", "INFO" if ok else "WARN")
        return ok

    mug = scene["mug"]
    mug_start = world.position(mug)
    say(f"[demo] seed {seed}: mug on {scene['pick_table']} at ({mug_start[0]:.2f}, {mug_start[1]:.2f}); "
        f"Spot at the origin; goal: put it on {scene['place_table']}")
    place_target = None
    lifted = 0.0
    try:
        start_xy = spot.base_pose().as_tuple()[:2]
        if not step("walk to the pick table", backend.navigate_to(
                _approach_pose(world, scene["pick_table"], mug_start[:2], np.array(start_xy), 0.30))):
            raise _Abort
        if not step("look at the mug with the hand camera", backend.gaze_at(mug_start + [0.0, 0.0, 0.05])):
            raise _Abort
        obs = backend.observe()
        ids = decode_body_ids(backend.segmentation_for(obs))
        vs, us = np.nonzero(ids == mug)
        if len(us) == 0:
            steps.append(StepLog("find the mug in the image", False, "mug not visible", 0.0))
            raise _Abort
        pixel = (int(np.median(us)), int(np.median(vs)))
        say(f"[demo]    mug covers {len(us)} pixels; grasping at pixel {pixel}")
        if not step(f"grasp at pixel {pixel}", backend.grasp(obs, pixel)):
            raise _Abort
        lifted = float(world.position(mug)[2] - mug_start[2])
        if not step("carry pose", backend.stow_arm()):
            raise _Abort
        place_info = world.body(scene["place_table"])
        place_centre = world.position(place_info.body_id)[:2]
        robot_xy = np.array(spot.base_pose().as_tuple()[:2])
        d = (place_centre - robot_xy) / np.linalg.norm(place_centre - robot_xy)
        # Release 20 cm inside the near edge of the table top, as the paper's place heuristic does.
        near_edge = place_centre - d * _table_extent(world, scene["place_table"], d)
        place_xy = near_edge + d * 0.20
        if not step("walk to the place table", backend.navigate_to(
                _approach_pose(world, scene["place_table"], place_xy, robot_xy, 0.20))):
            raise _Abort
        top = place_info.extra["top_height"]
        place_target = np.array([place_xy[0], place_xy[1], top])
        if not step("release 10 cm above the table", backend.place(place_target, release_height=0.10)):
            raise _Abort
        step("stow the arm", backend.stow_arm())
    except _Abort:
        pass
    # Judge the physical outcome only once everything has come to rest (a failed grasp may still
    # be tumbling).
    world.settle([b.body_id for b in world.bodies_of_kind("object")], max_time=3.0)
    backend.drain_frames()  # streamed frames render in a worker process; collect the last ones
    final = world.position(mug)
    support = support_body(world, mug)
    resting_on = world.bodies[support].name if support is not None else None
    settled = world.is_at_rest(mug)
    offset = float(np.linalg.norm(final[:2] - place_target[:2])) if place_target is not None else math.nan
    outcome = DemoOutcome(
        seed=seed, success=bool(resting_on == scene["place_table"] and settled and not backend.holding),
        resting_on=resting_on, settled=settled, lifted_by=lifted, final_position=tuple(map(float, final)),
        object_poses={b.name: tuple(map(float, np.concatenate(world.client.getBasePositionAndOrientation(b.body_id))))
                      for b in world.bodies_of_kind("object")},
        offset_from_target=offset, collisions=len(backend.collision_events), sim_time=world.time - sim0,
        wall_time=time.perf_counter() - wall0, setup_time=setup_wall, frames=frames[0], steps=steps,
        recording=str(record_path) if record_path else None)
    if recorder is not None:
        recorder.set_time(world.time)
        recorder.log_scalar("success", float(outcome.success))
        recorder.log_text(f"outcome: mug resting on {resting_on}, settled={settled}")
        recorder.close()
    backend.close()
    return outcome


class _Abort(Exception):
    """A demo step failed; stop the script and report the physical state as it is."""


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


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seed", type=int, default=0, help="scene seed (mug placement)")
    parser.add_argument("--out", default="runs/demo", help="folder for the .rrd recording")
    parser.add_argument("--no-record", action="store_true", help="do not write a rerun recording")
    parser.add_argument("overrides", nargs="*", metavar="KEY=VALUE",
                        help="simulator config overrides, e.g. camera.width=640 camera.height=480 stream_hz=5")


def run(args: argparse.Namespace) -> int:
    record = None if args.no_record else Path(args.out) / f"demo_seed{args.seed}.rrd"
    outcome = run_demo(args.seed, args.overrides, record)
    print()
    print(format_outcome(outcome))
    return 0 if outcome.success else 1
