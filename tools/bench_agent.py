"""``python -m tools bench agent``: HELIOS agent costs on this machine.

1. Planner replans on the default 2000 x 2000 (2.5 cm) grid: the map a HELIOS agent built in a
   real val episode (the usual case: a home of 8-15 m explored), and the worst case of the whole
   50 m x 50 m grid explored. Random start/goal pairs on free explored cells, timed one by one.
2. Wall time of whole HELIOS val episodes, with the agent's own split into perception, map
   updates and planning (the rest is the simulator: physics, rendering, arm and base motion).

Targets (issue): replan <= 100 ms, median val episode <= 60 s on the 2-core machine.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("agent suite")
    group.add_argument("--agent-name", default="helios", help="registered agent to time (default helios)")
    group.add_argument("--agent-episodes", type=int, default=6, help="val episodes to run (default 6; --quick: 2)")
    group.add_argument("--agent-replans", type=int, default=40, help="planner calls per map (default 40)")


def _percentile(values, q):
    return float(np.percentile(np.asarray(values, dtype=float), q)) if len(values) else float("nan")


def _replans(planner, geometry, obstacle, explored, max_height, bounds, rng, n: int) -> dict:
    from robots.hal import SE2Pose

    free = np.argwhere(explored & ~obstacle)
    if len(free) < 2:
        return {"n": 0}
    times, ok = [], 0
    for _ in range(n):
        a, b = free[rng.integers(len(free), size=2)]
        start = SE2Pose(*geometry.cell_to_world(a[0], a[1]), float(rng.uniform(-math.pi, math.pi)))
        goal = geometry.cell_to_world(b[0], b[1])
        t0 = time.perf_counter()
        res = planner.plan(geometry, obstacle, explored, start, goal, 0.5, None, max_height, None, bounds)
        times.append(time.perf_counter() - t0)
        ok += res.success
    return {"n": n, "median_ms": 1e3 * statistics.median(times), "p90_ms": 1e3 * _percentile(times, 90),
            "max_ms": 1e3 * max(times), "ok": ok}


def _worst_case_map(geometry, rng):
    """The whole grid explored, walls every 6 m with doors, scattered boxes."""
    size = geometry.size
    obstacle = np.zeros(geometry.shape, dtype=bool)
    cells = int(round(6.0 / geometry.cell_size))
    door = int(round(1.0 / geometry.cell_size))
    for k in range(cells, size, cells):
        obstacle[k:k + 4, :] = True
        obstacle[:, k:k + 4] = True
        for j in range(cells // 2, size, cells):
            obstacle[k:k + 4, j:j + door] = False
            obstacle[j:j + door, k:k + 4] = False
    for _ in range(400):
        r, c = rng.integers(0, size - 40, size=2)
        h, w = rng.integers(10, 40, size=2)
        obstacle[r:r + h, c:c + w] = True
    explored = np.ones(geometry.shape, dtype=bool)
    max_height = np.where(obstacle, 1.0, 0.0).astype(np.float32)
    return obstacle, explored, max_height, (0, size, 0, size)


def run(args: argparse.Namespace) -> str:
    from helios.planning import FMMPlanner
    from helios.runtime import configure_threads
    from tasks.episodes import load_split
    from tasks.registry import check_agent, make_agent
    from tasks.runner import run_sim_episode

    configure_threads(1)
    check_agent(args.agent_name)
    n_eps = 2 if args.quick else args.agent_episodes
    n_plans = 10 if args.quick else args.agent_replans
    rng = np.random.default_rng(args.seed)
    episodes = load_split("val")[:n_eps]
    holder: dict = {}

    def make(sim):
        holder["agent"] = make_agent(args.agent_name, sim)
        return holder["agent"]

    rows, maps = [], []
    for i, ep in enumerate(episodes):
        res = run_sim_episode(make, ep)
        agent = holder["agent"]
        t = agent.timings
        rows.append({"episode": ep.episode_id, "wall": res.wall_time, "sim": res.sim_time, "commands": res.commands,
                     "success": res.success, "perception": t["perception"], "map": t["map"],
                     "planning": t["planning"], "plans": int(t["plans"])})
        if agent.map is not None:
            occ = agent.map.occupancy
            maps.append((agent.map.geometry, occ.obstacle.copy(), occ.explored.copy(), occ.max_height.copy(),
                         occ.explored_bounds))
        print(f"[bench agent] {i + 1}/{len(episodes)} {ep.episode_id}: {res.wall_time:.1f} s wall, "
              f"{res.sim_time:.0f} s simulated, success={res.success}", flush=True)

    planner = FMMPlanner()
    plan_rows = []
    for geometry, obstacle, explored, max_height, bounds in maps[:2]:
        r = _replans(planner, geometry, obstacle, explored, max_height, bounds, rng, n_plans)
        area = explored.sum() * geometry.cell_size ** 2
        plan_rows.append((f"home map after a val episode ({area:.0f} m^2 explored)", r))
    if maps:
        geometry = maps[0][0]
        worst = _worst_case_map(geometry, rng)
        plan_rows.append(("whole 2000x2000 grid explored (2500 m^2)", _replans(planner, geometry, *worst, rng, max(3, n_plans // 4))))

    out = [f"HELIOS agent benchmark ({args.agent_name}; 1 torch/BLAS thread)", "",
           "planner replan (FMM^2 + footprint-checked actions), 2000 x 2000 grid of 2.5 cm:",
           f"{'map':58s} {'n':>4s} {'median ms':>10s} {'p90 ms':>8s} {'max ms':>8s} {'ok':>4s}"]
    for name, r in plan_rows:
        if r.get("n"):
            out.append(f"{name:58s} {r['n']:4d} {r['median_ms']:10.1f} {r['p90_ms']:8.1f} {r['max_ms']:8.1f} {r['ok']:4d}")
    out += ["", "val episodes (wall seconds; perception/map/planning are the agent's own share):",
            f"{'episode':12s} {'wall s':>7s} {'sim s':>6s} {'cmds':>5s} {'perc s':>7s} {'map s':>6s} {'plan s':>7s} "
            f"{'plans':>6s} {'success':>8s}"]
    for r in rows:
        out.append(f"{r['episode']:12s} {r['wall']:7.1f} {r['sim']:6.0f} {r['commands']:5d} {r['perception']:7.2f} "
                   f"{r['map']:6.2f} {r['planning']:7.2f} {r['plans']:6d} {str(r['success']):>8s}")
    walls = [r["wall"] for r in rows]
    if walls:
        out.append(f"median wall per episode: {statistics.median(walls):.1f} s (target <= 60 s); "
                   f"p90 {_percentile(walls, 90):.1f} s; real-time factor {sum(r['sim'] for r in rows) / sum(walls):.1f}x")
    return "\n".join(out)
