"""``python -m tools bench agent``: what a HELIOS episode costs on this machine, and where it goes.

1. Wall time of whole val episodes (1 torch/BLAS thread, as a trial worker), each run as
   ``tools trials --seed 0`` runs it (the agent gets the episode's trial seed; ``--agent-seed``
   picks another master seed, or ``own`` for the episodes' own seeds), split per phase:
   the simulator's share (time inside HAL commands: physics, rendering, motion, collision
   queries), the agent's perception, map update and planning, its decisions and the rest, and
   the scene build; then the projected hours of the paper's ablation table (5 agents and their
   gt twins) on the 1000-episode val split with 2 workers.
2. Planner replans on the default 2000 x 2000 (2.5 cm) grid: the maps HELIOS built in the first
   two episodes (a home of 8-15 m explored) and the whole grid explored; random start/goal pairs.
3. ``--agent-profile``: every episode under cProfile, with the cumulative seconds per profiled
   phase (simulator stepping, rendering, collisions; map rendering, update, re-clustering;
   planning's FMM solve, clearance transforms, footprint checks, action generation; view
   information gain; perception) and the top functions by own time.
4. ``--agent-baseline REF``: the same episodes and replans for another commit (its files are
   extracted with ``git archive``) or a JSON file written by ``--agent-save``, printed side by
   side. Two worker processes answer in turn, episode by episode, so load hits both alike.

Targets (issue "Twice as fast"): median val episode <= 5 s wall; replan p90 <= 100 ms on the home
maps and whole-grid median <= 150 ms; peak RSS per worker not above ~765 MB.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import statistics
import subprocess
import sys
import tempfile
import threading
from pathlib import Path
from typing import NamedTuple

import numpy as np

from helios.schema import finite_number, shorten
from tools.cli import CliError, check_output_file

ROOT = Path(__file__).resolve().parents[1]
WORKER = Path(__file__).resolve().with_name("bench_agent_worker.py")
TABLE_RUNS, TABLE_EPISODES, TABLE_WORKERS = 10, 1000, 2     # the paper's table: 5 agents + gt twins
EPISODE_TIMEOUT_S = 1800.0
SAVE_FORMAT = "helios-bench-agent/1"
DEFAULT_EPISODES, DEFAULT_REPLANS = 6, 40
QUICK_EPISODES, QUICK_REPLANS = 2, 10          # --quick's defaults; an explicit value still wins


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("agent suite")
    group.add_argument("--agent-name", default="helios", help="registered agent to time (default helios)")
    # default None, so that an explicit value is known and wins over --quick (see episode_counts)
    group.add_argument("--agent-episodes", type=int, default=None,
                       help=f"val episodes to run (default {DEFAULT_EPISODES}; --quick: {QUICK_EPISODES})")
    group.add_argument("--agent-replans", type=int, default=None,
                       help=f"planner calls per map (default {DEFAULT_REPLANS}; --quick: {QUICK_REPLANS})")
    group.add_argument("--agent-repeats", type=int, default=1, metavar="N",
                       help="run each episode N times per tree (interleaved) and keep the run with the least "
                            "wall time: steadier ratios on a shared or busy machine (default 1)")
    group.add_argument("--agent-seed", default="0", metavar="SEED",
                       help="master seed of the episodes' trial seeds, as `tools trials --seed` (default 0: "
                            "the episodes the README's tables ran), or 'own' for each episode's own seed "
                            "(the bench's workload before 2026-12-05)")
    group.add_argument("--agent-profile", action="store_true",
                       help="profile the episodes (cProfile) and print the cost per phase and the top functions")
    group.add_argument("--agent-baseline", default=None, metavar="REF",
                       help="a git commit (e.g. HEAD~3) or a file saved with --agent-save: run/read it too and "
                            "print before and after side by side")
    group.add_argument("--agent-set", action="append", default=[], metavar="KEY=VALUE",
                       help="an option of the agent in this checkout (agent_config.*, helios.* or perception.*, "
                            "as in `tools trials`; repeatable): with --agent-baseline HEAD, an option's cost side "
                            "by side")
    group.add_argument("--agent-save", default=None, metavar="FILE",
                       help="write this run's numbers as JSON (a later run's --agent-baseline)")


def _percentile(values, q):
    return float(np.percentile(np.asarray(values, dtype=float), q)) if len(values) else float("nan")


class _WorkerProcess:
    """One bench worker on a source tree; requests and answers are JSON lines, each with a timeout."""

    def __init__(self, root: Path, agent: str, profile: bool, label: str, start_timeout: float = 300.0,
                 sets: tuple[str, ...] = ()):
        self.label = label
        cmd = [sys.executable, str(WORKER), str(root), agent, "1"] + (["--profile"] if profile else [])
        for s in sets:
            cmd += ["--set", s]
        env = dict(os.environ, PYTHONPATH=str(root))
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, cwd=str(root), env=env)
        self._lines: queue.Queue = queue.Queue()
        self._stderr: list[str] = []
        threading.Thread(target=self._pump, args=(self.proc.stdout, self._lines), daemon=True).start()
        threading.Thread(target=self._pump_err, daemon=True).start()
        self._read(start_timeout, "start up")

    @staticmethod
    def _pump(stream, q):
        for line in stream:
            q.put(line)
        q.put(None)

    def _pump_err(self):
        for line in self.proc.stderr:
            self._stderr.append(line)
            del self._stderr[:-20]

    def _read(self, timeout: float, what: str) -> dict:
        try:
            line = self._lines.get(timeout=timeout)
        except queue.Empty:
            self.close(graceful=False)
            raise CliError(f"bench worker ({self.label}) did not {what} within {timeout:.0f} s; stopped it") from None
        if line is None:
            tail = "".join(self._stderr[-8:]).strip()
            raise CliError(f"bench worker ({self.label}) exited while asked to {what}"
                           + (f":\n{tail}" if tail else ""))
        return json.loads(line)

    def ask(self, request: dict, timeout: float, what: str) -> dict:
        self.proc.stdin.write(json.dumps(request) + "\n")
        self.proc.stdin.flush()
        return self._read(timeout, what)

    def close(self, graceful: bool = True) -> None:
        """Ask the worker to quit (10 s), then kill it; an unresponsive one is killed at once."""
        try:
            if graceful and self.proc.poll() is None:
                self.proc.stdin.write(json.dumps({"quit": True}) + "\n")
                self.proc.stdin.flush()
                self.proc.wait(timeout=10)
        except (OSError, subprocess.TimeoutExpired, ValueError):
            pass
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)


AGENT_SET_PREFIXES = ("agent_config.", "helios.", "perception.")


def check_agent_sets(agent: str, sets: list[str]) -> tuple[str, ...]:
    """``--agent-set`` values, checked against the trial configuration's schema before any work."""
    from helios.schema import with_overrides
    from tasks.registry import check_agent_settings
    from tasks.trial_config import TrialConfig

    for s in sets:
        key = s.partition("=")[0]
        if "=" not in s or not key.startswith(AGENT_SET_PREFIXES):
            raise CliError(f"--agent-set {s!r}: give KEY=VALUE with a key under "
                           f"{', '.join(p.rstrip('.') for p in AGENT_SET_PREFIXES)} (e.g. "
                           f"helios.gaussians.view_evidence_max_width=80)")
    config = with_overrides(TrialConfig(agent=agent), list(sets))    # unknown keys and bad values: ConfigError
    check_agent_settings(config, [s.partition("=")[0] for s in sets])  # as `tools trials`: none the agent ignores
    return tuple(sets)


