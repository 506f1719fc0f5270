"""Conversions between the HAL's numpy types and the Spot SDK's protobuf messages.

Shared by the SDK backend (client side) and the fake Spot server, so both ends agree on every
convention by construction: 4x4 ``T_a_b`` matrices <-> ``geometry_pb2.SE3Pose`` (bosdyn stores
quaternions as w, x, y, z; this project uses x, y, z, w), frame-tree snapshots, image encodings
(RGB as JPEG or raw ``RGB_U8``; depth as ``DEPTH_U16`` scaled by the source's ``depth_scale``),
pinhole intrinsics and trajectories.

This module imports ``bosdyn`` at import time; the backend imports it lazily (``bosdyn`` is the
optional ``[spot]`` extra).
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np
from bosdyn.api import geometry_pb2, image_pb2, trajectory_pb2
from bosdyn.client.frame_helpers import validate_frame_tree_snapshot
from google.protobuf import duration_pb2, timestamp_pb2

from robots.hal import CameraIntrinsics, SE2Pose
from robots.transforms import matrix_to_quat_xyzw, quat_xyzw_to_matrix

# Frame names (bosdyn.client.frame_helpers constants, repeated here so the fake needs no client).
ODOM, VISION, BODY, FLAT_BODY, HAND = "odom", "vision", "body", "flat_body", "hand"
WRIST = "arm0.link_wr1"
HAND_COLOR_SENSOR = "hand_color_image_sensor"
GRASP_SOLUTION_FRAME = "grasp_planning_solution"
WORLD_FRAMES = (ODOM, VISION)           # frames the backend accepts as "the world"
ROOT_FRAMES = (BODY, FLAT_BODY, ODOM, VISION)

HAND_COLOR_SOURCE = "hand_color_image"
HAND_DEPTH_SOURCE = "hand_depth_in_hand_color_frame"
MAX_DEPTH_RAW = 65535                   # DEPTH_U16 value reserved for "invalid", like 0


# ------------------------------------------------------------------------------------ SE3 / SE2
def matrix_to_se3(T: np.ndarray) -> geometry_pb2.SE3Pose:
    T = np.asarray(T, dtype=float)
    x, y, z, w = matrix_to_quat_xyzw(T[:3, :3])
    return geometry_pb2.SE3Pose(position=geometry_pb2.Vec3(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
                                rotation=geometry_pb2.Quaternion(w=float(w), x=float(x), y=float(y), z=float(z)))


def se3_to_matrix(pose: geometry_pb2.SE3Pose) -> np.ndarray:
    q = pose.rotation
    T = np.eye(4)
    if q.w == 0.0 and q.x == 0.0 and q.y == 0.0 and q.z == 0.0:
        raise ValueError("SE3Pose has an all-zero quaternion")
    T[:3, :3] = quat_xyzw_to_matrix((q.x, q.y, q.z, q.w))
    T[:3, 3] = (pose.position.x, pose.position.y, pose.position.z)
    return T


def se2_to_proto(pose: SE2Pose) -> geometry_pb2.SE2Pose:
    return geometry_pb2.SE2Pose(position=geometry_pb2.Vec2(x=pose.x, y=pose.y), angle=pose.yaw)


def proto_to_se2(pose: geometry_pb2.SE2Pose) -> SE2Pose:
    return SE2Pose(pose.position.x, pose.position.y, pose.angle)


# ------------------------------------------------------------------------------------ time
def seconds_to_duration(seconds: float) -> duration_pb2.Duration:
    d = duration_pb2.Duration()
    whole = math.floor(seconds)
    d.seconds = int(whole)
    d.nanos = int(round((seconds - whole) * 1e9))
    if d.nanos >= 1_000_000_000:
        d.seconds += 1
        d.nanos -= 1_000_000_000
    return d


def duration_to_seconds(d: duration_pb2.Duration) -> float:
    return d.seconds + d.nanos * 1e-9


def seconds_to_timestamp(seconds: float) -> timestamp_pb2.Timestamp:
    t = timestamp_pb2.Timestamp()
    whole = math.floor(seconds)
    t.seconds = int(whole)
    t.nanos = min(999_999_999, int(round((seconds - whole) * 1e9)))
    return t


def timestamp_to_seconds(t: timestamp_pb2.Timestamp) -> float:
    return t.seconds + t.nanos * 1e-9


# ------------------------------------------------------------------------------------ frame trees
def frame_tree(edges: Mapping[str, tuple[str, np.ndarray]]) -> geometry_pb2.FrameTreeSnapshot:
    """``{child: (parent, T_parent_child)}`` to a snapshot; the root's parent is ``""``."""
    snap = geometry_pb2.FrameTreeSnapshot()
    for child, (parent, T) in edges.items():
        edge = snap.child_to_parent_edge_map[child]
        edge.parent_frame_name = parent
        edge.parent_tform_child.CopyFrom(matrix_to_se3(np.eye(4) if T is None else T))
    return snap


