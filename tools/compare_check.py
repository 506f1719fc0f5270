"""The checks `make compare` runs before its first episode: the Makefile's variables (COMPARE,
PICK_LIMITS, SPLIT) are otherwise first read by `tools report`, after every run has finished (7
runs of 200 episodes: an hour and more on 2 cores), and a misspelt run name only when its turn comes.

    python -m tools.compare_check "$(COMPARE)" "$(PICK_LIMITS)" "$(SPLIT)"    # one error line, exit 2
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def check(compare: str, pick_limits: str, split: str = "val", configs: Path = ROOT / "configs") -> list[str]:
    """The run names of ``compare`` (space-separated); CliError naming the first problem: none
    given, one named twice (the report would pair a run with itself), one without its scenario file
    ``configs/val_<run>.yaml``, ``pick_limits`` that `tools report --pick-limits` refuses, or a
    ``split`` that is not one of the committed splits."""
    from tasks.episodes import SPLITS
    from tools.cli import CliError
    from tools.report import parse_pick_limits

    if split not in SPLITS:
        raise CliError(f"SPLIT {split!r} is not a split; valid splits: {', '.join(SPLITS)}")
    runs = compare.split()
    if not runs:
        raise CliError('COMPARE is empty: name the runs, e.g. COMPARE="helios trusting"')
    twice = next((r for i, r in enumerate(runs) if r in runs[:i]), None)
    if twice is not None:
        raise CliError(f"COMPARE names {twice!r} twice")
    known = sorted(p.stem.removeprefix("val_") for p in configs.glob("val_*.yaml"))
    for run in runs:
        if not (configs / f"val_{run}.yaml").is_file():
            raise CliError(f"COMPARE names {run!r}, but configs/val_{run}.yaml does not exist; runs with a scenario "
                           f"file: {' '.join(known)}")
    if pick_limits.strip():
        try:
            parse_pick_limits(pick_limits)
        except CliError as exc:
            raise CliError(f"PICK_LIMITS: {exc}") from None
    return runs


def main(argv: list[str]) -> int:
    from tools.cli import CliError

    if len(argv) not in (2, 3):
        print('usage: python -m tools.compare_check "COMPARE" "PICK_LIMITS" ["SPLIT"]', file=sys.stderr)
        return 2
    try:
        check(*argv)
    except CliError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
