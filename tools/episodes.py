"""Episode datasets: generate a split from any seed, or check and summarise an episode file.

    python -m tools episodes generate --name heldout --seed 7 --count 200 --out heldout.jsonl
    python -m tools episodes generate --name large --seed 8 --count 60 --home-size 12 15 --out large.jsonl
    python -m tools episodes check tasks/data/val.jsonl
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    gen = sub.add_parser("generate", help="generate validated episodes deterministically from a seed")
    gen.add_argument("--name", required=True, help="split name (prefix of every episode id)")
    gen.add_argument("--seed", type=int, required=True)
    gen.add_argument("--count", type=int, required=True)
    gen.add_argument("--difficulty", default="normal", choices=["easy", "normal"], help="default: %(default)s")
    gen.add_argument("--home-size", type=float, nargs=2, metavar=("MIN", "MAX"), default=None,
                     help="bounds (m) of each home's side lengths, instead of the difficulty's (normal 8-15, "
                          "easy 8-9.5); e.g. 12 15 for a split of large homes only")
    gen.add_argument("--out", required=True, help="JSONL file to write")
    chk = sub.add_parser("check", help="validate an episode file and print what it holds")
    chk.add_argument("file")


def run(args: argparse.Namespace) -> int:
    import re

    from helios.schema import short_repr
    from tasks.episodes import generate_episodes, load_episodes, save_episodes
    from tools.cli import CliError, check_output_file, check_seed

    if args.action == "generate":
        if args.count <= 0:
            raise CliError(f"--count must be positive, got {args.count}")
        if args.count > 100_000:
            raise CliError(f"--count must be at most 100000, got {args.count}")
        check_seed(args.seed)
        if not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,80}", args.name):
            raise CliError(f"--name {short_repr(args.name, 80)} must be 1-81 letters, digits, '-', '_' or '.' "
                           f"(it starts every episode id)")
        if args.home_size is not None:
            from tasks.episodes import MAX_HOME_SIZE, MIN_HOME_SIZE, home_sizes_valid

            lo, hi = args.home_size
            if not home_sizes_valid(lo, hi):
                raise CliError(f"--home-size needs {MIN_HOME_SIZE:g} <= MIN <= MAX <= {MAX_HOME_SIZE:g} (m), "
                               f"got {lo:g} {hi:g}")
        check_output_file(args.out, "--out")
        progress = _Progress("")
        episodes = generate_episodes(args.name, args.seed, args.count, args.difficulty, progress,
                                     home_size=tuple(args.home_size) if args.home_size else None)
        progress.close()
        save_episodes(episodes, args.out)
        print(f"wrote {len(episodes)} episodes to {args.out}")
        return 0
    episodes = load_episodes(args.file)
    from tasks.episode_checks import check_episode_homes

    progress = _Progress("homes checked ")      # ~0.1-0.4 s per home: a 1000-episode split takes a minute or two
    check_episode_homes(episodes, args.file, progress)   # the checks `trials --episodes-file` makes
    progress.close()
    scenes = {e.scene.seed for e in episodes}
    objects = Counter(e.object_category for e in episodes)
    n, homes = len(episodes), len(scenes)
    print(f"{args.file}: {n} valid episode{'s' * (n != 1)} in {homes} home{'s' * (homes != 1)}")
    print("objects: " + ", ".join(f"{k} {v}" for k, v in objects.most_common()))
    print("goal receptacles: " + ", ".join(f"{k} {v}" for k, v in Counter(e.goal_receptacle_category
                                                                              for e in episodes).most_common()))
    return 0


class _Progress:
    """``progress(done, total)`` for long loops: one updating line on a terminal, otherwise a line
    per tenth (logs stay short)."""

    def __init__(self, label: str) -> None:
        self.label, self.tty, self.shown = label, sys.stdout.isatty(), False

    def __call__(self, done: int, total: int) -> None:
        if self.tty:
            print(f"\r[episodes] {self.label}{done}/{total}", end="", flush=True)
            self.shown = True
        elif done == total or done % max(1, total // 10) == 0:
            print(f"[episodes] {self.label}{done}/{total}", flush=True)

    def close(self) -> None:
        if self.shown:
            print()