def _saved_problem(saved: dict) -> str | None:
    """What :func:`format_report` would fail on in a saved result (a key it reads, missing or of the
    wrong kind); None when it can be shown."""
    for key in ("median_wall", "p90_wall", "table_hours", "peak_rss_mb"):
        if not finite_number(saved.get(key)):
            return f"{key} is {'missing' if key not in saved else 'not a number'}"
    if not isinstance(saved.get("phases"), dict) or not all(finite_number(v) for v in saved["phases"].values()):
        return "phases is not a mapping of seconds"
    if not isinstance(saved.get("replans", []), list) or not all(
            isinstance(r, dict) and {"map", "n", "ok", "median_ms", "p90_ms", "max_ms"} <= set(r)
            for r in saved.get("replans", [])):
        return "replans is malformed"
    return None


def _check_baseline(ref: str | None) -> tuple[str, str | None, dict | None]:
    """(label, commit to run, or saved results) of ``--agent-baseline``: reads the file or asks git
    for the commit, but extracts nothing, so :func:`check_inputs` can call it before any suite runs."""
    if ref is None:
        return "", None, None
    path = Path(ref)
    if path.is_file():
        try:
            saved = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
            raise CliError(f"--agent-baseline {ref!r}: not a readable JSON file ({shorten(exc, 100)})") from None
        if not isinstance(saved, dict) or saved.get("format") != SAVE_FORMAT:
            raise CliError(f"--agent-baseline {ref!r}: not a file written by `bench agent --agent-save` "
                           f"(format {SAVE_FORMAT!r})")
        problem = _saved_problem(saved)
        if problem:
            raise CliError(f"--agent-baseline {ref!r}: a damaged `bench agent --agent-save` file: {problem}")
        return saved.get("label", path.name), None, saved
    from tools.commit_tree import commit_has_file, resolve_commit

    commit = resolve_commit(ref, "--agent-baseline")
    if not commit:
        raise CliError(f"--agent-baseline {ref!r} is neither a file nor a commit of {ROOT}")
    if not commit_has_file(commit, "tasks/runner.py", f"--agent-baseline {ref!r}"):
        raise CliError(f"--agent-baseline {ref!r} ({commit[:12]}) has no tasks/runner.py: too old to bench")
    return f"{ref} ({commit[:10]})", commit, None


