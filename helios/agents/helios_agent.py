"""The HELIOS agent and its ablations: one phase machine, variants chosen by typed flags (the
paper's Sec. 3.3 and its flow chart).

Each ``act`` call makes one decision and carries it out through the HAL:

1. **Pick phase.** Target-object candidates (:mod:`helios.agents.candidates`) are judged with
   the decision rule (:mod:`helios.search.decisions`): grasp when Psi_g >= tau_g (the pick skill,
   :mod:`helios.agents.pick`); else take the one view (gaze point) with the highest predicted
   Psi'_g if Psi'_g >= min(tau_g, Psi_g + tau_inc); else leave it.
2. Otherwise continue a running **local search** (a candidate pick location's informative gaze
   points, or all of them as in the paper: ``AgentConfig.local_search_views``; nearest first;
   the location is then marked visited), or consult the **global objective**
   (:mod:`helios.search.objective`): locally search the best candidate pick location or walk
   towards the best frontier and look around.
3. **Place phase** (holding the object): the same rule for goal-receptacle candidates (tau_b)
   and the place skill (:mod:`helios.agents.place`); otherwise the frontier with the highest
   value for the goal receptacle. A claw that no longer holds the object (it slipped out on the
   way; the paper is silent) is back in the pick phase: search for the object again.

The rooms: :mod:`~helios.agents.observer` (what the agent sees, the map), :mod:`~helios.agents.body` (pose,
arm, planning, walking, looking), :mod:`~helios.agents.pick`/:mod:`~helios.agents.place` (the skills, returning a
:class:`~helios.agents.skill.SkillOutcome`), and this module (the decision).

Variants (``AgentConfig.variant``, read as :class:`~helios.agents.config.VariantFlags`): ``helios``;
``no_global`` (candidates always before frontiers); ``trusting`` (no Gaussian layer, no gaze points,
no objective: the highest-value frontier until the detector reports the object, which it then grasps;
likewise for the goal receptacle). The 50-50 IG ablation is ``HeliosConfig.search.information_gain``;
ground-truth semantics is a property of the detector/scorer passed in. The agent sees the world only
through ``observe()`` and the detector/scorer it was given.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from enum import Enum
from typing import Sequence

import numpy as np

from helios.agents.activities import ACTIVITIES, DECISION_COUNTS  # noqa: F401  (ACTIVITIES: re-exported)
from helios.agents.body import Body
from helios.agents.candidates import candidate_targets, is_candidate, still_candidate
from helios.agents.config import AgentConfig
from helios.agents.frontier_goals import StallWatch, frontier_options, revisit_goals
from helios.agents.geometry import away_from, facing, fresh_views, gaze_cameras
from helios.agents.observer import Observer
from helios.agents.pick import pick
from helios.agents.place import place
from helios.agents.target import Target
from helios.config import HeliosConfig
from helios.maps.hierarchical import HierarchicalMap
from helios.perception.detection import Detector, ImageTextScorer
from helios.planning.fmm import FMMPlanner
from helios.search.decisions import Verdict, decide
from helios.search.gaze_points import GazePoint, gaze_points, visiting_order
from helios.search.information import best_view_prediction, informative_views, views_information_gain
from helios.search.objective import CandidateLocation, FrontierOption, GlobalObjective
from robots.hal import RobotBackend, SE2Pose


class Phase(Enum):
    """Where the episode stands: the start scan, searching and picking, carrying and placing, done."""

    START = "start"
    PICK = "pick"
    PLACE = "place"
    DONE = "done"


@dataclass
class _LocalSearch:
    instance_id: int
    queue: list[GazePoint] = field(default_factory=list)
    choice: dict | None = None     # the global decision that chose it (see decision_stats), views counted there


class HeliosAgent:
    """HELIOS (and its ablations) behind the runner's Agent protocol (``reset``, ``act``).

    ``search_policy``: the pick phase's choice between candidates and frontiers, made per episode as
    ``search_policy(method.search, cell_size, mode)`` (default: the paper's :class:`GlobalObjective`);
    a policy of your own has its interface (``choose``, ``calibrated``, ``note_frontier_chosen``)."""

    def __init__(self, detector: Detector, scorer: ImageTextScorer, config: AgentConfig = AgentConfig(),
                 method: HeliosConfig = HeliosConfig(), name: str = "helios", search_policy=GlobalObjective):
        self.detector, self.scorer, self.config, self.method = detector, scorer, config, method
        self.name, self.search_policy = name, search_policy
        self.planner = FMMPlanner(config.planner)
        self.log: list[str] = []
        self.observer: Observer | None = None

    @property
    def map(self) -> HierarchicalMap | None:
        return self.observer.map if self.observer is not None else None

    # ================================================================== episode life cycle
    def reset(self, task, rng: np.random.Generator) -> None:
        """Start an episode. ``rng`` is part of the runner's protocol; HELIOS draws no random numbers."""
        self.task = task
        self.object_class = task.object
        self.start_class = task.start_receptacle
        self.goal_class = task.goal_receptacle
        self.log = []
        self.timings: Counter = Counter()   # wall seconds per stage: perception, map, planning
        self.observer = Observer(self.detector, self.scorer, self.config, self.method, task, self.timings)
        self.body = Body(self.config, self.planner, self.observer, self.log, self.timings)
        cell = self.map.geometry.cell_size
        self.pick_objective = self.search_policy(self.method.search, cell, self.config.flags.pick_objective)
        self.place_objective = GlobalObjective(self.method.search, cell, "frontiers_only")
        self.phase = Phase.START
        self.pick_attempts, self.grasp_frame = 0, None
        self.visited: set[int] = set()
        self.local: _LocalSearch | None = None
        self.viewed: defaultdict[tuple, list] = defaultdict(list)   # per candidate: where its extra views were taken
        self.failures: Counter = Counter()
        self.reached: list[np.ndarray] = []        # frontiers walked to and looked past
        self.unreachable: list[np.ndarray] = []    # goals the planner or the walk failed on
        self.rescued_at: np.ndarray | None = None
        self.revisited: list[np.ndarray] = []
        self._frontier_cells: dict[int, np.ndarray] = {}
        self.last_frontier: np.ndarray | None = None
        self.stall = StallWatch(self.config) if self.config.stall_steps else None
        self._logged = 0
        self.decisions = 0
        self.activity = "start_scan"
        """What the latest ``act`` did, one of ``ACTIVITIES`` (the runner times each)."""
        self.stats: Counter = Counter()   # decision counts, see decision_stats()
        self.choices: list[dict] = []     # global decisions with open candidates, see decision_stats()
        self._last_choice: dict | None = None   # the latest of them, if the latest decision was one
        self.local_search_sizes: list[int] = []

    def act(self, robot: RobotBackend) -> bool:
        self.decisions += 1
        if self.phase is Phase.START:
            self.activity = "start_scan"
            self.body.start_scan(robot)
            self.phase = Phase.PICK
            return False
        if self.phase is Phase.PICK:
            self._pick_step(robot)
        elif self.phase is Phase.PLACE:
            self._place_step(robot)
        return self.phase is Phase.DONE

    # ================================================================== hooks for trial batches
    def memory_bytes(self) -> dict[str, int]:
        """Bytes of the agent's map per layer (sampled by the trial instrumentation)."""
        return self.map.memory_bytes() if self.map is not None else {}

    def record(self, recorder) -> None:
        """Log what the agent knows to an episode recording (an ``EpisodeRecorder``)."""
        if self.map is None:
            return
        recorder.log_map(self.map)
        recorder.log_detections(self.observer.last_detections, self.observer.query_classes)
        plan = self.body.last_plan
        if plan is not None and plan.waypoints:
            recorder.log_path("plan", [(w.x, w.y, 0.05) for w in plan.waypoints])
        for line in self.log[self._logged:]:
            recorder.log_text(line)
        self._logged = len(self.log)

    def decision_stats(self) -> dict:
        """What the agent decided this episode, for the trial report (``DECISION_COUNTS``; their meaning:
        ``tasks.decisions``), the gaze points planned per local search, and ``global_choices``: per
        decision with open candidates, those offered (``[id, x, y]``, world metres), the one chosen
        (None: a frontier) and its search's ``views`` (checked, then dropped)."""
        out = {k: int(self.stats.get(k, 0)) for k in DECISION_COUNTS}
        out["local_search_sizes"] = list(self.local_search_sizes)
        if self.config.flags.object_map:      # agents without candidates (trusting) have nothing to check
            out["global_choices"] = list(self.choices)
        return out

    # ================================================================== the decision
    def _pick_step(self, robot: RobotBackend) -> None:
        limit = self.config.max_pick_attempts
        if limit and self.pick_attempts >= limit:
            self._finish(f"pick attempt limit ({limit}) reached")
            return
        target, verdict, view = self._judge_targets(self.object_class)
        if verdict is Verdict.ACT:
            self.activity = "pick"
            outcome = pick(robot, self.body, self.observer, target, self.config)
            self.pick_attempts += outcome.attempted
            if outcome.ok:           # the frames after the grasp frame say whether the claw still holds it
                self.phase, self.grasp_frame = Phase.PLACE, self.observer.last_obs
            else:
                self._fail(target, outcome.reason)
            return
        if verdict is Verdict.LOOK:
            self.activity = "local_search"
            self.stats["extra_views_object"] += 1
            self._take_view(robot, target, view)
            return
        if self.local is not None:
            self.activity = "local_search"
            self._continue_local_search(robot)
            return
        choice, frontiers = self._global_choice()
        if choice is None:
            self.activity = "exploration"
            if not self._rescue(robot) and not self._revisit(robot, self.start_class):
                self._finish("nothing left to search for the object")
        elif choice.kind == "candidate":
            self.activity = "local_search"
            self._start_local_search(choice.index, self._last_choice)
            self._continue_local_search(robot)
        else:
            self.activity = "exploration"
            self._explore(robot, frontiers[choice.index], self.pick_objective)

    def _place_step(self, robot: RobotBackend) -> None:
        if self.observer.last_obs is not self.grasp_frame and not self.observer.last_obs.holding:
            self.log.append("the claw no longer holds the object: searching for it again")
            self.stats["claw_drops"] += 1
            self.phase, self.local = Phase.PICK, None      # not the local search the grasp interrupted
            return
        target, verdict, view = self._judge_targets(self.goal_class)
        self.activity = "carry"
        if verdict is Verdict.ACT:
            self.activity = "place"
            outcome = place(robot, self.body, self.observer, target, self.config)
            if outcome.ok:
                self._finish("placed")
            else:
                self._fail(target, outcome.reason)
            return
        if verdict is Verdict.LOOK:
            self.stats["extra_views_goal"] += 1
            self._take_view(robot, target, view)
            return
        options = self._frontier_options(self.goal_class)
        choice = self.place_objective.choose(self.body.xy(), [], options)
        if choice is None:
            if not self._rescue(robot) and not self._revisit(robot, self.goal_class):
                self._finish("nothing left to search for the goal receptacle")
            return
        self._explore(robot, options[choice.index], self.place_objective)

    def _finish(self, why: str) -> None:
        self.log.append(f"done: {why}")
        self.phase = Phase.DONE

    def _fail(self, target: Target, why: str) -> None:
        self.failures[target.key] += 1
        self.log.append(f"{target.key}: {why}")

    # ------------------------------------------------------------------ candidates
    def _judge_targets(self, cls: str) -> tuple[Target | None, Verdict, GazePoint | None]:
        """The paper's rule over the candidates: act on the best confident one, else the first
        one worth another view, else nothing; the trusting baseline acts on its first target."""
        targets = candidate_targets(self.observer, cls, self.config, self.method, self.failures)
        if not self.config.flags.object_map:    # Psi 1 reaches any tau: it reads no decision setting
            return (targets[0], Verdict.ACT, None) if targets else (None, Verdict.IGNORE, None)
        decision = self.method.decision
        tau = decision.tau_object if cls == self.object_class else decision.tau_goal_receptacle
        for t in targets:
            if t.psi >= tau:
                return t, Verdict.ACT, None
        for t in (t for t in targets if len(self.viewed[t.key]) < self.config.max_looks_per_candidate):
            view, predicted = self._best_view(t, cls)
            if decide(t.psi, predicted, tau, decision.tau_increase) is Verdict.LOOK:
                return t, Verdict.LOOK, view
        return None, Verdict.IGNORE, None

    def _best_view(self, t: Target, cls: str) -> tuple[GazePoint | None, float | None]:
        """The gaze point whose view would give the highest Psi' (under ``view_prediction``), and
        the Psi' that decides whether to take it (``view_prediction_poses``)."""
        decision = self.method.decision
        assumption = "optimistic" if decision.view_prediction == "optimistic" \
            else self.method.search.information_gain
        views = fresh_views(self._gaze_points_of(t.instance_id), self.viewed[t.key], self.config.fresh_view_distance)
        i, psi = best_view_prediction(self.map.objects, t.instance_id, cls, self.observer.last_obs.intrinsics,
                                      gaze_cameras(views, self.body.body_height, self.config.view), assumption,
                                      decision.view_prediction_poses)
        return (None if i is None else views[i]), psi

    def _gaze_points_of(self, instance_id: int) -> list[GazePoint]:
        """The instance's gaze points on seen floor, away from goals found unreachable (cached per frame)."""
        cache = self.observer.cache
        key = ("gaze", instance_id)
        if key not in cache:
            inst = next((i for i in self.observer.instances() if i.id == instance_id), None)
            if inst is None:
                cache[key] = []
            else:
                occ = self.map.occupancy
                pts = gaze_points(inst.footprint_xy, inst.max_height, self.map.geometry, occ.obstacle, occ.max_height,
                                  self.body.checker(), self.config.gaze, centre_xy=inst.centre[:2],
                                  can_look=self.body.can_look_from)
                rows, cols = self.map.geometry.world_to_cell(np.array([[g.pose.x, g.pose.y] for g in pts]).reshape(-1, 2))
                known = occ.explored[rows, cols] if len(pts) else np.zeros(0, dtype=bool)
                cache[key] = [g for g, k in zip(pts, known) if k and not self._blacklisted(g.pose)]
        return cache[key]

    # ------------------------------------------------------------------ global search
    def _global_choice(self):
        """The objective's pick among candidate pick locations and frontiers."""
        cands: list[CandidateLocation] = []
        if self.config.flags.object_map:
            cs = self.method.search.cs_start_receptacle
            intr = self.observer.last_obs.intrinsics
            for inst in self.observer.instances():
                if inst.id in self.visited or not is_candidate(inst, self.start_class, cs, self.method):
                    continue
                views = self._gaze_points_of(inst.id)
                if not views:
                    continue
                cams = gaze_cameras(views, self.body.body_height, self.config.view)
                ig = views_information_gain(self.map.objects, inst.id, self.start_class, intr, cams,
                                            self.method.search.information_gain, self.method.search.candidate_gain)
                cands.append(CandidateLocation(inst.id, inst.centre, inst.class_scores[self.start_class], ig))
        frontiers = self._frontier_options(self.start_class)
        calibrated = self.pick_objective.calibrated
        choice = self.pick_objective.choose(self.body.xy(), cands, frontiers)
        self._last_choice = None
        if cands and choice is not None:
            self.stats["global_with_candidates"] += 1
            self.stats[f"chose_{choice.kind}_{'after' if calibrated else 'before'}_f0"] += 1
            self._last_choice = {"chosen": choice.index if choice.kind == "candidate" else None,
                                 "candidates": [[c.instance_id, float(c.centre[0]), float(c.centre[1])] for c in cands]}
            self.choices.append(self._last_choice)
        return choice, frontiers

    def _frontier_options(self, layer: str) -> list[FrontierOption]:
        out, self._frontier_cells = frontier_options(self.map.frontiers(), layer, self.map.geometry, self.reached,
                                                     self.unreachable, self.config)
        return out

    def _mark_unreachable(self, xy) -> None:
        """Blacklist a goal the planner or the walk failed on (see ``Observer.goals_changed``)."""
        self.unreachable.append(np.asarray(xy, dtype=float))
        self.observer.goals_changed()

    def _blacklisted(self, pose: SE2Pose, radius: float = 0.3, extra: Sequence[np.ndarray] = ()) -> bool:
        return any(math.hypot(pose.x - b[0], pose.y - b[1]) < radius for b in (*self.unreachable, *extra))

    def _explore(self, robot: RobotBackend, frontier: FrontierOption, objective: GlobalObjective) -> None:
        """One stretch towards a frontier, then look around."""
        body = self.body
        if self.last_frontier is None or np.linalg.norm(self.last_frontier - frontier.xy) > 0.5:
            objective.note_frontier_chosen(frontier)
            self.last_frontier = np.asarray(frontier.xy, dtype=float)
        # any part of the frontier will do: its centre may sit in a corner the body cannot reach
        goals = parts = self._frontier_cells.get(frontier.key, np.asarray(frontier.xy, dtype=float)[None])
        start = body.xy()
        if self.config.frontier_parts:
            near = ~away_from(goals, [start], self.config.frontier_reach)
            if near.all():       # every unreached part is within reach already: look, done
                self.reached.extend(goals)
                body.look_from_frontier(robot, facing(body.pose, frontier.xy), goals)
                return
            goals = goals[~near]
        plan = body.plan(goals, self.config.frontier_reach)
        approach = self.config.frontier_approach
        if not plan.success and approach > self.config.frontier_reach:
            plan = body.plan(goals, approach)      # see AgentConfig.frontier_approach
            if plan.success:
                self.log.append(f"frontier ({frontier.xy[0]:.1f}, {frontier.xy[1]:.1f}) out of reach: "
                                f"looking at it from within {approach:.1f} m")
        if not plan.success:
            if not (plan.reason == "blocked" and body.unstick(robot)):
                self._mark_unreachable(frontier.xy)
                self.log.append(f"frontier ({frontier.xy[0]:.1f}, {frontier.xy[1]:.1f}) unreachable: {plan.reason}")
            return
        if plan.waypoints and not body.execute(robot, plan):
            self._mark_unreachable(frontier.xy)
        arrived = plan.reaches_goal or not plan.waypoints
        if arrived:
            self.reached.append(np.asarray(frontier.xy, dtype=float))
        body.look_from_frontier(robot, facing(body.pose, frontier.xy) if arrived else None, parts)
        if self.config.frontier_parts and not arrived and np.linalg.norm(body.xy() - start) < 0.25 \
                and not body.unstick(robot):
            self._mark_unreachable(frontier.xy)     # blocked at the first step: never loop on it
            self.log.append(f"frontier ({frontier.xy[0]:.1f}, {frontier.xy[1]:.1f}): no way forward")
        elif self.stall and not arrived and (n := self.stall.stalled(frontier.xy, body.xy(), self.map.occupancy)):
            self._mark_unreachable(frontier.xy)     # see AgentConfig.stall_steps
            self.stats["frontiers_given_up"] += 1
            self.log.append(f"frontier ({frontier.xy[0]:.1f}, {frontier.xy[1]:.1f}): "
                            f"{n + 1} steps without progress, given up")

    def _revisit(self, robot: RobotBackend, layer: str) -> bool:
        """No frontier left: walk to the most promising seen place (highest value-map score for
        ``layer``, away from places already revisited) and look all around it again; detections
        are view-dependent, so a second look from elsewhere may find what the first missed."""
        if len(self.revisited) >= self.config.max_revisits:
            return False
        goals = revisit_goals(self.map.occupancy, self.map.geometry, self.map.values.layer(layer),
                              [*self.revisited, self.body.xy()], self.config)
        if not len(goals):
            return False
        self.revisited.append(goals[0])       # counted even if the walk fails: never loop
        ok, i = self.body.go(robot, goals, 0.3)
        if ok:
            self.revisited[-1] = goals[i]
            self.log.append(f"revisit ({goals[i][0]:.1f}, {goals[i][1]:.1f}) for the {layer}")
            self.body.look_all_around(robot)
        return True

    def _rescue(self, robot: RobotBackend) -> bool:
        """Before giving up: look all around (near floor included) from here, once per place, and
        forget which goals were unreachable; a boxed-in start or a narrow passage often opens up
        once the floor beside the robot has been seen. False if already done here."""
        here = self.body.xy()
        if self.rescued_at is not None and np.linalg.norm(self.rescued_at - here) < 0.5:
            return False
        self.rescued_at = here
        self.unreachable.clear()
        self.log.append("stuck: looking all around before giving up")
        self.body.look_all_around(robot)
        return True

    # ------------------------------------------------------------------ local search and views
    def _start_local_search(self, instance_id: int, choice: dict | None = None) -> None:
        views = list(self._gaze_points_of(instance_id))
        if self.config.local_search_views == "informative" and len(views) > 1:
            cams = gaze_cameras(views, self.body.body_height, self.config.view)
            keep = informative_views(self.map.objects, instance_id, self.start_class, self.observer.last_obs.intrinsics,
                                     cams, self.config.local_search_min_gain, self.method.search.information_gain)
            views = [views[i] for i in sorted(keep)]
        order = visiting_order(views, self.body.xy())
        if choice is not None:
            choice["views"] = 0
        self.local = _LocalSearch(instance_id, order, choice)
        self.local_search_sizes.append(len(order))
        self.log.append(f"local search of instance {instance_id}: {len(order)} gaze points")

    def _continue_local_search(self, robot: RobotBackend) -> None:
        iid, cls = self.local.instance_id, self.start_class
        if self.config.end_local_search_on_doubt and not still_candidate(self.observer, iid, cls, self.method):
            self.log.append(f"local search of instance {iid} ended: no longer a {cls} candidate")
            self.local.queue.clear()
        else:
            self.stats["gaze_point_visits"] += 1
            if self.body.view_from(robot, self.local.queue.pop(0)):
                self.stats["gaze_point_views"] += 1
                if self.local.choice is not None:
                    self.local.choice["views"] += 1
        if not self.local.queue:
            self.visited.add(self.local.instance_id)
            self.local = None

    def _take_view(self, robot: RobotBackend, target: Target, view: GazePoint) -> None:
        spot = (view.pose.x, view.pose.y)
        self.viewed[target.key].append(spot)
        if not self.body.view_from(robot, view):
            self._mark_unreachable(spot)
