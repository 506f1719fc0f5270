"""How the simulated Spot grasps, places and works its claw, with real physics: approach, close
until both jaws pinch the object, attach it with a finite-force constraint, lift; on a failed grasp,
back out; on a place, turn the hand to the release point, open, retreat; drive the claw and let
loose objects come to rest.

A mixin of :class:`robots.spot.sim_backend.SimSpotBackend` (the state it reads and sets is set up by
that class's ``__init__``: ``world``, ``spot``, ``config``, ``_held``, ``last_release``,
``last_grasp_hand_pose``). It moves the arm through :class:`robots.spot.sim_arm.SimArm`
(``_move_arm``, ``_move_hand_linear``) and steps physics through the main class (``_step``). What
a hold leaves in ``_held`` is a :class:`_Held`; every motion then checks it for slip
(``SimSpotBackend._check_slip``) and carries it along (``SimSpotBackend._kinematic_carry``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from robots.hal import (
    as_pixel,
    as_point,
    GraspResult,
    InvalidCommandError,
    Observation,
    PlaceResult,
    Reason,
)
from robots.spot import kinematics, model
from robots.transforms import invert_transform, rot_z
from sim import grasping
from sim.world import OBJECT


@dataclass
class _Held:
    """What a grasp leaves in ``SimSpotBackend._held``: the object, the constraint that holds it,
    and its pose in the wrist frame (what the slip check and the kinematic carry start from)."""

    body_id: int
    constraint_id: int
    T_wrist_obj: np.ndarray   # where the object sat in the claw when the constraint was made



class SimManipulation:
    """Grasp, place and claw physics of :class:`robots.spot.sim_backend.SimSpotBackend`."""

    # ================================================================== grasp and place
    def grasp(self, observation: Observation, pixel: tuple[int, int]) -> GraspResult:
        self._check_open()
        if not isinstance(observation, Observation):
            raise InvalidCommandError(f"grasp needs the Observation the pixel refers to, got {type(observation).__name__}")
        u, v = as_pixel(pixel, observation)
        t0 = self.world.time
        if self._held is not None:
            return GraspResult(False, Reason.ALREADY_HOLDING, "the claw already holds an object", holding=True)
        target = observation.point_at_pixel(u, v)
        if target is None:
            return GraspResult(False, Reason.NO_DEPTH, f"no depth at pixel ({u}, {v})")
        tgt = tuple(float(x) for x in target)
        cfg = self.config.grasp
        T_world_body = self.spot.T_world_body()
        shoulder = (T_world_body @ np.array([*model.SHOULDER_ORIGIN, 1.0]))[:3]
        reach = model.UPPER_ARM[0] + math.hypot(model.FOREARM[0], model.FOREARM[2]) + model.HAND_OFFSET
        dist = float(np.linalg.norm(target - shoulder))
        plan = grasping.plan_side_grasp(observation, target, T_world_body[:2, 3], cfg, model.HAND_OFFSET)
        T_body_world = invert_transform(T_world_body)
        solution = None
        for T_world_grasp in plan.hand_poses:
            T_grasp = T_body_world @ T_world_grasp
            T_pre = T_grasp.copy()
            T_pre[:3, 3] -= cfg.approach_back * T_grasp[:3, 0]
            T_pre[:3, 3] += cfg.approach_up * (T_body_world[:3, :3] @ np.array([0.0, 0.0, 1.0]))
            q_pre = kinematics.inverse_kinematics(T_pre, self.spot.arm_q())
            q_grasp = kinematics.inverse_kinematics(T_grasp, q_pre) if q_pre is not None else None
            if q_pre is not None and q_grasp is not None:
                solution = (T_grasp, q_pre, q_grasp)
                break
        if solution is None:
            reason = Reason.OUT_OF_REACH if dist > reach - 0.3 else Reason.IK_FAILED
            return GraspResult(False, reason, f"grasp point {dist:.2f} m from the shoulder cannot be reached from "
                                              f"here (arm length {reach:.2f} m); move closer", target_world=tgt)
        T_grasp, q_pre, q_grasp = solution
        res = self._move_arm(q_pre, "grasp")  # free-space move to the pre-grasp pose
        if not res:
            return GraspResult(False, res.reason, f"approach failed: {res.message}", target_world=tgt,
                               duration=self.world.time - t0)
        self._gripper_to(cfg.open_angle, cfg.close_force, cfg.close_speed * 2, 0.4)
        res = self._move_arm(q_grasp, "grasp", allow_gripper_contact=True)
        if res.reason == Reason.COLLISION:
            self._retreat_after_failed_grasp()
            return GraspResult(False, Reason.COLLISION, f"approach hit the scene: {res.message}", target_world=tgt,
                               duration=self.world.time - t0)
        fixed_link = self.spot.link_index["arm0.link_wr1"]
        moving_link = self.spot.link_index["arm0.link_fngr"]
        body = self._close_until_pinch(fixed_link, moving_link)
        if body is None:
            self._retreat_after_failed_grasp()
            return GraspResult(False, Reason.GRASP_MISSED, "the jaws closed without both touching an object",
                               target_world=tgt, duration=self.world.time - t0)
        cid = grasping.attach(self.world, self.spot.id, fixed_link, body, cfg.hold_force)
        T_wrist_obj = invert_transform(self.spot.link_pose("arm0.link_wr1")) @ self.world.pose(body)
        self._held = _Held(body, cid, T_wrist_obj)
        self._lift(T_body_world[:3, :3] @ np.array([0.0, 0.0, 1.0]))
        self._check_slip()
        if self._held is None:
            self._retreat_after_failed_grasp()
            return GraspResult(False, Reason.GRASP_SLIPPED, "the object slipped out of the claw during the lift",
                               target_world=tgt, duration=self.world.time - t0)
        return GraspResult(True, Reason.OK, f"holding {self.world.bodies[body].name}", holding=True,
                           target_world=tgt, duration=self.world.time - t0)

    def _lift(self, up_body: np.ndarray) -> None:
        """Raise the grasped object clear of its support: straight up by ``lift_height`` if the arm
        reaches, otherwise up and back towards the body (an arm at full stretch cannot go straight up)."""
        cfg = self.config.grasp
        T0 = kinematics.hand_pose(self.spot.arm_q())
        back = -np.array([T0[0, 0], T0[1, 0], 0.0])
        back /= max(np.linalg.norm(back), 1e-9)
        for up, away in ((1.0, 0.0), (0.8, 0.5), (0.6, 0.9), (0.4, 1.2)):
            T = T0.copy()
            T[:3, 3] += cfg.lift_height * (up * up_body + away * back)
            if kinematics.inverse_kinematics(T, self.spot.arm_q()) is not None:
                self._move_hand_linear([T], "grasp", allow_gripper_contact=True)
                return

    def _retreat_after_failed_grasp(self) -> None:
        """Open, back the hand out along its approach axis, close again."""
        cfg = self.config.grasp
        self._gripper_to(cfg.open_angle, cfg.close_force, 4.0, 0.3)
        T = kinematics.hand_pose(self.spot.arm_q())
        T[:3, 3] -= cfg.approach_back * T[:3, 0]
        q = kinematics.inverse_kinematics(T, self.spot.arm_q())
        if q is not None:
            self._move_arm(q, "grasp", allow_gripper_contact=True)
        self._gripper_to(0.0, cfg.close_force, 4.0, 0.3)

    def _close_until_pinch(self, fixed_link: int, moving_link: int) -> int | None:
        """Close the claw under motor force; return the object as soon as both jaws touch it.

        Attaching at the first pinch (rather than after the jaw stops) keeps the sweeping jaw from
        pushing the object out past the jaw tips.
        """
        cfg = self.config.grasp
        self.last_grasp_hand_pose = self.spot.T_world_hand()
        self.spot.command_gripper(0.0, cfg.close_force, cfg.close_speed)
        for _ in range(max(1, int(cfg.close_time / self.world.timestep))):
            self._step(1)
            body = grasping.pinched_object(self.world, self.spot.id, fixed_link, moving_link)
            if body is not None:
                self._step(4)  # let the jaw press in before the constraint freezes the relative pose
                return body
        return None

    def _gripper_to(self, angle: float, force: float, speed: float, duration: float) -> None:
        self.spot.command_gripper(angle, force, speed)
        self._step(max(1, int(duration / self.world.timestep)))

    def place(self, point: Sequence[float], release_height: float = 0.10) -> PlaceResult:
        self._check_open()
        p_world = as_point(point, "place point")
        if not (math.isfinite(release_height) and 0.0 <= release_height <= 1.0):
            raise InvalidCommandError(f"release_height must be within [0, 1] m, got {release_height}")
        if self._held is None:
            return PlaceResult(False, Reason.NOT_HOLDING, "nothing in the claw to place")
        t0 = self.world.time
        held = self._held.body_id
        T_world_hand = self.spot.T_world_hand()
        lo, hi = self.world.aabb(held)
        below = T_world_hand[2, 3] - lo[2]   # how far the object hangs below the hand frame
        centre_hand = invert_transform(T_world_hand) @ np.array([*(lo[:2] + hi[:2]) / 2, T_world_hand[2, 3], 1.0])
        T_world_body = self.spot.T_world_body()
        yaw = math.atan2(p_world[1] - T_world_body[1, 3], p_world[0] - T_world_body[0, 3])
        # Turn the hand (about world z) to face the release point, keeping its roll and the grip.
        x = T_world_hand[:3, 0]
        R = rot_z(yaw - math.atan2(x[1], x[0])) @ T_world_hand[:3, :3]
        T_target = np.eye(4)
        T_target[:3, :3] = R
        offset = R @ centre_hand[:3]
        T_target[:3, 3] = [p_world[0] - offset[0], p_world[1] - offset[1], p_world[2] + release_height + below]
        T_body = invert_transform(T_world_body) @ T_target
        q = kinematics.inverse_kinematics(T_body, self.spot.arm_q())
        if q is None:
            return PlaceResult(False, Reason.OUT_OF_REACH, "the release point cannot be reached from here; move closer",
                               duration=self.world.time - t0)
        res = self._move_arm(q, "place", allow_gripper_contact=True)
        if not res.success:   # never let go somewhere it was not meant to
            return PlaceResult(False, res.reason, f"did not reach the release pose: {res.message}",
                               duration=self.world.time - t0)
        release = tuple(float(v) for v in self.spot.T_world_hand()[:3, 3])
        self._release()
        T_back = kinematics.hand_pose(self.spot.arm_q())
        T_back[:3, 3] -= self.config.grasp.release_retreat * T_back[:3, 0]
        T_back[:3, 3] += 0.05 * (invert_transform(T_world_body)[:3, :3] @ np.array([0.0, 0.0, 1.0]))
        q_back = kinematics.inverse_kinematics(T_back, self.spot.arm_q())
        if q_back is not None:
            self._move_arm(q_back, "place", allow_gripper_contact=True)
        self._gripper_to(0.0, self.config.grasp.close_force, 4.0, 0.2)
        self.world.settle([held])
        return PlaceResult(True, Reason.OK, f"released {self.world.bodies[held].name}", duration=self.world.time - t0,
                           release_point=release)

    def _release(self) -> None:
        if self._held is None:
            return
        self.last_release = (self._held.body_id, self.world.position(self._held.body_id))
        grasping.detach(self.world, self._held.constraint_id, self.spot.id, self._held.body_id)
        self._held = None
        self._gripper_to(self.config.grasp.open_angle, self.config.grasp.close_force, 4.0, 0.25)

    # ================================================================== robot-level primitives
    # What a real Spot executes that the HAL does not name (see SimSpotBackend).
    def set_claw(self, angle: float) -> None:
        """Drive the claw joint to ``angle`` (0 closed, -pi/2 open). Opening while holding lets go."""
        self._check_open()
        cfg = self.config.grasp
        angle = float(min(max(angle, model.GRIPPER_LIMITS[0]), model.GRIPPER_LIMITS[1]))
        if self._held is not None and angle < -0.05:
            self._release()
            return
        self._gripper_to(angle, cfg.close_force, 4.0, 0.25 if angle < -0.05 else 0.2)

    def drop_held_object(self) -> None:
        """The claw loses the held object (the fake Spot's ``object_dropped`` fault): the hold lets
        go as a slip does (``SimSpotBackend._check_slip``) and the claw opens (the jaws alone would
        go on pinching it), so the object falls; :meth:`settle_loose_objects` lets it land. Between
        motions only: a motion's rigid carry would put it back on the wrist. Not a release: no place
        is recorded."""
        if self._held is None:
            return
        grasping.detach(self.world, self._held.constraint_id, self.spot.id, self._held.body_id)
        self._held = None
        self._gripper_to(self.config.grasp.open_angle, self.config.grasp.close_force, 4.0, 0.3)

    def settle_loose_objects(self, max_time: float = 2.0) -> None:
        """Let objects still moving (e.g. just dropped) come to rest: real time runs on between a
        robot's commands, while the simulation only runs while asked to."""
        if self._held is not None:
            return
        moving = [b.body_id for b in self.world.bodies_of_kind(OBJECT) if not self.world.is_at_rest(b.body_id)]
        if moving:
            self.world.settle(moving, max_time=max_time)

    @property
    def gripper_angle(self) -> float:
        return self.spot.gripper_q()
