"""Did a change keep every result? Run the same val episodes with the code of a commit and with
this working tree, both on this machine, and compare their records field by field (wall time,
memory and recording paths aside, as ``tools diff`` does).

    python -m tools unchanged HEAD                          # the working tree against the last commit
    python -m tools unchanged 3f77267 --runs helios,trusting --episodes 60

A refactor or an exact speed-up must give identical records; this is that check in one command.
Both sides run here because records can differ between machines (README, "One CPU code path"):
the reference records of ``tests/test_reference_records.py`` are exact only on the CPU that made
them, this check on any. Each run name is a scenario ``configs/val_<run>.yaml``, taken from each
side's own tree. Exit status 0 when every record of every run is identical, 1 when any differs,
2 for bad input.

The run folders stay under ``--out`` (``<run>/base`` and ``<run>/now``, the commit's files in
``base-tree``). The commit's side is kept: calling again with the same commit resumes it (a
killed check loses none of it) and a different commit starts it afresh. The working tree's side
is run afresh on every call, since the code may have changed since the last one.
"""

from __future__ import annotations

import argparse
import collections
import os
import re
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

from tools.cli import CliError, check_output_dir
from tools.commit_tree import ROOT, commit_has_file, extract_commit, resolve_commit

DEFAULT_RUNS = "helios,helios-no-global,trusting"
DEFAULT_EPISODES = 30
MAX_EPISODES = 1000
SECONDS_PER_EPISODE_LIMIT = 300.0     # a val episode takes 1-15 s wall; a side that needs more is hung
MARKER = ".helios-unchanged"          # what makes --out ours to clear


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("base", metavar="COMMIT", help="the commit to compare the working tree with (e.g. HEAD)")
    parser.add_argument("--runs", default=DEFAULT_RUNS, metavar="RUN[,RUN...]",
                        help=f"scenarios configs/val_<run>.yaml to run on both sides (default {DEFAULT_RUNS})")
    parser.add_argument("--episodes", type=int, default=DEFAULT_EPISODES, metavar="N",
                        help=f"the first N val episodes of each run (default {DEFAULT_EPISODES}, at most {MAX_EPISODES})")
    parser.add_argument("--workers", type=int, default=2, help="episodes in parallel on each side (default 2)")
    parser.add_argument("--out", default="runs/unchanged", help="folder for both sides' run folders "
                        "(default runs/unchanged)")
    parser.add_argument("--ignore", default="", metavar="FIELD[,FIELD...]",
                        help="dotted record fields to leave out, as in `tools diff` (e.g. config_fingerprint "
                             "when the change added a config key)")
    parser.add_argument("--fresh", action="store_true",
                        help="discard the commit's side of an earlier check under --out too and run it again")


def parse_runs(text: str) -> list[str]:
    """The run names of ``--runs``: non-empty, no repeats, each with a scenario in this tree."""
    names = [n.strip() for n in text.split(",")]
    if not text.strip() or any(not n for n in names):
        raise CliError(f"--runs {text!r}: give run names separated by commas, e.g. {DEFAULT_RUNS}")
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise CliError(f"--runs names {', '.join(repeated)} more than once")
    for n in names:
        if "/" in n or n.startswith("."):
            raise CliError(f"--runs: {n!r} is not a run name (the <run> of configs/val_<run>.yaml)")
        if not (ROOT / "configs" / f"val_{n}.yaml").is_file():
            known = sorted(p.stem[len("val_"):] for p in (ROOT / "configs").glob("val_*.yaml"))
            raise CliError(f"--runs: there is no configs/val_{n}.yaml; runs: {', '.join(known)}")
    return names


