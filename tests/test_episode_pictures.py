"""Per-episode pictures (issue 20): captured during the trials without changing an episode, drawn
where things really are, and linked from the report (every episode row, a failure gallery)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from tasks.episode_trace import load_trace, trace_path
from tasks.trial_config import deterministic_view
from tasks.trials import run_batch
from tools.episode_pages import EVENT, FAILED_TEXT, FOOTER, HEADER, MAP_PX, PATH, TARGET, map_picture


def _image(path: Path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB"))


def _pixel(trace: dict, x: float, y: float) -> tuple[int, int]:
    """World (x, y) -> (column, row) in the top-down picture, worked out from the trace's grid and
    the picture's documented layout (the map scaled to MAP_PX on its longer side, 1-12 px per
    cell, north up, below a HEADER-pixel title band) rather than taken from the renderer."""
    rows, cols = trace["map"].shape
    cell = trace["meta"]["grid"]["cell_size"]
    ox, oy = trace["meta"]["grid"]["origin_xy"]
    scale = min(12.0, max(1.0, MAP_PX / max(rows, cols)))
    sx, sy = round(cols * scale) / cols, round(rows * scale) / rows
    return int((x - ox) / cell * sx), int(HEADER + (rows - (y - oy) / cell) * sy)


def _page_file(runs, run: str, suffix: str) -> Path:
    page = runs["report"]["pages"][run][0].page
    return runs["root"] / "report" / page.replace(".html", suffix)


def _true_target_xy(episode) -> np.ndarray:
    """Where the episode's target object stands: from a freshly built scene, not from the trace."""
    from sim.world import World
    from tasks.runner import build_episode_scene

    world = World()
    try:
        scene = build_episode_scene(world, episode)
        return world.position(scene.object_ids[episode.target_object])[:2]
    finally:
        world.close()


def test_pictures_do_not_change_an_episode(picture_runs, tmp_path):
    """The same episodes with pictures off: identical records (bar wall time and memory), no traces."""
    ep = picture_runs["episode"]
    for name, cfg in picture_runs["configs"].items():
        off = run_batch(cfg, [ep], tmp_path / name, pictures=False)[0]
        on = picture_runs["records"][name]
        assert deterministic_view(off) == deterministic_view(on), name
        assert not (tmp_path / name / "episodes").exists()
        assert trace_path(picture_runs["root"] / name, ep.episode_id).stat().st_size < 200_000


def test_the_drawn_path_passes_through_the_start_pose(picture_runs):
    ep = picture_runs["episode"]
    walked = []
    for run in ("helios", "oracle"):
        trace = load_trace(trace_path(picture_runs["root"] / run, ep.episode_id))
        path = trace["path"]
        walked.append(len(path) >= 3 and np.ptp(path[:, 1:3], axis=0).max() > 0.5)
        img = _image(_page_file(picture_runs, run, ".png"))
        col, row = _pixel(trace, ep.start_pose.x, ep.start_pose.y)
        assert tuple(img[row, col]) == PATH, (run, col, row, img[row, col])
        assert (img == PATH).all(axis=-1).mean() < 0.2                        # a path, not a flood
    assert any(walked)                                                        # somewhere beyond the start


def test_the_target_marker_sits_at_the_true_target_location(picture_runs):
    ep = picture_runs["episode"]
    xy = _true_target_xy(ep)
    for run in ("helios", "oracle"):
        trace = load_trace(trace_path(picture_runs["root"] / run, ep.episode_id))
        img = _image(_page_file(picture_runs, run, ".png"))
        col, row = _pixel(trace, *xy)
        assert tuple(img[row, col]) == TARGET, (run, img[row, col])
        red = np.argwhere((img[:-FOOTER] == TARGET).all(axis=-1))                # (the legend has one too)
        # the marker is small and centred there: every TARGET pixel of the map within 10 px of the true spot
        assert len(red) and np.abs(red - (row, col)).max() <= 10, run


