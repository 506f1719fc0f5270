"""Episode recordings as rerun ``.rrd`` files: the robot (URDF + joint states), the hand camera
(pinhole, RGB, depth), trajectories as line strips, scene boxes, an agent's map (occupancy and
value maps as images, object Gaussians as ellipsoids coloured by class and uncertainty, instances,
frontiers), scalars and a text log.

Headless by design: a ``RecordingStream`` saves straight to a file (no viewer, no network), so it
runs in CI. Open the file with ``python -m tools view FILE.rrd`` or ``rerun FILE.rrd``.
Entity layout: ``/spot/...`` robot visuals (URDF frames; ``body`` is placed in the world by a
transform on ``/transforms``), ``/world/hand_camera`` camera, ``/world/paths/*`` trajectories,
``/world/plans/*`` planned paths, ``/world/scene/*`` boxes, ``/world/map/*`` the agent's map in 3D
(obstacle cells, Gaussians, instances, frontiers), ``/maps/*`` the map layers as 2D images
(north up: image up is world +y), ``/metrics/*`` scalars, ``/log`` text.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from robots.hal import Observation
from robots.spot.urdf import URDF_PATH
from robots.transforms import matrix_to_quat_xyzw

ROOT_FRAME = "tf#/"  # rerun's implicit frame of the entity root; the URDF's "body" hangs off it
# Class colours for Gaussians and instances (index = class index; the background class is grey).
PALETTE = np.array([(230, 25, 75), (60, 180, 75), (0, 130, 200), (245, 130, 48), (145, 30, 180),
                    (70, 240, 240), (240, 50, 230), (210, 245, 60), (250, 190, 212), (0, 128, 128)], dtype=np.float64)
BACKGROUND_RGB = np.array([128, 128, 128], dtype=np.float64)
# A 5-stop viridis-like ramp for value maps (0 = dark purple, 1 = yellow).
_RAMP = np.array([(68, 1, 84), (59, 82, 139), (33, 145, 140), (94, 201, 98), (253, 231, 37)], dtype=np.float64)


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
        self._time: float | None = None
        self._last_map_image: float | None = None
        self._classes: tuple[str, ...] | None = None

    # ------------------------------------------------------------------ time
    def set_time(self, sim_time: float, step: int | None = None) -> None:
        self._time = float(sim_time)
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

    def log_robot_state(self, T_world_body: np.ndarray, joints: Mapping[str, float]) -> None:
        """The robot's pose and joints without a camera frame (e.g. after a command)."""
        self._log_robot(np.asarray(T_world_body, dtype=float), joints)
        self.append_path("body", np.asarray(T_world_body)[:3, 3], color=(255, 200, 0))

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

    # ------------------------------------------------------------------ an agent's map
    def log_map(self, hmap: Any, frontiers: bool = True, max_gaussians: int = 20000,
                image_interval: float = 1.0) -> None:
        """Everything of a :class:`helios.maps.hierarchical.HierarchicalMap` (duck-typed):
        occupancy and value layers as images (at most every ``image_interval`` s of the timeline),
        Gaussians, instances and frontiers in 3D."""
        now = self._time
        if now is None or self._last_map_image is None or now - self._last_map_image >= image_interval:
            self._last_map_image = now
            geo = hmap.geometry
            crop = self.log_occupancy(hmap.occupancy.obstacle, hmap.occupancy.explored, geo,
                                      hmap.occupancy.explored_bounds)
            values = getattr(hmap, "values", None)
            if values is not None and len(values.layers):
                for name, grid in zip(values.layers, values.values):
                    self.log_value_map(name, grid, values.confidence, crop)
        objects = getattr(hmap, "objects", None)
        if objects is not None:
            self.log_gaussians(objects, max_gaussians=max_gaussians)
            self.log_instances(hmap.instances())
        if frontiers:
            fr = hmap.frontiers()
            pts = np.array([(f.x, f.y, 0.05) for f in fr], dtype=np.float32).reshape(-1, 3)
            self.rec.log("world/map/frontiers", self.rr.Points3D(pts, radii=0.08, colors=[(0, 200, 255)],
                                                                labels=[f"{f.size}" for f in fr]))

    def log_occupancy(self, obstacle: np.ndarray, explored: np.ndarray, geometry,
                      bounds: tuple[int, int, int, int] | None = None, margin: int = 20,
                      max_points: int = 20000) -> tuple[int, int, int, int]:
        """Occupancy as a PNG image (unknown dark grey, free white, obstacle black; cropped to the
        explored box) on ``maps/occupancy`` and the obstacle cells as points on ``world/map/obstacles``.
        Returns the crop (row0, row1, col0, col1) for the value maps."""
        import cv2

        h, w = obstacle.shape
        if bounds is None:
            r0, r1, c0, c1 = 0, h, 0, w
        else:
            r0, r1 = max(0, bounds[0] - margin), min(h, bounds[1] + margin)
            c0, c1 = max(0, bounds[2] - margin), min(w, bounds[3] + margin)
        obs, exp = obstacle[r0:r1, c0:c1], explored[r0:r1, c0:c1]
        img = np.full(obs.shape, 60, dtype=np.uint8)
        img[exp] = 235
        img[obs] = 0
        ok, png = cv2.imencode(".png", np.ascontiguousarray(np.flipud(img)))
        if ok:
            self.rec.log("maps/occupancy", self.rr.EncodedImage(contents=png.tobytes(), media_type="image/png"))
        rows, cols = np.nonzero(obs)
        if len(rows) > max_points:
            keep = np.linspace(0, len(rows) - 1, max_points).astype(int)
            rows, cols = rows[keep], cols[keep]
        xy = np.asarray(geometry.cell_to_world(rows + r0, cols + c0), dtype=np.float32).reshape(-1, 2)
        pts = np.column_stack([xy, np.full(len(xy), 0.02, dtype=np.float32)])
        self.rec.log("world/map/obstacles", self.rr.Points3D(pts, radii=geometry.cell_size / 2, colors=[(40, 40, 40)]))
        return r0, r1, c0, c1

    def log_value_map(self, name: str, values: np.ndarray, confidence: np.ndarray | None = None,
                      crop: tuple[int, int, int, int] | None = None) -> None:
        """One value-map layer as a colour image on ``maps/value/<name>`` (scaled to its maximum;
        cells never seen are grey); the maximum goes to ``metrics/value_max/<name>``."""
        import cv2

        r0, r1, c0, c1 = crop or (0, values.shape[0], 0, values.shape[1])
        v = np.asarray(values[r0:r1, c0:c1], dtype=np.float64)
        vmax = float(v.max()) if v.size else 0.0
        rgb = colormap(v / vmax if vmax > 0 else v)
        if confidence is not None:
            rgb[np.asarray(confidence[r0:r1, c0:c1]) <= 0] = 90
        ok, jpg = cv2.imencode(".jpg", np.ascontiguousarray(np.flipud(rgb[..., ::-1])), [cv2.IMWRITE_JPEG_QUALITY, 85])
        if ok:
            self.rec.log(f"maps/value/{name}", self.rr.EncodedImage(contents=jpg.tobytes(), media_type="image/jpeg"))
        self.log_scalar(f"value_max/{name}", vmax)

    def log_gaussians(self, objects: Any, max_gaussians: int = 20000, sigmas: float = 1.0) -> None:
        """Object Gaussians as ellipsoids (``sigmas`` x scale) coloured by their most likely class,
        faded towards grey with the uncertainty (std of that class's probability; 0.5 = fully grey)."""
        n = len(objects)
        path = "world/map/gaussians"
        if n == 0:
            self.rec.log(path, self.rr.Clear(recursive=False))
            return
        idx = np.arange(n) if n <= max_gaussians else np.linspace(0, n - 1, max_gaussians).astype(int)
        means = _numpy(objects.means)[idx]
        scales = _numpy(objects.scales)[idx]
        cls = np.asarray(objects.most_likely_classes())[idx]
        std = np.sqrt(np.clip(_numpy(objects.variances())[idx, :], 0.0, None))
        u = np.clip(std[np.arange(len(idx)), cls] / 0.5, 0.0, 1.0)
        bg = objects.classes.background_index
        base = np.where((cls == bg)[:, None], BACKGROUND_RGB, PALETTE[cls % len(PALETTE)])
        colors = (base * (1 - u)[:, None] + BACKGROUND_RGB * u[:, None]).astype(np.uint8)
        self._class_context(objects.classes.names, bg)
        self.rec.log(path, self.rr.Ellipsoids3D(centers=means, half_sizes=np.repeat(sigmas * scales[:, None], 3, axis=1),
                                                colors=colors, class_ids=cls, fill_mode=self.rr.components.FillMode.Solid))
        self.log_scalar("map/gaussians", float(n))

    def log_instances(self, instances: Sequence[Any]) -> None:
        """Instances as labelled points at their centres: class, id, S (score) and U (uncertainty)."""
        path = "world/map/instances"
        if not instances:
            self.rec.log(path, self.rr.Clear(recursive=False))
            return
        centres = np.array([np.asarray(i.centre, dtype=np.float32) for i in instances])
        labels = [f"{i.class_name} #{i.id} S={i.class_scores.get(i.class_name, 0.0):.2f} "
                  f"U={i.uncertainties.get(i.class_name, 0.0):.2f}" for i in instances]
        self.rec.log(path, self.rr.Points3D(centres, radii=0.06, labels=labels, colors=[(255, 255, 255)]))

    def _class_context(self, names: Sequence[str], background: int) -> None:
        key = tuple(names)
        if key == self._classes:
            return
        self._classes = key
        infos = [self.rr.AnnotationInfo(id=i, label=n, color=tuple(int(c) for c in
                                                                    (BACKGROUND_RGB if i == background else PALETTE[i % len(PALETTE)])))
                 for i, n in enumerate(names)]
        self.rec.log("world/map", self.rr.AnnotationContext(infos), static=True)

    def log_detections(self, detections: Sequence[Any], class_names: Sequence[str] | None = None) -> None:
        """Detections on the hand-camera image (``helios.perception.detection.Detection``: mask,
        class_name, score; duck-typed): a 2D box and label per detection, and the masks as one
        segmentation image (class index + 1; 0 = none). Log after ``log_observation`` of that frame."""
        path = "world/hand_camera/detections"
        if not detections:
            self.rec.log(path, self.rr.Clear(recursive=True))
            return
        names = list(class_names) if class_names else sorted({d.class_name for d in detections})
        boxes, labels, ids = [], [], []
        seg = np.zeros(np.asarray(detections[0].mask).shape, dtype=np.uint16)
        for d in sorted(detections, key=lambda d: d.score):          # best on top
            mask = np.asarray(d.mask, dtype=bool)
            vs, us = np.nonzero(mask)
            if len(us) == 0:
                continue
            cid = names.index(d.class_name) if d.class_name in names else len(names)
            seg[mask] = cid + 1
            boxes.append((us.min(), vs.min(), us.max() - us.min() + 1, vs.max() - vs.min() + 1))
            labels.append(f"{d.class_name} {d.score:.2f}")
            ids.append(cid)
        colors = [tuple(int(c) for c in PALETTE[i % len(PALETTE)]) for i in ids]
        self.rec.log(f"{path}/boxes", self.rr.Boxes2D(array=np.asarray(boxes, dtype=np.float32).reshape(-1, 4),
                                                      array_format=self.rr.Box2DFormat.XYWH, labels=labels,
                                                      colors=colors))
        infos = [self.rr.AnnotationInfo(id=0, label="none", color=(0, 0, 0, 0))] + [
            self.rr.AnnotationInfo(id=i + 1, label=n, color=tuple(int(c) for c in PALETTE[i % len(PALETTE)]))
            for i, n in enumerate(names)]
        self.rec.log(f"{path}/masks", self.rr.AnnotationContext(infos))
        self.rec.log(f"{path}/masks", self.rr.SegmentationImage(seg, opacity=0.5))

    def log_command(self, name: str, result: Any) -> None:
        """A HAL command and its result (success, reason, message) on the text log."""
        ok = bool(result)
        reason = getattr(getattr(result, "reason", None), "value", "")
        msg = getattr(result, "message", "") or ""
        dur = getattr(result, "duration", None)
        self.log_text(f"{name}: {'ok' if ok else 'FAILED'} {reason} {msg}".rstrip()
                      + (f" [{dur:.1f} s]" if isinstance(dur, (int, float)) else ""), "INFO" if ok else "WARN")

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


