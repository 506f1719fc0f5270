"""Spot-with-arm model facts: the single source of truth for joint names, origins, axes, limits,
masses, collision primitives, the stand and stow poses, the hand frame and the hand camera.

Numbers come from Boston Dynamics' ``spot_with_arm.urdf`` (SDK ``files/``), cross-checked with
``bdaiinstitute/spot_ros2`` ``spot_description`` and the measured hand-camera calibration in
``RussTedrake/manipulation`` (see ``robots/spot/README.md`` for provenance). Geometry of the arm
links and the claw is our own primitive approximation. The URDF in this folder is generated from
this module (``python -m robots.spot.urdf``) and a test checks the two agree.

Joint and link names follow the Spot SDK robot-state names (``fl.hx``, ``arm0.sh0``...), so the
simulator and the real robot report the same keys.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DEG = math.pi / 180.0


@dataclass(frozen=True)
class Geometry:
    """A primitive collision/visual shape placed in its link frame."""

    kind: str                                  # "box" | "cylinder" | "sphere"
    size: tuple[float, ...]                    # box: full extents xyz; cylinder: (radius, length); sphere: (radius,)
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    collide: bool = True


@dataclass(frozen=True)
class Link:
    name: str
    mass: float
    geometry: tuple[Geometry, ...] = ()
    com: tuple[float, float, float] = (0.0, 0.0, 0.0)
    color: tuple[float, float, float, float] = (0.95, 0.77, 0.06, 1.0)  # Spot yellow


@dataclass(frozen=True)
class Joint:
    name: str
    parent: str
    child: str
    xyz: tuple[float, float, float]
    axis: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lower: float = 0.0
    upper: float = 0.0
    effort: float = 0.0
    velocity: float = 0.0
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    kind: str = "revolute"                     # "revolute" | "fixed"


@dataclass(frozen=True)
class CameraMount:
    """A camera's optical frame (x right, y down, z forward) on a link, with native intrinsics."""

    name: str
    parent: str
    xyz: tuple[float, float, float]
    rpy_deg: tuple[float, float, float]
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float


BODY = "body"
FRAME_MASS = 0.001  # massless frames (hand, camera) get a token mass so PyBullet keeps them as links
ROBOT_NAME = "spot"

LEGS = ("fl", "fr", "hl", "hr")
LEG_JOINT_SUFFIXES = ("hx", "hy", "kn")
LEG_JOINTS = tuple(f"{leg}.{j}" for leg in LEGS for j in LEG_JOINT_SUFFIXES)
ARM_JOINTS = ("arm0.sh0", "arm0.sh1", "arm0.el0", "arm0.el1", "arm0.wr0", "arm0.wr1")
GRIPPER_JOINT = "arm0.f1x"

# --- body and legs (BD spot_with_arm.urdf) ---------------------------------------------------
BODY_MASS = 16.708
BODY_BOX = (0.85, 0.24, 0.18)
BODY_BOX_Z = -0.015
HIP_X_ORIGIN = (0.29785, 0.05500, 0.0)
HIP_Y_ORIGIN = (0.0, 0.110945, 0.0)
KNEE_ORIGIN = (0.025, 0.0, -0.3205)
FOOT_Z = -0.33532
FOOT_RADIUS = 0.035
HIP_MASS, ULEG_MASS, LLEG_MASS = 1.137, 2.256, 0.330
HX_LIMITS = (-0.785398, 0.785398)
HY_LIMITS = (-0.898845, 2.295108)
KN_LIMITS = (-2.7929, -0.2471)
LEG_EFFORT = {"hx": 45.0, "hy": 45.0, "kn": 115.0}
LEG_VELOCITY = {"hx": 17.647, "hy": 17.647, "kn": 12.0}

# Stand pose: legs hold these angles while the base moves kinematically (no gait simulation).
STAND_HY = 0.75
STAND_KN = -1.50

# --- arm (BD names arm0.*) -------------------------------------------------------------------
SHOULDER_ORIGIN = (0.292, 0.0, 0.188)
UPPER_ARM = (0.3385, 0.0, 0.0)          # sh1 -> el0
FOREARM = (0.4033, 0.0, 0.0750)         # el0 -> el1 (wrist centre; el1, wr0, wr1 axes intersect)
HAND_OFFSET = 0.19557                   # wr1 -> hand frame along x
FINGER_HINGE = (0.11745, 0.0, 0.01482)  # wr1 -> f1x
ARM_LIMITS = {
    "arm0.sh0": (-2.61799, 3.14159),
    "arm0.sh1": (-3.14159, 0.523599),
    "arm0.el0": (0.0, 3.14159),
    "arm0.el1": (-2.79253, 2.79253),
    "arm0.wr0": (-1.8326, 1.8326),
    "arm0.wr1": (-2.87979, 2.87979),
}
ARM_EFFORT = {"arm0.sh0": 90.9, "arm0.sh1": 181.8, "arm0.el0": 90.9, "arm0.el1": 30.3, "arm0.wr0": 30.3,
              "arm0.wr1": 30.3}
