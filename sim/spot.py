"""Spot's body in PyBullet: loading the URDF, holding the stand pose, kinematic base placement,
position-controlled arm and claw, link and camera poses, and robot-scene collision queries.

The base is a fixed-base multibody that we *place* along trajectories (Spot's API takes SE2 goals
and walks there; gait is not simulated). Legs hold the stand pose with position motors. The arm
and the claw are motor-driven, so grasps and carried objects obey physics.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from robots.hal import SE2Pose
from robots.spot import model
from robots.spot.urdf import SIM_URDF_PATH, UrdfError, parse_urdf
from robots.transforms import pose_to_transform, transform_to_pose
from sim.world import ROBOT, World

GRIPPER_LINKS = ("arm0.link_wr1", "arm0.link_fngr")


class SpotBody:
    """The simulated Spot multibody inside a :class:`World`."""

    def __init__(self, world: World, pose: SE2Pose = SE2Pose(0.0, 0.0, 0.0), urdf_path: str | Path = SIM_URDF_PATH):
        self.world = world
        c = world.client
        parse_urdf(urdf_path)  # one clear UrdfError for missing/malformed files before PyBullet sees it
        self.body_height = model.stand_body_height()
        try:
            self.id = c.loadURDF(str(urdf_path), useFixedBase=True)
        except Exception as exc:  # pybullet.error: "Cannot load URDF file."
            raise UrdfError(f"PyBullet could not load URDF {str(urdf_path)!r}: {exc}") from exc
        world.register(self.id, "spot", "robot", ROBOT)
        # PyBullet reports and sets a base's pose at its centre of mass; Spot's body frame is the URDF
        # link frame, offset by the body's CoM (BD: z -4.96 mm). Keep the offset to convert.
        dyn = c.getDynamicsInfo(self.id, -1)
        self._T_body_com = pose_to_transform(dyn[3], dyn[4])
        self._T_com_body = np.linalg.inv(self._T_body_com)
        self.joint_index: dict[str, int] = {}
        self.link_index: dict[str, int] = {model.BODY: -1}
        for i in range(c.getNumJoints(self.id)):
            info = c.getJointInfo(self.id, i)
            self.joint_index[info[1].decode()] = i
            self.link_index[info[12].decode()] = i
        missing = [j for j in (*model.ARM_JOINTS, model.GRIPPER_JOINT) if j not in self.joint_index]
        if missing:
            raise UrdfError(f"URDF {str(urdf_path)!r} lacks Spot joints {missing}")
        self.link_name = {i: n for n, i in self.link_index.items()}
        self._arm_idx = [self.joint_index[j] for j in model.ARM_JOINTS]
        self._grip_idx = self.joint_index[model.GRIPPER_JOINT]
        self.gripper_link_ids = {self.link_index[n] for n in GRIPPER_LINKS}
        self.moving_joint_indices = [i for i in range(c.getNumJoints(self.id))
                                     if c.getJointInfo(self.id, i)[2] != world.pb.JOINT_FIXED]
        # Links with a collision shape (15 of 22: hips, wrist frame, hand and camera frames have
        # none). Only they can touch anything, so their boxes bound every contact ``touching`` finds.
        self._collider_links = [link for link in range(-1, c.getNumJoints(self.id))
                                if c.getCollisionShapeData(self.id, link)]
        self._arm_reach: float | None = None
        for link in self.gripper_link_ids:  # rubber jaw pads
            c.changeDynamics(self.id, link, lateralFriction=1.5, spinningFriction=0.01)
        # The feet stand on the floor: those contacts are not collisions and cost solver time.
        for link in range(-1, c.getNumJoints(self.id)):
            c.setCollisionFilterPair(self.id, world.ground_id, link, -1, 0)
            c.changeDynamics(self.id, link, linearDamping=0.0, angularDamping=0.0)
        self.set_base_pose(pose)
        # Legs: locked at the stand pose in the sim URDF; a URDF with revolute legs gets them set
        # and held by position motors instead.
        self._stand = model.stand_pose()
        free_legs = [j for j in model.LEG_JOINTS
                     if j in self.joint_index and c.getJointInfo(self.id, self.joint_index[j])[2] != world.pb.JOINT_FIXED]
        for name in free_legs:
            c.resetJointState(self.id, self.joint_index[name], self._stand[name])
        if free_legs:
            c.setJointMotorControlArray(self.id, [self.joint_index[j] for j in free_legs], world.pb.POSITION_CONTROL,
                                        targetPositions=[self._stand[j] for j in free_legs],
                                        forces=[model.LEG_EFFORT[j.split(".")[1]] for j in free_legs])
        self.reset_arm(model.ARM_STOW)
        self.reset_gripper(0.0)

    # ------------------------------------------------------------------ base
    def base_pose(self) -> SE2Pose:
        return SE2Pose.from_matrix(self.T_world_body())

    def T_world_body(self) -> np.ndarray:
        return self.world.pose(self.id) @ self._T_com_body

    def set_base_pose(self, pose: SE2Pose) -> None:
        """Place the body (kinematically) at an SE2 pose at standing height."""
        T_world_com = pose.to_matrix(self.body_height) @ self._T_body_com
        pos, quat = transform_to_pose(T_world_com)
        self.world.client.resetBasePositionAndOrientation(self.id, pos.tolist(), quat.tolist())

    # ------------------------------------------------------------------ joints
    def arm_q(self) -> np.ndarray:
        return np.array([s[0] for s in self.world.client.getJointStates(self.id, self._arm_idx)])

    def gripper_q(self) -> float:
        return float(self.world.client.getJointState(self.id, self._grip_idx)[0])

    def joint_positions(self) -> dict[str, float]:
        """All joints as Spot's robot state reports them (legs at the stand pose they hold)."""
        names = (*model.ARM_JOINTS, model.GRIPPER_JOINT)
        states = self.world.client.getJointStates(self.id, [self.joint_index[n] for n in names])
        out = dict(self._stand)
        out.update({n: float(s[0]) for n, s in zip(names, states)})
        return out

    def reset_arm(self, q) -> None:
        """Teleport the arm (setup only) and hold the pose with the motors."""
        c = self.world.client
        for idx, v in zip(self._arm_idx, q):
            c.resetJointState(self.id, idx, float(v), 0.0)
        self.command_arm(q)

    def set_arm_state(self, q, qd=None) -> None:
        """Kinematically place the arm at q (velocities qd) and point the motors at q."""
        c = self.world.client
        qd = [0.0] * 6 if qd is None else qd
        for idx, v, w in zip(self._arm_idx, q, qd):
            c.resetJointState(self.id, idx, float(v), float(w))
        self.command_arm(q)

    def command_arm(self, q, qd=None) -> None:
        """Position-control targets for the six arm joints (tracked during physics steps)."""
        kwargs = {}
        if qd is not None:
            kwargs["targetVelocities"] = [float(v) for v in qd]
        self.world.client.setJointMotorControlArray(
            self.id, self._arm_idx, self.world.pb.POSITION_CONTROL, targetPositions=[float(v) for v in q],
            forces=[model.ARM_EFFORT[j] for j in model.ARM_JOINTS], positionGains=[0.3] * 6,
            velocityGains=[1.0] * 6, **kwargs)

    def reset_gripper(self, q: float) -> None:
        self.world.client.resetJointState(self.id, self._grip_idx, float(q), 0.0)
        self.command_gripper(q)

    def command_gripper(self, q: float, force: float = model.GRIPPER_EFFORT, max_velocity: float = 3.0) -> None:
        self.world.client.setJointMotorControl2(self.id, self._grip_idx, self.world.pb.POSITION_CONTROL,
                                                targetPosition=float(q), force=float(force),
                                                maxVelocity=float(max_velocity))

    # ------------------------------------------------------------------ frames
    def link_pose(self, link_name: str) -> np.ndarray:
        """World pose of a URDF link frame (not its centre of mass)."""
        idx = self.link_index[link_name]
        if idx < 0:
            return self.T_world_body()
        st = self.world.client.getLinkState(self.id, idx, computeForwardKinematics=True)
        return pose_to_transform(st[4], st[5])

    def T_world_hand(self) -> np.ndarray:
        return self.link_pose("arm0.hand")

    def T_world_camera(self) -> np.ndarray:
        return self.link_pose(model.HAND_CAMERA.name)

    # ------------------------------------------------------------------ collisions
    def touching(self, exclude_bodies=(), exclude_links=(), margin: float = 0.0) -> list[tuple[str, int]]:
        """(robot link, other body id) pairs closer than ``margin`` at the current poses.

        Works without stepping physics (closest-point queries on current transforms), so kinematic
        base motion can be checked pose by pose. The floor and excluded bodies/links are ignored.
        """
        c = self.world.client
        hits: list[tuple[str, int]] = []
        for body_id in self._bodies_near(self._collider_boxes(), margin, exclude_bodies):
            for pt in c.getClosestPoints(self.id, body_id, distance=margin):
                link_name = self.link_name.get(pt[3], str(pt[3]))
                if pt[3] in exclude_links:
                    continue
                hits.append((link_name, body_id))
        return hits

    def clearance(self, within: float, exclude_bodies=(), turning_axis=None) -> tuple[float, float]:
        """(distance, reach) at the current poses: the least distance PyBullet measures between
        the robot and any body but the floor and ``exclude_bodies`` (``within`` when none is
        closer), and, given a ``turning_axis`` (x, y), the robot's reach about it: the largest
        horizontal distance of its collider boxes from that vertical axis (bounds how far any
        point of the robot moves when the base turns about it; 0.0 without an axis). See
        :class:`ContactGuard`."""
        c = self.world.client
        boxes = self._collider_boxes()
        distance = float(within)
        for body_id in self._bodies_near(boxes, within, exclude_bodies):
            for pt in c.getClosestPoints(self.id, body_id, distance=within):
                if pt[8] < distance:
                    distance = float(pt[8])
        if turning_axis is None:
            return distance, 0.0
        x, y = turning_axis
        dx = np.maximum(np.abs(boxes[:, 0, 0] - x), np.abs(boxes[:, 1, 0] - x))
        dy = np.maximum(np.abs(boxes[:, 0, 1] - y), np.abs(boxes[:, 1, 1] - y))
        return distance, float(np.sqrt(dx * dx + dy * dy).max())

    def arm_reach(self) -> float:
        """A bound, the same in every arm configuration, on the distance from the first arm
        joint's origin to any point of the arm (its links from the shoulder on, claw included):
        the link-frame offsets along the chain plus the farthest corner of each link's collider
        box from its own frame. No arm point moves farther than this per radian of any arm joint
        (:class:`ContactGuard`). Measured once, in the configuration of the first call."""
        if self._arm_reach is not None:
            return self._arm_reach
        c = self.world.client
        first = self.joint_index[model.ARM_JOINTS[0]]          # its child link is link ``first``
        parent = {i: c.getJointInfo(self.id, i)[16] for i in range(c.getNumJoints(self.id))}
        origin = {i: np.array(c.getLinkState(self.id, i, computeForwardKinematics=True)[4]) for i in parent}
        colliders = set(self._collider_links)
        path = {first: 0.0}
        reach = 0.0
        for link in sorted(parent):                      # parents come before their children
            if link != first:
                if parent[link] not in path:
                    continue                             # not downstream of the shoulder
                path[link] = path[parent[link]] + float(np.linalg.norm(origin[link] - origin[parent[link]]))
            extent = 0.0
            if link in colliders:
                lo, hi = (np.array(v) for v in c.getAABB(self.id, link))
                extent = float(np.linalg.norm(np.maximum(np.abs(lo - origin[link]), np.abs(hi - origin[link]))))
            reach = max(reach, path[link] + extent)
        self._arm_reach = reach
        return reach

    def _collider_boxes(self) -> np.ndarray:
        """(links, 2, 3) world AABBs of the links with a collision shape (never cached: they move)."""
        c = self.world.client
        return np.array([c.getAABB(self.id, link) for link in self._collider_links])

    def _bodies_near(self, boxes: np.ndarray, margin: float, exclude_bodies) -> list[int]:
        """Bodies (not the floor, not ``exclude_bodies``) whose boxes come within ``margin`` (+1 cm)
        of the robot's: only they can hold a closest point within ``margin``."""
        pad = margin + 0.01
        lo = boxes[:, 0].min(axis=0) - pad
        hi = boxes[:, 1].max(axis=0) + pad
        return self.world.bodies_overlapping(lo, hi, set(exclude_bodies) | {self.id})


