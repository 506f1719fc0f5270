"""Map benchmark: object-only versus full-scene Gaussians, and the 2D layers, over one trajectory.

``python -m tools bench maps`` replays a recorded trajectory through two ``HierarchicalMap``s,
one per mode (the paper's efficiency comparison: Gaussians for detected objects of interest only,
or for every depth pixel), each in its own fresh process so peak memory is measured per mode.
It prints per-frame Gaussian-update time (median, p90), occupancy + value-map update time,
frontier extraction time, and peak memory: the map's tensors, the renderer's pair lists, and the
process peak RSS above the level after loading the trajectory.

Frame source. Anything that yields ``(Observation, list[Detection], scores)`` tuples can be
benchmarked (:func:`benchmark_frames`); the command reads a recorded ``.npz`` trajectory given by
``--maps-recording PATH`` (``python -m tools.bench_maps``) or the ``HELIOS_MAPS_RECORDING``
environment variable. Without one it records, once, 300 frames of the simulated Spot doing a val
episode (HELIOS's own observations, :func:`sim_frames`, cached under ``runs/bench_maps/``); ``--maps-synthetic`` uses a
synthetic furnished two-room flat of boxes instead (:func:`sim.synthetic_boxes.synthetic_frames`).

Recorded trajectory format (``.npz``, written by :func:`save_trajectory`; N frames, M detections):

==============  ======================  ===================================================
key             shape / dtype           meaning
==============  ======================  ===================================================
rgb             (N, H, W, 3) uint8      hand-camera colour
depth           (N, H, W) float32       metres along the optical axis, 0 = no return
K               (3, 3) float64          pinhole intrinsics (same for every frame)
T_world_cam     (N, 4, 4) float64       optical frame (x right, y down, z forward) -> world
T_world_body    (N, 4, 4) float64       body -> world
stamps          (N,) float64            seconds
det_frame       (M,) int32              frame index of each detection
det_class       (M,) int32              index into ``class_names``
det_score       (M,) float32            detector confidence
det_masks       (M, ceil(H*W/8)) uint8  ``np.packbits`` of each flattened (H, W) bool mask
class_names     (C,) str                names ``det_class`` refers to
task_classes    (T,) str                episode classes: object, start / goal receptacle
value_layers    (L,) str                value-map layers (search targets)
scores          (N, L) float32          image-text score per frame and layer
==============  ======================  ===================================================
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import resource
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Iterable, Iterator, Sequence

import numpy as np

from helios.perception.config import apply_thresholds, role_thresholds
from helios.perception.detection import Detection
from robots.hal import CameraIntrinsics, CommandProxy, Observation
from sim.synthetic_boxes import HEIGHT, WIDTH, Frame, synthetic_frames

DEFAULT_FRAMES = 300
RECORDING_ENV = "HELIOS_MAPS_RECORDING"     # a trajectory .npz, when --maps-recording is not given
THREADS_ENV = "HELIOS_BENCH_THREADS"        # torch threads, when --maps-threads is not given
QUICK_FRAMES = 60
SYNTHETIC_DIR = Path("runs/bench_maps")


# ============================================================================ trajectory files
def save_trajectory(path: str | Path, frames: Iterable[Frame], task_classes: Sequence[str],
                    value_layers: Sequence[str]) -> Path:
    """Write frames of ``(Observation, detections, {layer: score})`` to a trajectory ``.npz``."""
    rgb, depth, T_cam, T_body, stamps, scores = [], [], [], [], [], []
    det_frame, det_class, det_score, det_masks = [], [], [], []
    class_names: list[str] = list(task_classes)
    K = None
    for i, (obs, detections, frame_scores) in enumerate(frames):
        if K is None:
            K = obs.intrinsics.K
            size = (obs.intrinsics.width, obs.intrinsics.height)
        elif (obs.intrinsics.width, obs.intrinsics.height) != size or not np.allclose(obs.intrinsics.K, K):
            raise ValueError(f"frame {i}: all frames of a trajectory must share one camera")
        rgb.append(obs.rgb)
        depth.append(obs.depth)
        T_cam.append(obs.T_world_cam)
        T_body.append(obs.T_world_body)
        stamps.append(obs.stamp)
        scores.append([float(frame_scores[name]) for name in value_layers])
        for det in detections:
            if det.class_name not in class_names:
                class_names.append(det.class_name)
            det_frame.append(i)
            det_class.append(class_names.index(det.class_name))
            det_score.append(det.score)
            det_masks.append(np.packbits(det.mask.reshape(-1)))
    if K is None:
        raise ValueError("a trajectory needs at least one frame")
    n_bytes = math.ceil(size[0] * size[1] / 8)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        path, rgb=np.stack(rgb), depth=np.stack(depth).astype(np.float32), K=K,
        T_world_cam=np.stack(T_cam), T_world_body=np.stack(T_body), stamps=np.asarray(stamps, dtype=np.float64),
        det_frame=np.asarray(det_frame, dtype=np.int32), det_class=np.asarray(det_class, dtype=np.int32),
        det_score=np.asarray(det_score, dtype=np.float32),
        det_masks=np.stack(det_masks) if det_masks else np.zeros((0, n_bytes), dtype=np.uint8),
        class_names=np.asarray(class_names), task_classes=np.asarray(list(task_classes)),
        value_layers=np.asarray(list(value_layers)), scores=np.asarray(scores, dtype=np.float32).reshape(-1, len(value_layers)))
    return path


TRAJECTORY_ARRAYS = frozenset({"rgb", "depth", "K", "T_world_cam", "T_world_body", "stamps", "det_frame", "det_class",
                               "det_score", "det_masks", "class_names", "task_classes", "value_layers", "scores"})


@dataclass
class Trajectory:
    """A loaded trajectory file; iterate ``frames()`` for (Observation, detections, scores)."""

    arrays: dict[str, np.ndarray]

    @staticmethod
    def load(path: str | Path) -> "Trajectory":
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"trajectory file {str(path)!r} does not exist")
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
        missing = sorted(TRAJECTORY_ARRAYS - set(arrays))
        if missing:
            raise ValueError(f"trajectory {str(path)!r} lacks the arrays {missing}; see tools/bench_maps.py")
        return Trajectory(arrays)

    def __len__(self) -> int:
        return int(self.arrays["depth"].shape[0])

    @property
    def task_classes(self) -> list[str]:
        return [str(s) for s in self.arrays["task_classes"]]

    @property
    def value_layers(self) -> list[str]:
        return [str(s) for s in self.arrays["value_layers"]]

    @property
    def intrinsics(self) -> CameraIntrinsics:
        K = self.arrays["K"]
        h, w = self.arrays["depth"].shape[1:]
        return CameraIntrinsics(w, h, float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]))

    def frames(self, limit: int | None = None) -> Iterator[Frame]:
        a = self.arrays
        cam = self.intrinsics
        names = [str(s) for s in a["class_names"]]
        shape = a["depth"].shape[1:]
        order = np.argsort(a["det_frame"], kind="stable")
        starts = np.searchsorted(a["det_frame"][order], np.arange(len(self) + 1))
        for i in range(len(self) if limit is None else min(limit, len(self))):
            detections = []
            for j in order[starts[i]:starts[i + 1]]:
                mask = np.unpackbits(a["det_masks"][j], count=shape[0] * shape[1]).reshape(shape).astype(bool)
                detections.append(Detection(mask, names[a["det_class"][j]], float(a["det_score"][j])))
            obs = Observation(rgb=a["rgb"][i], depth=a["depth"][i], intrinsics=cam, T_world_cam=a["T_world_cam"][i],
                              T_world_body=a["T_world_body"][i], stamp=float(a["stamps"][i]), frame_id=i)
            yield obs, detections, dict(zip(self.value_layers, a["scores"][i].tolist()))


def check_trajectory(path: str | Path, where: str = "--maps-recording") -> None:
    """``path`` is a trajectory ``.npz`` this benchmark can replay (the arrays of the module
    docstring, with matching shapes); a CliError naming ``where`` otherwise. Loads it in this
    process, so a bad file is one line before any worker starts."""
    import zipfile

    from helios.schema import short_repr
    from tools.cli import CliError

    name = f"{where} {short_repr(str(path))}"
    if not Path(path).is_file():
        raise CliError(f"{name} is not a file")
    def bad(what: str):
        return CliError(f"{name}: {what}; see tools/bench_maps.py for the format")

    try:
        data = np.load(path, allow_pickle=False)
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise bad("a single NumPy array, not a trajectory .npz")
        with data:
            a = {key: data[key] for key in data.files}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError, RuntimeError) as exc:
        why = "not a .npz file" if isinstance(exc, (zipfile.BadZipFile, EOFError)) else one_line_text(exc)
        if "pickle" in str(exc):
            why = "not a trajectory .npz (it holds pickled objects, or is not a NumPy file)"
        raise bad(why) from None
    missing = sorted(TRAJECTORY_ARRAYS - set(a))
    if missing:
        raise bad(f"lacks the arrays {', '.join(missing)}")
    rgb, depth = a["rgb"], a["depth"]
    if depth.ndim != 3 or depth.shape[0] < 1 or min(depth.shape[1:]) < 1:
        raise bad(f"depth has shape {depth.shape}, expected (N, H, W) with N >= 1")
    n, h, w = depth.shape
    expected = {"rgb": (n, h, w, 3), "K": (3, 3), "T_world_cam": (n, 4, 4), "T_world_body": (n, 4, 4),
                "stamps": (n,)}
    for key, shape in expected.items():
        if a[key].shape != shape:
            raise bad(f"{key} has shape {a[key].shape}, expected {shape}")
    if rgb.dtype != np.uint8:
        raise bad(f"rgb is {rgb.dtype}, expected uint8")
    m = a["det_frame"].shape[0] if a["det_frame"].ndim == 1 else -1
    for key in ("det_frame", "det_class", "det_score"):
        if a[key].shape != (m,) or m < 0:
            raise bad(f"{key} has shape {a[key].shape}, expected one value per detection")
    if a["det_masks"].shape != (m, math.ceil(h * w / 8)):
        raise bad(f"det_masks has shape {a['det_masks'].shape}, expected {(m, math.ceil(h * w / 8))}")
    for key in ("class_names", "task_classes", "value_layers"):
        if a[key].ndim != 1 or a[key].dtype.kind not in "US":
            raise bad(f"{key} must be a list of names")
    if a["scores"].shape != (n, len(a["value_layers"])):
        raise bad(f"scores has shape {a['scores'].shape}, expected {(n, len(a['value_layers']))}")
    if m and (a["det_frame"].min() < 0 or a["det_frame"].max() >= n
              or a["det_class"].min() < 0 or a["det_class"].max() >= len(a["class_names"])):
        raise bad("a detection names a frame or class the file does not have")


def one_line_text(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def synthetic_trajectory_file(n_frames: int, seed: int) -> Path:
    """Path of the cached synthetic trajectory, generating it on first use."""
    path = SYNTHETIC_DIR / f"synthetic_flat_{n_frames}f_{WIDTH}x{HEIGHT}_seed{seed}.npz"
    if not path.is_file():
        save_trajectory(path, synthetic_frames(n_frames, seed), ("cup", "table", "counter"), ("table", "counter"))
    return path


class _EnoughFrames(Exception):
    """Stops the recording episode once it has the frames it needs."""


class _RecordingBackend(CommandProxy):
    """A HAL backend wrapper that runs the simulated detector and scorer on every observation the
    agent takes, and on one more frame after every other command (as a camera streaming during
    the episode would), and keeps ``(Observation, detections, scores)``."""

    def __init__(self, backend, detector, scorer, task_classes, value_layers, thresholds, n_frames: int):
        from helios.perception.prompts import value_prompt

        self._backend = backend
        self._detector, self._scorer = detector, scorer
        self._classes, self._layers = list(task_classes), list(value_layers)
        self._prompts = [value_prompt(layer) for layer in value_layers]
        self._thresholds = thresholds
        self._n = n_frames
        self.frames: list[Frame] = []

    def observe(self, *args, **kwargs):
        obs = self._backend.observe(*args, **kwargs)
        detections = apply_thresholds(self._detector(obs.rgb, obs.depth, self._classes), self._thresholds, default=1.0)
        scores = dict(zip(self._layers, (float(v) for v in self._scorer(obs.rgb, self._prompts))))
        self.frames.append((obs, detections, scores))
        if len(self.frames) >= self._n:
            raise _EnoughFrames()
        return obs

    def _command(self, name: str, *args, **kwargs):
        result = getattr(self._backend, name)(*args, **kwargs)
        self.observe()                    # a streaming camera: one more frame after every command
        return result

    def __getattr__(self, name):
        return getattr(self._backend, name)


def sim_frames(n_frames: int, episode_index: int = 0,
               agent: str = "helios") -> tuple[list[Frame], list[str], list[str]]:
    """Frames of the simulated Spot working on a val episode: the HELIOS agent's own observations,
    with the simulated detector's detections (above the paper's per-class thresholds) and the
    image-text scores; up to ``n_frames`` (fewer if the episode ends first). Returns the frames,
    the episode's classes (object, start and goal receptacle) and its value-map layers."""
    from helios.config import HeliosConfig
    from sim.perception import make_sim_perception
    from tasks.episodes import load_split
    from tasks.registry import make_agent
    from tasks.runner import RunnerConfig, SimEpisode, run_episode

    episode = load_split("val")[episode_index]
    spec = episode.spec
    classes = [spec.object, spec.start_receptacle, spec.goal_receptacle]
    layers = [spec.start_receptacle, spec.goal_receptacle]
    thresholds = role_thresholds(HeliosConfig().detection, spec.object, spec.start_receptacle, spec.goal_receptacle)
    sim = SimEpisode.create(episode)
    try:
        detector, scorer = make_sim_perception(sim.backend, seed=episode.seed, rooms=sim.scene.layout.rooms)
        robot = _RecordingBackend(sim.backend, detector, scorer, classes, layers, thresholds, n_frames)
        try:
            run_episode(make_agent(agent, sim), robot, episode, RunnerConfig(), sim.judge,
                        start_time=sim.world.time, seed=episode.seed)
        except _EnoughFrames:
            pass
        return robot.frames, classes, layers
    finally:
        sim.close()


