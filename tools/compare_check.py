"""The checks `make compare` and `make sensitivity` run before their first episode: the
Makefile's variables (COMPARE, PICK_LIMITS, SPLIT, SENSITIVITY) are otherwise first read by
`tools report`, after every run has finished (7 runs of 200 episodes: an hour and more on 2
cores), and a misspelt run name or setting only when its turn comes.

    python -m tools.compare_check "$(COMPARE)" "$(PICK_LIMITS)" "$(SPLIT)" ["$(SENSITIVITY)"]   # one error line, exit 2
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _distinct_words(text: str, variable: str, noun: str, example: str, shown=repr) -> list[str]:
    """The space-separated words of the Makefile variable ``variable``; CliError when there are
    none or one comes twice (``shown`` writes it in the message)."""
    from tools.cli import CliError

    words = text.split()
    if not words:
        raise CliError(f"{variable} is empty: name the {noun}, e.g. {example}")
    twice = next((w for i, w in enumerate(words) if w in words[:i]), None)
    if twice is not None:
        raise CliError(f"{variable} names {shown(twice)} twice")
    return words


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
    runs = _distinct_words(compare, "COMPARE", "runs", 'COMPARE="helios trusting"')
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


# settings every run of `make sensitivity` shares, and what gives them
RUN_SHAPE_KEYS = {"split": "SPLIT= gives it", "episodes_file": "SPLIT= names the episodes", "episodes": "N= gives it",
                  "agent": "every run is HELIOS; make compare compares agents"}


def check_sensitivity(sensitivity: str, scenario: Path = ROOT / "configs" / "val_helios.yaml") -> list[str]:
    """The settings of ``sensitivity`` (space-separated ``KEY=VALUE``, one run each), each checked as
    `tools trials --config <scenario> KEY=VALUE` checks it (a known key, a valid value, a setting
    the agent reads); CliError naming the first problem: none given, one given twice, one that sets
    the runs' split, length or agent (those are the Makefile's SPLIT, N and COMPARE: a setting
    would make one run incomparable with the rest), or one with a "/" (each setting names its run
    folder, runs/<SPLIT>/sensitivity/KEY=VALUE)."""
    import argparse

    from helios.schema import ConfigError, short_repr
    from tools.cli import CliError
    from tools.trials import resolve_config

    settings = _distinct_words(sensitivity, "SENSITIVITY", "settings", 'SENSITIVITY="helios.decision.tau_object=0.3"',
                               shown=lambda s: short_repr(s, 80))
    for setting in settings:
        key = setting.partition("=")[0].strip()
        if key in RUN_SHAPE_KEYS:
            raise CliError(f"SENSITIVITY: {short_repr(setting, 80)} sets {key}, which is the same for every run "
                           f"({RUN_SHAPE_KEYS[key]})")
        if "/" in setting:
            raise CliError(f"SENSITIVITY: {short_repr(setting, 80)} holds a '/', but each setting names its run "
                           f"folder (runs/<SPLIT>/sensitivity/KEY=VALUE)")
        args = argparse.Namespace(config=str(scenario), agent=None, split=None, episodes_file=None, episodes=None,
                                  seed=None, overrides=[setting])
        try:
            resolve_config(args)
        except ConfigError as exc:
            raise CliError(f"SENSITIVITY: {exc}") from None
    return settings


def main(argv: list[str]) -> int:
    from tools.cli import CliError

    if len(argv) not in (2, 3, 4):
        print('usage: python -m tools.compare_check "COMPARE" "PICK_LIMITS" ["SPLIT" ["SENSITIVITY"]]', file=sys.stderr)
        return 2
    try:
        check(*argv[:3])
        if len(argv) == 4:
            check_sensitivity(argv[3])
    except CliError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
