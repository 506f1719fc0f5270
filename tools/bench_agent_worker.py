"""A worker process of ``python -m tools bench agent``: times HELIOS episodes and planner replans
for one source tree (this checkout, or another commit's files extracted by the parent).

Run as ``python tools/bench_agent_worker.py ROOT AGENT THREADS [--profile] [--set KEY=VALUE ...]``
(``--set``: the agent's options, ``agent_config.*``, ``helios.*`` or ``perception.*`` as in
``tools trials``; only this checkout's worker is given them). The first entry
of ``sys.path`` becomes ROOT, so ``helios``, ``tasks`` and ``robots`` are that tree's; the
worker itself only uses calls every version since the split of the agent has had
(``load_split``, ``make_agent``, ``run_sim_episode``, ``FMMPlanner.plan``, ``agent.timings``).
It reads one JSON request per line on stdin and answers one JSON line on stdout:

- ``{"episode": i, "seed": s, "episode_id": id}``: run val episode ``i`` (which must be ``id``)
  with the agent's trial seed ``s`` as ``tools trials`` gives it (no ``seed``: the episode's own
  seed); wall seconds per phase (and, with ``--profile``, per profiled phase and the top
  functions), simulated seconds, success;
- ``{"replans": n, "seed": s}``: ``n`` random replans on each of the first two episode maps and
  ``max(3, n // 4)`` on a fully explored 2000 x 2000 grid; per-map times in ms;
- ``{"quit": true}``.

The parent alternates requests between the "before" and "after" workers, so machine load hits
both alike.
"""

from __future__ import annotations

import json
import math
import sys
import time

# HAL commands whose wall time is the simulator's share (physics, rendering, motion, collisions).
HAL_COMMANDS = ("observe", "navigate_to", "gaze_at", "move_arm_joints", "move_hand", "grasp", "place",
                "stow_arm", "stand", "stop")

# Profiled phases: (phase, [(file suffix, function name, caller function name or None)]).
# A phase's time is the cumulative time of its entries (edges from the named caller only, when
# one is given); an entry missing from a profile (another commit's names) adds nothing.
PROFILE_PHASES = (
    ("simulator: camera rendering", [("sim/camera.py", "render", None)]),
    # World.step, not the pybullet call: that call runs inside World's client hook (``moving``),
    # where cProfile books it as the hook's own time
    ("simulator: physics stepping", [("sim/world.py", "step", None)]),
    ("simulator: collision queries", [("sim/spot.py", "touching", None)]),
    # _move_arm moved to sim_arm.py (the split of SimSpotBackend); one of the two exists per commit
    ("simulator: arm motion", [("robots/spot/sim_backend.py", "_move_arm", None),
                               ("robots/spot/sim_arm.py", "_move_arm", None)]),
    ("simulator: base motion", [("robots/spot/sim_backend.py", "follow_base_path", None)]),
    ("map: Gaussian rendering", [("helios/maps/gaussians.py", "render", "update")]),
    ("map: Gaussian update (all)", [("helios/maps/gaussians.py", "update", None)]),
    ("map: re-clustering instances", [("helios/maps/instances.py", "assign_instances", None)]),
    ("map: update (all layers)", [("helios/maps/hierarchical.py", "update", None)]),
    ("map: occupancy layer", [("helios/maps/occupancy.py", "integrate_depth", None)]),
    ("map: value layers", [("helios/maps/value_map.py", "fuse", None)]),
    ("map: instance summaries", [("helios/maps/gaussians.py", "instances", None)]),
    ("planning: all", [("helios/planning/fmm.py", "plan", None)]),
    ("planning: FMM solve", [("helios/planning/fmm.py", "_travel_time", None)]),
    ("planning: clearance transforms", [("scipy/ndimage/_morphology.py", "distance_transform_edt", "plan")]),
    ("planning: footprint checks", [("helios/planning/footprint.py", "poses_free", None)]),
    ("planning: action generation", [("helios/planning/fmm.py", "_actions", None)]),
    ("decisions: view information gain", [("helios/search/information.py", "optimistic_evidence", None)]),
    ("perception: detector and scorer", [("", "__call__", "observe")]),
)