def sim_trajectory_file(n_frames: int, episode_index: int = 0) -> Path:
    """Path of the cached simulator trajectory (HELIOS on val episode ``episode_index``),
    recording it on first use (about a minute)."""
    path = SYNTHETIC_DIR / f"sim_helios_val{episode_index}_{n_frames}f_{WIDTH}x{HEIGHT}.npz"
    if not path.is_file():
        frames, classes, layers = sim_frames(n_frames, episode_index)
        first = frames[0][0].intrinsics
        if (first.width, first.height) != (WIDTH, HEIGHT):
            raise ValueError(f"the simulated hand camera renders {first.width}x{first.height}, expected {WIDTH}x{HEIGHT}")
        save_trajectory(path, frames, classes, layers)
    return path


# ============================================================================ measurement
def _rss_bytes() -> int:
    import psutil

    return int(psutil.Process().memory_info().rss)


def benchmark_frames(frames: Iterable[Frame], task_classes: Sequence[str], value_layers: Sequence[str],
                     full_scene: bool, threads: int, frontier_every: int = 10, device: str = "cpu") -> dict:
    """Run one map over ``frames`` and measure it (call in a fresh process for clean peak RSS).
    ``device`` is the Gaussian layer's torch device (``cpu`` or ``cuda``)."""
    import torch

    from helios.config import HeliosConfig
    from helios.schema import with_overrides
    from helios.maps.hierarchical import HierarchicalMap

    torch.set_num_threads(threads)
    frames = list(frames)
    gc.collect()
    cfg = with_overrides(HeliosConfig(), [f"gaussians.full_scene={str(full_scene).lower()}", f"device={device}"])
    hmap = HierarchicalMap(cfg, task_classes, value_layers)
    baseline = _rss_bytes()
    gauss, layers2d, frontier_ms = [], [], []
    peak_map = peak_render = 0
    for i, (obs, detections, scores) in enumerate(frames):
        update = hmap.update(obs, detections, scores)
        if device == "cuda":
            torch.cuda.synchronize()
        gauss.append(update.seconds["gaussians"] * 1e3)
        layers2d.append((update.seconds["occupancy"] + update.seconds["value_map"]) * 1e3)
        peak_map = max(peak_map, hmap.objects.memory_bytes())
        peak_render = max(peak_render, update.objects.render_bytes)
        if i % frontier_every == frontier_every - 1:
            t = time.perf_counter()
            hmap.frontiers()
            frontier_ms.append((time.perf_counter() - t) * 1e3)
    peak_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux reports KiB
    return {
        "frames": len(frames), "gauss_ms": gauss, "layers2d_ms": layers2d, "frontier_ms": frontier_ms,
        "n_gaussians": len(hmap.objects), "n_instances": len(hmap.instances()),
        "peak_map_bytes": peak_map, "peak_render_bytes": peak_render,
        "peak_rss_increase": max(0, peak_rss - baseline),
        "grid_bytes": hmap.memory_bytes()["occupancy"] + hmap.memory_bytes()["value_map"],
    }


