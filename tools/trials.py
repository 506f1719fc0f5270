"""Run a trial batch: an agent over episodes of a split (or your own episode file), with resumable
results, a printed OVMM-style table and ``summary.json``.

    python -m tools trials --agent oracle --split smoke --episodes 20 --seed 0 --out runs/NAME
    python -m tools trials --agent oracle --split val --episodes 200 --workers 2 --out runs/val200
    python -m tools trials --agent oracle --episodes-file my_eval.jsonl --out runs/mine runner.max_sim_time=300
    python -m tools trials ... --executor ray --address local|auto|HOST:PORT   (pip install -e '.[ray]')
    python -m tools trials ... --record 3      (rerun recordings of the first 3 episodes)
    python -m tools trials ... --no-pictures   (skip the per-episode picture data in OUT/episodes/)
    python -m tools trials --config configs/val_helios.yaml --workers 2 --out runs/val/helios
    python -m tools trials --config runs/val/helios/config.yaml --episodes 300 --out runs/val/helios

Scenario files: ``--config FILE.yaml`` loads a trial config (schema ``tasks.trial_config.TrialConfig``;
examples in ``configs/``), then ``--agent``/``--split``/``--episodes-file``/``--episodes``/``--seed``
override it where given, then ``KEY=VALUE`` overrides. A run folder's ``config.yaml`` is such a
file (its ``helios_version``/``git_commit`` header is provenance, checked and otherwise ignored):
fed back with the same ``--out`` it resumes that run.

Re-running the same command continues an interrupted batch (finished episodes are skipped); the
number of workers, the executor, recording and pictures may change between runs without changing a
number.
"""

from __future__ import annotations

import argparse
import dataclasses
import signal
import sys
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from tasks.episodes import SPLITS
    from tasks.executors import EXECUTORS, WORKER_EPISODES
    from tasks.registry import agent_names
    from tools.progress import MODES

    parser.add_argument("--config", default=None, metavar="FILE.yaml",
                        help="scenario file: a trial config (e.g. configs/smoke.yaml, or a run folder's config.yaml); "
                             "the flags below and KEY=VALUE override it")
    parser.add_argument("--agent", default=None,
                        help=f"agent (default oracle): {', '.join(agent_names())}; or your own, FILE.py:FACTORY or "
                             f"package.module:FACTORY (README, \"Your own agent\")")
    parser.add_argument("--split", default=None, help=f"episode split (default smoke): {', '.join(SPLITS)}")
    parser.add_argument("--episodes-file", default=None,
                        help="JSONL episode file, instead of --split (it replaces a scenario file's split)")
    parser.add_argument("--episodes", type=int, default=None,
                        help="number of episodes from the start of the split (default 20)")
    parser.add_argument("--seed", type=int, default=None, help="master seed (per-episode seeds derive from it; default 0)")
    parser.add_argument("--out", default=None, help="run folder (default: runs/<agent>_<split>_s<seed>)")
    parser.add_argument("--workers", type=int, default=1,
                        help="episodes in parallel: local worker processes, or Ray CPUs with --address local")
    parser.add_argument("--worker-episodes", type=int, default=WORKER_EPISODES, metavar="N",
                        help=f"replace a local worker process by a fresh one after N episodes, which bounds its "
                             f"memory (PyBullet leaks ~11 MB per episode); 0 = never (default {WORKER_EPISODES})")
    parser.add_argument("--executor", default="local", choices=EXECUTORS,
                        help="local processes (default) or a Ray cluster (optional extra: pip install -e '.[ray]')")
    parser.add_argument("--address", default="local",
                        help="Ray cluster: 'local' (a private loopback-only instance), 'auto', or HOST:PORT")
    parser.add_argument("--record", type=int, default=0, metavar="N",
                        help="write rerun recordings of the first N episodes to OUT/recordings/")
    parser.add_argument("--no-pictures", action="store_true",
                        help="do not keep each episode's picture data (OUT/episodes/<id>.npz, 40-140 kB each; "
                             "drawn by `tools report` as one page per episode)")
    parser.add_argument("--replace-stale", action="store_true",
                        help="if the run folder holds results of a different configuration or of another commit, "
                             "move it aside to <out>.<date-time> and start a new run there, instead of refusing "
                             "it (a different configuration) or resuming it (another commit); `make run` uses this")
    parser.add_argument("--progress", default="auto", choices=MODES,
                        help="bar on a terminal, one line per episode otherwise (auto)")
    parser.add_argument("overrides", nargs="*", metavar="KEY=VALUE",
                        help="config overrides, e.g. runner.max_sim_time=300 sim.camera.width=640")


