"""The oracle agent: knows the true scene (where every object and receptacle is, which pixels show
the target) but acts only through the HAL, like any agent. It is the ceiling for the other agents
and the smoke test of the whole loop (scenes, runner, HAL, physics, metrics): its failures are
physical (a grasp that slips, a drop that rolls off), not perceptual.

Script: walk to a standing pose facing the target (ground-truth fast-marching path; turn in place,
then walk straight segments), point the hand camera at it, grasp at its pixels, carry, walk to the
nearest goal receptacle, drop it 10 cm above a point 15 cm inside the near edge, stow.
"""

from __future__ import annotations

import math

import numpy as np

from robots.hal import RobotBackend, SE2Pose
from sim.camera import decode_body_ids
from tasks.spec import TaskSpec


class OracleAgent:
    name = "oracle"

    def __init__(self, sim, max_attempts: int = 4, release_height: float = 0.10, edge_inset: float = 0.15):
        self._scene = sim.scene
        self._world = sim.world
        self._segmentation_for = sim.backend.segmentation_for
        self._targets = sorted(sim.judge.valid_targets, key=lambda b: self._world.bodies[b].name != sim.episode.target_object)
        self._goals = list(sim.episode.goal_receptacles)
        self._support = {oid: self._world.bodies[oid].extra.get("receptacle") for oid in self._targets}
        self.max_attempts = max_attempts
        self.release_height = release_height
        self.edge_inset = edge_inset
        self.log: list[str] = []

    def reset(self, task: TaskSpec, rng: np.random.Generator) -> None:
        self._phase = "fetch"

    # ------------------------------------------------------------------ the script
    def act(self, robot: RobotBackend) -> bool:
        if self._phase == "fetch":
            self._phase = "deliver" if self._fetch(robot) else "done"
            return self._phase == "done"
        if self._phase == "deliver":
            self._deliver(robot)
        self._phase = "done"
        return True

    def _fetch(self, robot: RobotBackend) -> bool:
        attempts = 0
        for body in self._targets:
            target = self._world.position(body)
            size = self._world.bodies[body].extra.get("size", (0.08, 0.08, 0.08))
            here = robot.observe().body_pose
            front = self._scene.front(self._support[body]) if self._support.get(body) else None
            # aim for a reach that leaves room to lift the object afterwards; where no pose reaches that
            # point (a tight spot), the object's centre + 0.15 m, which episode generation proved reachable
            poses = self._scene.nav.approach_poses(target + [0.0, 0.0, 0.15], (here.x, here.y), front) or \
                self._scene.nav.approach_poses(target + [0.0, 0.0, 0.5 * size[2] + 0.15], (here.x, here.y), front)
            for pose in poses[:6]:
                if attempts >= self.max_attempts:
                    return False
                if not self._walk(robot, pose):
                    continue
                aim = target + np.array([0.0, 0.0, 0.5 * size[2]])
                if not robot.gaze_at(aim):
                    continue
                obs = robot.observe()
                vs, us = np.nonzero(decode_body_ids(self._segmentation_for(obs)) == body)
                if len(us) < 30:
                    self.log.append(f"{self._world.bodies[body].name} not visible from {pose}")
                    continue
                attempts += 1
                res = robot.grasp(obs, (int(np.median(us)), int(np.median(vs))))
                self.log.append(f"grasp {self._world.bodies[body].name}: {res.reason.value} {res.message}")
                if res.success:
                    return True
                robot.stow_arm()
                target = self._world.position(body)    # a failed grasp may have moved it
        return False

    def _deliver(self, robot: RobotBackend) -> None:
        robot.stow_arm()
        here = robot.observe().body_pose
        options = []
        for name in self._goals:
            for si, centre in enumerate(self._scene.surface_points(name)):
                # the hand holds the object ~0.25 m above the surface when it lets go
                poses = self._scene.nav.approach_poses(centre + [0.0, 0.0, 0.25], (here.x, here.y),
                                                       self._scene.front(name))
                if poses:
                    options.append((math.dist((here.x, here.y), poses[0].as_tuple()[:2]), name, si, centre, poses))
        for _, name, si, centre, poses in sorted(options, key=lambda t: t[0]):
            for pose in poses[:4]:
                if not self._walk(robot, pose):
                    continue
                point = self._release_point(name, si, centre, pose)
                robot.gaze_at(point)          # look where it will go (this is also what FindRec measures)
                robot.observe()
                res = robot.place(point, release_height=self.release_height)
                self.log.append(f"place on {name}: {res.reason.value} {res.message}")
                if res.success:
                    robot.stow_arm()
                    return
        self.log.append("no goal receptacle could be reached")

    def _release_point(self, name: str, si: int, centre: np.ndarray, pose: SE2Pose) -> list[float]:
        """A point on the surface ``edge_inset`` inside its edge nearest the robot."""
        rec = self._scene.receptacle(name)
        surf = rec.model.surfaces[si]
        c, s = math.cos(rec.yaw), math.sin(rec.yaw)
        to_robot = np.array([pose.x, pose.y]) - centre[:2]
        local = np.array([c * to_robot[0] + s * to_robot[1], -s * to_robot[0] + c * to_robot[1]])
        hx, hy = surf.half
        limit = np.array([max(hx - self.edge_inset, 0.0), max(hy - self.edge_inset, 0.0)])
        scale = min(1.0, *(limit[i] / abs(local[i]) if abs(local[i]) > 1e-9 else 1.0 for i in range(2)))
        p_local = local * scale
        p = centre[:2] + np.array([c * p_local[0] - s * p_local[1], s * p_local[0] + c * p_local[1]])
        return [float(p[0]), float(p[1]), float(centre[2])]

    def _walk(self, robot: RobotBackend, goal: SE2Pose) -> bool:
        """Follow the ground-truth SE2 walk plan: turns in place and straight segments, all clear."""
        robot.stow_arm()    # walk with the arm folded (or in the carry pose when holding)
        here = robot.observe().body_pose
        plan = self._scene.nav.plan_walk(here, goal)
        if plan is None:
            self.log.append(f"no clear walk to {goal}")
            return False
        res = robot.navigate_to(plan[-1], via=plan[:-1]) if plan else robot.navigate_to(goal)
        if not res.success:
            self.log.append(f"walk to {goal}: {res.reason.value} {res.message}")
        return bool(res.success)