ARM_MASSES = {"arm0.link_sh0": 1.905, "arm0.link_sh1": 1.857, "arm0.link_el0": 0.948, "arm0.link_el1": 1.018,
              "arm0.link_wr0": 0.583, "arm0.link_wr1": 0.933, "arm0.link_fngr": 0.224}
ARM_VELOCITY = 10.0  # rad/s, spot_ros2 limit
GRIPPER_LIMITS = (-1.5708, 0.0)  # 0 = closed, -pi/2 = fully open
GRIPPER_EFFORT = 15.32

# Named arm configurations [sh0, sh1, el0, el1, wr0, wr1].
ARM_STOW = (0.0, -3.1, 3.1, 0.0, 0.0, 0.0)
ARM_READY = (0.0, -1.2, 1.9, 0.0, -0.7, 0.0)   # hand forward at body height, camera looking ahead/down

# --- cameras (measured on one real Spot; optical frames) ---------------------------------------
HAND_CAMERA = CameraMount(
    name="hand_color_image_sensor", parent="arm0.link_wr1",
    xyz=(0.13806, 0.020205, 0.02452), rpy_deg=(-81.0, 0.0, -90.0),
    width=640, height=480, fx=552.03, fy=552.03, cx=320.0, cy=240.0)

# --- claw geometry (our primitives, in arm0.link_wr1 / arm0.link_fngr frames) ------------------
GRIPPER_BODY = Geometry("box", (0.115, 0.08, 0.07), xyz=(0.0575, 0.0, 0.0))
FIXED_JAW = Geometry("box", (0.125, 0.030, 0.017), xyz=(0.1725, 0.0, -0.0165))   # inner face z = -0.008, tip x = 0.235
MOVING_JAW = Geometry("box", (0.118, 0.030, 0.012), xyz=(0.059, 0.0, -0.014))     # hangs below its hinge


def _leg_sign(leg: str) -> tuple[float, float]:
    """(front/hind, left/right) signs of a leg."""
    return (1.0 if leg[0] == "f" else -1.0, 1.0 if leg[1] == "l" else -1.0)


def links() -> tuple[Link, ...]:
    out = [Link(BODY, BODY_MASS, (Geometry("box", BODY_BOX, xyz=(0.0, 0.0, BODY_BOX_Z)),), com=(0.0, 0.0, -0.00496))]
    dark = (0.15, 0.15, 0.15, 1.0)
    for leg in LEGS:
        out.append(Link(f"{leg}.hip", HIP_MASS, (Geometry("sphere", (0.05,), collide=False),), color=dark))
        out.append(Link(f"{leg}.uleg", ULEG_MASS, (Geometry("cylinder", (0.045, 0.35), xyz=(0.0, 0.0, -0.115)),),
                        com=(0.0, 0.0, -0.14)))
        out.append(Link(f"{leg}.lleg", LLEG_MASS, (
            Geometry("cylinder", (0.015, 0.35), xyz=(0.0105, 0.0, -0.15), rpy=(0.0, -0.045, 0.0)),
            Geometry("sphere", (FOOT_RADIUS,), xyz=(0.0, 0.0, FOOT_Z)),
        ), com=(0.0, 0.0, -0.17), color=dark))
    fore_len = math.hypot(FOREARM[0], FOREARM[2])
    fore_pitch = -math.atan2(FOREARM[2], FOREARM[0])
    out += [
        Link("arm0.link_sh0", ARM_MASSES["arm0.link_sh0"], (Geometry("cylinder", (0.055, 0.10)),), color=dark),
        Link("arm0.link_sh1", ARM_MASSES["arm0.link_sh1"],
             (Geometry("box", (0.30, 0.07, 0.07), xyz=(0.17, 0.0, 0.0)),), com=(0.17, 0.0, 0.0)),
        Link("arm0.link_el0", ARM_MASSES["arm0.link_el0"],
             (Geometry("box", (fore_len - 0.10, 0.06, 0.06), xyz=(FOREARM[0] / 2 + 0.02, 0.0, FOREARM[2] / 2),
                       rpy=(0.0, fore_pitch, 0.0)),), com=(0.2, 0.0, 0.035)),
        Link("arm0.link_el1", ARM_MASSES["arm0.link_el1"],
             (Geometry("cylinder", (0.04, 0.08), rpy=(0.0, math.pi / 2, 0.0)),), color=dark),
        Link("arm0.link_wr0", ARM_MASSES["arm0.link_wr0"], (Geometry("sphere", (0.035,), collide=False),), color=dark),
        Link("arm0.link_wr1", ARM_MASSES["arm0.link_wr1"], (GRIPPER_BODY, FIXED_JAW), com=(0.07, 0.0, 0.0),
             color=dark),
        Link("arm0.link_fngr", ARM_MASSES["arm0.link_fngr"], (MOVING_JAW,), com=(0.05, 0.0, -0.014), color=dark),
        Link("arm0.hand", FRAME_MASS),
        Link(HAND_CAMERA.name, FRAME_MASS),
    ]
    return tuple(out)