def test_the_grasp_mark_rings_the_target_above_it_and_the_legend_names_the_events(picture_runs):
    """(audit 2026-12-05) The grasp ring was drawn under the target's diamond, a sliver left (about
    50 of its pixels within 14 px of the target; 110 now), and the legend had no event entries."""
    ep = picture_runs["episode"]
    rec = picture_runs["records"]["oracle"]
    assert rec["metrics"]["pick"], "the oracle grasps the target in this episode"
    trace = load_trace(trace_path(picture_runs["root"] / "oracle", ep.episode_id))
    img = _image(_page_file(picture_runs, "oracle", ".png"))
    col, row = _pixel(trace, *_true_target_xy(ep))
    ring = np.argwhere((img[:-FOOTER] == EVENT["grasp"]).all(axis=-1))
    assert (np.abs(ring - (row, col)).max(axis=1) <= 14).sum() >= 80
    legend = img[-FOOTER:]
    for kind in ("grasp", "release", "collision"):
        assert (legend == EVENT[kind]).all(axis=-1).sum() >= 10, kind


def test_a_run_of_tools_spot_says_why_its_pages_have_no_picture(picture_runs, tmp_path):
    """(audit 2026-12-05) A `tools spot --fake --episode` run folder (robot.yaml beside it) keeps no
    picture data; its pages blamed --no-pictures or an older version."""
    import shutil

    from tools.report import make_report

    run = tmp_path / "spot-run"
    shutil.copytree(picture_runs["root"] / "oracle", run)
    shutil.rmtree(run / "episodes")
    (run / "robot.yaml").write_text("hostname: 127.0.0.1\n")
    report = make_report([run], tmp_path / "rep")
    page = (tmp_path / "rep" / report["pages"]["spot-run"][0].page).read_text()
    assert "no picture data: episodes run through the Spot SDK backend (tools spot) keep none" in page
    assert "--no-pictures" not in page


def test_a_failed_episodes_page_names_its_failure_reason(picture_runs):
    root = picture_runs["root"] / "report"
    rec = picture_runs["records"]["helios"]
    reason = rec["metrics"]["failure_reason"]
    assert reason and not rec["success"], "HELIOS was meant to fail this episode in 60 s of robot time"
    page = (root / picture_runs["report"]["pages"]["helios"][0].page).read_text()
    assert f"<span id='failure-reason'>{reason}</span>" in page
    ok = (root / picture_runs["report"]["pages"]["oracle"][0].page).read_text()
    assert "Success" in ok and "failure-reason" not in ok
    # the picture says it too: its title band is in the failure colour (and names the reason)
    img = _image(_page_file(picture_runs, "helios", ".png"))
    assert (img[:HEADER] == FAILED_TEXT).all(axis=-1).sum() > 50


def test_the_report_links_every_episode_row_and_groups_failures(picture_runs):
    root = picture_runs["root"] / "report"
    index = (root / "index.html").read_text()
    rows = re.findall(r"<tr class='episode-row'><td><a href='([^']+)'>([^<]+)</a>", index)
    assert len(rows) == 2 and all((root / href).is_file() for href, _ in rows)
    assert {href.split("/")[1] for href, _ in rows} == {"1-oracle", "2-helios"}
    gallery = index[index.index("Failure gallery: helios"):index.index("Episodes: oracle")]
    reason = picture_runs["records"]["helios"]["metrics"]["failure_reason"]
    assert f"<h3 class='reason'>{reason} (1)</h3>" in gallery
    thumbs = re.findall(r"<a href='([^']+)'><img alt='[^']*' src='([^']+)'", gallery)
    assert len(thumbs) == 1 and all((root / a).is_file() and (root / b).is_file() for a, b in thumbs)
    assert "No failed episodes." in index[index.index("Failure gallery: oracle"):]
    assert "http://" not in index and "https://" not in index