def _baseline_tree(ref: str, commit: str, tmp: Path) -> Path:
    """The files of the ``--agent-baseline`` commit (checked by :func:`_check_baseline`) under ``tmp``."""
    from tools.commit_tree import extract_commit

    return extract_commit(commit, tmp / commit[:12], f"--agent-baseline {ref!r}")


MAX_REPEATS = 20
MAX_SEED = 2 ** 32 - 1


def episode_requests(agent_seed: str, n_eps: int) -> list[dict]:
    """The workers' request for each of the first ``n_eps`` val episodes: with a master seed, the
    agent's trial seed as ``tools trials --seed`` derives it (``tasks.trial_config.episode_seed``),
    so the bench times the very episodes of the tables; with ``own``, each episode's own seed."""
    from tasks.episodes import load_split
    from tasks.trial_config import episode_seed

    if agent_seed == "own":
        return [{"episode": i} for i in range(n_eps)]
    try:
        master = int(agent_seed)
    except ValueError:
        master = -1
    if not 0 <= master <= MAX_SEED:
        raise CliError(f"--agent-seed must be a master seed within 0..{MAX_SEED} or 'own', got {agent_seed!r}")
    episodes = load_split("val")[:n_eps]
    return [{"episode": i, "episode_id": e.episode_id, "seed": episode_seed(master, e.episode_id)}
            for i, e in enumerate(episodes)]


def least_wall(runs: list[dict]) -> dict:
    """The run of one episode with the least wall time (its phases with it), marked with how many
    runs there were and whether they all gave the same simulated time and outcome (they must:
    episodes are deterministic, and a difference is reported rather than hidden)."""
    best = min(runs, key=lambda r: r["wall"])
    same = all((r["sim"], r["success"]) == (best["sim"], best["success"]) for r in runs)
    return {**best, "repeats": len(runs), "repeats_agree": same}


def _summary(episodes: list[dict], replans: list[dict]) -> dict:
    walls = [e["wall"] for e in episodes]
    phases: dict[str, float] = {}
    profile: dict[str, float] = {}
    for e in episodes:
        for k, v in e["phases"].items():
            phases[k] = phases.get(k, 0.0) + v / len(episodes)
        for k, v in (e.get("profile") or {}).items():
            profile[k] = profile.get(k, 0.0) + v / len(episodes)
    per_episode = statistics.mean(e["wall"] + e["phases"].get("scene build and judge", 0.0) for e in episodes)
    hours = TABLE_RUNS * TABLE_EPISODES * per_episode / TABLE_WORKERS / 3600.0
    return {"median_wall": statistics.median(walls), "p90_wall": _percentile(walls, 90),
            "mean_wall": statistics.mean(walls), "phases": phases, "profile": profile, "table_hours": hours,
            "peak_rss_mb": max(e.get("peak_rss_mb", 0.0) for e in episodes),
            "replans": [{"map": r["map"], "n": len(r["times_ms"]), "ok": r["ok"],
                         "median_ms": statistics.median(r["times_ms"]) if r["times_ms"] else float("nan"),
                         "p90_ms": _percentile(r["times_ms"], 90), "max_ms": max(r["times_ms"], default=float("nan"))}
                        for r in replans]}


def episode_counts(args: argparse.Namespace) -> tuple[int, int]:
    """(val episodes, planner calls per map) to run. ``--quick`` only changes the defaults: an
    explicit ``--agent-episodes`` or ``--agent-replans`` wins (``--quick`` once replaced it silently)."""
    quick = getattr(args, "quick", False)
    n_eps = args.agent_episodes if args.agent_episodes is not None else QUICK_EPISODES if quick else DEFAULT_EPISODES
    n_plans = args.agent_replans if args.agent_replans is not None else QUICK_REPLANS if quick else DEFAULT_REPLANS
    return n_eps, n_plans