# flags that set a TrialConfig field (argparse dest = field name); None = not given
CONFIG_FLAGS = ("agent", "split", "episodes_file", "episodes", "seed")


def resolve_config(args: argparse.Namespace):
    """Defaults < ``--config`` file < flags given on the command line < ``KEY=VALUE`` overrides.
    Settings the agent would not use (``tasks.registry.check_agent_settings``) are refused."""
    from helios.schema import ConfigError, short_repr, with_overrides
    from tasks.episodes import SPLITS
    from tasks.plugin_agents import canonical_spec, is_plugin_spec
    from tasks.registry import check_agent_settings
    from tasks.trial_config import TrialConfig, canonical_episodes_file, load_trial_config

    base = TrialConfig()
    for flag in ("config", "episodes_file", "split", "agent"):     # an empty one once meant "the default"
        value = getattr(args, flag, None)
        if value is not None and not str(value).strip():
            raise ConfigError(f"--{flag.replace('_', '-')} must not be empty")
    if getattr(args, "config", None):
        header, base = load_trial_config(args.config)
        _check_provenance(args.config, header)
    flags = {name: getattr(args, name) for name in CONFIG_FLAGS if getattr(args, name, None) is not None}
    # a flag and an override that set the same field: one would be dropped without a word
    set_by_override = {o.partition("=")[0].strip(): o for o in args.overrides}
    for name in flags:
        if name in set_by_override:
            raise ConfigError(f"--{name.replace('_', '-')} and {short_repr(set_by_override[name], 60)} both set "
                              f"{name}; give one")
    given = {**{k: f"--{k.replace('_', '-')}" for k in flags}, **{k: short_repr(v, 60) for k, v in set_by_override.items()}}
    config = with_overrides(with_overrides(base, flags), list(args.overrides))
    if config.episodes_file and config.split not in SPLITS:     # replaced by the file, but never misspelt unseen
        raise ConfigError(f"unknown split {short_repr(config.split, 40)}; valid splits: {', '.join(SPLITS)}")
    if "split" in given and "episodes_file" in given and config.episodes_file:
        raise ConfigError(f"{given['split']} and {given['episodes_file']} both name the episodes; give one")
    check_agent_settings(config, explicit=[o.partition("=")[0] for o in args.overrides])
    # one spelling of the episode file however it was named (relative or absolute, from a flag, an
    # override or a --config file), so that the same file gives the same configuration fingerprint
    # (tasks.trial_config.canonical_episodes_file); the same for the file of an agent of your own
    agent = canonical_spec(config.agent) if is_plugin_spec(config.agent) else config.agent
    return dataclasses.replace(config, episodes_file=canonical_episodes_file(config.episodes_file), agent=agent)


def _check_map_covers_homes(config, episodes) -> None:
    """The agent's map grid is at least as wide as the episodes' homes can be: a 64-cell grid (1.6 m)
    was accepted and every episode ended on an OpenCV error deep in the search (determinism audit).
    An agent without a map (the oracle) is refused any map setting elsewhere."""
    from tasks.registry import reads_section
    from tools.cli import CliError

    if not reads_section(config.agent, "helios"):
        return
    occ = config.helios.occupancy
    side = occ.grid_size * occ.cell_size
    widest = max(e.scene.max_size for e in episodes)
    if side < widest:
        raise CliError(f"helios.occupancy.grid_size={occ.grid_size} cells of {occ.cell_size:g} m is a {side:g} m map, "
                       f"narrower than these episodes' homes (up to {widest:g} m a side); the paper's is 2000 "
                       f"cells (50 m)")