def test_key_frames_and_the_hand_camera_animation(picture_runs):
    from PIL import Image

    ep = picture_runs["episode"]
    trace = load_trace(trace_path(picture_runs["root"] / "oracle", ep.episode_id))
    kinds = [info["kind"] for info, _ in trace["key_frames"]]
    m = picture_runs["records"]["oracle"]["metrics"]
    assert m["pick_attempts"] > 0, "the oracle was meant to try a grasp here"
    expected = ["find_obj"] * m["find_obj"] + ["grasp"] + ["find_rec"] * m["find_rec"] \
        + ["release"] * (m["released_on"] is not None) + ["end"]
    assert set(expected) <= set(kinds), kinds
    present = [k for k in ("find_obj", "grasp", "release", "end") if k in expected]
    assert [kinds.index(k) for k in present] == sorted(kinds.index(k) for k in present), kinds     # in time order
    strip = Image.open(_page_file(picture_runs, "oracle", ".frames.png"))
    assert strip.width >= len(kinds) * 240 and np.asarray(strip).std() > 10
    gif = Image.open(_page_file(picture_runs, "oracle", ".gif"))
    assert gif.n_frames >= 3
    helios = load_trace(trace_path(picture_runs["root"] / "helios", ep.episode_id))
    assert helios["meta"]["has_map"] and (helios["map"] > 0).mean() > 0.05      # the agent's map, explored
    assert "detected" in [info["kind"] for info, _ in helios["key_frames"]] or helios["meta"]["candidates"]


def test_a_trace_of_an_episode_that_never_observed_still_draws():
    """An agent that crashed before its first frame: an empty path, no frames, no map."""
    import io

    from tasks.episode_trace import EpisodeTracer

    data = EpisodeTracer().finish(object(), {"episode_id": "x", "task": "t", "agent": "a", "success": False,
                                             "metrics": None, "error": "RuntimeError: boom\ntrace"})
    trace = load_trace(io.BytesIO(data))
    img, _ = map_picture(trace)
    assert img.width > 0 and trace["meta"]["outcome"]["error"] == "RuntimeError: boom"


def test_a_file_where_the_pictures_folder_belongs_is_one_clear_error(tmp_path):
    from tasks.run_folder import RunFolderError, check_folder_layout

    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "episodes").write_text("")
    with pytest.raises(RunFolderError, match="episodes is a file"):
        check_folder_layout(tmp_path / "run", pictures=True)
    check_folder_layout(tmp_path / "run", pictures=False)


def test_the_release_cross_is_drawn_where_the_drop_point_projects():
    """The release frame's cross once sat on the frame's top row whatever the point: the projection
    took the depth (a second return value) for the pixel row."""
    from types import SimpleNamespace

    from robots.hal import CameraIntrinsics
    from tasks.episode_trace import _project

    K = CameraIntrinsics(width=320, height=240, fx=200.0, fy=200.0, cx=160.0, cy=120.0)
    T_world_cam = np.eye(4)
    T_world_cam[:3, 3] = [1.0, 2.0, 0.5]                # the camera looks along world +z from here
    obs = SimpleNamespace(intrinsics=K, T_world_cam=T_world_cam, rgb=np.zeros((240, 320, 3), np.uint8))
    # 0.3 m right of and 0.4 m below the optical axis, 2.0 m ahead: u = 160 + 200*0.3/2, v = 120 + 200*0.4/2
    assert _project(obs, np.array([1.3, 2.4, 2.5])) == (190, 160)
    assert _project(obs, np.array([1.0, 2.0, 0.4])) is None          # behind the camera
    assert _project(obs, np.array([5.0, 2.0, 2.5])) is None          # outside the frame


def test_the_first_detection_frame_says_whether_it_is_on_a_true_target():
    """The caption once read "first detection of the cup" for a false detection behind the robot;
    it now says whether a mask covers where a true target projects."""
    from types import SimpleNamespace

    from robots.hal import CameraIntrinsics
    from tasks.episode_trace import EpisodeTracer

    K = CameraIntrinsics(width=320, height=240, fx=200.0, fy=200.0, cx=160.0, cy=120.0)
    obs = SimpleNamespace(intrinsics=K, T_world_cam=np.eye(4), rgb=np.zeros((240, 320, 3), np.uint8))
    tracer = EpisodeTracer()
    tracer.object_class = "cup"
    tracer.truth = {"targets": [{"name": "cup_1", "xyz": [0.3, 0.4, 2.0], "named": True}]}   # pixel (190, 160)
    on, off = np.zeros((240, 320), bool), np.zeros((240, 320), bool)
    on[150:170, 180:200] = True
    off[10:30, 10:30] = True
    assert tracer._detection_label(obs, [off, on]) == "first detection of a cup (on a true target)"
    assert tracer._detection_label(obs, [off]).startswith("first detection of a cup (not on a true target")
    tracer.truth = {}                                     # a run without ground truth (a real robot)
    assert tracer._detection_label(obs, [on]) == "first detection of a cup"