def _to_root(snapshot, frame: str) -> np.ndarray:
    T = np.eye(4)
    cur = frame
    for _ in range(len(snapshot.child_to_parent_edge_map) + 1):
        edge = snapshot.child_to_parent_edge_map[cur]
        if not edge.parent_frame_name:
            return T
        T = se3_to_matrix(edge.parent_tform_child) @ T
        cur = edge.parent_frame_name
    raise ValueError("frame tree has a cycle")


def tform(snapshot: geometry_pb2.FrameTreeSnapshot, frame_a: str, frame_b: str, validate: bool = True) -> np.ndarray:
    """``T_a_b`` from a frame-tree snapshot; KeyError naming the missing frame."""
    if validate:
        validate_frame_tree_snapshot(snapshot)
    for f in (frame_a, frame_b):
        if f not in snapshot.child_to_parent_edge_map:
            raise KeyError(f"frame {f!r} is not in the robot's frame tree "
                           f"(has: {sorted(snapshot.child_to_parent_edge_map)})")
    T_root_a = _to_root(snapshot, frame_a)
    T_root_b = _to_root(snapshot, frame_b)
    return np.linalg.inv(T_root_a) @ T_root_b


# ------------------------------------------------------------------------------------ images
def pinhole_to_intrinsics(source: image_pb2.ImageSource) -> CameraIntrinsics:
    """Intrinsics of an image source; only undistorted pinhole models are accepted."""
    model = source.WhichOneof("camera_models")
    if model != "pinhole":
        raise ValueError(f"image source {source.name!r} uses a {model or 'missing'} camera model; "
                         f"the HAL needs an undistorted pinhole model")
    i = source.pinhole.intrinsics
    if abs(i.skew.x) > 1e-9 or abs(i.skew.y) > 1e-9:
        raise ValueError(f"image source {source.name!r} has a skewed pinhole model")
    return CameraIntrinsics(int(source.cols), int(source.rows), float(i.focal_length.x), float(i.focal_length.y),
                            float(i.principal_point.x), float(i.principal_point.y))


def intrinsics_to_pinhole(intr: CameraIntrinsics) -> image_pb2.ImageSource.PinholeModel:
    model = image_pb2.ImageSource.PinholeModel()
    model.intrinsics.focal_length.x = intr.fx
    model.intrinsics.focal_length.y = intr.fy
    model.intrinsics.principal_point.x = intr.cx
    model.intrinsics.principal_point.y = intr.cy
    return model


def encode_rgb(rgb: np.ndarray, image_format: int, quality: int = 75) -> bytes:
    if image_format == image_pb2.Image.FORMAT_RAW:
        return np.ascontiguousarray(rgb, dtype=np.uint8).tobytes()
    if image_format == image_pb2.Image.FORMAT_JPEG:
        import cv2

        ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
        if not ok:
            raise ValueError("JPEG encoding failed")
        return buf.tobytes()
    raise ValueError(f"unsupported colour image format {image_format}")


