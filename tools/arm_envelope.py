"""Measure where the simulated Spot arm goes when it points the hand camera, and check the agent's
table of it (``helios.agents.arm_room.BANDS``, the ``agent_config.view.arm_model=measured``
arm-room model): per band of the look's pitch, the lowest arm point in 5 cm slices ahead of the
body, and every measured cell the table's boxes miss. Writes arm_envelope.png (the lowest arm
height over the ground, per band, with the table's boxes) and exits 1 if the table misses any.

    python -m tools arm-envelope                    # 450 looks (~3 min)
    python -m tools arm-envelope --quick --out runs/arm   # 63 looks (~30 s)
"""

from __future__ import annotations

import argparse
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="63 looks instead of 450 (a smoke check, not the table)")
    parser.add_argument("--out", default="runs/arm_envelope", help="output folder for arm_envelope.png (default: %(default)s)")


def run(args: argparse.Namespace) -> int:
    from helios.agents.arm_room import BANDS, MARGIN, band_name
    from tasks.arm_sweep import QUICK, Targets, measure, slices, uncovered
    from tools.cli import check_output_dir, check_output_file
    from tools.tables import format_table

    out = check_output_dir(args.out)
    picture = check_output_file(out / "arm_envelope.png", "--out")
    targets = QUICK if args.quick else Targets()
    print(f"[arm-envelope] {targets.count} looks (stow -> gaze -> stow) on an empty floor; "
          f"lowest arm point per 2.5 cm cell, per band of the look's pitch")
    step = max(1, targets.count // 10)

    def progress(done: int, total: int) -> None:
        if done % step == 0 or done == total:
            print(f"[arm-envelope] {done}/{total} looks", file=sys.stderr, flush=True)

    env = measure(targets, progress=progress)
    misses = 0
    for band, (_, boxes) in enumerate(BANDS):
        rows = []
        for x0, x1, half, z in slices(env, band):
            table = [b for b in boxes if b[0] - MARGIN <= (x0 + x1) / 2 <= b[1] + MARGIN]
            rows.append([f"{x0:.2f}-{x1:.2f}", f"{half:.2f}", f"{z:.2f}",
                         ", ".join(f"{b[3] - MARGIN:.2f}" for b in table) or "-"])
        bad = uncovered(env, band, MARGIN)
        misses += len(bad)
        print(f"\n{band_name(band)}: {env.looks[band]} looks; {len(bad)} measured cells the table misses")
        print(format_table(["x ahead (m)", "half width (m)", "lowest arm (m)", "table blocks above (m)"], rows))
        for x, y, z in bad[:5]:
            print(f"  missed: x {x:+.3f} y {y:+.3f} lowest arm {z:.3f} m")
    if env.failed:
        print(f"\n{env.failed} of {targets.count} looks failed (no arm solution); their moves are counted up to the failure")
    out.mkdir(parents=True, exist_ok=True)
    _plot(env, picture)
    print(f"\npicture: {picture}")
    if misses:
        print(f"the table (helios/agents/arm_room.py) misses {misses} measured cells: update BANDS")
        return 1
    print("the table covers every measured cell (with its 3 cm margins)")
    return 0


def _plot(env, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from helios.agents.arm_room import BANDS, MARGIN, band_name
    from helios.planning.footprint import FootprintConfig

    x_lo, x_hi, y_lo, y_hi = FootprintConfig().body     # the footprint `uncovered` leaves out
    fig, axes = plt.subplots(1, len(BANDS), figsize=(4 * len(BANDS), 4.2), constrained_layout=True)
    for ax, (band, (_, boxes)) in zip(axes, enumerate(BANDS)):
        grid = np.where(np.isfinite(env.lowest[band]), env.lowest[band], np.nan)
        hx, hy = (env.xs[1] - env.xs[0]) / 2, (env.ys[1] - env.ys[0]) / 2     # cell edges, not centres
        im = ax.imshow(grid.T, origin="lower", extent=(env.xs[0] - hx, env.xs[-1] + hx, env.ys[0] - hy, env.ys[-1] + hy),
                       cmap="viridis_r", vmin=0.6, vmax=1.1)
        # each box's height label in its own row above the boxes, a leader line to the box's corner
        # (side by side at the corners they overlapped: boxes a few cm apart)
        top = max((half + MARGIN for _, _, half, _ in boxes), default=0.0)
        for k, (x0, x1, half, low) in enumerate(boxes):
            ax.add_patch(plt.Rectangle((x0 - MARGIN, -half - MARGIN), x1 - x0 + 2 * MARGIN, 2 * (half + MARGIN),
                                       fill=False, edgecolor="red", lw=1))
            y = top + 0.06 + 0.065 * k
            ax.plot([x1 + MARGIN, x1 + MARGIN + 0.04], [half + MARGIN, y], color="red", lw=0.6)
            ax.text(x1 + MARGIN + 0.05, y, f"{low - MARGIN:.2f} m", color="red", fontsize=7, va="center")
        ax.add_patch(plt.Rectangle((x_lo, y_lo), x_hi - x_lo, y_hi - y_lo, fill=False, edgecolor="0.45", ls="--", lw=1))
        ax.set_xlim(-0.6, 1.25)
        ax.set_ylim(-0.6, 0.8)
        ax.set_title(band_name(band), fontsize=9)
        ax.set_xlabel("ahead of the body centre (m)")
    axes[0].set_ylabel("left (m)")
    fig.colorbar(im, ax=list(axes), label="lowest arm point (m)")
    fig.suptitle("Spot's arm pointing the hand camera: lowest point over the ground (body dashed; red: the agent's table, blocks above)")
    fig.savefig(path, dpi=90)
    plt.close(fig)