def _benchmark_file(path: str, full_scene: bool, threads: int, limit: int | None, device: str = "cpu") -> dict:
    trajectory = Trajectory.load(path)
    return benchmark_frames(trajectory.frames(limit), trajectory.task_classes, trajectory.value_layers,
                            full_scene, threads, device=device)


def format_device_report(cpu: dict, gpu: dict, name: str) -> str:
    """The object-only Gaussian update on the CPU and on CUDA, side by side."""
    from tools.tables import format_table

    rows = []
    for label, q in (("median", 50), ("p90", 90)):
        c, g = float(np.percentile(cpu["gauss_ms"], q)), float(np.percentile(gpu["gauss_ms"], q))
        rows.append([f"Gaussian update, {label} (ms/frame)", c, g, c / g if g else float("inf")])
    rows.append(["Gaussians at the end", cpu["n_gaussians"], gpu["n_gaussians"],
                 cpu["n_gaussians"] / gpu["n_gaussians"] if gpu["n_gaussians"] else float("nan")])
    return format_table(["metric", "CPU", f"CUDA ({name})", "CPU/GPU"], rows,
                        title="maps on CPU vs CUDA: object-only Gaussian layer, same frames")


def _in_fresh_process(*args) -> dict:
    with ProcessPoolExecutor(max_workers=1, mp_context=get_context("spawn")) as pool:
        return pool.submit(_benchmark_file, *args).result()