class AgentInputs(NamedTuple):
    """The agent suite's options, checked: what :func:`run` needs of them."""
    sets: tuple[str, ...]
    episodes: int
    replans: int
    requests: list[dict]
    baseline: tuple[str, str | None, dict | None]      # (label, commit, saved results): _check_baseline


def check_inputs(args: argparse.Namespace) -> AgentInputs:
    """Every agent-suite option, a CliError naming the first bad one. ``tools bench`` calls it
    before its first suite (``bench scenes agent --agent-repeats 0`` once ran the scenes suite
    first), :func:`run` again for the values; it is cheap (no episode, no ``git archive``). The
    episode and replan counts' ranges are checked by ``tools.bench._check_options``."""
    from tasks.episodes import load_split
    from tasks.registry import check_agent

    check_agent(args.agent_name)
    if args.agent_name == "oracle":     # ground truth, no perception, map or planner: nothing to time
        raise CliError(f"--agent-name {args.agent_name!r}: the oracle keeps no timings of perception, map and "
                       f"planning; time a HELIOS agent")
    sets = check_agent_sets(args.agent_name, args.agent_set)
    n_eps, n_plans = episode_counts(args)
    n_val = len(load_split("val"))
    if n_eps > n_val:
        raise CliError(f"--agent-episodes {n_eps} is more than the {n_val} val episodes")
    repeats = args.agent_repeats
    if not 1 <= repeats <= MAX_REPEATS:
        raise CliError(f"--agent-repeats must be within 1..{MAX_REPEATS}, got {repeats}")
    requests = episode_requests(args.agent_seed, n_eps)
    if args.agent_save is not None:       # a folder, a FIFO, '' or no such folder: before the episodes run
        check_output_file(args.agent_save, "--agent-save")
        save = Path(args.agent_save)
        if not save.parent.is_dir():
            raise CliError(f"--agent-save {args.agent_save!r}: folder {str(save.parent)!r} does not exist")
    return AgentInputs(sets, n_eps, n_plans, requests, _check_baseline(args.agent_baseline))


def run(args: argparse.Namespace) -> str:
    inputs = check_inputs(args)
    sets, n_eps, n_plans, requests = inputs.sets, inputs.episodes, inputs.replans, inputs.requests
    repeats = args.agent_repeats
    after_label = "this checkout" + (f" ({', '.join(sets)})" if sets else "")
    with tempfile.TemporaryDirectory(prefix="bench-agent-") as tmp:
        base_label, base_commit, base_saved = inputs.baseline
        base_tree = _baseline_tree(args.agent_baseline, base_commit, Path(tmp)) if base_commit else None
        workers = {"after": _WorkerProcess(ROOT, args.agent_name, args.agent_profile, after_label, sets=sets)}
        try:
            if base_tree is not None:
                workers["before"] = _WorkerProcess(base_tree, args.agent_name, args.agent_profile, base_label)
            results: dict[str, dict] = {k: {"episodes": [], "replans": []} for k in workers}
            for i in range(n_eps):
                runs: dict[str, list] = {k: [] for k in workers}
                for rep in range(repeats):
                    for key in sorted(workers, reverse=True):       # before, then after
                        r = workers[key].ask(requests[i], EPISODE_TIMEOUT_S, f"finish val episode {i}")
                        runs[key].append(r)
                        again = f" (run {rep + 1}/{repeats})" if repeats > 1 else ""
                        print(f"[bench agent] {key:6s} {i + 1}/{n_eps} {r['episode']}{again}: {r['wall']:.1f} s wall, "
                              f"{r['sim']:.0f} s simulated, success={r['success']}", flush=True)
                for key in workers:
                    results[key]["episodes"].append(least_wall(runs[key]))
            for key in sorted(workers, reverse=True):
                results[key]["replans"] = workers[key].ask({"replans": n_plans, "seed": args.seed}, EPISODE_TIMEOUT_S,
                                                           "finish the replans")["replans"]
        finally:
            for w in workers.values():
                w.close()
    from tasks.run_folder import cpu_paths_now

    cpu = cpu_paths_now()     # both workers inherit this process's environment, hence its code paths
    after = {"label": after_label, "cpu": cpu, "agent_seed": args.agent_seed, **results["after"],
             **_summary(**results["after"])}
    before = None
    if "before" in results:
        before = {"label": base_label, "cpu": cpu, "agent_seed": args.agent_seed, **results["before"],
                  **_summary(**results["before"])}
    elif base_saved is not None:
        before = base_saved
    if args.agent_save:
        Path(args.agent_save).write_text(json.dumps({"format": SAVE_FORMAT, **after}, indent=1), encoding="utf-8")
    return format_report(after, before, args.agent_name)


