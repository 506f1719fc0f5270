"""Episode recordings as rerun ``.rrd`` files: the robot (URDF + joint states), the hand camera
(pinhole, RGB, depth), trajectories as line strips, scene boxes, scalars and a text log.

Headless by design: a ``RecordingStream`` saves straight to a file (no viewer, no network), so it
runs in CI. Open the file with ``rerun FILE.rrd`` (the ``rerun-sdk`` package ships the viewer).
Entity layout: ``/spot/...`` robot visuals (URDF frames; ``body`` is placed in the world by a
transform on ``/transforms``), ``/world/hand_camera`` camera, ``/world/paths/*`` trajectories,
``/world/scene/*`` boxes, ``/metrics/*`` scalars, ``/log`` text.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from robots.hal import Observation
from robots.spot.urdf import URDF_PATH
from robots.transforms import matrix_to_quat_xyzw

ROOT_FRAME = "tf#/"  # rerun's implicit frame of the entity root; the URDF's "body" hangs off it


class EpisodeRecorder:
    """Writes one episode to a ``.rrd`` file. Use as a context manager or call ``close()``."""

    def __init__(self, path: str | Path, recording_id: str = "episode", urdf_path: str | Path = URDF_PATH,
                 depth_every: int = 1):
        import rerun as rr
        import rerun.urdf

        self.rr = rr
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.rec = rr.RecordingStream("helios", recording_id=recording_id)
        self.rec.save(str(self.path))
        self.rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self.rec.log_file_from_path(str(urdf_path), static=True)
        self._joints = [j for j in rerun.urdf.UrdfTree.from_file_path(str(urdf_path)).joints()
                        if j.joint_type == "revolute"]
        self._paths: dict[str, list[np.ndarray]] = {}
        self._depth_every = max(1, depth_every)
        self._frames = 0
        self._closed = False

    # ------------------------------------------------------------------ time
    def set_time(self, sim_time: float, step: int | None = None) -> None:
        self.rec.set_time("sim_time", duration=float(sim_time))
        if step is not None:
            self.rec.set_time("step", sequence=int(step))

    # ------------------------------------------------------------------ robot + camera
    def log_observation(self, obs: Observation) -> None:
        """Robot pose and joints, the hand camera image/depth, and the body's path so far."""
        rr = self.rr
        self.set_time(obs.stamp, obs.frame_id)
        self._log_robot(obs.T_world_body, obs.joint_positions)
        T = obs.T_world_cam
        cam = "world/hand_camera"
        self.rec.log(cam, rr.Transform3D(translation=T[:3, 3], quaternion=rr.Quaternion(xyzw=matrix_to_quat_xyzw(T[:3, :3]))))
        intr = obs.intrinsics
        self.rec.log(cam, rr.Pinhole(image_from_camera=intr.K, resolution=[intr.width, intr.height],
                                     camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.3))
        self.rec.log(f"{cam}/rgb", rr.Image(obs.rgb).compress(jpeg_quality=85))
        if self._frames % self._depth_every == 0:
            self.rec.log(f"{cam}/depth", rr.DepthImage(obs.depth, meter=1.0))
        self._frames += 1
        self.append_path("body", obs.T_world_body[:3, 3], color=(255, 200, 0))
        self.append_path("hand_camera", T[:3, 3], color=(80, 160, 255))

    def _log_robot(self, T_world_body: np.ndarray, joints: Mapping[str, float]) -> None:
        rr = self.rr
        tfs = [rr.Transform3D(translation=T_world_body[:3, 3],
                              quaternion=rr.Quaternion(xyzw=matrix_to_quat_xyzw(T_world_body[:3, :3])),
                              parent_frame=ROOT_FRAME, child_frame="body")]
        for j in self._joints:
            if j.name in joints:
                q = min(max(float(joints[j.name]), j.limit_lower), j.limit_upper)  # sim noise at the limits
                tfs.append(j.compute_transform(q))
        for tf in tfs:
            self.rec.log("transforms", tf)

    # ------------------------------------------------------------------ geometry
    def append_path(self, name: str, point, color=(255, 255, 255)) -> None:
        pts = self._paths.setdefault(name, [])
        pts.append(np.asarray(point, dtype=np.float32))
        if len(pts) >= 2:
            self.rec.log(f"world/paths/{name}", self.rr.LineStrips3D([np.stack(pts)], colors=[color], radii=0.01))

    def log_path(self, name: str, points: Iterable, color=(0, 255, 120)) -> None:
        """A planned or executed path as one line strip (replaces the previous one of that name)."""
        pts = np.asarray(list(points), dtype=np.float32)
        if len(pts) >= 2:
            self.rec.log(f"world/plans/{name}", self.rr.LineStrips3D([pts], colors=[color], radii=0.015))

    def log_boxes(self, name: str, centers, half_sizes, labels=None, colors=None, static: bool = False) -> None:
        self.rec.log(f"world/scene/{name}", self.rr.Boxes3D(centers=centers, half_sizes=half_sizes, labels=labels,
                                                           colors=colors), static=static)

    def log_points(self, name: str, points, colors=None, radius: float = 0.01) -> None:
        self.rec.log(f"world/{name}", self.rr.Points3D(np.asarray(points, dtype=np.float32), colors=colors,
                                                      radii=radius))

    # ------------------------------------------------------------------ scalars and text
    def log_scalar(self, name: str, value: float) -> None:
        self.rec.log(f"metrics/{name}", self.rr.Scalars(float(value)))

    def log_text(self, text: str, level: str = "INFO") -> None:
        self.rec.log("log", self.rr.TextLog(text, level=level))

    # ------------------------------------------------------------------ teardown
    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.rec.flush()
            self.rec.disconnect()

    def __enter__(self) -> "EpisodeRecorder":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