def check_arguments(args: argparse.Namespace) -> tuple[str, list[str], Path, frozenset[str]]:
    """Everything checked before any work: (the base commit's full hash, the runs, --out, --ignore)."""
    from tools.diff_runs import parse_ignore

    if not 1 <= args.episodes <= MAX_EPISODES:
        raise CliError(f"--episodes must be 1-{MAX_EPISODES}, got {args.episodes}")
    if not 1 <= args.workers <= 64:
        raise CliError(f"--workers must be 1-64, got {args.workers}")
    runs = parse_runs(args.runs)
    # absolute: each side's `tools trials` runs in its own tree, where a relative path (the
    # default --out) would name a folder that does not exist
    out = check_output_dir(args.out).resolve()
    if out.is_dir() and any(out.iterdir()) and not (out / MARKER).is_file():
        raise CliError(f"--out {str(out)!r} holds files that are not an earlier `tools unchanged` check's; "
                       f"name an empty or new folder")
    ignore = parse_ignore(args.ignore)
    commit = resolve_commit(args.base, "COMMIT")
    if commit is None:
        raise CliError(f"COMMIT {args.base!r} is not a commit of {ROOT} (try HEAD, a hash or a branch)")
    if not commit_has_file(commit, "tasks/trials.py", "COMMIT"):
        raise CliError(f"COMMIT {commit[:12]} has no tasks/trials.py: too old to run trials")
    missing = [r for r in runs if not commit_has_file(commit, f"configs/val_{r}.yaml", "COMMIT")]
    if missing:
        raise CliError(f"COMMIT {commit[:12]} has no {', '.join(f'configs/val_{r}.yaml' for r in missing)}")
    return commit, runs, out, ignore


def prepare(out: Path, commit: str, runs: list[str], fresh: bool) -> Path:
    """The base tree for ``commit`` under ``out``, extracted once; a different commit than the
    last check's (or ``fresh``) clears that check's folders first."""
    out.mkdir(parents=True, exist_ok=True)
    (out / MARKER).write_text("run folders of `python -m tools unchanged`; the command may clear this folder\n")
    last = out / "base-commit"
    stale = fresh or not last.is_file() or last.read_text().strip() != commit
    if stale:
        for child in out.iterdir():
            if child.is_dir():
                shutil.rmtree(child)
        last.unlink(missing_ok=True)
    for name in runs:                      # the working tree may have changed since the last check
        shutil.rmtree(out / name / "now", ignore_errors=True)
    tree = out / "base-tree"
    if not (tree / "tasks" / "trials.py").is_file():      # (check_arguments asked git that the commit has it)
        extract_commit(commit, tree, f"COMMIT {commit[:12]}")
        last.write_text(commit + "\n")
    return tree


PROGRESS = re.compile(r"\[trials\] (\d+/\d+ .*)")     # `tools trials --progress lines`: one per episode
STOP_GRACE_S = 15.0


def run_side(tree: Path, run: str, episodes: int, workers: int, folder: Path, label: str) -> float:
    """``tools trials`` for ``run`` with the code in ``tree``, its own interpreter's packages,
    into ``folder`` (resumed if it holds some of the episodes), its progress passed on one line per
    episode; its wall seconds. A side that fails or outlives its time limit is a CliError with its
    last lines; an interrupted one is given ``STOP_GRACE_S`` to stop (it keeps what it finished)."""
    cmd = [sys.executable, "-m", "tools", "trials", "--config", str(tree / "configs" / f"val_{run}.yaml"),
           "--episodes", str(episodes), "--workers", str(workers), "--no-pictures", "--progress", "lines",
           "--out", str(folder.resolve())]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tree), *filter(None, [os.environ.get("PYTHONPATH")])])}
    if tree != ROOT:    # an extracted tree has no .git: git must not find this checkout's (a wrong commit)
        env["GIT_CEILING_DIRECTORIES"] = str(tree.resolve().parent)
    limit = 120.0 + SECONDS_PER_EPISODE_LIMIT * episodes / workers
    print(f"[unchanged] {run}: {label}, {episodes} episode(s) -> {folder}", flush=True)
    t0 = time.perf_counter()
    tail: collections.deque[str] = collections.deque(maxlen=20)
    proc = subprocess.Popen(cmd, cwd=tree, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            errors="replace")

    def pump() -> None:
        for line in proc.stdout:
            tail.append(line.rstrip("\n"))
            m = PROGRESS.match(line)
            if m:
                print(f"[unchanged] {run} ({label}): {m.group(1).strip()}", flush=True)

    reader = threading.Thread(target=pump, daemon=True)
    reader.start()
    try:
        code = proc.wait(timeout=limit)
    except subprocess.TimeoutExpired:
        _stop(proc, signalled=False)
        raise CliError(f"{run} ({label}) did not finish {episodes} episode(s) within {limit:.0f} s; what it "
                       f"finished is kept in {str(folder)!r} and a second call resumes it") from None
    except BaseException:                  # Ctrl-C reaches the child too: let it keep what it finished
        _stop(proc)
        raise
    reader.join(timeout=5.0)
    if code != 0:
        last = " | ".join(line for line in list(tail)[-3:] if line.strip())
        raise CliError(f"{run} ({label}): `tools trials` exited with status {code}: {last}")
    return time.perf_counter() - t0