def _mb(n: float) -> float:
    return n / 2 ** 20


def format_report(obj: dict, full: dict, source: str, threads: int, device: str = "cpu") -> str:
    from tools.tables import format_table

    def stats(xs):
        return float(np.median(xs)), float(np.percentile(xs, 90))

    og, fg = stats(obj["gauss_ms"]), stats(full["gauss_ms"])
    ol, fl = stats(obj["layers2d_ms"]), stats(full["layers2d_ms"])
    ofr = float(np.median(obj["frontier_ms"])) if obj["frontier_ms"] else float("nan")

    def ratio(a, b):
        return b / a if a else float("inf")

    rows = [
        ["Gaussian update, median (ms/frame)", og[0], fg[0], ratio(og[0], fg[0])],
        ["Gaussian update, p90 (ms/frame)", og[1], fg[1], ratio(og[1], fg[1])],
        ["Gaussians at the end", obj["n_gaussians"], full["n_gaussians"], ratio(obj["n_gaussians"], full["n_gaussians"])],
        ["Instances at the end", obj["n_instances"], full["n_instances"], ratio(obj["n_instances"], full["n_instances"])],
        ["Peak Gaussian map tensors (MB)", _mb(obj["peak_map_bytes"]), _mb(full["peak_map_bytes"]),
         ratio(obj["peak_map_bytes"], full["peak_map_bytes"])],
        ["Peak renderer pair lists (MB)", _mb(obj["peak_render_bytes"]), _mb(full["peak_render_bytes"]),
         ratio(obj["peak_render_bytes"], full["peak_render_bytes"])],
        ["Peak RSS above baseline (MB)", _mb(obj["peak_rss_increase"]), _mb(full["peak_rss_increase"]),
         ratio(obj["peak_rss_increase"], full["peak_rss_increase"])],
        ["Occupancy + value map, median (ms/frame)", ol[0], fl[0], ratio(ol[0], fl[0])],
        ["Occupancy + value map, p90 (ms/frame)", ol[1], fl[1], ratio(ol[1], fl[1])],
    ]
    title = (f"maps: {obj['frames']} frames at {WIDTH}x{HEIGHT} from {source}; torch threads={threads}, {device.upper()}; "
             f"each mode in its own process")
    table = format_table(["metric", "object-only", "full-scene", "full/object"], rows, title=title)
    mem_ratio = ratio(full["peak_map_bytes"], obj["peak_map_bytes"])
    checks = [
        f"object-only Gaussian update median {og[0]:.1f} ms (target <= 50 ms): {'PASS' if og[0] <= 50 else 'FAIL'}",
        f"object-only peak map memory = 1/{1 / mem_ratio:.0f} of full-scene (target <= 1/10): "
        f"{'PASS' if mem_ratio <= 0.1 else 'FAIL'}" if mem_ratio > 0 else "object-only map is empty",
        f"occupancy + value map median {ol[0]:.1f} ms (target <= 15 ms): {'PASS' if ol[0] <= 15 else 'FAIL'}",
        f"frontier extraction median {ofr:.1f} ms per call (every 10 frames); 2D grids hold "
        f"{_mb(obj['grid_bytes']):.0f} MB (2000 x 2000 cells)",
    ]
    return table + "\n" + "\n".join(checks)


