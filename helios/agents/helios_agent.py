"""The HELIOS agent and its ablations: one code path, variants chosen by flags (paper Fig. flow chart).

Each ``act`` call makes one decision and carries it out through the HAL:

1. **Pick phase.** Target-object candidates (instances with S_g >= cs_g resting on a start
   receptacle candidate) are judged with the decision rule (:mod:`helios.search.decisions`):
   grasp when Psi_g >= tau_g; else take the one view (gaze point) with the highest predicted
   Psi'_g if Psi'_g >= min(tau_g, Psi_g + tau_inc); else leave it.
2. Otherwise continue a running **local search** (all gaze points of a candidate pick location,
   nearest first; the location is then marked visited), or consult the **global objective**
   (:mod:`helios.search.objective`): locally search the best candidate pick location or walk
   towards the best frontier and look around.
3. **Place phase** (holding the object): the same rule for goal-receptacle candidates
   (tau_b); otherwise the frontier with the highest value for the goal receptacle.

Variants (``AgentConfig.variant``): ``helios``; ``no_global`` (candidates always before
frontiers); ``trusting`` (no Gaussian layer, no gaze points, no objective: the highest-value
frontier until the detector reports the object, which it then grasps; likewise for the goal
receptacle). The 50-50 IG ablation is ``HeliosConfig.search.information_gain``; ground-truth
semantics is a property of the detector/scorer passed in.

The agent sees the world only through ``observe()`` and the detector/scorer it was given.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np
from scipy import ndimage

from helios.agents.config import AgentConfig
from helios.agents.geometry import approach_poses, backproject, predicted_camera, project, reach_distances
from helios.agents.place import PlaceTarget, choose_place_point
from helios.config import HeliosConfig
from helios.maps.hierarchical import HierarchicalMap
from helios.maps.instances import Instance
from helios.perception.detection import Detection, Detector, ImageTextScorer
from helios.perception.prompts import value_prompt
from helios.planning.fmm import FMMPlanner, PlanResult
from helios.planning.footprint import FootprintChecker
from helios.search.decisions import Verdict, decide
from helios.search.gaze_points import GazePoint, gaze_points
from helios.search.information import predicted_object_score, views_information_gain
from helios.search.objective import CandidateLocation, FrontierOption, GlobalObjective
from robots.hal import Observation, Reason, RobotBackend, SE2Pose
from robots.transforms import wrap_angle

_MAX_GAZE_YAW = math.radians(105)   # the hand camera can be pointed this far to the side


@dataclass
class Target:
    """Something to act on: a target-object or goal-receptacle candidate."""

    key: tuple                       # ("instance", id) or ("detection", n)
    centre: np.ndarray               # (3,) world
    footprint_xy: np.ndarray         # (K, 2) world
    top: float                       # highest point, m
    psi: float                       # uncertainty-weighted score (1 for trusted detections)
    points: np.ndarray | None = None  # (N, 3) its Gaussian centres or detected points, when chosen
    instance_id: int | None = None


@dataclass
class _LocalSearch:
    instance_id: int
    queue: list[GazePoint] = field(default_factory=list)


class HeliosAgent:
    """HELIOS (and its ablations) behind the runner's Agent protocol (``reset``, ``act``)."""

    def __init__(self, detector: Detector, scorer: ImageTextScorer, config: AgentConfig = AgentConfig(),
                 method: HeliosConfig = HeliosConfig(), name: str = "helios"):
        self.detector = detector
        self.scorer = scorer
        self.config = config
        self.method = method
        self.name = name
        self.planner = FMMPlanner(config.planner)
        self.log: list[str] = []
        self.map: HierarchicalMap | None = None

    # ================================================================== episode life cycle
    def reset(self, task, rng: np.random.Generator) -> None:
        self.task = task
        self.rng = rng
        self.object_class = task.object
        self.start_class = task.start_receptacle
        self.goal_class = task.goal_receptacle
        classes = (self.object_class, self.start_class, self.goal_class)
        self.layers = tuple(dict.fromkeys((self.start_class, self.goal_class)))
        self.prompts = [value_prompt(c) for c in self.layers]
        self.query_classes = list(dict.fromkeys(classes))
        self.thresholds = self.method.detection.thresholds_for(*classes)
        self.map = HierarchicalMap(self.method, classes, self.layers, self.thresholds)
        cell = self.map.geometry.cell_size
        mode = {"helios": "objective", "no_global": "prefer_candidates", "trusting": "frontiers_only"}[self.config.variant]
        self.pick_objective = GlobalObjective(self.method.search, cell, mode)
        self.place_objective = GlobalObjective(self.method.search, cell, "frontiers_only")
        self.phase = "start"
        self.pose: SE2Pose | None = None
        self.body_height = 0.5
        self.last_obs: Observation | None = None
        self.last_detections: list[Detection] = []
        self.arm_stowed = False
        self.arm_direction: float | None = None     # world yaw the hand camera points along
        self.pick_attempts = 0
        self.visited: set[int] = set()
        self.local: _LocalSearch | None = None
        self.looks: Counter = Counter()
        self.failures: Counter = Counter()
        self.reached: list[np.ndarray] = []        # frontiers walked to and looked past
        self.unreachable: list[np.ndarray] = []    # goals the planner or the walk failed on
        self.rescued_at: np.ndarray | None = None
        self.revisited: list[np.ndarray] = []
        self._frontier_cells: dict[int, np.ndarray] = {}
        self.last_frontier: np.ndarray | None = None
        self.trusted: dict[str, list[Target]] = {self.object_class: [], self.goal_class: []}
        self._cache: dict = {}
        self.log = []
        self._logged = 0
        self.last_plan: PlanResult | None = None
        self.decisions = 0
        self.timings: Counter = Counter()   # wall seconds per stage: perception, map, planning

    def act(self, robot: RobotBackend) -> bool:
        self.decisions += 1
        if self.phase == "start":
            self._initial_scan(robot)
            self.phase = "pick"
            return False
        if self.phase == "pick":
            self._pick_step(robot)
        elif self.phase == "place":
            self._place_step(robot)
        return self.phase == "done"

    def _initial_scan(self, robot: RobotBackend) -> None:
        """Look around the start: the front half with the arm, turn round, the other half. The
        turn relies on the start clearance (``PlannerConfig.start_clearance``) that episode
        generation guarantees; it is skipped if the map already shows it is not free."""
        view = self.config.view
        self._observe(robot)
        # the start clearance is free by construction: keep it as seen floor, or the strip beside
        # the start that no view covers can cut the start off from the rest once the robot leaves
        self.map.occupancy.mark_seen(self._xy()[None], self.config.planner.start_clearance)
        self._look(robot, view.start_look_yaws_deg, near_yaws_deg=view.start_near_yaws_deg)
        if not view.start_turn_around:
            return
        back = SE2Pose(self.pose.x, self.pose.y, float(wrap_angle(self.pose.yaw + math.pi)))
        plan = self._plan(np.array([[back.x, back.y]]), 0.05, back.yaw)
        if not plan.success or plan.final_turn_blocked or not plan.waypoints:
            self.log.append("start: no room to turn round")
            return
        if self._execute(robot, plan):
            self._look(robot, view.start_look_yaws_deg, near_yaws_deg=view.start_near_yaws_deg)

    # ================================================================== hooks for trial batches
    def memory_bytes(self) -> dict[str, int]:
        """Bytes of the agent's map per layer (sampled by the trial instrumentation)."""
        return self.map.memory_bytes() if self.map is not None else {}

    def record(self, recorder) -> None:
        """Log what the agent knows to an episode recording (tools.recording.EpisodeRecorder)."""
        if self.map is None:
            return
        recorder.log_map(self.map)
        recorder.log_detections(self.last_detections, self.query_classes)
        if self.last_plan is not None and self.last_plan.waypoints:
            recorder.log_path("plan", [(w.x, w.y, 0.05) for w in self.last_plan.waypoints])
        for line in self.log[self._logged:]:
            recorder.log_text(line)
        self._logged = len(self.log)

    # ================================================================== perception
    def _observe(self, robot: RobotBackend) -> Observation:
        """One frame through the detector and scorer into the map."""
        obs = self._without_self(robot.observe())
        t0 = time.perf_counter()
        detections = self.detector(obs.rgb, obs.depth, self.query_classes)
        scores = self.scorer(obs.rgb, self.prompts)
        t1 = time.perf_counter()
        kept = [d for d in detections if d.score >= self.thresholds.get(d.class_name, 1.0)]
        self.map.update(obs, [] if self.config.variant == "trusting" else kept,
                        {layer: float(s) for layer, s in zip(self.layers, scores)})
        self.timings["perception"] += t1 - t0
        self.timings["map"] += time.perf_counter() - t1
        if self.config.variant == "trusting":
            self._trust(obs, kept)
        self.pose = obs.body_pose
        self.body_height = float(obs.T_world_body[2, 3])
        self.last_obs = obs
        self.last_detections = kept
        self._cache.clear()
        return obs

    def _without_self(self, obs: Observation) -> Observation:
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
        v, u = np.nonzero(obs.depth > 0)
        if not len(v):
            return obs
        pc = obs.intrinsics.backproject(u, v, obs.depth[v, u])
        T = np.linalg.inv(obs.T_world_body) @ obs.T_world_cam
        pb = pc @ T[:3, :3].T + T[:3, 3]
        own = (pb[:, 0] > x0 - m) & (pb[:, 0] < x1 + m) & (pb[:, 1] > y0 - m) & (pb[:, 1] < y1 + m) & \
              (pb[:, 2] < self.config.view.self_mask_top)
        if not own.any():
            return obs
        depth = obs.depth.copy()
        depth[v[own], u[own]] = 0.0
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

    # ================================================================== the decision
    def _pick_step(self, robot: RobotBackend) -> None:
        limit = self.config.max_pick_attempts
        if limit and self.pick_attempts >= limit:
            self._finish(f"pick attempt limit ({limit}) reached")
            return
        target, verdict, view = self._judge_targets(self.object_class)
        if verdict is Verdict.ACT:
            self._try_pick(robot, target)
            return
        if verdict is Verdict.LOOK:
            self._take_view(robot, target, view)
            return
        if self.local is not None:
            self._continue_local_search(robot)
            return
        choice, frontiers = self._global_choice()
        if choice is None:
            if not self._rescue(robot) and not self._revisit(robot, self.start_class):
                self._finish("nothing left to search for the object")
        elif choice.kind == "candidate":
            self._start_local_search(choice.index)
            self._continue_local_search(robot)
        else:
            self._explore(robot, frontiers[choice.index], self.start_class, self.pick_objective)

    def _place_step(self, robot: RobotBackend) -> None:
        target, verdict, view = self._judge_targets(self.goal_class)
        if verdict is Verdict.ACT:
            self._try_place(robot, target)
            return
        if verdict is Verdict.LOOK:
            self._take_view(robot, target, view)
            return
        options = self._frontier_options(self.goal_class)
        choice = self.place_objective.choose(self._xy(), [], options)
        if choice is None:
            if not self._rescue(robot) and not self._revisit(robot, self.goal_class):
                self._finish("nothing left to search for the goal receptacle")
            return
        self._explore(robot, options[choice.index], self.goal_class, self.place_objective)

    def _finish(self, why: str) -> None:
        self.log.append(f"done: {why}")
        self.phase = "done"

    # ------------------------------------------------------------------ candidates
    def _instances(self) -> list[Instance]:
        if "instances" not in self._cache:
            self._cache["instances"] = self.map.instances()
        return self._cache["instances"]

    def _targets(self, cls: str) -> list[Target]:
        """Candidates for the object (or goal receptacle) class, best Psi first."""
        if self.config.variant == "trusting":
            return [t for t in self.trusted[cls] if self.failures[t.key] < self.config.max_failures_per_candidate]
        decision = self.method.decision
        cs = decision.cs_object if cls == self.object_class else decision.cs_goal_receptacle
        out = []
        for inst in self._instances():
            key = ("instance", inst.id)
            if inst.class_scores.get(cls, 0.0) < cs or self.failures[key] >= self.config.max_failures_per_candidate:
                continue
            if cls == self.object_class and self.config.require_start_support and not self._supported(inst):
                continue
            points = self.map.objects.means[inst.gaussian_indices].cpu().numpy().astype(float)
            out.append(Target(key, inst.centre, inst.footprint_xy, inst.max_height, inst.psi[cls], points, inst.id))
        return sorted(out, key=lambda t: -t.psi)

    def _supported(self, obj: Instance) -> bool:
        """The object candidate rests on (or right next to) a start-receptacle candidate."""
        cs = self.method.search.cs_start_receptacle
        for inst in self._instances():
            if inst.id == obj.id or inst.class_scores.get(self.start_class, 0.0) < cs:
                continue
            d = np.min(np.linalg.norm(inst.footprint_xy - obj.centre[:2], axis=1))
            if d <= self.config.support_radius:
                return True
        return False

    def _judge_targets(self, cls: str) -> tuple[Target | None, Verdict, GazePoint | None]:
        """The paper's rule over the candidates: act on the best confident one, else the first
        one worth another view, else nothing."""
        targets = self._targets(cls)
        decision = self.method.decision
        tau = decision.tau_object if cls == self.object_class else decision.tau_goal_receptacle
        for t in targets:
            if t.psi >= tau:
                return t, Verdict.ACT, None
        for t in targets:
            if t.instance_id is None or self.looks[t.key] >= self.config.max_looks_per_candidate:
                continue
            view, predicted = self._best_view(t, cls)
            if decide(t.psi, predicted, tau, decision.tau_increase) is Verdict.LOOK:
                return t, Verdict.LOOK, view
        return None, Verdict.IGNORE, None

    def _best_view(self, t: Target, cls: str) -> tuple[GazePoint | None, float | None]:
        """The gaze point whose view would give the highest Psi' (optimistic)."""
        best, best_psi = None, None
        for gp in self._gaze_points_of(t.instance_id):
            T = predicted_camera(gp.pose, gp.look_at, self.body_height, self.config.view)
            p = predicted_object_score(self.map.objects, t.instance_id, cls, self.last_obs.intrinsics, T).predicted_psi
            if best_psi is None or p > best_psi:
                best, best_psi = gp, p
        return best, best_psi

    def _gaze_points_of(self, instance_id: int) -> list[GazePoint]:
        key = ("gaze", instance_id)
        if key not in self._cache:
            inst = next((i for i in self._instances() if i.id == instance_id), None)
            if inst is None:
                self._cache[key] = []
            else:
                occ = self.map.occupancy
                pts = gaze_points(inst.footprint_xy, inst.max_height, self.map.geometry, occ.obstacle, occ.max_height,
                                  self._checker(), self.config.gaze, centre_xy=inst.centre[:2])
                rows, cols = self.map.geometry.world_to_cell(np.array([[g.pose.x, g.pose.y] for g in pts]).reshape(-1, 2))
                known = occ.explored[rows, cols] if len(pts) else np.zeros(0, dtype=bool)
                self._cache[key] = [g for g, k in zip(pts, known) if k and not self._blacklisted(g.pose)]
        return self._cache[key]

    def _global_choice(self):
        """The objective's pick among candidate pick locations and frontiers."""
        cands: list[CandidateLocation] = []
        if self.config.variant != "trusting":
            cs = self.method.search.cs_start_receptacle
            intr = self.last_obs.intrinsics
            for inst in self._instances():
                if inst.id in self.visited or inst.class_scores.get(self.start_class, 0.0) < cs:
                    continue
                views = self._gaze_points_of(inst.id)
                if not views:
                    continue
                cams = [predicted_camera(g.pose, g.look_at, self.body_height, self.config.view) for g in views]
                ig = views_information_gain(self.map.objects, inst.id, self.start_class, intr, cams,
                                            self.method.search.information_gain)
                cands.append(CandidateLocation(inst.id, inst.centre, inst.class_scores[self.start_class], ig))
        frontiers = self._frontier_options(self.start_class)
        return self.pick_objective.choose(self._xy(), cands, frontiers), frontiers

    def _frontier_options(self, layer: str) -> list[FrontierOption]:
        out = []
        self._frontier_cells = {}
        for f in self.map.frontiers():
            if self._blacklisted(SE2Pose(f.x, f.y, 0.0), self.config.frontier_blacklist_radius, self.reached):
                continue
            cells = f.cells[:: max(1, len(f.cells) // 16)]
            self._frontier_cells[len(out)] = self.map.geometry.cell_to_world(cells[:, 0], cells[:, 1])
            out.append(FrontierOption(f.xy, float(f.values.get(layer, 0.0)), key=len(out)))
        return out

    def _blacklisted(self, pose: SE2Pose, radius: float = 0.3, extra: Sequence[np.ndarray] = ()) -> bool:
        return any(math.hypot(pose.x - b[0], pose.y - b[1]) < radius for b in (*self.unreachable, *extra))

    def _revisit(self, robot: RobotBackend, layer: str) -> bool:
        """No frontier left: walk to the most promising seen place (highest value-map score for
        ``layer``, away from places already revisited) and look all around it again; detections
        are view-dependent, so a second look from elsewhere may find what the first missed."""
        cfg = self.config
        if len(self.revisited) >= cfg.max_revisits:
            return False
        occ, geo = self.map.occupancy, self.map.geometry
        b = occ.explored_bounds
        step = max(1, int(round(0.5 / geo.cell_size)))
        rows, cols = np.mgrid[b[0]:b[1]:step, b[2]:b[3]:step]
        rows, cols = rows.ravel(), cols.ravel()
        free = occ.explored[rows, cols] & ~occ.obstacle[rows, cols]
        rows, cols = rows[free], cols[free]
        if not len(rows):
            return False
        xy = geo.cell_to_world(rows, cols)
        value = self.map.values.layer(layer)[rows, cols]
        far = np.ones(len(xy), dtype=bool)
        for p in [*self.revisited, self._xy()]:
            far &= np.linalg.norm(xy - p, axis=1) > cfg.revisit_spacing
        order = np.argsort(-value[far], kind="stable")[: cfg.revisit_candidates]
        goals = xy[far][order]
        if not len(goals):
            return False
        self.revisited.append(goals[0])       # counted even if the walk fails: never loop
        ok, i = self._go(robot, goals, 0.3)
        if ok:
            self.revisited[-1] = goals[i]
            self.log.append(f"revisit ({goals[i][0]:.1f}, {goals[i][1]:.1f}) for the {layer}")
            view = self.config.view
            self._look(robot, view.start_look_yaws_deg, near_yaws_deg=view.start_near_yaws_deg)
        return True

    def _rescue(self, robot: RobotBackend) -> bool:
        """Before giving up: look all around (near floor included) from here, once per place, and
        forget which goals were unreachable; a boxed-in start or a narrow passage often opens up
        once the floor beside the robot has been seen. False if already done here."""
        if self.rescued_at is not None and np.linalg.norm(self.rescued_at - self._xy()) < 0.5:
            return False
        self.rescued_at = self._xy()
        self.unreachable.clear()
        self.log.append("stuck: looking all around before giving up")
        view = self.config.view
        self._look(robot, view.start_look_yaws_deg, near_yaws_deg=view.start_near_yaws_deg)
        return True

    # ================================================================== local search and views
    def _start_local_search(self, instance_id: int) -> None:
        views = list(self._gaze_points_of(instance_id))
        order, here = [], self._xy()
        while views:   # nearest first, then nearest to the last one
            i = int(np.argmin([math.hypot(g.pose.x - here[0], g.pose.y - here[1]) for g in views]))
            order.append(views.pop(i))
            here = np.array([order[-1].pose.x, order[-1].pose.y])
        self.local = _LocalSearch(instance_id, order)
        self.log.append(f"local search of instance {instance_id}: {len(order)} gaze points")

    def _continue_local_search(self, robot: RobotBackend) -> None:
        gp = self.local.queue.pop(0)
        self._visit(robot, gp)
        if not self.local.queue:
            self.visited.add(self.local.instance_id)
            self.local = None

    def _take_view(self, robot: RobotBackend, target: Target, view: GazePoint) -> None:
        self.looks[target.key] += 1
        if not self._visit(robot, view):
            self.unreachable.append(np.array([view.pose.x, view.pose.y]))

    def _visit(self, robot: RobotBackend, gp: GazePoint) -> bool:
        ok, _ = self._go(robot, np.array([[gp.pose.x, gp.pose.y]]), self.config.gaze_goal_radius, gp.pose.yaw)
        if not ok:
            return False
        direction = math.atan2(gp.look_at[1] - self.pose.y, gp.look_at[0] - self.pose.x)
        if abs(wrap_angle(direction - self.pose.yaw)) > _MAX_GAZE_YAW:
            self.log.append("gaze point: could not turn to face the object")
            return False
        if not self._make_room(robot) or not self._arm_clear(direction):
            self.log.append("gaze point: the arm has no room to look from here")
            return False
        if not self._gaze(robot, gp.look_at).success:
            return False
        self._observe(robot)
        return True

    def _look(self, robot: RobotBackend, yaws_deg: Sequence[float], facing: float | None = None,
              near_yaws_deg: Sequence[float] = (0.0,)) -> None:
        """Point the hand camera in several directions and observe each (plus the near floor)."""
        view = self.config.view
        if not self._make_room(robot):
            return
        base = self.pose.yaw if facing is None else facing
        for deg in sorted(yaws_deg, key=abs):     # front first: each view reveals walls for the next
            a = base + math.radians(deg)
            if abs(wrap_angle(a - self.pose.yaw)) > _MAX_GAZE_YAW:
                continue
            if not self._arm_clear(a):
                continue
            point = [self.pose.x + view.look_distance * math.cos(a), self.pose.y + view.look_distance * math.sin(a),
                     view.look_height]
            res = self._gaze(robot, point)
            if res.success:
                self._observe(robot)
        for deg in sorted(near_yaws_deg, key=abs) if view.near_look_distance > 0 else ():
            a = base + math.radians(deg)      # the floor close by, which the far views miss
            if abs(wrap_angle(a - self.pose.yaw)) > _MAX_GAZE_YAW or not self._arm_clear(a):
                continue
            res = self._gaze(robot, [self.pose.x + view.near_look_distance * math.cos(a),
                                     self.pose.y + view.near_look_distance * math.sin(a), 0.0])
            if res.success:
                self._observe(robot)

    def _gaze(self, robot: RobotBackend, point):
        """Point the hand camera at a world point (the arm leaves its stowed/carry pose)."""
        res = robot.gaze_at(point)
        self.arm_stowed = False
        self.arm_direction = math.atan2(point[1] - self.pose.y, point[0] - self.pose.x)
        if not res.success:
            self.log.append(f"gaze failed: {res.reason.value} {res.message}")
            if res.reason is Reason.COLLISION:   # the arm met something the map lacks: remember it
                view = self.config.view
                reach = view.elbow_radius
                sx = self.pose.x + view.shoulder_ahead * math.cos(self.pose.yaw)
                sy = self.pose.y + view.shoulder_ahead * math.sin(self.pose.yaw)
                self.map.occupancy.mark_obstacle((sx + reach * math.cos(self.arm_direction),
                                                  sy + reach * math.sin(self.arm_direction)), 0.1, height=1.5)
        return res

    def _shoulder(self, x: float, y: float, yaw: float) -> tuple[float, float]:
        ahead = self.config.view.shoulder_ahead
        return x + ahead * math.cos(yaw), y + ahead * math.sin(yaw)

    def _elbow_clear(self, x: float, y: float, yaw: float) -> bool:
        """No tall obstacle within ``elbow_radius`` of the shoulder: moving the arm at all swings
        its links up to 0.34 m round the shoulder, on any side (measured along gaze moves in sim)."""
        view = self.config.view
        sx, sy = self._shoulder(x, y, yaw)
        ring = np.linspace(0.0, 2 * math.pi, 32, endpoint=False)
        rr = np.linspace(0.1, view.elbow_radius, 4)
        disc = np.stack([sx + np.outer(rr, np.cos(ring)), sy + np.outer(rr, np.sin(ring))], axis=-1).reshape(-1, 2)
        rows, cols = self.map.geometry.world_to_cell(disc)
        occ = self.map.occupancy
        return not bool((occ.obstacle[rows, cols] & (occ.max_height[rows, cols] > view.arm_swing_height)).any())

    def _arm_clear(self, direction: float) -> bool:
        """The arm can point the camera in ``direction`` (world yaw): the elbow has room, and no
        tall obstacle lies on the arc the hand sweeps from where it points now (out to
        ``arm_swing_radius`` from the shoulder). Far to the side, unseen cells count as blocked too
        (a wall the camera has not looked at yet)."""
        view = self.config.view
        if not self._elbow_clear(self.pose.x, self.pose.y, self.pose.yaw):
            return False
        sx, sy = self._shoulder(self.pose.x, self.pose.y, self.pose.yaw)
        now = self.pose.yaw if self.arm_direction is None else self.arm_direction
        sweep = float(wrap_angle(direction - now))
        lo, hi = min(0.0, sweep) - 0.3, max(0.0, sweep) + 0.3
        angles = now + np.linspace(lo, hi, max(7, int((hi - lo) / 0.1) + 1))
        r, a = np.meshgrid(np.linspace(0.1, view.arm_swing_radius, 10), angles)
        pts = np.stack([sx + r * np.cos(a), sy + r * np.sin(a)], axis=-1).reshape(-1, 2)
        side = np.abs(wrap_angle(a.reshape(-1) - self.pose.yaw)) > math.radians(75)
        rows, cols = self.map.geometry.world_to_cell(pts)
        occ = self.map.occupancy
        blocked = occ.obstacle[rows, cols] & (occ.max_height[rows, cols] > view.arm_swing_height)
        blocked |= side & ~occ.explored[rows, cols]
        return not bool(blocked.any())

    def _make_room(self, robot: RobotBackend) -> bool:
        """Before looking around: if a wall or a tall piece of furniture is too close for the arm,
        step straight away from it (at the current heading) to the nearest pose where the elbow
        has room. False if there is none within ``make_room_distance``."""
        if self._elbow_clear(self.pose.x, self.pose.y, self.pose.yaw):
            return True
        x, y, yaw = self.pose.x, self.pose.y, self.pose.yaw
        checker = self._checker().clear_under(self.pose)
        c, s = math.cos(yaw), math.sin(yaw)
        limit = self.config.view.make_room_distance
        offsets = [(dx, dy) for dx in np.arange(-limit, limit + 1e-9, 0.1) for dy in np.arange(-limit, limit + 1e-9, 0.1)
                   if 0 < math.hypot(dx, dy) <= limit + 1e-9]
        for dx, dy in sorted(offsets, key=lambda o: math.hypot(*o)):
            nx, ny = x + dx * c - dy * s, y + dx * s + dy * c
            if self._elbow_clear(nx, ny, yaw) and checker.segment_free(x, y, nx, ny, yaw):
                if not self.arm_stowed:
                    robot.stow_arm()
                    self.arm_stowed, self.arm_direction = True, None
                res = robot.navigate_to(SE2Pose(nx, ny, yaw))
                final = getattr(res, "final_pose", None)
                self.pose = final if final is not None else robot.observe().body_pose
                self.log.append(f"made room for the arm: stepped ({dx:+.1f}, {dy:+.1f}) m")
                return bool(res.success) and self._elbow_clear(self.pose.x, self.pose.y, self.pose.yaw)
        self.log.append("no room for the arm to look around here")
        return False

    # ================================================================== walking
    def _checker(self) -> FootprintChecker:
        occ = self.map.occupancy
        unknown = ~occ.explored if self.config.planner.unknown_is_obstacle else None
        return FootprintChecker(self.config.planner.footprint, self.map.geometry, occ.obstacle, occ.max_height, unknown)

    def _plan(self, goals, radius: float, yaws=None, horizon: float | None = None) -> PlanResult:
        occ = self.map.occupancy
        t0 = time.perf_counter()
        plan = self.planner.plan(self.map.geometry, occ.obstacle, occ.explored, self.pose, goals, radius, yaws,
                                 occ.max_height, horizon, occ.explored_bounds)
        self.timings["planning"] += time.perf_counter() - t0
        self.timings["plans"] += 1
        self.last_plan = plan
        return plan

    def _execute(self, robot: RobotBackend, plan: PlanResult) -> bool:
        if not self.arm_stowed:
            robot.stow_arm()
            self.arm_stowed = True
            self.arm_direction = None
        start = self._xy()
        res = robot.navigate_to(plan.waypoints[-1], via=plan.waypoints[:-1])
        final = getattr(res, "final_pose", None)
        self.pose = final if final is not None else robot.observe().body_pose
        self._mark_swept(start, plan, res.success)
        if not res.success:
            self.log.append(f"walk stopped: {res.reason.value} {res.message}")
            if getattr(res, "collided", False):
                self._mark_bump(plan)
        return bool(res.success)

    def _mark_swept(self, start: np.ndarray, plan: PlanResult, completed: bool) -> None:
        """Where the body walked is free space, whether or not the camera ever saw the floor there."""
        pts = [start] + [np.array([w.x, w.y]) for w in plan.waypoints]
        if not completed:   # stopped early: only up to where it stands now
            here = self._xy()
            k = int(np.argmin([np.linalg.norm(p - here) for p in pts]))
            pts = pts[:k] + [here]
        samples = [pts[0]]
        for a, b in zip(pts[:-1], pts[1:]):
            n = max(1, int(np.linalg.norm(b - a) / 0.15))
            samples += [a + (b - a) * t for t in np.linspace(1.0 / n, 1.0, n)]
        self.map.occupancy.mark_seen(np.array(samples), self.config.planner.footprint.body[3])

    def _mark_bump(self, plan: PlanResult) -> None:
        """The walk ran into something the map does not show: put an obstacle just beyond the
        footprint in the direction the body was moving, so the next plan goes around it."""
        here = np.array([self.pose.x, self.pose.y])
        for wp in plan.waypoints:
            step = np.array([wp.x, wp.y]) - here
            dist = float(np.linalg.norm(step))
            if dist > 0.02:
                d = step / dist
                body = self.config.planner.footprint.body
                c, s = math.cos(self.pose.yaw), math.sin(self.pose.yaw)
                local = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])   # direction in the body frame
                half = body[1] if local[0] > 0 else -body[0]
                side = body[3]
                extent = min(half / max(abs(local[0]), 1e-6), side / max(abs(local[1]), 1e-6))
                self.map.occupancy.mark_obstacle(here + d * (extent + 0.12), 0.12)
                self.log.append(f"bumped into something near ({here[0] + d[0] * extent:.2f}, {here[1] + d[1] * extent:.2f})")
                return

    def _go(self, robot: RobotBackend, goals: np.ndarray, radius: float, yaws=None) -> tuple[bool, int]:
        """Plan-walk-look until within ``radius`` of one of ``goals`` (and facing its yaw)."""
        for _ in range(self.config.max_walk_chunks):
            plan = self._plan(goals, radius, yaws)
            if not plan.success:
                self.log.append(f"no path: {plan.reason}")
                return False, -1
            if not plan.waypoints:
                return True, plan.goal_index
            if not self._execute(robot, plan):
                return False, -1
            if plan.reaches_goal:
                return True, plan.goal_index
            self._look(robot, (0.0,))   # see what lies ahead (far and near) before the next stretch
        return False, -1

    def _explore(self, robot: RobotBackend, frontier: FrontierOption, layer: str, objective: GlobalObjective) -> None:
        """One stretch towards a frontier, then look around."""
        if self.last_frontier is None or np.linalg.norm(self.last_frontier - frontier.xy) > 0.5:
            objective.note_frontier_chosen(frontier)
            self.last_frontier = np.asarray(frontier.xy, dtype=float)
        # any part of the frontier will do: its centre may sit in a corner the body cannot reach
        goals = np.concatenate([np.asarray(frontier.xy, dtype=float)[None], self._frontier_cells.get(frontier.key, np.zeros((0, 2)))])
        plan = self._plan(goals, self.config.frontier_reach)
        if not plan.success:
            self.unreachable.append(np.asarray(frontier.xy, dtype=float))
            self.log.append(f"frontier ({frontier.xy[0]:.1f}, {frontier.xy[1]:.1f}) unreachable: {plan.reason}")
            return
        if plan.waypoints and not self._execute(robot, plan):
            self.unreachable.append(np.asarray(frontier.xy, dtype=float))
        arrived = plan.reaches_goal or not plan.waypoints
        if arrived:
            self.reached.append(np.asarray(frontier.xy, dtype=float))
        facing = math.atan2(frontier.xy[1] - self.pose.y, frontier.xy[0] - self.pose.x)
        self._look(robot, self.config.view.look_yaws_deg, facing if arrived else None)

    # ================================================================== manipulation
    def _fail(self, target: Target, why: str) -> None:
        self.failures[target.key] += 1
        self.log.append(f"{target.key}: {why}")

    def _try_pick(self, robot: RobotBackend, target: Target) -> None:
        reach = self.config.reach
        aim = np.asarray(target.centre, dtype=float)
        poses = approach_poses(aim + [0.0, 0.0, reach.grasp_lift], reach, self._checker())
        if not len(poses):
            self._fail(target, "no free standing pose to grasp from")
            return
        ok, _ = self._go(robot, poses[:, :2], self.config.gaze_goal_radius, poses[:, 2])
        if not ok:
            self._fail(target, "could not reach a grasp pose")
            return
        for closer in (False, True):
            self._face(robot, aim)
            if not self._gaze(robot, aim).success:
                self._fail(target, "cannot look at the object from the grasp pose")
                return
            obs = self._observe(robot)
            pixel = self._grasp_pixel(obs, target)
            if pixel is None:
                self._fail(target, "not visible from the grasp pose")
                return
            if closer or not self._close_in(robot, obs, pixel):
                break
        self.pick_attempts += 1
        res = robot.grasp(obs, pixel)
        self.log.append(f"grasp {target.key} at {pixel}: {res.reason.value} {res.message}")
        robot.stow_arm()
        self.arm_stowed, self.arm_direction = True, None
        if res.success:
            self.phase = "place"
        else:
            self._fail(target, f"grasp failed ({res.reason.value})")


    def _face(self, robot: RobotBackend, point) -> None:
        """Turn on the spot towards ``point`` if it lies well to the side (a goal pose is reached
        within a radius, and its final turn may have been blocked)."""
        direction = math.atan2(point[1] - self.pose.y, point[0] - self.pose.x)
        if abs(wrap_angle(direction - self.pose.yaw)) > self.config.view.face_tolerance:
            self._go(robot, self._xy()[None], self.config.gaze_goal_radius, [direction])

    def _close_in(self, robot: RobotBackend, obs: Observation, pixel: tuple[int, int]) -> bool:
        """Step straight towards the grasp point when it lies beyond a comfortable reach (the
        approach pose is only reached within a goal radius and the object's visible surface may sit
        behind its centre). True if the robot moved (the caller looks again)."""
        reach = self.config.reach
        point = obs.point_at_pixel(*pixel, window=0)
        if point is None:
            return False
        _, comfortable = reach_distances(float(point[2]), reach)
        d = np.asarray(point[:2]) - self._xy()
        dist = float(np.linalg.norm(d))
        if dist - comfortable < reach.close_in_threshold or dist < 1e-6:
            return False
        unit = d / dist
        goal = np.asarray(point[:2]) - unit * comfortable
        yaw = math.atan2(unit[1], unit[0])
        moved, _ = self._go(robot, goal[None], reach.close_in_radius, [yaw])
        self.log.append(f"closing in on the grasp point: {dist:.2f} m -> {comfortable:.2f} m "
                        f"({'done' if moved else 'blocked'})")
        return moved

    def _visible_projection(self, obs: Observation, points: np.ndarray):
        """Pixels (u, v) of the points that are in view and not hidden behind a nearer surface."""
        u, v, z = project(points, obs.intrinsics, obs.T_world_cam)
        h, w = obs.depth.shape
        ui, vi = np.round(u).astype(int), np.round(v).astype(int)
        ok = (z > 0.05) & (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
        ui, vi, z = ui[ok], vi[ok], z[ok]
        d = obs.depth[vi, ui]
        seen = (d > 0) & (np.abs(d - z) < 0.08)
        return ui[seen], vi[seen]

    def _matching_mask(self, obs: Observation, target: Target, cls: str) -> np.ndarray | None:
        """The detection of ``cls`` in the latest frame that covers most of the target."""
        masks = [d.mask for d in self.last_detections if d.class_name == cls]
        if not masks:
            return None
        u, v = self._visible_projection(obs, target.points)
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

    def _grasp_pixel(self, obs: Observation, target: Target) -> tuple[int, int] | None:
        mask = self._matching_mask(obs, target, self.object_class)
        if mask is not None:
            mask = mask & (obs.depth > 0)
        if mask is not None and mask.sum() >= 5:
            vs, us = np.nonzero(mask)
            cu, cv = np.median(us), np.median(vs)
            i = int(np.argmin((us - cu) ** 2 + (vs - cv) ** 2))
            return int(us[i]), int(vs[i])
        u, v = self._visible_projection(obs, target.points)
        if len(u) >= 3:
            cu, cv = np.median(u), np.median(v)
            i = int(np.argmin((u - cu) ** 2 + (v - cv) ** 2))
            return int(u[i]), int(v[i])
        return None

    def _try_place(self, robot: RobotBackend, target: Target) -> None:
        cfg, reach = self.config.place, self.config.reach
        fp = np.asarray(target.footprint_xy, dtype=float)
        here = self._xy()
        nearest = fp[int(np.argmin(np.linalg.norm(fp - here, axis=1)))]
        inward = fp.mean(axis=0) - nearest
        n = float(np.linalg.norm(inward))
        spot = nearest + (inward / n * min(cfg.approach_inset, n) if n > 1e-6 else 0.0)
        surface = np.array([spot[0], spot[1], target.top])
        poses = approach_poses(surface + [0.0, 0.0, reach.place_lift], reach, self._checker())
        if not len(poses):
            self._fail(target, "no free standing pose to place from")
            return
        ok, _ = self._go(robot, poses[:, :2], self.config.gaze_goal_radius, poses[:, 2])
        if not ok:
            self._fail(target, "could not reach a place pose")
            return
        self._face(robot, surface)
        if not self._gaze(robot, surface).success:
            self._fail(target, "cannot look at the place point from the place pose")
            return
        obs = self._observe(robot)
        mask = self._matching_mask(obs, target, self.goal_class)
        chosen = None
        if mask is not None:
            inner = ndimage.binary_erosion(mask, iterations=cfg.mask_erosion_px) if cfg.mask_erosion_px else mask
            chosen = choose_place_point(backproject(obs, inner), obs.T_world_body, cfg)
        if chosen is None:   # not detected in this frame: what the camera sees near the mapped top
            pts = backproject(obs, stride=2)
            chosen = choose_place_point(pts[np.abs(pts[:, 2] - target.top) < 0.1], obs.T_world_body, cfg)
        if chosen is None:
            chosen = PlaceTarget(surface, cfg.drop_height if cfg.mode == "drop" else cfg.improved_height, 0)
            self.log.append("place: no detected surface in front; using the map's estimate")
        res = robot.place(chosen.point, release_height=chosen.release_height)
        self.log.append(f"place on {target.key} at {np.round(chosen.point, 2).tolist()}: {res.reason.value} {res.message}")
        robot.stow_arm()
        self.arm_stowed, self.arm_direction = True, None
        if res.success:
            self._finish("placed")
        else:
            self._fail(target, f"place failed ({res.reason.value})")

    # ================================================================== small helpers
    def _xy(self) -> np.ndarray:
        return np.array([self.pose.x, self.pose.y])
