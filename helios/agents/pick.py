"""The pick skill: walk to a standing pose the arm reaches the target from, look at it, step
closer if it lies beyond a comfortable reach, and grasp it by pixel (Spot's pick-in-image).

The grasp pixel is the middle of the target's detection mask in that last frame (the detection
that covers most of the target's Gaussians), or, if no detection matches, the middle of the
target's visible projected points.
"""

from __future__ import annotations

import math

import numpy as np

from helios.agents.body import Body
from helios.agents.config import AgentConfig
from helios.agents.geometry import reach_distances
from helios.agents.observer import Observer
from helios.agents.skill import SkillOutcome
from helios.agents.target import Target
from robots.hal import Observation, RobotBackend


def pick(robot: RobotBackend, body: Body, observer: Observer, target: Target, config: AgentConfig) -> SkillOutcome:
    """One grasp attempt on ``target``; the arm is stowed again afterwards (holding or not)."""
    reach = config.reach
    aim = np.asarray(target.centre, dtype=float)
    failed = body.approach(robot, aim + [0.0, 0.0, reach.grasp_lift], "grasp")
    if failed:
        return SkillOutcome(False, failed)
    for closer in (False, True):
        body.face(robot, aim)
        if not body.gaze(robot, aim).success:
            return SkillOutcome(False, "cannot look at the object from the grasp pose")
        obs = body.observe(robot)
        pixel = grasp_pixel(observer, obs, target)
        if pixel is None:
            return SkillOutcome(False, "not visible from the grasp pose")
        if closer or not _close_in(robot, body, obs, pixel, config):
            break
    res = robot.grasp(obs, pixel)
    body.log.append(f"grasp {target.key} at {pixel}: {res.reason.value} {res.message}")
    body.stow(robot)
    return SkillOutcome(res.success, "" if res.success else f"grasp failed ({res.reason.value})", attempted=True)


def _close_in(robot: RobotBackend, body: Body, obs: Observation, pixel: tuple[int, int], config: AgentConfig) -> bool:
    """Step straight towards the grasp point when it lies beyond a comfortable reach (the
    approach pose is only reached within a goal radius and the object's visible surface may sit
    behind its centre). True if the robot moved (the caller looks again)."""
    reach = config.reach
    point = obs.point_at_pixel(*pixel, window=0)
    if point is None:
        return False
    _, comfortable = reach_distances(float(point[2]), reach)
    d = np.asarray(point[:2]) - body.xy()
    dist = float(np.linalg.norm(d))
    if dist - comfortable < reach.close_in_threshold or dist < 1e-6:
        return False
    unit = d / dist
    goal = np.asarray(point[:2]) - unit * comfortable
    yaw = math.atan2(unit[1], unit[0])
    moved, _ = body.go(robot, goal[None], reach.close_in_radius, [yaw])
    body.log.append(f"closing in on the grasp point: {dist:.2f} m -> {comfortable:.2f} m "
                    f"({'done' if moved else 'blocked'})")
    return moved


def grasp_pixel(observer: Observer, obs: Observation, target: Target) -> tuple[int, int] | None:
    """The pixel to grasp ``target`` at in ``obs`` (None if it is not visible)."""
    mask = observer.matching_mask(obs, target, observer.object_class)
    if mask is not None:
        mask = mask & (obs.depth > 0)
    if mask is not None and mask.sum() >= 5:
        vs, us = np.nonzero(mask)
        cu, cv = np.median(us), np.median(vs)
        i = int(np.argmin((us - cu) ** 2 + (vs - cv) ** 2))
        return int(us[i]), int(vs[i])
    u, v = observer.visible_projection(obs, target.points)
    if len(u) >= 3:
        cu, cv = np.median(u), np.median(v)
        i = int(np.argmin((u - cu) ** 2 + (v - cv) ** 2))
        return int(u[i]), int(v[i])
    return None