def _profile_phases(profiler) -> tuple[dict, list]:
    import pstats

    stats = pstats.Stats(profiler).stats
    phases = {}
    for phase, entries in PROFILE_PHASES:
        total = 0.0
        for suffix, name, caller in entries:
            for (path, _line, func), (_cc, _nc, _tt, ct, callers) in stats.items():
                if func != name and not (suffix == "~" and func.startswith(name)):
                    continue
                if suffix != "~" and not path.replace("\\", "/").endswith(suffix):
                    continue
                if caller is None:
                    total += ct
                else:
                    total += sum(edge[3] for (_p, _l, f), edge in callers.items() if f == caller)
        phases[phase] = total
    top = sorted(((tt, f"{'/'.join(path.replace(chr(92), '/').split('/')[-2:])}:{line}({func})")
                  for (path, line, func), (_cc, _nc, tt, _ct, _callers) in stats.items()), reverse=True)[:15]
    return phases, [[round(t, 3), name] for t, name in top]


def agent_options(agent: str, sets: list[str]) -> dict:
    """``make_agent``'s options for ``KEY=VALUE`` settings (none: the agent's defaults)."""
    if not sets:
        return {}
    from helios.schema import with_overrides
    from tasks.trial_config import TrialConfig

    config = with_overrides(TrialConfig(agent=agent), sets)
    return {"agent_config": config.agent_config, "method_config": config.helios,
            "perception_config": config.perception}