def joints() -> tuple[Joint, ...]:
    out: list[Joint] = []
    for leg in LEGS:
        fx, ly = _leg_sign(leg)
        out.append(Joint(f"{leg}.hx", BODY, f"{leg}.hip", (fx * HIP_X_ORIGIN[0], ly * HIP_X_ORIGIN[1], 0.0),
                         (1.0, 0.0, 0.0), *HX_LIMITS, LEG_EFFORT["hx"], LEG_VELOCITY["hx"]))
        out.append(Joint(f"{leg}.hy", f"{leg}.hip", f"{leg}.uleg", (0.0, ly * HIP_Y_ORIGIN[1], 0.0),
                         (0.0, 1.0, 0.0), *HY_LIMITS, LEG_EFFORT["hy"], LEG_VELOCITY["hy"]))
        out.append(Joint(f"{leg}.kn", f"{leg}.uleg", f"{leg}.lleg", KNEE_ORIGIN,
                         (0.0, 1.0, 0.0), *KN_LIMITS, LEG_EFFORT["kn"], LEG_VELOCITY["kn"]))
    arm_chain = [
        ("arm0.sh0", BODY, "arm0.link_sh0", SHOULDER_ORIGIN, (0.0, 0.0, 1.0)),
        ("arm0.sh1", "arm0.link_sh0", "arm0.link_sh1", (0.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
        ("arm0.el0", "arm0.link_sh1", "arm0.link_el0", UPPER_ARM, (0.0, 1.0, 0.0)),
        ("arm0.el1", "arm0.link_el0", "arm0.link_el1", FOREARM, (1.0, 0.0, 0.0)),
        ("arm0.wr0", "arm0.link_el1", "arm0.link_wr0", (0.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
        ("arm0.wr1", "arm0.link_wr0", "arm0.link_wr1", (0.0, 0.0, 0.0), (1.0, 0.0, 0.0)),
    ]
    for name, parent, child, xyz, axis in arm_chain:
        out.append(Joint(name, parent, child, xyz, axis, *ARM_LIMITS[name], ARM_EFFORT[name], ARM_VELOCITY))
    out.append(Joint(GRIPPER_JOINT, "arm0.link_wr1", "arm0.link_fngr", FINGER_HINGE, (0.0, 1.0, 0.0),
                     *GRIPPER_LIMITS, GRIPPER_EFFORT, ARM_VELOCITY))
    out.append(Joint("arm0.hand_fixed", "arm0.link_wr1", "arm0.hand", (HAND_OFFSET, 0.0, 0.0), kind="fixed"))
    out.append(Joint(f"{HAND_CAMERA.name}_fixed", HAND_CAMERA.parent, HAND_CAMERA.name, HAND_CAMERA.xyz,
                     rpy=tuple(a * DEG for a in HAND_CAMERA.rpy_deg), kind="fixed"))
    return tuple(out)


def joint_by_name(name: str) -> Joint:
    for j in joints():
        if j.name == name:
            return j
    raise KeyError(f"unknown Spot joint {name!r}")


def stand_pose() -> dict[str, float]:
    """Leg joint angles the sim holds while standing (hx 0, hy STAND_HY, kn STAND_KN)."""
    return {f"{leg}.{j}": {"hx": 0.0, "hy": STAND_HY, "kn": STAND_KN}[j] for leg in LEGS for j in LEG_JOINT_SUFFIXES}


def stand_body_height() -> float:
    """Height of the body frame above flat ground in the stand pose (foot sphere touching z=0)."""
    hy, kn = STAND_HY, STAND_KN

    def ry(a: float, v: np.ndarray) -> np.ndarray:
        c, s = math.cos(a), math.sin(a)
        return np.array([c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2]])

    knee = ry(hy, np.array(KNEE_ORIGIN))
    foot = knee + ry(hy + kn, np.array([0.0, 0.0, FOOT_Z]))
    return float(-foot[2] + FOOT_RADIUS)


def arm_limits_array() -> tuple[np.ndarray, np.ndarray]:
    lo = np.array([ARM_LIMITS[n][0] for n in ARM_JOINTS])
    hi = np.array([ARM_LIMITS[n][1] for n in ARM_JOINTS])
    return lo, hi