def cpu_lines(after: dict, before: dict | None) -> list[str]:
    """Which CPU code paths the numbers come from (README, "One CPU code path"), and a warning
    when a saved baseline ran on others: its ratios then include those paths' cost, and its
    episodes may have behaved differently."""
    now = after.get("cpu")
    if now is None:
        return []
    if before is None or before.get("cpu") == now:
        return [f"CPU code paths: {now}"]
    if before.get("cpu") is None:
        return [f"CPU code paths: {now}; the baseline does not say which it ran on (saved before 2026-12-03): "
                "a ratio may include the difference"]
    return [f"CPU code paths: {now}; the baseline ran on OTHER code paths ({before['cpu']}): the ratios include "
            "their cost and its episodes may have behaved differently"]


def wall_per_sim_second(run: dict) -> float:
    """Milliseconds of wall time per simulated second over all episodes: the cost of the same robot
    time, comparable where two trees' episodes take other courses (and so last other times)."""
    sim = sum(e["sim"] for e in run.get("episodes", []))
    return 1e3 * sum(e["wall"] for e in run.get("episodes", [])) / sim if sim > 0 else float("nan")


def workload(run: dict) -> str:
    """Which seeds a run's episodes ran with, in words (files saved before 2026-12-05: their own)."""
    seed = run.get("agent_seed", "own")
    if seed == "own" or any(e.get("seed") is None for e in run.get("episodes", [])):
        return "each episode's own seed (not the tables' episodes)"
    return f"the trial seeds of master seed {seed}, as `tools trials --seed {seed}` runs them"


def workload_lines(after: dict, before: dict | None) -> list[str]:
    """The episodes' seeds, and a warning when the baseline ran other ones: a saved file from
    before 2026-12-05 timed the episodes with their own seeds, a heavier workload (5 of the first
    6 val episodes ran to the 600 s cap, against 2 with the trial seeds)."""
    lines = [f"episodes: {workload(after)}"]
    if before is not None and workload(before) != workload(after):
        lines.append(f"the baseline's episodes: {workload(before)}: OTHER WORKLOADS, the ratios compare different "
                     "episodes")
    return lines


def _fmt(v, spec=".1f") -> str:
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, spec)


def camera_frames(run: dict) -> tuple[float, float] | None:
    """Mean (seconds, frames) of the hand camera's renders per episode; None for runs made before
    the worker timed them (a baseline commit's own worker, an older saved file)."""
    cams = [e["camera"] for e in run.get("episodes", []) if "camera" in e]
    if not cams or len(cams) != len(run.get("episodes", [])):
        return None
    return (sum(c["seconds"] for c in cams) / len(cams), sum(c["frames"] for c in cams) / len(cams))


