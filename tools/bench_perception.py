"""``python -m tools bench perception``: cost per frame of the simulated detector + image-text
scorer at 320x240 on random views of val scenes (target: <= 10 ms per frame on the 2-core machine).

Each frame is timed cold (nothing cached for it): the detector with the episode's three task
classes, then the scorer with HELIOS's two value-map prompts (start and goal receptacle), sharing
one frame analysis as ``make_sim_perception`` wires them. Rendering is not timed. The full
catalogue as vocabulary (33 classes) is timed too, for reference.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from tools.tables import format_table


def _stats(ms: list[float]) -> tuple[float, float, float]:
    a = np.asarray(ms)
    return float(np.median(a)), float(np.percentile(a, 90)), float(a.max())


def run(args: argparse.Namespace) -> str:
    from helios.perception.prompts import value_prompt
    from sim.perception import SimPerceptionConfig, make_sim_perception
    from sim.perception.views import random_view
    from sim.scenes.catalog import ALL_CATEGORIES
    from tasks.episodes import load_split
    from tasks.runner import SimEpisode

    rng = np.random.default_rng(args.seed)
    episodes = load_split("val")
    picked, seen = [], set()
    for ep in episodes:
        if ep.scene.seed not in seen:
            seen.add(ep.scene.seed)
            picked.append(ep)
        if len(picked) == (1 if args.quick else 3):
            break
    per_scene = 15 if args.quick else 50
    timings: dict[str, dict[str, list[float]]] = {m: {"detector": [], "scorer": [], "total": [], "full vocabulary": []}
                                                  for m in ("noisy", "gt")}
    n_dets = {"noisy": [], "gt": []}
    resolution = None
    for ep in picked:
        sim = SimEpisode.create(ep)
        try:
            scene, world, backend = sim.scene, sim.world, sim.backend
            bodies = list(scene.object_ids.values()) + list(scene.receptacle_ids.values())
            classes = [ep.object_category, ep.start_receptacle_category, ep.goal_receptacle_category]
            classes = list(dict.fromkeys(classes))
            prompts = [value_prompt(ep.start_receptacle_category), value_prompt(ep.goal_receptacle_category)]
            frames = []
            while len(frames) < per_scene:
                T = random_view(scene, world, int(rng.choice(bodies)), rng)
                if T is not None:
                    frames.append(T)
            for mode in ("noisy", "gt"):
                detector, scorer = make_sim_perception(backend, ep.seed, SimPerceptionConfig(mode=mode),
                                                       rooms=scene.layout.rooms)
                full_detector, _ = make_sim_perception(backend, ep.seed, SimPerceptionConfig(mode=mode))
                obs = backend.render_at(frames[0])          # warm-up: body records, shapes
                detector(obs.rgb, obs.depth, classes)
                full_detector(obs.rgb, obs.depth, list(ALL_CATEGORIES))
                for T in frames:
                    obs = backend.render_at(T)
                    resolution = obs.rgb.shape[1], obs.rgb.shape[0]
                    t0 = time.perf_counter()
                    dets = detector(obs.rgb, obs.depth, classes)
                    t1 = time.perf_counter()
                    scorer(obs.rgb, prompts)
                    t2 = time.perf_counter()
                    full_detector(obs.rgb, obs.depth, list(ALL_CATEGORIES))
                    t3 = time.perf_counter()
                    tm = timings[mode]
                    tm["detector"].append(1e3 * (t1 - t0))
                    tm["scorer"].append(1e3 * (t2 - t1))
                    tm["total"].append(1e3 * (t2 - t0))
                    tm["full vocabulary"].append(1e3 * (t3 - t2))
                    n_dets[mode].append(len(dets))
        finally:
            sim.close()
    rows = []
    for mode, tm in timings.items():
        for part in ("detector", "scorer", "total", "full vocabulary"):
            med, p90, mx = _stats(tm[part])
            label = {"detector": "detector (3 task classes)", "scorer": "scorer (2 prompts)",
                     "total": "detector + scorer", "full vocabulary": "detector (33 classes, reference)"}[part]
            rows.append((mode, label, round(med, 2), round(p90, 2), round(mx, 2)))
    n = len(timings["noisy"]["total"])
    table = format_table(["mode", "stage", "median ms", "p90 ms", "max ms"], rows,
                         title=f"Simulated perception per frame at {resolution[0]}x{resolution[1]} "
                               f"({n} views of {len(picked)} val scenes)")
    worst = max(_stats(timings[m]["total"])[1] for m in timings)
    verdict = "met" if worst <= 10.0 else "NOT met"
    return (f"{table}\n\ndetections per frame (noisy, task classes): mean {statistics.mean(n_dets['noisy']):.1f}; "
            f"detector + scorer p90 {worst:.2f} ms (target <= 10 ms per frame: {verdict})")
