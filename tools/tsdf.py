"""Reconstruct what an episode saw with a TSDF and report how much of the true receptacle surfaces
the robot's observations covered (within 2 cm); writes the mesh.

    python -m tools tsdf smoke-00003                     # runs the oracle on that smoke episode
    python -m tools tsdf val-00012 --split val --out runs/tsdf --stream-hz 4
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("episode", help="episode id, e.g. smoke-00003")
    parser.add_argument("--split", default=None,       # None: an explicit --split can be told apart
                        help="split to look the id up in (default: from the id's prefix; not with --episodes-file)")
    parser.add_argument("--episodes-file", default=None, help="JSONL episode file to look the id up in (instead of a "
                                                            "split)")
    parser.add_argument("--out", default="runs/tsdf", help="folder for the mesh")
    parser.add_argument("--stream-hz", type=float, default=2.0, help="hand-camera frames integrated per simulated second")
    parser.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="TSDF config overrides, e.g. voxel_size=0.02")


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from helios.schema import with_overrides
    from robots.spot.sim_backend import SimBackendConfig
    from tasks.episodes import load_episodes, load_split
    from tasks.oracle import OracleAgent
    from tasks.runner import RunnerConfig, SimEpisode, run_episode
    from tasks.tsdf import TsdfConfig, TsdfIntegrator, coverage, receptacle_surface_samples
    from helios.schema import short_repr
    from tasks.episode_checks import check_episode_homes
    from tools.cli import CliError, check_finite, check_output_dir, check_output_file
    from tools.tables import format_table

    for flag, value in (("--split", args.split), ("--episodes-file", args.episodes_file)):
        if value is not None and not value.strip():          # an empty one once meant the default
            raise CliError(f"{flag} must not be empty")
    if args.split is not None and args.episodes_file:
        # the id is looked up in one place: the file, which would leave --split silently ignored
        raise CliError("--split and --episodes-file both say where to look the episode id up; give one of them "
                       "(with --episodes-file, --split is ignored)")
    cfg = with_overrides(TsdfConfig(), list(args.overrides))
    check_finite(args.stream_hz, "--stream-hz", positive=True)
    if args.stream_hz > 1000:
        raise CliError(f"--stream-hz must be at most 1000 frames per simulated second, got {args.stream_hz:g}")
    out = check_output_dir(args.out)
    split = args.split or args.episode.split("-")[0]
    episodes = load_episodes(args.episodes_file) if args.episodes_file else load_split(split)
    matches = [e for e in episodes if e.episode_id == args.episode]
    if not matches:
        where = (f"episode file {short_repr(str(args.episodes_file), 200)}" if args.episodes_file
                 else f"split {short_repr(split, 40)}")
        raise CliError(f"no episode {short_repr(args.episode, 80)} in {where}")
    episode = matches[0]
    if args.episodes_file:
        check_episode_homes([episode], args.episodes_file)
    check_output_file(out / f"{episode.episode_id}_tsdf.ply", "--out")
    sim = SimEpisode.create(episode, replace(SimBackendConfig(), stream_hz=args.stream_hz, stream_renderer="inline"))
    tsdf = TsdfIntegrator(cfg)
    sim.backend.add_frame_listener(tsdf.integrate)
    try:
        print(f"[tsdf] {episode.episode_id}: {episode.task}; running the oracle, integrating {args.stream_hz:g} frames/s")
        result = run_episode(OracleAgent(sim), sim.backend, episode, RunnerConfig(), sim.judge, start_time=sim.world.time)
        points = tsdf.points()
        objects = [(*sim.world.position(oid)[:2], 0.5 * max(sim.world.bodies[oid].extra.get("size", (0.1, 0.1))[:2]) + 0.02)
                   for oid in sim.scene.object_ids.values()]
        rows = []
        names = [episode.start_receptacle] + list(episode.goal_receptacles)
        for name in dict.fromkeys(names):
            samples = receptacle_surface_samples(sim.scene, name, cfg.sample_spacing, objects)
            role = "start" if name == episode.start_receptacle else "goal"
            if len(samples):
                rows.append((name, role, len(samples), f"{100 * coverage(points, samples, cfg.tolerance):.1f}%"))
        mesh_path = out / f"{episode.episode_id}_tsdf.ply"
        triangles = tsdf.export_mesh(mesh_path)
    finally:
        sim.close()
    outcome = "success" if result.success else f"failed ({result.metrics.failure_reason})"
    print(f"[tsdf] episode {outcome}; {tsdf.frames} frames integrated, {len(points)} surface points")
    print(format_table(["receptacle", "role", "surface samples", f"covered within {100 * cfg.tolerance:.0f} cm"], rows,
                       title="True receptacle surfaces reconstructed by the robot's observations"))
    print(f"mesh: {mesh_path} ({triangles} triangles)")
    return 0