def check_device(device: str) -> None:
    """A clear error, before any work, when CUDA is asked for and there is none."""
    if device == "cpu":
        return
    import torch

    if not torch.cuda.is_available():
        from tools.cli import CliError

        raise CliError(f"--maps-device {device}: no CUDA device here (torch.cuda.is_available() is False; "
                       f"torch {torch.__version__}); use --maps-device cpu")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--maps-recording", default=None, help="trajectory .npz (see tools/bench_maps.py)")
    parser.add_argument("--maps-synthetic", action="store_true",
                        help="replay a synthetic two-room flat instead of a simulator recording")
    parser.add_argument("--maps-device", choices=("cpu", "cuda", "both"), default="cpu",
                        help="Gaussian layer on the CPU (default), on CUDA, or both with the CPU/GPU ratio")
    parser.add_argument("--maps-threads", type=int, default=None,
                        help="torch threads (default 1, or $HELIOS_BENCH_THREADS)")


def _env_threads() -> int:
    """Torch threads from ``HELIOS_BENCH_THREADS`` (default 1); a CliError naming it unless it is a
    whole number within 1..100000."""
    from helios.schema import short_repr
    from tools.cli import CliError

    text = os.environ.get(THREADS_ENV, "").strip()
    if not text:
        return 1
    try:
        threads = int(text)
    except ValueError:
        threads = 0
    if not 1 <= threads <= 100_000:
        raise CliError(f"{THREADS_ENV}={short_repr(text, 40)} must be a whole number of torch threads "
                       f"within 1..100000 (or unset: 1 thread)")
    return threads


