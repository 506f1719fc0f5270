"""Camera rendering: exact pinhole geometry (general intrinsics), metric depth, segmentation decoding,
the analytic floor, and bit-identical frames from the render worker process."""

from __future__ import annotations

import numpy as np
import pytest

from robots.hal import CameraIntrinsics, SE2Pose
from robots.spot.kinematics import look_at_hand_pose
from robots.transforms import matrix_to_rpy
from sim import assets
from sim.camera import CameraConfig, decode_body_ids, decode_link_indices, render
from sim.render_worker import RenderWorker, moving_state
from robots.spot.sim_backend import SimSpotBackend
from sim.spot import SpotBody


def _optical_pose(eye, target) -> np.ndarray:
    T = look_at_hand_pose(eye, target)          # x forward, z up
    R = T[:3, :3]
    T[:3, :3] = np.column_stack([-R[:, 1], -R[:, 2], R[:, 0]])   # optical: x right, y down, z forward
    return T


@pytest.mark.parametrize("intr", [
    CameraIntrinsics(320, 240, 276.0, 276.0, 160.0, 120.0),
    CameraIntrinsics(200, 150, 180.0, 150.0, 90.0, 80.0),    # fx != fy, off-centre principal point
])
def test_projected_points_land_on_their_pixels_with_exact_depth(world, intr):
    T = _optical_pose([0.0, 0.0, 1.5], [2.0, 0.3, 0.2])
    cfg = CameraConfig(width=intr.width, height=intr.height)
    rng = np.random.default_rng(0)
    markers = []
    for i in range(6):
        u, v = rng.uniform(0.15, 0.85) * intr.width, rng.uniform(0.15, 0.85) * intr.height
        d = rng.uniform(1.2, 3.0)
        p_cam = intr.backproject(u, v, d)
        p_world = T[:3, :3] @ p_cam + T[:3, 3]
        # a small cube aligned with the camera: its front face is exactly at optical depth d - 0.02
        rpy = matrix_to_rpy(T[:3, :3])
        body = assets.add_static(world, f"m{i}", "marker", [assets.Part("box", (0.02, 0.02, 0.02), rpy=rpy)], p_world)
        markers.append((body, u, v, d))
    frame = render(world, intr, T, cfg)
    ids = decode_body_ids(frame.segmentation)
    for body, u, v, d in markers:
        ui, vi = int(round(u)), int(round(v))
        assert ids[vi, ui] == body
        assert frame.depth[vi, ui] == pytest.approx(d - 0.02, abs=0.001)


def test_floor_pixels_are_filled_analytically_at_z_zero(world):
    intr = CameraIntrinsics(320, 240, 276.0, 276.0, 160.0, 120.0)
    T = _optical_pose([0.0, 0.0, 0.8], [3.0, 0.0, 0.0])
    frame = render(world, intr, T, CameraConfig())
    ids = decode_body_ids(frame.segmentation)
    floor = ids == world.ground_id
    assert floor[-1].all() and not floor[0].any()        # floor below the horizon, sky above
    assert np.all(frame.depth[0] == 0)                   # sky: no return
    v, u = np.nonzero(floor)
    pts = intr.backproject(u, v, frame.depth[v, u]) @ T[:3, :3].T + T[:3, 3]
    assert np.max(np.abs(pts[:, 2])) < 1e-4


def test_segmentation_decodes_body_and_link(world):
    parts = assets.table_parts(1.0, 0.6, 0.5, (0.6, 0.4, 0.2, 1), (0.2, 0.2, 0.2, 1))
    table = assets.add_static(world, "table", "table", parts, (2.0, 0.0, 0.0))
    mug = assets.add_mug(world, "mug", (1.8, 0.0, 0.5))
    spot = SpotBody(world, SE2Pose(0.8, 0.0, 0.0))
    backend = SimSpotBackend(world, spot, owns_world=False)
    assert backend.gaze_at([1.8, 0.0, 0.55]).success                   # looking down at the mug
    intr = CameraIntrinsics(320, 240, 276.0, 276.0, 160.0, 120.0)
    frame = render(world, intr, spot.T_world_camera(), CameraConfig())
    ids, links = decode_body_ids(frame.segmentation), decode_link_indices(frame.segmentation)
    assert (ids == table).sum() > 1000 and (ids == mug).sum() > 50
    assert set(np.unique(links[(ids == table) | (ids == mug)])) == {-1}       # single-link bodies
    jaw = ids == spot.id                                                     # the claw in view
    assert jaw.any() and set(np.unique(links[jaw])) <= set(spot.link_name) - {-1}
    assert np.all(ids[frame.segmentation < 0] == -1)


def test_render_worker_frames_are_identical_to_inline_frames(world):
    assets.add_table(world, "table", (1.5, 0.0))
    mug = assets.add_mug(world, "mug", (1.3, 0.1, 0.5))
    spot = SpotBody(world, SE2Pose(0.2, 0.0, 0.1))
    spot.reset_arm((0.0, -1.0, 1.8, 0.0, -0.5, 0.0))
    intr = CameraIntrinsics(320, 240, 276.0, 276.0, 160.0, 120.0)
    cfg = CameraConfig()
    worker = RenderWorker(world)
    try:
        for step in range(3):
            world.client.resetBasePositionAndOrientation(mug, [1.3, 0.1 * step, 0.5], [0, 0, 0, 1])
            T = spot.T_world_camera()
            inline = render(world, intr, T, cfg)
            from sim.camera import camera_request

            poses, joints = moving_state(world, spot.id, spot.moving_joint_indices)
            worker.submit(poses, joints, camera_request(intr, T, cfg, world.ground_id), cfg, meta=step)
            (meta, remote), = worker.poll(block=True)
            assert meta == step
            assert np.array_equal(inline.rgb, remote.rgb)
            assert np.array_equal(inline.depth, remote.depth)
            assert np.array_equal(inline.segmentation, remote.segmentation)
    finally:
        worker.close()