def format_report(after: dict, before: dict | None, agent: str) -> str:
    """The benchmark's tables; ``before`` (a baseline run or saved file) adds columns and ratios."""
    cols = [("after", after)] if before is None else [("before", before), ("after", after)]
    head = "".join(f"{name:>10s}" for name, _ in cols) + ("" if before is None else f"{'ratio':>8s}")

    def row(label, values, spec=".1f", width=44):
        cells = "".join(f"{_fmt(v, spec):>10s}" for v in values)
        if before is not None and len(values) == 2 and values[0] and values[1]:
            cells += f"{values[0] / values[1]:7.2f}x"
        return f"{label:{width}s}{cells}"

    out = [f"HELIOS agent benchmark ({agent}; 1 torch/BLAS thread per worker)"]
    if before is not None:
        out.append(f"before: {before.get('label', '?')}    after: {after.get('label', 'this checkout')}"
                   "    (ratio = before / after: above 1 is faster)")
    elif after.get("label", "this checkout") != "this checkout":   # --agent-set without a baseline: say so
        out.append(f"after: {after['label']}")
    out += cpu_lines(after, before)
    out += workload_lines(after, before)
    repeats = max([e.get("repeats", 1) for c in (after, before) if c for e in c.get("episodes", [])] or [1])
    least = f" (the least of {repeats} runs of each episode)" if repeats > 1 else ""
    out += ["", f"val episodes, wall seconds{least}:", f"{'episode':44s}{head}"]
    by_id = {e["episode"]: e for e in (before or {}).get("episodes", [])}
    for e in after["episodes"]:
        vals = ([by_id[e["episode"]]["wall"]] if before is not None and e["episode"] in by_id else
                [None] if before is not None else []) + [e["wall"]]
        out.append(row(f"{e['episode']} ({e['sim']:.0f} s simulated, success={e['success']})", vals))
    out.append(row("median", [c["median_wall"] for _, c in cols]) + "   target <= 5 s")
    restless = [e["episode"] for _, c in cols for e in c.get("episodes", []) if not e.get("repeats_agree", True)]
    if restless:
        out.append(f"NOT DETERMINISTIC: the repeated runs of {', '.join(sorted(set(restless)))} gave different "
                   "simulated times or outcomes")
    out.append(row("p90", [c["p90_wall"] for _, c in cols]))
    out.append(row("wall ms per simulated s (all episodes)", [wall_per_sim_second(c) for _, c in cols]))
    if before is not None and by_id:
        other = [e["episode"] for e in after["episodes"]
                 if by_id.get(e["episode"], {}).get("task", e.get("task")) != e.get("task")
                 or (e["episode"] in by_id and by_id[e["episode"]].get("seed") != e.get("seed"))]
        if other:
            out.append(f"the baseline's {', '.join(other[:3])}{'...' if len(other) > 3 else ''} are other episodes "
                       f"(its own splits or seeds): compare the medians and phases, not episode by episode")
        else:
            same = all(by_id.get(e["episode"], {}).get("sim") == e["sim"] and
                       by_id.get(e["episode"], {}).get("success") == e["success"] for e in after["episodes"])
            out.append(f"same simulated time and outcome on every episode: {'yes' if same else 'NO (behaviour differs)'}")
    out += ["", "mean seconds per episode, by phase:", f"{'phase':44s}{head}"]
    frames = [camera_frames(c) for _, c in cols]
    for phase in after["phases"]:
        out.append(row(phase, [c["phases"].get(phase) for _, c in cols], ".2f"))
        if phase.startswith("simulator") and frames[-1] is not None:     # part of the simulator's time
            out.append(row("  of which hand-camera frames (TinyRenderer)", [f and f[0] for f in frames], ".2f"))
            out.append(row("  hand-camera frames per episode", [f and f[1] for f in frames], ".0f"))
            out.append(row("  ms per hand-camera frame", [f and 1e3 * f[0] / max(f[1], 1) for f in frames], ".1f"))
    if after.get("profile"):
        out += ["", "profiled phases (cumulative seconds per episode under cProfile; phases nest):", f"{'phase':44s}{head}"]
        for phase in after["profile"]:
            out.append(row(phase, [c.get("profile", {}).get(phase) for _, c in cols], ".2f"))
        top: dict[str, float] = {}
        for e in after["episodes"]:
            for t, name in e.get("top", []):
                top[name] = top.get(name, 0.0) + t / len(after["episodes"])
        out += ["", "top functions by own time (after; seconds per episode):"]
        out += [f"  {t:7.2f}  {name}" for name, t in sorted(top.items(), key=lambda kv: -kv[1])[:15]]
    out += ["", f"projected hours for the paper's table ({TABLE_RUNS} runs x {TABLE_EPISODES} val episodes, "
                f"{TABLE_WORKERS} workers, every agent costing what {agent} does):",
            row("hours", [c["table_hours"] for _, c in cols]),
            row("peak RSS per worker, MB", [c["peak_rss_mb"] for _, c in cols], ".0f") + "   target <= ~765 MB"]
    out += ["", "planner replans (FMM^2 + footprint-checked actions), 2000 x 2000 grid of 2.5 cm, ms:"]
    base_plans = (before or {}).get("replans", [])
    for i, r in enumerate(after["replans"]):
        b = base_plans[i] if i < len(base_plans) else None
        out.append(f"{r['map']}  (n={r['n']}, ok {r['ok']})")
        for stat in ("median_ms", "p90_ms", "max_ms"):
            vals = ([b[stat] if b else None] if before is not None else []) + [r[stat]]
            out.append(row(f"  {stat[:-3]}", vals))
    out.append("targets: replan p90 <= 100 ms on the home maps; whole-grid median <= 150 ms")
    return "\n".join(out)