def _check_writable_parts(out: Path, record: int, pictures: bool) -> None:
    """The parts of an existing run folder this batch writes to can be written: a read-only
    ``episodes/`` (or recordings/, or results file) once failed only after the first episode had
    run, which was then thrown away (reliability audit)."""
    import os

    from tools.cli import CliError, check_output_dir

    for name, used in (("episodes", pictures), ("recordings", record > 0)):
        if used and (out / name).is_dir():
            check_output_dir(out / name, flag=f"--out {str(out)!r}: its {name}/ folder")
    results = out / "episodes.jsonl"
    if results.is_file() and not os.access(results, os.W_OK):
        raise CliError(f"--out {str(out)!r}: its episodes.jsonl cannot be written (read-only)")


def _stop_as_interrupt(signum, frame):
    raise KeyboardInterrupt(signal.Signals(signum).name)


def _check_provenance(path: str, header: dict) -> None:
    """A run folder's config.yaml names the version and commit that made it: say when they differ."""
    from tasks.provenance import differs, git_commit, package_version

    made = {"helios_version": header.get("helios_version"), "git_commit": header.get("git_commit")}
    now = {"helios_version": package_version(), "git_commit": git_commit()}
    if any(differs(made[k], now[k]) for k in made):
        print(f"warning: {path} was written by helios {made['helios_version']} at commit "
              f"{str(made['git_commit'])[:10]}; this is {now['helios_version']} at {now['git_commit'][:10]}: "
              f"the same config may not give the same numbers", file=sys.stderr)


def select_episodes(config):
    """The first ``config.episodes`` episodes of the split or file. Episodes from a file are also
    checked against the homes they name (``tasks.episode_checks``); the committed splits are
    checked by the test suite."""
    from tasks.episode_checks import check_episode_homes
    from tasks.episodes import DatasetError, load_episodes, load_split

    episodes = load_episodes(config.episodes_file) if config.episodes_file else load_split(config.split)
    if config.episodes <= 0:
        raise DatasetError(f"--episodes must be positive, got {config.episodes}")
    if config.episodes > len(episodes):
        source = config.episodes_file or f"split {config.split!r}"
        raise DatasetError(f"{source} has {len(episodes)} episodes, fewer than the {config.episodes} requested")
    if config.episodes_file:
        check_episode_homes(episodes[:config.episodes], config.episodes_file)
    return episodes[:config.episodes]


def default_out(config) -> Path:
    """``runs/<agent>_<split or episode file>_s<seed>``; an agent of your own is named by its file
    (or module) and factory: ``my_agent.py:make`` -> ``my_agent-make``."""
    from tasks.plugin_agents import is_plugin_spec, parse_spec

    source = Path(config.episodes_file).stem if config.episodes_file else config.split
    agent = config.agent
    if is_plugin_spec(agent):
        module, factory, is_file = parse_spec(agent)
        agent = f"{Path(module).stem if is_file else module}-{factory}"
    return Path(f"runs/{agent}_{source}_s{config.seed}")


