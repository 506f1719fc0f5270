"""``python -m tools bench scenes``: time and memory to generate and build validated homes of the
val split (target: a val scene builds in <= 3 s on the 2-core machine)."""

from __future__ import annotations

import argparse
import statistics
import time

from tools.tables import format_table


def run(args: argparse.Namespace) -> str:
    import psutil

    from sim.scenes.home import build_home
    from sim.scenes.layout import generate_layout
    from sim.world import World
    from tasks.episodes import load_split

    proc = psutil.Process()
    seeds = list(dict.fromkeys(e.scene.seed for e in load_split("val")))[: 5 if args.quick else 20]
    rows, builds = [], []
    for seed in seeds:
        rss0 = proc.memory_info().rss
        t0 = time.perf_counter()
        layout = generate_layout(seed)
        t1 = time.perf_counter()
        world = World()
        build_home(world, layout)               # its validation builds the navigation grids planners use
        t2 = time.perf_counter()
        rss = (proc.memory_info().rss - rss0) / 2 ** 20
        builds.append(t2 - t0)
        rows.append((seed, f"{layout.width:.1f} x {layout.depth:.1f}", len(layout.rooms), len(layout.receptacles),
                     len(layout.objects), round(t1 - t0, 3), round(t2 - t1, 3), round(t2 - t0, 3), round(rss, 1)))
        world.close()
    # (a "nav grids s" column timed the grids again after the validation had built and cached them: always 0)
    headers = ["seed", "size m", "rooms", "receptacles", "objects", "layout s", "build+settle+validate+nav grids s",
               "total s", "RSS delta MiB"]
    table = format_table(headers, rows, title="Procedural home build (val scenes)")
    verdict = "met" if max(builds) <= 3.0 else "NOT met"
    return (f"{table}\n\nmedian {statistics.median(builds):.2f} s, max {max(builds):.2f} s per scene "
            f"(target <= 3 s: {verdict}); process RSS {proc.memory_info().rss / 2 ** 20:.0f} MiB")