def close_recording(recorder: "EpisodeRecorder", path, say=print, final_text: str | None = None) -> str | None:
    """Log ``final_text`` (if any) and close ``recorder``; where that fails (a full disk: rerun's
    "File-writer thread shut down prematurely") say so in one warning line and return the error
    for the record's ``recording.errors``: (part of) the recording is lost, never the trial's record."""
    try:
        if final_text is not None:
            recorder.log_text(final_text)
        recorder.close()
    except Exception as exc:  # noqa: BLE001 - whatever the writer raises, the record is written
        say(f"[spot] warning: the recording {path} may be incomplete ({type(exc).__name__}: {exc})")
        return f"closing the recording: {type(exc).__name__}: {exc}"
    return None


def colormap(values: np.ndarray) -> np.ndarray:
    """(H, W) values in [0, 1] to (H, W, 3) uint8 RGB on a viridis-like ramp."""
    v = np.clip(np.nan_to_num(np.asarray(values, dtype=np.float64)), 0.0, 1.0) * (len(_RAMP) - 1)
    i = np.minimum(v.astype(int), len(_RAMP) - 2)
    f = (v - i)[..., None]
    return (_RAMP[i] * (1 - f) + _RAMP[i + 1] * f).astype(np.uint8)


def _numpy(x) -> np.ndarray:
    """A torch tensor (any device) or array as a numpy array."""
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x)
