"""The hardware abstraction layer: what an agent may ask of a robot, and what it gets back.

The contract is cut at the level the Boston Dynamics Spot SDK offers and HELIOS uses: SE2 base
goals in the odometry frame, arm gaze / joint / hand-pose moves, pick-in-image grasps, releasing
above a point, stow, stand, stop, and RGB-D observations from the hand camera with intrinsics and
poses. The PyBullet backend exposes nothing more than this (ground truth for metrics lives in
``sim``, behind a separately named oracle), so the same agent code runs on the real robot.

Every command returns a typed result with ``success`` and a ``reason``; bad arguments raise
:class:`InvalidCommandError` (a ``ValueError``) before anything moves; robot-side faults (lease
revoked, e-stop, lost connection, timeouts) raise a :class:`RobotFault` subclass.
"""

from __future__ import annotations

import abc
import enum
import math
from dataclasses import dataclass, field
from typing import Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from robots.transforms import is_valid_transform, wrap_angle


# --------------------------------------------------------------------------------------------
# Errors
# --------------------------------------------------------------------------------------------
class HalError(Exception):
    """Base class of everything the HAL raises."""


class InvalidCommandError(HalError, ValueError):
    """A command argument is malformed (NaN, wrong shape, outside joint limits...). Nothing moved."""


class InvalidObservationError(HalError, ValueError):
    """A backend produced an observation that violates the contract (shape, dtype, NaN)."""


class BackendClosedError(HalError, RuntimeError):
    """The backend was closed (perhaps by another thread while this command ran): nothing more is
    sent to the robot. Also a RuntimeError, what using a closed backend always raised."""


class RobotFault(HalError):
    """The robot (or its link) failed in a way the agent cannot fix by choosing another action."""


class LeaseLostError(RobotFault):
    """Another client took or revoked the body lease; no further commands are accepted."""


class EstopError(RobotFault):
    """The robot is e-stopped; motion is cut and commands are refused."""


class ConnectionLostError(RobotFault):
    """The connection to the robot dropped or could not be made."""


class CommandTimeoutError(RobotFault):
    """The robot did not acknowledge or finish a command within the allowed time."""


class TimeSyncLostError(RobotFault):
    """Clock synchronisation with the robot was lost; timed commands cannot be sent safely."""


class PowerError(RobotFault):
    """Motor power could not be switched on (or was cut)."""


class BehaviorFaultError(RobotFault):
    """The robot's own controller faulted (it fell, a hardware fault): it stopped, and it refuses
    motion until the fault is cleared (the tablet; an unclearable one needs a power cycle)."""


# --------------------------------------------------------------------------------------------
# Value types
# --------------------------------------------------------------------------------------------
def _finite(name: str, *values: float) -> None:
    for v in values:
        if not isinstance(v, (int, float, np.floating, np.integer)) or not math.isfinite(float(v)):
            raise InvalidCommandError(f"{name} must be finite numbers, got {values!r}")