def run(args: argparse.Namespace) -> int:
    import os

    from robots.spot.signals import handling_signals
    from tasks.executors import check_address
    from tasks.plugin_agents import is_plugin_spec
    from tasks.registry import check_agent
    from tasks.run_folder import (FolderLock, RunFolderError, check_folder_layout, move_aside, prepare_run_folder,
                                  read_results, stale_results)
    from tasks.trial_config import check_devices
    from tasks.trials import BatchReport, EpisodeSetupError, run_batch, run_folder_episodes
    from tools.cli import CliError, check_output_dir
    from tools.progress import Progress

    config = resolve_config(args)
    check_agent(config.agent)
    if args.executor == "ray" and is_plugin_spec(config.agent):
        raise CliError(f"--agent {config.agent}: an agent of your own runs on local workers (--executor local); Ray "
                       f"workers may run on machines without its file")
    if args.workers < 1:
        raise CliError(f"--workers must be >= 1, got {args.workers}")
    if args.workers > 1024:
        raise CliError(f"--workers must be <= 1024, got {args.workers}")
    if args.record < 0:
        raise CliError(f"--record must be >= 0, got {args.record}")
    if not 0 <= args.worker_episodes <= 1_000_000:
        raise CliError(f"--worker-episodes must be in [0, 1000000] (0 = never replace a worker), got {args.worker_episodes}")
    if args.executor == "local" and args.address != "local":
        raise CliError("--address only applies to --executor ray")
    if args.executor == "ray":
        check_address(args.address)           # syntax, then a bounded wait for the head to answer
    if args.executor == "local" or args.address == "local":
        check_devices(config)                 # (a Ray cluster's workers may have the device this machine lacks)
    episodes = select_episodes(config)
    _check_map_covers_homes(config, episodes)
    if args.record > len(episodes):      # once silently the number of episodes
        raise CliError(f"--record {args.record} is more than the {len(episodes)} episode(s) of this run; "
                       f"give at most {len(episodes)}")
    out = check_output_dir(args.out if args.out is not None else default_out(config))
    if args.replace_stale:
        why = stale_results(out, config)
        if why:
            moved = move_aside(out)
            print(f"[trials] {out} held {why}; moved it to {moved} and starting a new run", flush=True)
    check_folder_layout(out, args.record, not args.no_pictures)
    _check_writable_parts(out, args.record, not args.no_pictures)
    # refuse a folder before creating or locking anything (checked as run_batch will check it)
    try:
        prepare_run_folder(out, config, dry_run=True, **run_folder_episodes(config, episodes))
    except RunFolderError as exc:
        if args.replace_stale or not stale_results(out, config):
            raise
        raise RunFolderError(f"{exc}, or --replace-stale to move it aside and start a new run in it") from None
    FolderLock(out).check_free()      # a folder another batch is running: say so before "resuming: ..."
    where = "" if args.executor == "local" else f" on Ray ({args.address})"
    print(f"[trials] {config.agent} on {len(episodes)} episode(s) "
          f"({config.episodes_file or 'split ' + config.split}), seed {config.seed}, "
          f"{args.workers} worker(s){where}; results in {out}/", flush=True)

    ids = {e.episode_id for e in episodes}
    before = {k: v for k, v in read_results(out / "episodes.jsonl").items() if k in ids}
    if before:
        print(f"[trials] resuming: {len(before)} of {len(episodes)} episode(s) already finished", flush=True)
    progress = Progress(len(episodes), done=len(before), successes=sum(bool(r.get("success")) for r in before.values()),
                        workers=args.workers, mode=args.progress)
    report = BatchReport([])
    finished = False
    try:
        # SIGTERM (kill, a scheduler, Docker) and SIGHUP (a closed terminal) stop the batch the way
        # Ctrl-C does, with its message, instead of killing it silently (the records were safe
        # either way); one the process was started with ignored (nohup) stays ignored
        with handling_signals(("SIGTERM", "SIGHUP"), _stop_as_interrupt):
            records = run_batch(config, episodes, out, on_episode=lambda r, d, t: progress.update(r),
                                workers=args.workers, executor=args.executor, address=args.address,
                                record=args.record, on_tick=progress.tick, report=report,
                                pictures=not args.no_pictures, worker_episodes=args.worker_episodes)
            finished = True
            progress.close()
            # the handler stays while the summary prints: a signal now ends it with a line, not silently
            return _print_summary(args, out, records, report)
    except EpisodeSetupError as exc:
        progress.close()
        print(f"error: {exc}" + ("" if os.environ.get("HELIOS_DEBUG") else " (HELIOS_DEBUG=1 shows the traceback)"),
              file=sys.stderr)
        if os.environ.get("HELIOS_DEBUG"):
            print(exc.trace, file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        progress.close()
        name = str(exc) if str(exc) in ("SIGTERM", "SIGHUP") else ""
        if finished:
            lost = (f"; {len(report.crashed)} episode(s) whose worker process died were not recorded: re-run the "
                    f"same command to retry them" if report.crashed else "")
            print(f"interrupted{f' ({name})' if name else ''} after the batch finished, while printing its summary; "
                  f"results in {out}/summary.json and {out}/episodes.jsonl{lost}", file=sys.stderr)
        else:
            print(f"interrupted{f' ({name})' if name else ''}; finished episodes are saved in {out}/episodes.jsonl: "
                  f"re-run the same command to continue", file=sys.stderr)
        return 128 + getattr(signal, name) if name else 130


def _print_summary(args, out: Path, records: list, report) -> int:
    """The finished batch's warnings, table and file names; the exit status (1 when a worker died)."""
    from tasks.trial_summary import METRIC_NAMES, metrics_table_rows, summarize
    from tools.progress import format_duration
    from tools.tables import format_markdown, format_table

    for note in report.notes:
        print(f"warning: {out}: {note}", file=sys.stderr)
    if report.commit_changed:
        print(f"warning: this run folder was started at commit {report.commit_changed[:10]}; episodes from "
              f"different code versions are mixed", file=sys.stderr)
    if report.agent_source_changed:
        print(f"warning: earlier episodes of this run folder were made by another version of its agent's source "
              f"file (sha256 {report.agent_source_changed}, invocations.jsonl): episodes from different versions of "
              f"the agent are mixed; --replace-stale starts afresh", file=sys.stderr)
    if report.cpu_changed:
        print(f"warning: earlier episodes of this run folder ran on other CPU code paths ({report.cpu_changed}); "
              f"episodes from different code paths can differ in outcome (README, \"One CPU code path\")",
              file=sys.stderr)
    summary = summarize(records)
    headers = ["run"] + list(METRIC_NAMES.values())
    rows = [metrics_table_rows(out.name, summary)]
    print()
    scored = summary["scored"]
    unscored = f" ({scored} scored: the rates are over those)" if scored != len(records) else ""
    print(format_table(headers, rows, title=f"{len(records)} episodes{unscored}, percent ± standard error"))
    reasons = ", ".join(f"{k} {v}" for k, v in summary["failure_reasons"].items() if v) or "none"
    mem = summary["memory"]["peak_rss_mb"]
    print(f"failure reasons: {reasons}; collisions per episode {summary['collisions_per_episode']:.2f}; "
          f"{summary['sim_seconds_per_episode']:.0f} s simulated, {summary['wall_seconds_per_episode']:.1f} s wall "
          f"per episode" + (f"; peak RSS {mem['max']:.0f} MB" if mem else ""))
    if report.ran:
        rate = 3600.0 * report.ran / report.wall_seconds if report.wall_seconds > 0 else 0.0
        print(f"this run: {report.ran} episode(s) in {format_duration(report.wall_seconds)} "
              f"({rate:.0f} episodes/hour with {args.workers} worker(s)); {report.skipped} already done")
    print()
    print(format_markdown(headers, rows))
    print(f"\nsummary: {out / 'summary.json'}   episodes: {out / 'episodes.jsonl'}")
    if args.record:
        print(f"recordings: {out / 'recordings'}/   (view: python -m tools view FILE.rrd)")
    if summary["errors"]:
        print(f"warning: {summary['errors']} episode(s) ended on an exception; see 'error' in episodes.jsonl",
              file=sys.stderr)
    if report.crashed:
        listed = "; ".join(f"{k}: {v}" for k, v in sorted(report.crashed.items()))
        print(f"error: {len(report.crashed)} episode(s) were not recorded because their worker process died "
              f"({listed}); re-run the same command to retry them", file=sys.stderr)
        return 1
    return 0