def test_a_failed_grasp_is_slashed_not_drawn_like_a_held_one(picture_runs):
    """(pictures audit 2026-12-05) Six failed grasps drew six rings like the held one; the event's
    ``ok`` was never read. A failed grasp or release is now slashed."""
    ep = picture_runs["episode"]
    trace = load_trace(trace_path(picture_runs["root"] / "oracle", ep.episode_id))
    grasps = [e for e in trace["meta"]["events"] if e["kind"] == "grasp"]
    assert grasps and grasps[-1]["ok"], "the oracle's last grasp holds the target"
    col, row = _pixel(trace, *grasps[-1]["xy"])

    def slash_pixels(ok: bool) -> int:
        for e in grasps:
            e["ok"] = ok
        img = np.asarray(map_picture(trace)[0].convert("RGB"))
        on = (img == EVENT["grasp"]).all(axis=-1)
        # the slash runs from the ring's lower left to its upper right, through the middle
        return sum(int(on[row - k, col + k]) for k in range(-6, 7))

    held, failed = slash_pixels(True), slash_pixels(False)
    assert failed >= held + 8, (held, failed)
    legend = np.asarray(map_picture(trace)[0].convert("RGB"))[-FOOTER:]
    assert (legend == EVENT["grasp"]).all(axis=-1).sum() >= 20          # ring G and the slashed one


def test_the_top_down_picture_has_a_scale_bar_of_true_length(picture_runs):
    """(pictures audit 2026-12-05) The picture showed no distances: a scale bar of 1, 2 or 5 m now
    sits in the map's lower right corner, as long as that many metres are in the picture."""
    from tools.episode_pages import SCALE_BAR, map_frame

    trace = load_trace(trace_path(picture_runs["root"] / "oracle", picture_runs["episode"].episode_id))
    img = _image(_page_file(picture_runs, "oracle", ".png"))
    frame = map_frame(trace)
    per_m = frame.sx / frame.cell_size
    bar = (img[:-FOOTER] == SCALE_BAR).all(axis=-1)
    row = int(np.argmax(bar.sum(axis=1)))
    cols = np.flatnonzero(bar[row])
    length = cols.max() - cols.min()
    metres = length / per_m
    assert min(abs(metres - m) for m in (1, 2, 5, 10)) * per_m <= 2, (length, per_m)
    assert length >= 38 and cols.max() > img.shape[1] - 40          # in the lower right corner


def test_the_scale_bar_grows_to_two_five_or_ten_metres_on_a_coarse_picture():
    """A picture with fewer than 40 px per metre draws a 2, 5 or 10 m bar, at least 40 px long."""
    from PIL import Image, ImageDraw

    from tools.episode_pages import HEADER, SCALE_BAR, MapFrame, _font, _scale_bar

    for per_m, metres in ((60.0, 1), (20.0, 2), (10.0, 5), (5.0, 10)):
        frame = MapFrame((0.0, 0.0), 0.025, 100, 100, per_m * 0.025, per_m * 0.025)
        img = Image.new("RGB", (400, HEADER + 300), (255, 255, 255))
        _scale_bar(ImageDraw.Draw(img), frame, 400, 300, _font(11))
        bar = (np.asarray(img) == SCALE_BAR).all(axis=-1)
        cols = np.flatnonzero(bar[int(np.argmax(bar.sum(axis=1)))])
        assert abs((cols.max() - cols.min()) - metres * per_m) <= 1.5, (per_m, cols.max() - cols.min())
