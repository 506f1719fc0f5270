"""How the simulated Spot moves its arm: joint and hand-pose moves, gaze, stow, straight-line hand
paths, and the arm's contact checks.

A mixin of :class:`robots.spot.sim_backend.SimSpotBackend` (the state it reads is set up by that
class's ``__init__``: ``world``, ``spot``, ``config``, ``_held``). An arm move replays its ruckig
trajectory either kinematically, pose by pose with collision checks (free space, or carrying an
object rigidly on the wrist: :meth:`SimArm._follow_arm_kinematically`), or under physics with the
position controllers tracking it (grasping, placing, or once a kinematic replay touched something:
:meth:`SimArm._move_arm`). It uses the main class's contact bookkeeping (``_new_base_hits``,
``_record_contacts``, ``_contact_guard``), the held object's ride and slip check
(``_kinematic_carry``, ``_check_slip``) and its clock (``_physics_needed``, ``_advance``,
``_step``). Kept apart from the grasp physics (:mod:`robots.spot.sim_manipulation`), which moves the
arm through these methods.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from robots.hal import as_hand_pose, as_point, CommandResult, Reason
from robots.spot import kinematics, model
from robots.spot.motion import check_arm_target, plan_arm
from robots.transforms import invert_transform, rot_y, rot_z, transform_points
from sim.world import FURNITURE, OBJECT, STRUCTURE


class SimArm:
    """Arm motion of :class:`robots.spot.sim_backend.SimSpotBackend`."""

    # ================================================================== arm
    def move_arm_joints(self, joints: Sequence[float]) -> CommandResult:
        self._check_open()
        q = check_arm_target(joints)
        return self._move_arm(q, phase="arm")

    def move_hand(self, T_body_hand: np.ndarray) -> CommandResult:
        self._check_open()
        T = as_hand_pose(T_body_hand)
        q = kinematics.inverse_kinematics(T, self.spot.arm_q())
        if q is None:
            return CommandResult(False, Reason.IK_FAILED, "no arm configuration within limits reaches that hand pose")
        return self._move_arm(q, phase="arm")

    def gaze_at(self, point: Sequence[float]) -> CommandResult:
        self._check_open()
        p_world = as_point(point, "gaze point")
        T_body_world = invert_transform(self.spot.T_world_body())
        p_body = transform_points(T_body_world, p_world[None])[0]
        q = self._gaze_solution(p_body)
        if q is None:
            return CommandResult(False, Reason.UNREACHABLE,
                                 f"cannot point the hand camera at ({p_world[0]:.2f}, {p_world[1]:.2f}, "
                                 f"{p_world[2]:.2f}) from here; turn the body towards it")
        return self._move_arm(q, phase="gaze")

    def _gaze_solution(self, p_body: np.ndarray) -> np.ndarray | None:
        cam = model.HAND_CAMERA
        R_hand_cam = kinematics.forward_kinematics(model.ARM_READY)
        R_hand_cam = (invert_transform(R_hand_cam["arm0.hand"]) @ R_hand_cam[cam.name])[:3, :3]
        axis = R_hand_cam[:, 2]
        tilt = math.atan2(axis[2], axis[0])  # the camera looks ~9 degrees above the hand's x axis
        base = np.array(self.config.gaze_hand_position)
        for dz, dx in ((0.0, 0.0), (-0.15, 0.1), (0.1, -0.1), (-0.3, 0.15), (0.0, -0.2)):
            hand_p = base + np.array([dx, 0.0, dz])
            if np.linalg.norm(p_body - hand_p) < 0.15:
                continue
            try:
                T = kinematics.look_at_hand_pose(hand_p, p_body)
            except ValueError:
                continue
            T[:3, :3] = T[:3, :3] @ rot_y(tilt)
            q = kinematics.inverse_kinematics(T, self.spot.arm_q())
            if q is not None:
                return q
        return None

    def stow_arm(self) -> CommandResult:
        """Stow; with an object in the claw, go to the carry pose instead (Spot refuses to stow it).

        From an extended arm the hand first retracts along a straight line: back towards the body
        at its current height, then up to the carry/gaze height, so neither the hand nor a held
        object is dragged through the furniture it was just working on.
        """
        self._check_open()
        t0 = self.world.time
        holding = self._held is not None
        T_cur = kinematics.hand_pose(self.spot.arm_q())
        x = T_cur[:3, 0]
        R_fwd = rot_z(-math.atan2(x[1], x[0])) @ T_cur[:3, :3]   # same pitch/roll, facing forward
        tuck = np.array(self.config.carry_hand_position if holding else self.config.gaze_hand_position)
        waypoints = []
        if T_cur[0, 3] > tuck[0] + 0.05 or T_cur[2, 3] < tuck[2] - 0.15:
            back = T_cur.copy()
            back[:3, 3] = [tuck[0], T_cur[1, 3] * 0.5, max(T_cur[2, 3], tuck[2] - 0.3)]
            waypoints.append(back)
            up = np.eye(4)
            up[:3, :3] = R_fwd if holding else kinematics.look_at_hand_pose(tuck, tuck + [1.0, 0.0, -0.3])[:3, :3]
            up[:3, 3] = tuck
            waypoints.append(up)
        phase = "carry" if holding else "stow"
        res = self._move_hand_linear(waypoints, phase)
        if not res:
            return res
        if holding:
            T = np.eye(4)
            T[:3, :3] = R_fwd
            T[:3, 3] = tuck
            q = kinematics.inverse_kinematics(T, self.spot.arm_q())
            if q is None:
                return CommandResult(False, Reason.IK_FAILED, "carry pose unreachable", duration=self.world.time - t0)
        else:
            q = np.array(model.ARM_STOW)
        res = self._move_arm(q, phase=phase)
        return CommandResult(res.success, res.reason, res.message, duration=self.world.time - t0)

    def _move_hand_linear(self, waypoints, phase: str, steps_per_metre: float = 12.0,
                          allow_gripper_contact: bool = False) -> CommandResult:
        """Move the hand through body-frame poses along (approximately) straight lines: each leg
        is cut into short joint-space moves between IK solutions of interpolated poses."""
        t0 = self.world.time
        T_prev = kinematics.hand_pose(self.spot.arm_q())
        for T_next in waypoints:
            n = max(1, int(math.ceil(np.linalg.norm(T_next[:3, 3] - T_prev[:3, 3]) * steps_per_metre)))
            for k in range(1, n + 1):
                T = T_prev.copy()
                T[:3, 3] = T_prev[:3, 3] + (T_next[:3, 3] - T_prev[:3, 3]) * k / n
                T[:3, :3] = T_prev[:3, :3] if k < n else T_next[:3, :3]
                q = kinematics.inverse_kinematics(T, self.spot.arm_q())
                if q is None:
                    continue   # skip an unreachable intermediate pose; the next one may be fine
                res = self._move_arm(q, phase, allow_gripper_contact)
                if not res:
                    return CommandResult(False, res.reason, res.message, duration=self.world.time - t0)
            T_prev = T_next
        return CommandResult(True, Reason.OK, duration=self.world.time - t0)

    def _move_arm(self, q_goal: np.ndarray, phase: str, allow_gripper_contact: bool = False) -> CommandResult:
        t0 = self.world.time
        traj = plan_arm(self.spot.arm_q(), q_goal, self.config.motion.arm)
        kinematic = self.config.kinematic_carry if self._held is not None else self.config.kinematic_free_arm
        if kinematic and not allow_gripper_contact:
            result = self._follow_arm_kinematically(traj, q_goal, phase, t0)
            if result is not None:
                return result
            traj = plan_arm(self.spot.arm_q(), q_goal, self.config.motion.arm)  # continue under physics
        ts = self.world.timestep
        n = max(1, int(math.ceil(traj.duration / ts)))
        every = self.config.contact_check_every
        for k in range(1, n + 1):
            q, qd = traj.at_time(k * ts)
            self.spot.command_arm(q, qd)
            self._step(1)
            if k % every == 0 or k == n:
                hit = self._new_arm_hits(phase, allow_gripper_contact)
                if hit:
                    self.spot.command_arm(self.spot.arm_q())
                    self._step(every)
                    link, body = hit
                    return CommandResult(False, Reason.COLLISION,
                                         f"{link} touched {self.world.bodies[body].name} during the {phase} move",
                                         duration=self.world.time - t0)
        # Let the position controllers converge on the final target.
        self.spot.command_arm(q_goal)
        settle_steps = int(self.config.arm_settle_time / ts)
        for _ in range(settle_steps):
            if np.max(np.abs(self.spot.arm_q() - q_goal)) < self.config.arm_tolerance:
                break
            self._step(1)
        self._check_slip()
        q_now = self.spot.arm_q()
        err = float(np.max(np.abs(q_now - q_goal)))
        hand_err = float(np.linalg.norm(kinematics.hand_pose(q_now)[:3, 3] - kinematics.hand_pose(q_goal)[:3, 3]))
        if err >= self.config.arm_tolerance and hand_err >= self.config.hand_tolerance:
            return CommandResult(False, Reason.TIMEOUT, f"arm stopped {err:.3f} rad ({100 * hand_err:.1f} cm) short "
                                                        f"of the target", duration=self.world.time - t0)
        return CommandResult(True, Reason.OK, duration=self.world.time - t0)

    def _follow_arm_kinematically(self, traj, q_goal: np.ndarray, phase: str, t0: float) -> CommandResult | None:
        """Replay an arm trajectory pose by pose (free space, or carrying with the held object
        moved along); None means 'touched an object, or the held object touched anything: use
        physics from here'."""
        times = traj.sample_times(self.config.motion.control_dt)
        carry = self._kinematic_carry()
        dynamic = self._physics_needed(held_is_kinematic=carry is not None)
        q_prev = self.spot.arm_q()
        guard = self._contact_guard("arm", carry, dynamic)
        for t_prev, t in zip(times[:-1], times[1:]):
            q, qd = traj.at_time(t)
            self.spot.set_arm_state(q, qd)
            if carry is not None:
                carry.follow()
            hits = self._new_base_hits(phase, guard, q)
            if hits:
                static = [(l, b) for l, b in hits if self.world.bodies[b].kind != OBJECT]
                if not static:
                    return None
                self.spot.set_arm_state(q_prev)
                if carry is not None:
                    carry.follow()
                self._advance(t - t_prev, dynamic)
                link, body = static[0]
                return CommandResult(False, Reason.COLLISION,
                                     f"{link} touched {self.world.bodies[body].name} during the {phase} move",
                                     duration=self.world.time - t0)
            if carry is not None and carry.touching():
                return None
            q_prev = q
            self._advance(t - t_prev, dynamic)
        self.spot.set_arm_state(q_goal)
        if carry is not None:
            carry.follow()
        return CommandResult(True, Reason.OK, duration=self.world.time - t0)

    def _new_arm_hits(self, phase: str, allow_gripper_contact: bool) -> tuple[str, int] | None:
        held = self._held.body_id if self._held else None
        current = set()
        for pt in self.world.contacts(self.spot.id):
            body, link = pt[2], pt[3]
            if body == held or body == self.spot.id:
                continue
            if allow_gripper_contact and link in self.spot.gripper_link_ids:
                continue
            current.add((self.spot.link_name.get(link, str(link)), body))
        self._record_contacts(sorted(current), phase)
        if held is not None and not allow_gripper_contact:
            # Outside grasping and placing, the held object is part of what the arm moves: jammed
            # against furniture or a wall it stops the arm and counts as a collision.
            for pt in self.world.contacts(held):
                other = pt[2]
                if other != self.spot.id and self.world.bodies.get(other) is not None and \
                        self.world.bodies[other].kind in (FURNITURE, STRUCTURE):
                    self._record_contacts(sorted(current) + [("held object", other)], phase)
                    return ("held object", other)
        if not current:
            return None
        # Only contacts with the static scene stop the arm; nudging a small object is allowed.
        static = [(l, b) for l, b in sorted(current) if self.world.bodies[b].kind != OBJECT]
        return static[0] if static else None

    # ================================================================== robot-level primitives
    # What a real Spot executes that the HAL does not name (see SimSpotBackend).
    def arm_is_stowed(self, tol: float = 0.05) -> bool:
        return bool(np.max(np.abs(self.spot.arm_q() - np.array(model.ARM_STOW))) < tol)
