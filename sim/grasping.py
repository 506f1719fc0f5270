"""Grasp and release physics: finger contact tests, the fixed constraint that holds an object once
both jaws touch it, and a depth-based planner for horizontal claw grasps.

Friction-only grasps are unreliable in PyBullet (bullet3 #1936, #2101, ...), so, as PyRep and
Gazebo's link attacher do, we let friction and motors decide *whether* a grasp happened (both jaws
must touch the object after closing under motor force) and a fixed constraint with a finite force
does the holding. A finite force lets heavy or badly held objects slip.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from helios.schema import require_range
from robots.hal import Observation
from robots.transforms import invert_transform, pose_to_transform, transform_to_pose
from sim.world import FURNITURE, GROUND, OBJECT, STRUCTURE, World


@dataclass(frozen=True)
class GraspConfig:
    open_angle: float = -1.50         # rad of the claw joint when opened for a grasp (0 = closed)
    close_force: float = 15.0         # N*m on the claw joint (Spot: 15.32 peak)
    close_speed: float = 2.0          # rad/s
    close_time: float = 0.8           # s allowed for the jaws to close
    hold_force: float = 60.0          # N, maximum force of the holding constraint (~6x a 1 kg weight)
    slip_distance: float = 0.03       # m an object may be dragged from its grasp pose before it is lost
    lift_height: float = 0.20         # m the hand rises after the jaws close
    approach_pitch: float = 0.35      # rad the claw points below horizontal (keeps the wrist off the support)
    approach_back: float = 0.12       # m the pre-grasp pose sits behind the grasp pose (hand -x)
    approach_up: float = 0.05         # m the pre-grasp pose sits above the grasp pose
    search_radius: float = 0.12       # m around the grasp point that belongs to the object
    depth_past_hinge: float = 0.03    # m the object's near face sits beyond the moving jaw's hinge
    side_gap: float = 0.002           # m between the fixed jaw's inner face and the object
    min_floor_clearance: float = 0.008  # m between the jaws' lower edge and the supporting surface
    release_retreat: float = 0.12     # m the hand backs off (and rises) after letting go

    def __post_init__(self) -> None:
        require_range(self, "open_angle", -math.pi, 0.0, hi_open=True)
        require_range(self, "close_force close_speed close_time hold_force", 0.0, 1e4, lo_open=True)
        require_range(self, "slip_distance search_radius", 0.0, 1.0, lo_open=True)
        require_range(self, "approach_pitch", -math.pi / 2, math.pi / 2)
        require_range(self, "lift_height approach_back approach_up depth_past_hinge side_gap min_floor_clearance "
                            "release_retreat", 0.0, 1.0)


@dataclass(frozen=True)
class GraspPlan:
    """A horizontal claw grasp: candidate hand poses (world), the approach yaw and object extent."""

    hand_poses: tuple[np.ndarray, ...]   # same grasp with the claw rolled either way; try in order
    approach_yaw: float
    target: np.ndarray                    # the 3D point the pixel resolved to
    top_z: float
    support_z: float


# Claw geometry in the wrist (arm0.link_wr1) frame, from robots.spot.model's primitives.
_HINGE_X = 0.117           # moving jaw hinge, along hand x
_JAW_TIP_X = 0.235         # jaw tips, along hand x
_FIXED_JAW_FACE_Z = -0.008  # inner face of the fixed jaw (hand z)
_JAW_HALF_HEIGHT = 0.015    # half extent of the jaws along hand y


def plan_side_grasp(obs: Observation, target: np.ndarray, body_xy: np.ndarray,
                    config: GraspConfig, hand_offset: float) -> GraspPlan:
    """Plan a grasp of whatever is at ``target`` using only the observation's depth.

    The claw approaches from the robot's side, rolled 90 degrees so the moving jaw sweeps in a
    (nearly) horizontal plane: it then pushes the object sideways into the fixed jaw instead of
    pressing it down onto its support (a top-down claw meets the object's top edge first and jams).
    The claw points ``approach_pitch`` below horizontal so the wrist stays clear of the support.
    Depth decides the grasp height (between the support and the object's top) and the jaw offsets.
    """
    v, u = np.nonzero(obs.depth > 0)
    pts_cam = obs.intrinsics.backproject(u, v, obs.depth[v, u])
    pts = pts_cam @ obs.T_world_cam[:3, :3].T + obs.T_world_cam[:3, 3]
    d_xy = np.linalg.norm(pts[:, :2] - target[:2], axis=1)
    below = pts[(d_xy < config.search_radius + 0.08) & (pts[:, 2] < target[2] - 0.01)]
    support_z = float(np.percentile(below[:, 2], 90)) if len(below) >= 20 else float(target[2]) - 0.05
    obj = pts[(d_xy < config.search_radius) & (pts[:, 2] > support_z + 0.008)]
    if len(obj) < 5:
        obj = np.asarray(target, dtype=float)[None, :]
    rough_centre = obj[:, :2].mean(axis=0)
    approach = rough_centre - body_xy
    yaw = math.atan2(approach[1], approach[0])
    a = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    pitch = config.approach_pitch
    x_axis = math.cos(pitch) * a + np.array([0.0, 0.0, -math.sin(pitch)])
    top_z = float(np.max(obj[:, 2]))
    height = top_z - support_z
    # Lowest claw point: the jaw tip's lower edge, below the hand frame because of the pitch.
    tip_drop = (_JAW_TIP_X - hand_offset) * math.sin(pitch) + _JAW_HALF_HEIGHT * math.cos(pitch)
    grasp_z = support_z + max(tip_drop + config.min_floor_clearance, min(0.5 * height, 0.06))
    along = obj[:, :2] @ a[:2]
    near = float(np.min(along))
    poses = []
    for side_sign in (1.0, -1.0):
        z_axis = side_sign * np.array([a[1], -a[0], 0.0])   # the moving jaw opens towards +z
        y_axis = np.cross(z_axis, x_axis)
        fixed_side = float(np.min(obj[:, :2] @ z_axis[:2]))
        # Object's near face 3 cm past the hinge; the fixed jaw's inner face grazing the object's
        # side (2 mm), so the sweeping jaw's first push already pinches it against the fixed jaw
        # instead of shoving it out past the jaw tips.
        p_along = near + (hand_offset - _HINGE_X - config.depth_past_hinge) * math.cos(pitch)
        p_side = fixed_side - config.side_gap - _FIXED_JAW_FACE_Z
        p = a * p_along + z_axis * p_side
        T = np.eye(4)
        T[:3, :3] = np.column_stack([x_axis, y_axis, z_axis])
        T[:3, 3] = [p[0], p[1], grasp_z]
        poses.append(T)
    return GraspPlan(tuple(poses), yaw, np.asarray(target, dtype=float), top_z, support_z)


def graspable_bodies(world: World) -> set[int]:
    return {b.body_id for b in world.bodies_of_kind(OBJECT)}


def bodies_touching_link(world: World, robot_id: int, link: int) -> set[int]:
    return {pt[2] for pt in world.client.getContactPoints(bodyA=robot_id, linkIndexA=link)}


def pinched_object(world: World, robot_id: int, fixed_link: int, moving_link: int) -> int | None:
    """The movable object both jaws touch after a physics step, if any."""
    both = bodies_touching_link(world, robot_id, fixed_link) & bodies_touching_link(world, robot_id, moving_link)
    candidates = sorted(both & graspable_bodies(world))
    return candidates[0] if candidates else None


def attach(world: World, robot_id: int, link: int, body_id: int, max_force: float) -> int:
    """Fix ``body_id`` to a robot link at their current relative pose; returns the constraint id.

    While held, the object's contacts with the robot are switched off: the constraint does the
    holding, and jaw contacts pressing on a constrained body only cost solver time (~40% of a step).
    """
    c = world.client
    _robot_collisions(world, robot_id, body_id, enable=False)
    st = c.getLinkState(robot_id, link, computeForwardKinematics=True)
    T_world_link = pose_to_transform(st[0], st[1])  # constraint frames are relative to the link's CoM frame
    T_world_obj = world.pose(body_id)
    T_link_obj = invert_transform(T_world_link) @ T_world_obj
    pos, quat = transform_to_pose(T_link_obj)
    cid = c.createConstraint(robot_id, link, body_id, -1, world.pb.JOINT_FIXED, [0, 0, 0],
                             parentFramePosition=pos.tolist(), childFramePosition=[0, 0, 0],
                             parentFrameOrientation=quat.tolist(), childFrameOrientation=[0, 0, 0, 1])
    c.changeConstraint(cid, maxForce=max_force)
    return cid


def detach(world: World, constraint_id: int, robot_id: int, body_id: int) -> None:
    world.client.removeConstraint(constraint_id)
    _robot_collisions(world, robot_id, body_id, enable=True)


def _robot_collisions(world: World, robot_id: int, body_id: int, enable: bool) -> None:
    for link in range(-1, world.client.getNumJoints(robot_id)):
        world.client.setCollisionFilterPair(robot_id, body_id, link, -1, int(enable))


def support_body(world: World, body_id: int) -> int | None:
    """The static body (furniture/structure/ground) a resting object touches from below, if any."""
    kinds = {b.body_id: b.kind for b in world.bodies.values()}
    best, best_z = None, -math.inf
    for pt in world.client.getContactPoints(bodyA=body_id):
        other = pt[2]
        if kinds.get(other) in (FURNITURE, STRUCTURE, GROUND) and pt[5][2] > best_z:
            best, best_z = other, pt[5][2]
    return best