class _Worker:
    def __init__(self, agent: str, threads: int, profile: bool, sets: list[str] | None = None):
        from helios.runtime import configure_threads
        from tasks.episodes import load_split

        configure_threads(threads)
        self.options = agent_options(agent, sets or [])
        self.agent_name = agent
        self.profile = profile
        self.episodes = load_split("val")
        self.maps: list = []
        self._mapped: set[int] = set()      # episodes whose maps are kept (repeats add none)

    def episode(self, index: int, seed: int | None = None, episode_id: str | None = None) -> dict:
        """Run val episode ``index``; ``seed`` is the agent's trial seed, given as ``tools trials``
        gives it (``None``: the episode's own seed, the workload before 2026-12-05)."""
        from tasks.registry import make_agent
        from tasks.runner import run_sim_episode

        episode = self.episodes[index]
        if episode_id is not None and episode.episode_id != episode_id:
            raise ValueError(f"val episode {index} of this tree is {episode.episode_id}, not {episode_id}: its "
                             "splits differ, so the trial seeds do not apply (use --agent-seed own)")
        holder: dict = {}
        hal = {"seconds": 0.0, "depth": 0}

        def timed(call):
            def wrapper(*args, **kwargs):      # outermost command only (one may call another)
                hal["depth"] += 1
                t0 = time.perf_counter()
                try:
                    return call(*args, **kwargs)
                finally:
                    hal["depth"] -= 1
                    if hal["depth"] == 0:
                        hal["seconds"] += time.perf_counter() - t0
            return wrapper

        def make(sim):
            for name in HAL_COMMANDS:
                if hasattr(sim.backend, name):
                    setattr(sim.backend, name, timed(getattr(sim.backend, name)))
            context = sim
            if seed is not None:      # what tools trials hands the agent: the episode's trial seed
                from tasks.registry import RunContext

                context = RunContext.for_episode(sim, seed)
            holder["agent"] = make_agent(self.agent_name, context, **self.options)
            return holder["agent"]

        import sim.camera as sim_camera

        camera = {"seconds": 0.0, "frames": 0}
        raw_render = sim_camera.raw_render

        def timed_render(*args, **kwargs):
            """The hand camera's frames inside HAL commands, the part of the simulator's time the
            report nests under it (the judge's own check views render outside them)."""
            if not hal["depth"]:
                return raw_render(*args, **kwargs)
            t0 = time.perf_counter()
            try:
                return raw_render(*args, **kwargs)
            finally:
                camera["seconds"] += time.perf_counter() - t0
                camera["frames"] += 1

        profiler = None
        if self.profile:
            import cProfile

            profiler = cProfile.Profile()
            profiler.enable()
        sim_camera.raw_render = timed_render
        t0 = time.perf_counter()
        try:
            result = run_sim_episode(make, episode, seed=seed)
        finally:
            sim_camera.raw_render = raw_render
        total = time.perf_counter() - t0
        if profiler is not None:
            profiler.disable()
        agent = holder["agent"]
        t = agent.timings
        wall = result.wall_time
        own = {k: float(t.get(k, 0.0)) for k in ("perception", "map", "planning")}
        out = {"episode": episode.episode_id, "task": f"{episode.scene}|{episode.task}", "seed": seed,
               "wall": wall, "sim": result.sim_time, "success": result.success,
               "plans": int(t.get("plans", 0)),
               "phases": {"simulator (HAL commands)": hal["seconds"], "agent: perception": own["perception"],
                          "agent: map update": own["map"], "agent: planning": own["planning"],
                          "agent: decisions and the rest": max(0.0, wall - hal["seconds"] - sum(own.values())),
                          "scene build and judge": max(0.0, total - wall)},
               "camera": camera}
        if profiler is not None:
            out["profile"], out["top"] = _profile_phases(profiler)
        import resource

        out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        if agent.map is not None and len(self.maps) < 2 and index not in self._mapped:
            self._mapped.add(index)
            occ = agent.map.occupancy
            self.maps.append((agent.map.geometry, occ.obstacle.copy(), occ.explored.copy(), occ.max_height.copy(),
                              occ.explored_bounds))
        return out

    def replans(self, n: int, seed: int) -> dict:
        import numpy as np

        from helios.planning import FMMPlanner

        rng = np.random.default_rng(seed)
        planner = FMMPlanner()
        rows = []
        for geometry, obstacle, explored, max_height, bounds in self.maps:
            area = float(explored.sum() * geometry.cell_size ** 2)
            rows.append({"map": f"home map after a val episode ({area:.0f} m^2 explored)",
                         **_replans(planner, geometry, obstacle, explored, max_height, bounds, rng, n)})
        if self.maps:
            geometry = self.maps[0][0]
            worst = _worst_case_map(geometry, rng)
            rows.append({"map": "whole 2000x2000 grid explored (2500 m^2)",
                         **_replans(planner, geometry, *worst, rng, max(3, n // 4))})
        return {"replans": rows}


def _replans(planner, geometry, obstacle, explored, max_height, bounds, rng, n: int) -> dict:
    import numpy as np

    from robots.hal import SE2Pose

    free = np.argwhere(explored & ~obstacle)
    if len(free) < 2:
        return {"times_ms": [], "ok": 0}
    times, ok = [], 0
    for _ in range(n):
        a, b = free[rng.integers(len(free), size=2)]
        start = SE2Pose(*geometry.cell_to_world(a[0], a[1]), float(rng.uniform(-math.pi, math.pi)))
        goal = geometry.cell_to_world(b[0], b[1])
        t0 = time.perf_counter()
        res = planner.plan(geometry, obstacle, explored, start, goal, 0.5, None, max_height, None, bounds)
        times.append(1e3 * (time.perf_counter() - t0))
        ok += bool(res.success)
    return {"times_ms": times, "ok": ok}


def _worst_case_map(geometry, rng):
    """The whole grid explored, walls every 6 m with doors, scattered boxes."""
    import numpy as np

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


def main(argv: list[str]) -> int:
    root, agent, threads = argv[0], argv[1], int(argv[2])
    sys.path[0] = root
    sets = [argv[i + 1] for i, a in enumerate(argv[:-1]) if a == "--set"]
    worker = _Worker(agent, threads, "--profile" in argv, sets)
    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        request = json.loads(line)
        if request.get("quit"):
            break
        if "episode" in request:
            answer = worker.episode(int(request["episode"]), request.get("seed"), request.get("episode_id"))
        else:
            answer = worker.replans(int(request["replans"]), int(request["seed"]))
        print(json.dumps(answer), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