@dataclass(frozen=True)
class SE2Pose:
    """A planar pose (x, y in metres, yaw in radians) in the odometry frame."""

    x: float
    y: float
    yaw: float

    def __post_init__(self) -> None:
        _finite("SE2Pose", self.x, self.y, self.yaw)
        object.__setattr__(self, "x", float(self.x))
        object.__setattr__(self, "y", float(self.y))
        object.__setattr__(self, "yaw", float(wrap_angle(float(self.yaw))))

    @staticmethod
    def from_matrix(T: np.ndarray) -> "SE2Pose":
        return SE2Pose(float(T[0, 3]), float(T[1, 3]), math.atan2(T[1, 0], T[0, 0]))

    def to_matrix(self, z: float = 0.0) -> np.ndarray:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.array([[c, -s, 0, self.x], [s, c, 0, self.y], [0, 0, 1, z], [0, 0, 0, 1]], dtype=float)

    def compose(self, other: "SE2Pose") -> "SE2Pose":
        """self * other: ``other`` expressed in this pose's frame, returned in the parent frame."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return SE2Pose(self.x + c * other.x - s * other.y, self.y + s * other.x + c * other.y, self.yaw + other.yaw)

    def distance_to(self, other: "SE2Pose") -> float:
        return math.hypot(other.x - self.x, other.y - self.y)

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.yaw)


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics of an undistorted image (pixels; u right, v down; optical z forward)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ValueError(f"camera resolution must be positive, got {self.width}x{self.height}")
        if not all(math.isfinite(v) and v > 0 for v in (self.fx, self.fy)):
            raise ValueError(f"focal lengths must be positive and finite, got fx={self.fx} fy={self.fy}")

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def vertical_fov(self) -> float:
        return 2.0 * math.atan(self.height / (2.0 * self.fy))

    @property
    def horizontal_fov(self) -> float:
        return 2.0 * math.atan(self.width / (2.0 * self.fx))

    def scaled(self, width: int, height: int) -> "CameraIntrinsics":
        """The same camera resampled to another resolution (same field of view)."""
        sx, sy = width / self.width, height / self.height
        return CameraIntrinsics(width, height, self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy)

    def backproject(self, u, v, depth) -> np.ndarray:
        """Pixel(s) with metric depth (along optical z) to points in the camera optical frame."""
        u, v, d = (np.asarray(a, dtype=float) for a in (u, v, depth))
        x = (u - self.cx) / self.fx * d
        y = (v - self.cy) / self.fy * d
        return np.stack([x, y, d], axis=-1)

    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points in the optical frame (N, 3) to pixel coordinates (u, v) and depth z."""
        p = np.asarray(points_cam, dtype=float)
        z = p[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([self.fx * p[..., 0] / z + self.cx, self.fy * p[..., 1] / z + self.cy], axis=-1)
        return uv, z


@dataclass(frozen=True)
class Observation:
    """One registered RGB-D frame from the hand camera plus the robot state at capture time.

    ``depth`` is float32 metres along the optical axis, 0 where the sensor has no return (the Spot
    convention; NaN/inf are rejected). ``T_world_cam`` maps the optical frame (x right, y down,
    z forward) into the world/odometry frame; ``T_world_body`` is the body pose in the same frame.
    """

    rgb: np.ndarray
    depth: np.ndarray
    intrinsics: CameraIntrinsics
    T_world_cam: np.ndarray
    T_world_body: np.ndarray
    stamp: float
    holding: bool = False
    joint_positions: Mapping[str, float] = field(default_factory=dict)
    frame_id: int = 0
    camera: str = "hand_color_image"

    def __post_init__(self) -> None:
        h, w = self.intrinsics.height, self.intrinsics.width
        if not isinstance(self.rgb, np.ndarray) or self.rgb.shape != (h, w, 3) or self.rgb.dtype != np.uint8:
            raise InvalidObservationError(
                f"rgb must be a uint8 array of shape {(h, w, 3)}, got "
                f"{getattr(self.rgb, 'dtype', type(self.rgb))} {getattr(self.rgb, 'shape', None)}")
        if not isinstance(self.depth, np.ndarray) or self.depth.shape != (h, w) or self.depth.dtype != np.float32:
            raise InvalidObservationError(
                f"depth must be a float32 array of shape {(h, w)} in metres, got "
                f"{getattr(self.depth, 'dtype', type(self.depth))} {getattr(self.depth, 'shape', None)}")
        if not np.all(np.isfinite(self.depth)):
            n = int(np.size(self.depth) - np.count_nonzero(np.isfinite(self.depth)))
            raise InvalidObservationError(f"depth has {n} NaN/inf pixels; backends must report no-return as 0.0")
        if np.any(self.depth < 0):
            raise InvalidObservationError("depth has negative values")
        for name in ("T_world_cam", "T_world_body"):
            if not is_valid_transform(getattr(self, name)):
                raise InvalidObservationError(f"{name} must be a finite 4x4 rigid transform")
        if not math.isfinite(self.stamp):
            raise InvalidObservationError(f"stamp must be finite, got {self.stamp}")

    @property
    def body_pose(self) -> SE2Pose:
        return SE2Pose.from_matrix(self.T_world_body)

    def point_at_pixel(self, u: int, v: int, window: int = 2) -> np.ndarray | None:
        """World point seen at pixel (u, v) using the median valid depth of a small window."""
        h, w = self.depth.shape
        if not (0 <= u < w and 0 <= v < h):
            return None
        patch = self.depth[max(0, v - window):v + window + 1, max(0, u - window):u + window + 1]
        valid = patch[patch > 0]
        if valid.size == 0:
            return None
        p_cam = self.intrinsics.backproject(u, v, float(np.median(valid)))
        return self.T_world_cam[:3, :3] @ p_cam + self.T_world_cam[:3, 3]


class Reason(str, enum.Enum):
    """Why a command ended the way it did (one fixed vocabulary for every backend)."""

    OK = "ok"
    COLLISION = "collision"              # robot touched the scene; motion stopped at the last free pose
    UNREACHABLE = "unreachable"          # goal is outside what the base/arm can reach
    OUT_OF_REACH = "out_of_reach"        # grasp/place target farther than the arm reaches from here
    IK_FAILED = "ik_failed"              # no joint solution within limits for the hand pose
    JOINT_LIMIT = "joint_limit"          # planned motion would leave the joint limits
    NO_DEPTH = "no_depth"                # grasp pixel has no valid depth
    GRASP_MISSED = "grasp_missed"        # fingers closed without both touching an object
    GRASP_SLIPPED = "grasp_slipped"      # object attached but lost during the lift
    NOT_HOLDING = "not_holding"          # place requested with an empty gripper
    ALREADY_HOLDING = "already_holding"  # grasp requested while holding something
    STOPPED = "stopped"                  # interrupted by stop()
    TIMEOUT = "timeout"                  # motion did not finish in the allowed time


@dataclass(frozen=True)
class CommandResult:
    """Outcome of a command. ``message`` is for humans; branch on ``success`` and ``reason``."""

    success: bool
    reason: Reason = Reason.OK
    message: str = ""
    duration: float = 0.0  # robot-clock seconds the command took

    def __bool__(self) -> bool:  # lets callers write ``if backend.stow_arm(): ...``
        return self.success


@dataclass(frozen=True)
class NavigateResult(CommandResult):
    final_pose: SE2Pose | None = None
    collided: bool = False
    distance: float = 0.0  # metres travelled by the body


@dataclass(frozen=True)
class GraspResult(CommandResult):
    holding: bool = False
    target_world: tuple[float, float, float] | None = None  # the 3D point the pixel resolved to


@dataclass(frozen=True)
class PlaceResult(CommandResult):
    release_point: tuple[float, float, float] | None = None  # world position of the hand at release


# --------------------------------------------------------------------------------------------
# Argument checks shared by the backends
# --------------------------------------------------------------------------------------------
def as_se2(value, name: str) -> SE2Pose:
    """A command argument as an SE2Pose (an SE2Pose or any (x, y, yaw)); one clear error otherwise."""
    if isinstance(value, SE2Pose):
        return value
    try:
        x, y, yaw = (float(v) for v in value)
    except (TypeError, ValueError) as exc:
        raise InvalidCommandError(f"{name} must be an SE2Pose or (x, y, yaw), got {value!r}") from exc
    return SE2Pose(x, y, yaw)


def as_point(value, name: str) -> np.ndarray:
    """A command argument as a finite 3D point; every backend validates the same way."""
    try:
        p = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise InvalidCommandError(f"{name} must be 3 numbers, got {value!r}") from exc
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise InvalidCommandError(f"{name} must be 3 finite numbers, got {value!r}")
    return p


def as_hand_pose(value, name: str = "hand pose") -> np.ndarray:
    """A command argument as a rigid 4x4 transform (finite, orthonormal rotation with det +1, last
    row 0 0 0 1); every backend refuses anything else the same way (the sim backend used to answer
    a non-rigid pose with IK_FAILED where the SDK backend raised)."""
    try:
        T = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidCommandError(f"{name} must be a 4x4 transform, got {type(value).__name__}") from exc
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InvalidCommandError(f"{name} must be a finite 4x4 transform, got shape {T.shape}")
    if not is_valid_transform(T):
        raise InvalidCommandError(f"{name} must be a rigid transform (orthonormal rotation, last row 0 0 0 1)")
    return T


def as_pixel(pixel, obs: Observation) -> tuple[int, int]:
    """A command argument as an integer (u, v) pixel inside ``obs``'s image."""
    try:
        u, v = (int(round(float(x))) for x in pixel)
    except (TypeError, ValueError) as exc:
        raise InvalidCommandError(f"pixel must be (u, v), got {pixel!r}") from exc
    if not (0 <= u < obs.intrinsics.width and 0 <= v < obs.intrinsics.height):
        raise InvalidCommandError(f"pixel ({u}, {v}) is outside the {obs.intrinsics.width}x{obs.intrinsics.height} image")
    return u, v


# --------------------------------------------------------------------------------------------
# The backend protocol
# --------------------------------------------------------------------------------------------
@runtime_checkable
class RobotBackend(Protocol):
    """What the agent may ask of a robot. Implemented by the PyBullet and the Spot SDK backends.

    All poses and points are in the world (odometry) frame. Commands block until the motion ends.
    """

    def observe(self) -> Observation:
        """Capture the hand camera RGB-D frame and the robot state."""

    def navigate_to(self, goal: SE2Pose, via: Sequence[SE2Pose] = ()) -> NavigateResult:
        """Walk the body through ``via`` (planner waypoints) to ``goal``, stopping on contact."""

    def gaze_at(self, point: Sequence[float]) -> CommandResult:
        """Point the hand camera at a world point without moving the body."""

    def move_arm_joints(self, joints: Sequence[float]) -> CommandResult:
        """Move the six arm joints [sh0, sh1, el0, el1, wr0, wr1] (radians) along a smooth path."""

    def move_hand(self, T_body_hand: np.ndarray) -> CommandResult:
        """Move the hand frame to a pose given in the body frame (a rigid 4x4 transform, else
        InvalidCommandError; IK_FAILED when no arm configuration within limits reaches it)."""

    def grasp(self, observation: Observation, pixel: tuple[int, int]) -> GraspResult:
        """Pick up what is seen at ``pixel`` of ``observation`` (Spot's pick-in-image)."""

    def place(self, point: Sequence[float], release_height: float = 0.10) -> PlaceResult:
        """Carry the held object over ``point`` and release it ``release_height`` above it."""

    def stow_arm(self) -> CommandResult:
        """Fold the arm into its stowed pose (opens nothing; a held object stays held)."""

    def stand(self) -> CommandResult:
        """Power on (if needed) and stand."""

    def stop(self) -> CommandResult:
        """Stop all motion now and hold position."""

    def close(self) -> None:
        """Release the robot (leases, connections, simulator) — safe to call twice. Every command
        afterwards raises BackendClosedError without reaching the robot."""


class CommandProxy(abc.ABC):
    """Base of HAL wrappers (budget monitors, instrumentation) that route every command through
    one hook, ``_command(name, *args)``, so the list of HAL commands is written once. Subclasses
    implement ``_command`` and ``observe``."""

    @abc.abstractmethod
    def _command(self, name: str, *args, **kwargs):
        """Run HAL command ``name`` on the wrapped backend (and do the wrapper's own work)."""

    @abc.abstractmethod
    def observe(self) -> Observation:
        """The wrapped backend's observation (wrappers usually record or check it)."""

    def navigate_to(self, goal: SE2Pose, via: Sequence[SE2Pose] = ()):
        return self._command("navigate_to", goal, via)

    def gaze_at(self, point):
        return self._command("gaze_at", point)

    def move_arm_joints(self, joints):
        return self._command("move_arm_joints", joints)

    def move_hand(self, T_body_hand):
        return self._command("move_hand", T_body_hand)

    def grasp(self, observation: Observation, pixel):
        return self._command("grasp", observation, pixel)

    def place(self, point, release_height: float = 0.10):
        return self._command("place", point, release_height)

    def stow_arm(self):
        return self._command("stow_arm")

    def stand(self):
        return self._command("stand")

    def stop(self):
        return self._command("stop")