def check_inputs(args: argparse.Namespace) -> None:
    """The device, thread count and recording (flag or ``HELIOS_MAPS_RECORDING``): CliError before
    any work (``tools bench`` calls it before its first suite; ``main`` before :func:`run`)."""
    check_device(getattr(args, "maps_device", "cpu") or "cpu")   # before a recording that may take a minute
    if getattr(args, "maps_threads", None) is None:
        _env_threads()
    recording = getattr(args, "maps_recording", None)
    if recording:
        check_trajectory(recording, "--maps-recording")
    elif os.environ.get(RECORDING_ENV):
        check_trajectory(os.environ[RECORDING_ENV], RECORDING_ENV)


def run(args: argparse.Namespace) -> str:
    """The benchmark, on inputs :func:`check_inputs` accepted."""
    device = getattr(args, "maps_device", "cpu") or "cpu"
    recording = getattr(args, "maps_recording", None) or os.environ.get(RECORDING_ENV)
    # One torch thread by default: on a 2-core machine that also runs the simulator, 2 threads
    # make the p90 erratic (oversubscription) while gaining little on the median.
    threads = getattr(args, "maps_threads", None) or _env_threads()
    limit = QUICK_FRAMES if getattr(args, "quick", False) else None
    if recording:
        path, source = Path(recording), f"recording {recording}"
    elif getattr(args, "maps_synthetic", False):
        path = synthetic_trajectory_file(DEFAULT_FRAMES, getattr(args, "seed", 0))
        source = f"synthetic two-room flat ({path})"
    else:
        path = sim_trajectory_file(DEFAULT_FRAMES)
        source = f"simulator recording: HELIOS on val episode 0 ({path})"
    first = "cuda" if device == "cuda" else "cpu"
    obj = _in_fresh_process(str(path), False, threads, limit, first)
    full = _in_fresh_process(str(path), True, threads, limit, first)
    report = format_report(obj, full, source, threads, first)
    if device == "both":
        import torch

        gpu = _in_fresh_process(str(path), False, threads, limit, "cuda")
        report += "\n\n" + format_device_report(obj, gpu, torch.cuda.get_device_name(0))
    return report


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.bench_maps", description=__doc__.splitlines()[0])
    add_arguments(parser)
    parser.add_argument("--quick", action="store_true", help=f"first {QUICK_FRAMES} frames only")
    parser.add_argument("--seed", type=int, default=0, help="seed of the synthetic trajectory")
    args = parser.parse_args(argv)
    check_inputs(args)
    print(run(args))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