class ContactGuard:
    """Skips the contact queries of a kinematic motion that provably find nothing.

    During a kinematic move (no physics stepped, so nothing but the robot moves) every point of
    the robot moves, between two states of the move, by at most a bound the move's kind gives:
    ``|dxy| + reach * |dyaw|`` for a base walk (the robot rigid, ``reach`` its largest distance
    from the turning axis), ``arm_reach * sum_j |dq_j|`` for an arm move (the base still;
    :meth:`SpotBody.arm_reach`). No distance between the robot and another body changes by more
    than that. So once a clearance query finds every body at least ``d`` away, each state within
    ``d - slack`` of it touches nothing, and :meth:`SpotBody.touching` would return no pairs
    there: one query stands in for those of several 50 ms poses (conservative advancement).
    ``slack`` (2 cm) covers PyBullet's distance tolerances with a wide margin. Where the robot
    comes within ``slack`` of something the guard answers "check", the caller runs the exact
    query, and the guard tries a clearance query again ``retry_after`` states later.
    """

    slack = 0.02

    def __init__(self, spot: SpotBody, within: float, kind: str, exclude_bodies=(), retry_after: int = 4):
        if kind not in ("base", "arm"):
            raise ValueError(f"kind must be 'base' or 'arm', got {kind!r}")
        self.spot = spot
        self.within = float(within)
        self.kind = kind
        self.exclude = tuple(exclude_bodies)
        self.retry_after = int(retry_after)
        self._arm_reach = spot.arm_reach() if kind == "arm" else 0.0
        self._anchor = None
        self._distance = 0.0
        self._reach = 0.0
        self._wait = 0
        self.skipped = 0
        """States answered without a contact query (for tests and benchmarks)."""

    def _moved(self, state) -> float:
        a = self._anchor
        if self.kind == "base":
            turn = abs(math.remainder(state.yaw - a.yaw, 2.0 * math.pi))
            return math.hypot(state.x - a.x, state.y - a.y) + self._reach * turn
        return self._arm_reach * float(np.abs(np.asarray(state, dtype=float) - a).sum())

    def vouches(self, state) -> bool:
        """True when the last clearance query alone shows that the robot at ``state`` touches
        nothing (what :meth:`free` answers first, without a query): then the robot need not even
        be put at ``state`` (the caller may skip the pose, see ``SimSpotBackend``). False:
        put it there and ask :meth:`free`, which then asks the world."""
        if self._anchor is not None and self._moved(state) <= self._distance - self.slack:
            self.skipped += 1
            return True
        return False

    def free(self, state) -> bool:
        """True when the robot, now at ``state`` (the base's SE2Pose, or the six arm joint
        angles), certainly touches nothing; False: check it."""
        if self.vouches(state):
            return True
        self._anchor = None
        if self._wait > 0:
            self._wait -= 1
            return False
        distance, reach = self.spot.clearance(self.within, self.exclude,
                                              (state.x, state.y) if self.kind == "base" else None)
        if distance > self.slack:
            self._anchor = state if self.kind == "base" else np.array(state, dtype=float)
            self._distance, self._reach = distance, reach
            return True
        self._wait = self.retry_after
        return False
