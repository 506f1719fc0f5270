"""What the agent sees: one frame through self-masking, the detector and the scorer into the map.

The observer owns the episode's :class:`~helios.maps.hierarchical.HierarchicalMap` and the latest
frame and detections, so every other room (the body, the skills, the decision) asks it rather
than the robot. It also answers the perception question the skills share: which detection in the
latest frame is the target we mean (:meth:`Observer.matching_mask`).

The trusting baseline keeps no Gaussian layer: its detections never reach the object map and each
one becomes a :class:`~helios.agents.target.Target` at once (:meth:`Observer._trust`).
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import replace
from typing import Sequence

import numpy as np

from helios.agents.config import AgentConfig
from helios.agents.geometry import backproject, project
from helios.agents.self_mask import own_pixels
from helios.agents.target import Target
from helios.config import HeliosConfig
from helios.maps.hierarchical import HierarchicalMap
from helios.maps.instances import Instance
from helios.perception.config import apply_thresholds, role_thresholds
from helios.perception.detection import Detection, Detector, ImageTextScorer
from helios.perception.prompts import value_prompt
from robots.hal import Observation, RobotBackend


class Observer:
    """Perception glue for one episode: detect + score each frame, update the map, remember the
    latest frame. ``timings`` (shared with the agent) collects wall seconds for perception and map."""

    def __init__(self, detector: Detector, scorer: ImageTextScorer, config: AgentConfig, method: HeliosConfig,
                 task, timings: Counter):
        self.detector = detector
        self.scorer = scorer
        self.config = config
        self.method = method
        self.timings = timings
        self.object_class = task.object
        self.start_class = task.start_receptacle
        self.goal_class = task.goal_receptacle
        classes = (self.object_class, self.start_class, self.goal_class)
        self.layers = tuple(dict.fromkeys((self.start_class, self.goal_class)))
        self.prompts = [value_prompt(c) for c in self.layers]
        self.query_classes = list(dict.fromkeys(classes))
        self.thresholds = role_thresholds(self.method.detection, *classes)
        self.map = HierarchicalMap(self.method, classes, self.layers, self.thresholds)
        self.last_obs: Observation | None = None
        self.last_detections: list[Detection] = []
        self.trusted: dict[str, list[Target]] = {self.object_class: [], self.goal_class: []}
        self.cache: dict = {}
        """Values derived from the map (instances, gaze points); cleared with every new frame."""

    def observe(self, robot: RobotBackend) -> Observation:
        """One frame through the detector and scorer into the map."""
        obs = self.without_self(robot.observe())
        t0 = time.perf_counter()
        detections = self.detector(obs.rgb, obs.depth, self.query_classes)
        scores = self.scorer(obs.rgb, self.prompts)
        t1 = time.perf_counter()
        kept = apply_thresholds(detections, self.thresholds, default=1.0)
        object_map = self.config.flags.object_map
        self.map.update(obs, kept if object_map else [],
                        {layer: float(s) for layer, s in zip(self.layers, scores)})
        self.timings["perception"] += t1 - t0
        self.timings["map"] += time.perf_counter() - t1
        if not object_map:
            self._trust(obs, kept)
        self.last_obs = obs
        self.last_detections = kept
        self.cache.clear()
        return obs

    def goals_changed(self) -> None:
        """A goal was found unreachable: drop the gaze points cached for this frame, which were
        filtered against the old blacklist, so a view that failed without a new frame (unreachable,
        no room for the arm) is not offered again at once. Before (``fresh_gaze_after_failure =
        False``) the same failing gaze point came back until the candidate's views ran out, all at
        the same instant (train-00009: six "looks" at 413.9 s, then the object was never tried)."""
        if self.config.fresh_gaze_after_failure:
            for key in [k for k in self.cache if isinstance(k, tuple) and k and k[0] == "gaze"]:
                del self.cache[key]

    def instances(self) -> list[Instance]:
        """The map's object instances as of the latest frame (computed once per frame)."""
        if "instances" not in self.cache:
            self.cache["instances"] = self.map.instances()
        return self.cache["instances"]

    def without_self(self, obs: Observation) -> Observation:
        """The frame with the robot's own legs and body blanked out of the depth (no return): the
        hand camera sees them when it looks down or sideways, and the map would turn them into
        obstacles that box the robot in wherever it has stood. While the claw holds something,
        the near field (closer than the map's ``min_depth``) is blanked too: it is the claw and
        the held object, 5-12 cm from the lens, and the place skill would otherwise take them for
        the highest point of the receptacle and let go where the object already is."""
        if obs.holding:
            near = (obs.depth > 0) & (obs.depth < self.method.occupancy.min_depth)
            if near.any():
                obs = replace(obs, depth=np.where(near, np.float32(0.0), obs.depth))
        x0, x1, y0, y1 = self.config.planner.footprint.body
        m = self.config.view.self_mask_margin
        T_body_cam = np.linalg.inv(obs.T_world_body) @ obs.T_world_cam
        own = own_pixels(obs.depth, obs.intrinsics, T_body_cam, (x0 - m, x1 + m, y0 - m, y1 + m),
                         self.config.view.self_mask_top)
        if not own.any():
            return obs
        depth = obs.depth.copy()
        depth[own] = 0.0
        return replace(obs, depth=depth)

    def _trust(self, obs: Observation, detections: Sequence[Detection]) -> None:
        """Trusting agent: every detection of the object / goal class becomes a target at once."""
        for d in detections:
            if d.class_name not in self.trusted:
                continue
            pts = backproject(obs, d.mask, stride=2)
            if len(pts) < 5:
                continue
            centre = np.median(pts, axis=0)
            known = self.trusted[d.class_name]
            if any(np.linalg.norm(t.centre[:2] - centre[:2]) < 0.3 for t in known):
                continue
            top = float(np.percentile(pts[:, 2], 95))
            known.append(Target(("detection", d.class_name, len(known)), centre, pts[:, :2], top, 1.0, points=pts))

    # ------------------------------------------------------------------ which mask is the target
    def visible_projection(self, obs: Observation, points: np.ndarray):
        """Pixels (u, v) of the points that are in view and not hidden behind a nearer surface."""
        u, v, z = project(points, obs.intrinsics, obs.T_world_cam)
        h, w = obs.depth.shape
        ui, vi = np.round(u).astype(int), np.round(v).astype(int)
        ok = (z > 0.05) & (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
        ui, vi, z = ui[ok], vi[ok], z[ok]
        d = obs.depth[vi, ui]
        seen = (d > 0) & (np.abs(d - z) < 0.08)
        return ui[seen], vi[seen]

    def matching_mask(self, obs: Observation, target: Target, cls: str) -> np.ndarray | None:
        """The detection of ``cls`` in the latest frame that covers most of the target."""
        masks = [d.mask for d in self.last_detections if d.class_name == cls]
        if not masks:
            return None
        u, v = self.visible_projection(obs, target.points)
        counts = [int(m[v, u].sum()) for m in masks]
        if max(counts, default=0) > 0:
            return masks[int(np.argmax(counts))]
        if target.instance_id is None:   # trusted detection: the mask nearest to the remembered point
            dists = []
            for m in masks:
                pts = backproject(obs, m, stride=2)
                dists.append(np.linalg.norm(np.median(pts, axis=0) - target.centre) if len(pts) else np.inf)
            if min(dists) < 0.4:
                return masks[int(np.argmin(dists))]
        return None