def decode_rgb(image: image_pb2.Image) -> np.ndarray:
    """An ``Image`` holding RGB (JPEG or raw RGB_U8/RGBA_U8/GREYSCALE_U8) as (rows, cols, 3) uint8."""
    rows, cols = int(image.rows), int(image.cols)
    if image.format == image_pb2.Image.FORMAT_JPEG:
        import cv2

        arr = cv2.imdecode(np.frombuffer(image.data, dtype=np.uint8), cv2.IMREAD_COLOR)
        if arr is None:
            raise ValueError("the robot sent a JPEG that does not decode")
        rgb = np.ascontiguousarray(arr[..., ::-1])
    elif image.format == image_pb2.Image.FORMAT_RAW:
        channels = {image_pb2.Image.PIXEL_FORMAT_RGB_U8: 3, image_pb2.Image.PIXEL_FORMAT_RGBA_U8: 4,
                    image_pb2.Image.PIXEL_FORMAT_GREYSCALE_U8: 1}.get(image.pixel_format)
        if channels is None:
            raise ValueError(f"unsupported colour pixel format {image_pb2.Image.PixelFormat.Name(image.pixel_format)}")
        flat = np.frombuffer(image.data, dtype=np.uint8)
        if flat.size != rows * cols * channels:
            raise ValueError(f"raw image has {flat.size} bytes, expected {rows * cols * channels}")
        arr = flat.reshape(rows, cols, channels)
        rgb = np.repeat(arr, 3, axis=2) if channels == 1 else np.ascontiguousarray(arr[..., :3])
    else:
        raise ValueError(f"unsupported colour image format {image.format}")
    if rgb.shape[:2] != (rows, cols):
        raise ValueError(f"decoded image is {rgb.shape[1]}x{rgb.shape[0]}, header says {cols}x{rows}")
    return rgb


def encode_depth(depth_m: np.ndarray, depth_scale: float) -> bytes:
    """Metric depth (0 = no return) to DEPTH_U16 raw bytes: value = metres * depth_scale."""
    raw = np.rint(np.asarray(depth_m, dtype=np.float64) * depth_scale)
    raw[(raw <= 0) | (raw >= MAX_DEPTH_RAW) | ~np.isfinite(raw)] = 0
    return raw.astype("<u2").tobytes()


def decode_depth(image: image_pb2.Image, depth_scale: float) -> np.ndarray:
    """A DEPTH_U16 raw image to float32 metres (0 and 65535 -> 0, "no return")."""
    if image.format != image_pb2.Image.FORMAT_RAW or image.pixel_format != image_pb2.Image.PIXEL_FORMAT_DEPTH_U16:
        raise ValueError("depth must come as a raw DEPTH_U16 image")
    if not (depth_scale > 0 and math.isfinite(depth_scale)):
        raise ValueError(f"depth image has an invalid depth_scale {depth_scale}")
    rows, cols = int(image.rows), int(image.cols)
    raw = np.frombuffer(image.data, dtype="<u2")
    if raw.size != rows * cols:
        raise ValueError(f"depth image has {raw.size} pixels, expected {rows * cols}")
    raw = raw.reshape(rows, cols)
    depth = (raw.astype(np.float64) / depth_scale).astype(np.float32)
    depth[(raw == 0) | (raw == MAX_DEPTH_RAW)] = 0.0
    return depth


# ------------------------------------------------------------------------------------ trajectories
def se2_trajectory(times: Sequence[float], poses: Sequence[SE2Pose]) -> trajectory_pb2.SE2Trajectory:
    traj = trajectory_pb2.SE2Trajectory()
    for t, p in zip(times, poses):
        pt = traj.points.add()
        pt.pose.CopyFrom(se2_to_proto(p))
        pt.time_since_reference.CopyFrom(seconds_to_duration(float(t)))
    return traj


def resample_times(duration: float, dt: float, max_points: int) -> np.ndarray:
    """Sample times over [0, duration] spaced at most ``dt`` apart (``SegmentedTrajectory``'s
    convention: n = ceil(duration / dt) equal steps) but never more than ``max_points`` points."""
    n = max(1, int(math.ceil(duration / dt - 1e-9))) if duration > 0 else 1
    n = min(n, max_points - 1)
    return np.linspace(0.0, duration, n + 1)