def _stop(proc: subprocess.Popen, signalled: bool = True) -> None:
    """Stop a side: wait up to ``STOP_GRACE_S`` for it to stop on its own when it was sent the same
    signal as this process (``signalled``), then terminate it, then kill it."""
    for action in ((None,) if signalled else ()) + (proc.terminate, proc.kill):
        if action is not None:
            action()
        try:
            proc.wait(timeout=STOP_GRACE_S)
            return
        except subprocess.TimeoutExpired:
            continue


def compare(out: Path, runs: list[str], episodes: int, workers: int, ignore: frozenset[str],
            base: tuple[Path, str], now: tuple[Path, str] = (ROOT, "this working tree")) -> bool:
    """Run each of ``runs`` with the code of ``base`` and of ``now`` (each a tree and its label)
    into ``out/<run>/base`` and ``out/<run>/now``, print each comparison and a verdict per run;
    whether every record of every run is identical and every episode finished on both sides."""
    from tools.diff_runs import diff_runs, report_lines
    from tools.report_runs import load_run

    verdicts = []
    for name in runs:
        folders = {side: out / name / side for side in ("base", "now")}
        for side, (code, label) in (("base", base), ("now", now)):
            seconds = run_side(code, name, episodes, workers, folders[side], label)
            print(f"[unchanged] {name}: {label} done in {seconds:.0f} s", flush=True)
        warnings: list[str] = []
        a, b = load_run(folders["base"], warnings=warnings), load_run(folders["now"], warnings=warnings)
        diff = diff_runs(a, b, episodes, ignore, common=True)     # an episode missing on a side: checked below
        for w in warnings:
            print(f"warning: {w}", file=sys.stderr)
        print("\n".join(report_lines(a, b, diff)))
        verdicts.append((name, diff))
    print()
    for name, diff in verdicts:
        what = "" if not diff.differing else f" ({len(diff.differing)} differ)"
        short = len(diff.compared) < episodes
        print(f"{name}: {diff.identical} of {len(diff.compared)} records identical{what}, {now[1]} against "
              f"{base[1]}" + (f"; only {len(diff.compared)} of the {episodes} episodes finished on both sides"
                              if short else ""))
    fields = {path for _, d in verdicts for diffs in d.differing.values() for path, _a, _b in diffs}
    if fields == {"config_fingerprint"}:
        print("only config_fingerprint differs: the change added (or renamed) a config key; if that was all, "
              "run again with --ignore config_fingerprint")
    same = all(not d.differing and len(d.compared) == episodes for _, d in verdicts)
    print("unchanged: every record is the same" if same else
          "CHANGED: records differ (above); a deliberate behaviour change says so in its commit")
    return same


def run(args: argparse.Namespace) -> int:
    commit, runs, out, ignore = check_arguments(args)
    tree = prepare(out, commit, runs, args.fresh)
    same = compare(out, runs, args.episodes, args.workers, ignore, base=(tree, f"commit {commit[:10]}"))
    return 0 if same else 1
