"""The maps benchmark's trajectory format and measurement loop (timings are not asserted)."""

import numpy as np

from tools.bench_maps import (Trajectory, benchmark_frames, check_trajectory, format_report, save_trajectory,
                              synthetic_frames)


def test_trajectory_file_round_trips_observations_detections_and_scores(tmp_path):
    frames = list(synthetic_frames(4, seed=1, width=80, height=60))
    path = save_trajectory(tmp_path / "t.npz", frames, ("cup", "table", "counter"), ("table", "counter"))
    check_trajectory(path)          # what bench maps checks before replaying a recording: it passes
    loaded = Trajectory.load(path)
    assert len(loaded) == 4 and loaded.task_classes == ["cup", "table", "counter"]
    for (obs, dets, scores), (obs2, dets2, scores2) in zip(frames, loaded.frames()):
        np.testing.assert_array_equal(obs.depth, obs2.depth)
        np.testing.assert_array_equal(obs.rgb, obs2.rgb)
        np.testing.assert_allclose(obs.T_world_cam, obs2.T_world_cam)
        assert obs.intrinsics == obs2.intrinsics
        assert [(d.class_name, d.score) for d in dets] == [(d.class_name, np.float32(d.score)) for d in dets2]
        for d, d2 in zip(dets, dets2):
            np.testing.assert_array_equal(d.mask, d2.mask)
        assert scores2 == {k: np.float32(v) for k, v in scores.items()}


def test_benchmark_reports_both_modes_side_by_side():
    frames = list(synthetic_frames(6, seed=0, width=160, height=120))
    obj = benchmark_frames(frames, ("cup", "table", "counter"), ("table", "counter"), full_scene=False, threads=1,
                           frontier_every=3)
    full = benchmark_frames(frames, ("cup", "table", "counter"), ("table", "counter"), full_scene=True, threads=1,
                            frontier_every=3)
    assert obj["frames"] == 6 and len(obj["gauss_ms"]) == 6 and len(obj["frontier_ms"]) == 2
    assert full["n_gaussians"] > 5 * obj["n_gaussians"] > 0
    assert full["peak_map_bytes"] > 5 * obj["peak_map_bytes"]
    report = format_report(obj, full, "test frames", 1)
    assert "object-only" in report and "full-scene" in report and "Peak Gaussian map tensors" in report


def test_simulator_recording_streams_frames_with_detections_and_scores(tmp_path):
    """The bench's default frame source: HELIOS's observations on val episode 0, one more frame
    after every command, each with thresholded detections and a score per value-map layer."""
    from tools.bench_maps import Trajectory, sim_frames

    frames, classes, layers = sim_frames(12)
    assert len(frames) == 12 and len(classes) == 3 and layers == classes[1:]
    stamps = [obs.stamp for obs, _, _ in frames]
    assert stamps == sorted(stamps) and stamps[-1] > stamps[0]
    for obs, detections, scores in frames:
        assert obs.depth.shape == (240, 320) and set(scores) == set(layers)
        assert all(d.class_name in classes and d.mask.shape == obs.depth.shape for d in detections)
    path = save_trajectory(tmp_path / "sim.npz", frames, classes, layers)
    check_trajectory(path)
    assert len(list(Trajectory.load(path).frames())) == 12
