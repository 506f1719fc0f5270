"""OVMM-style episode metrics, judged from simulator ground truth (agents never see the judge).

Phases are latched (once true, true for the rest of the episode) and chained, so
FindObj >= Pick >= FindRec >= Place >= SR over any set of episodes:

- **FindObj**: the body centre is within ``find_radius`` of a valid target object (horizontal
  distance) while that object covers at least ``min_coverage`` of the hand camera's pixels in an
  observation the agent took. Valid targets are all instances of the object category resting on a
  receptacle of the start category when the episode begins (any instance counts, as in OVMM).
- **Pick**: FindObj and the claw holds a valid target.
- **FindRec**: Pick and the same visibility test for a receptacle of the goal category, with the
  distance measured to the receptacle's footprint. The object in the claw sits right in front of
  the hand camera (as on the real Spot) and would blind this test, so the judge renders its own
  check view from the same camera pose with the near plane at ``held_clip`` metres.
- **Place**: FindRec, the claw holds nothing, and a valid target touches the top of a goal
  receptacle (a contact within ``surface_tolerance`` of one of its surfaces, not its side) while at
  rest (< 5e-3 m/s, < 5e-2 rad/s) for ``stability_steps`` consecutive physics steps.
- **SR**: Place and zero robot-scene collisions during the whole episode.

Each failed episode gets exactly one reason from ``FAILURE_REASONS`` (see ``EpisodeJudge.finalize``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from helios.schema import require_range
from robots.hal import Observation
from sim.camera import decode_body_ids
from sim.world import FURNITURE

CANDIDATE_MARGIN = 0.2
"""m: how far an agent's candidate centre may lie outside a receptacle's footprint and still be
that receptacle (``EpisodeJudge.start_receptacle_truth``; instance centres of a partly seen piece
of furniture sit inside it, those of a neighbour 0.2 m away do not)."""

FAILURE_REASONS = ("collision", "not_found", "misidentified", "pick_failed", "receptacle_not_found",
                   "place_failed", "fell_off", "timeout")


@dataclass(frozen=True)
class MetricsConfig:
    find_radius: float = 1.5          # m, body centre to a valid target (xy); Spot must stand near it
    rec_radius: float = 1.5           # m, body centre to a goal receptacle's footprint (xy)
    min_coverage: float = 0.001       # fraction of hand-camera pixels (OVMM: 1e-3)
    surface_tolerance: float = 0.03   # m, a contact counts as "on top" within this of a surface height
    stability_steps: int = 50         # consecutive at-rest physics steps for Place (OVMM: 50)
    final_settle_time: float = 5.0    # s of simulated time the judge waits for a released object
    held_clip: float = 0.30           # m, near plane of the FindRec check view (clips the held object)

    def __post_init__(self) -> None:
        require_range(self, "find_radius rec_radius", 0.0, 100.0, lo_open=True)
        require_range(self, "min_coverage", 0.0, 1.0, lo_open=True)
        require_range(self, "surface_tolerance", 0.0, 1.0, lo_open=True)
        require_range(self, "stability_steps", 1, 100000)
        require_range(self, "final_settle_time", 0.0, 3600.0)
        require_range(self, "held_clip", 0.0, 5.0)


@dataclass
class EpisodeMetrics:
    find_obj: bool = False
    pick: bool = False
    find_rec: bool = False
    place: bool = False
    success: bool = False
    collisions: int = 0
    failure_reason: str | None = None
    pick_attempts: int = 0
    picked_wrong_object: bool = False
    released_on: str | None = None     # what the released object first came to rest on
    object_final: tuple[float, float, float] | None = None
    find_obj_time: float | None = None
    """Simulated seconds from the episode's start to FindObj (None: never reached); with
    ``pick_time`` and ``find_rec_time`` the measure of *how fast* a policy searches, which
    separates two policies on episodes both complete (``tools report``: "found it first")."""
    pick_time: float | None = None
    find_rec_time: float | None = None

    def as_dict(self) -> dict:
        return asdict(self)


class EpisodeJudge:
    """Watches a simulated episode through the sim backend and the world, and scores it."""

    def __init__(self, backend, scene, episode, config: MetricsConfig = MetricsConfig()):
        self.backend = backend
        self.world = backend.world
        self.scene = scene
        self.episode = episode
        self.config = config
        self.metrics = EpisodeMetrics()
        world = self.world
        start_cat = episode.start_receptacle_category
        start_ids = {rid for name, rid in scene.receptacle_ids.items() if scene.receptacle(name).category == start_cat}
        from sim.grasping import support_body

        self.valid_targets = {oid for name, oid in scene.object_ids.items()
                              if world.bodies[oid].category == episode.object_category
                              and support_body(world, oid) in start_ids}
        self.target_supports = sorted({support_body(world, oid) for oid in self.valid_targets})
        self.goal_ids = {rid for name, rid in scene.receptacle_ids.items()
                         if scene.receptacle(name).category == episode.goal_receptacle_category}
        if not self.valid_targets:
            raise ValueError(f"episode {episode.episode_id}: no {episode.object_category} rests on a "
                             f"{start_cat} in scene {episode.scene.seed}")
        self.support_seen_time: float | None = None
        """When a start receptacle holding a valid target first covered ``min_coverage`` of a frame
        the agent took (any distance; None: never), for ``start_receptacle_truth``."""
        self._last_held: int | None = None
        self._released: int | None = None
        self._release_xy: np.ndarray | None = None
        self._release_radius = 0.05
        self._t0 = world.time

    def _now(self) -> float:
        return round(self.world.time - self._t0, 3)

    # ------------------------------------------------------------------ live updates
    def on_observation(self, obs: Observation) -> None:
        m = self.metrics
        ids = None
        if self.support_seen_time is None:
            ids = decode_body_ids(self.backend.segmentation_for(obs))
            if any(np.count_nonzero(ids == rid) >= self.config.min_coverage * ids.size for rid in self.target_supports):
                self.support_seen_time = self._now()
        if m.find_obj and (not m.pick or m.find_rec):
            return
        if ids is None:
            ids = decode_body_ids(self.backend.segmentation_for(obs))
        n = ids.size
        body_xy = obs.T_world_body[:2, 3]
        if not m.find_obj:
            for oid in self.valid_targets:
                if np.count_nonzero(ids == oid) >= self.config.min_coverage * n and \
                        np.linalg.norm(self.world.position(oid)[:2] - body_xy) <= self.config.find_radius:
                    m.find_obj = True
                    m.find_obj_time = self._now()
                    break
        if m.pick and not m.find_rec:
            # Distance first: the check view (a whole extra render) only where it can decide.
            near = [rid for rid in self.goal_ids if self._footprint_distance(rid, body_xy) <= self.config.rec_radius]
            if near and self.backend.held_body is not None:
                from dataclasses import replace

                from sim.camera import render

                cfg = replace(self.backend.config.camera, near=self.config.held_clip)
                ids = decode_body_ids(render(self.world, obs.intrinsics, obs.T_world_cam, cfg).segmentation)
            if any(np.count_nonzero(ids == rid) >= self.config.min_coverage * n for rid in near):
                m.find_rec = True
                m.find_rec_time = self._now()

    def after_command(self, name: str, result=None) -> None:
        m = self.metrics
        if name == "place" and self.backend.last_release is not None:
            body, position = self.backend.last_release
            size = self.world.bodies[body].extra.get("size", (0.1, 0.1, 0.1))
            self._release_xy = np.array(position[:2])
            self._release_radius = 0.5 * max(size[0], size[1])
        if name == "grasp":
            m.pick_attempts += 1
        held = self.backend.held_body
        if held is not None:
            if held in self.valid_targets:
                if m.find_obj and not m.pick:
                    m.pick = True
                    m.pick_time = self._now()
            else:
                m.picked_wrong_object = True
        elif self._last_held is not None:
            self._released = self._last_held
        self._last_held = held

    # ------------------------------------------------------------------ end of episode
    def finalize(self, limit_hit: bool) -> EpisodeMetrics:
        """Wait for released objects to settle, judge Place/SR and pick one failure reason.

        Reasons, by the first phase that failed: never found the object -> ``not_found`` (or
        ``timeout`` when the episode ran out of time); grasped a wrong object -> ``misidentified``;
        found but never held -> ``pick_failed``; held but no goal receptacle found ->
        ``receptacle_not_found`` (``timeout`` likewise) unless it was put down on a receptacle of the
        wrong category -> ``misidentified``; released on a goal receptacle but it did not stay there ->
        ``fell_off``; anything else at the place stage -> ``place_failed`` (``timeout`` if the
        object was still in the claw when time ran out); all phases done but a collision happened
        -> ``collision``.
        """
        m = self.metrics
        world = self.world
        m.collisions = len(self.backend.collision_events)
        candidates = [b for b in self.valid_targets if b != self.backend.held_body]
        if self.backend.held_body is None and candidates:
            on_goal_steps = 0
            max_steps = int(self.config.final_settle_time / world.timestep)
            for _ in range(max_steps):
                if any(self._on_goal(b) and world.is_at_rest(b) for b in candidates):
                    on_goal_steps += 1
                    if on_goal_steps >= self.config.stability_steps:
                        break
                else:
                    on_goal_steps = 0
                    if all(world.is_at_rest(b) for b in candidates) and not any(self._on_goal(b) for b in candidates):
                        break   # everything is still and nothing is on a goal: no need to wait
                world.step()
            placed = on_goal_steps >= self.config.stability_steps
            m.place = bool(m.find_rec and placed)
        if self._released is not None:
            from sim.grasping import support_body

            sup = support_body(world, self._released)
            m.released_on = world.bodies[sup].name if sup is not None else None
            m.object_final = tuple(float(v) for v in world.position(self._released))
        m.success = bool(m.place and m.collisions == 0)
        m.failure_reason = None if m.success else self._reason(limit_hit)
        return m

    def _reason(self, limit_hit: bool) -> str:
        m = self.metrics
        if m.place:
            return "collision"
        if not m.find_obj:
            return "misidentified" if m.picked_wrong_object else ("timeout" if limit_hit else "not_found")
        if not m.pick:
            if m.picked_wrong_object:
                return "misidentified"
            return "timeout" if limit_hit and m.pick_attempts == 0 else "pick_failed"
        wrong_place = self._released is not None and m.released_on is not None and \
            self.world.body(m.released_on).kind == FURNITURE and self.world.body(m.released_on).body_id not in self.goal_ids
        if not m.find_rec:
            if wrong_place:
                return "misidentified"     # put down on a receptacle of the wrong category
            return "timeout" if limit_hit else "receptacle_not_found"
        if self.backend.held_body is not None:
            return "timeout" if limit_hit else "place_failed"
        if self._released is not None:
            rest = self.world.body(m.released_on) if m.released_on else None
            if rest is not None and rest.body_id in self.goal_ids:
                return "fell_off"          # touching the goal, but not resting on its top
            over_goal = self._release_xy is not None and any(   # let go with the object over the goal
                self._footprint_distance(g, self._release_xy) <= self._release_radius for g in self.goal_ids)
            if over_goal:
                return "fell_off"          # released above the goal, came to rest elsewhere
            if rest is not None and rest.kind == FURNITURE:
                return "misidentified"     # put down on a receptacle of the wrong category
        return "place_failed"

    # ------------------------------------------------------------------ the search, checked
    def start_receptacle_truth(self, choices) -> dict:
        """How the agent's global search treated the start receptacle(s) the object rests on.

        ``choices``: the agent's global decisions with open candidates, in order, each
        ``{"chosen": instance id or None (a frontier), "candidates": [[id, x, y], ...]}``
        (``HeliosAgent.decision_stats()["global_choices"]``). An offered candidate is that
        receptacle when its centre lies within ``CANDIDATE_MARGIN`` of the footprint of a start
        receptacle holding a valid target. Returns ``decisions``, ``offered`` (decisions in which
        it was among the open candidates), ``chosen`` (decisions that chose it) and
        ``first_offered`` (1-based index of the first decision that offered it; None: never);
        ``viewed``, of the decisions that chose it, those whose local search took at least one view
        (each choice's ``views``; None when the choices do not say: a search whose every gaze
        point failed, unreachable or without room to look, never looked at the receptacle).
        ``in_view`` is when that receptacle first covered ``min_coverage`` of a frame the agent
        took (simulated s; None: never). Offered but never chosen means the policy passed over the
        right receptacle until the end; never offered and never in view means the search never
        looked its way (coverage); in view but never offered, that the detector and the candidate
        test did not take it for one (recognition)."""
        offered = chosen = viewed = 0
        first = None
        for i, choice in enumerate(choices, start=1):
            true_ids = {int(c[0]) for c in choice["candidates"]
                        if any(self._footprint_distance(rid, np.asarray(c[1:3], dtype=float)) <= CANDIDATE_MARGIN
                               for rid in self.target_supports)}
            if not true_ids:
                continue
            offered += 1
            first = i if first is None else first
            hit = choice["chosen"] is not None and int(choice["chosen"]) in true_ids
            chosen += int(hit)
            viewed += int(hit and bool(choice.get("views")))
        views_known = all("views" in c for c in choices if c["chosen"] is not None)
        return {"decisions": len(choices), "offered": offered, "chosen": chosen, "first_offered": first,
                "in_view": None if self.support_seen_time is None else float(self.support_seen_time),
                "viewed": viewed if views_known else None}

    # ------------------------------------------------------------------ geometry
    def _on_goal(self, body: int) -> bool:
        for pt in self.world.client.getContactPoints(bodyA=body):
            other = pt[2]
            if other not in self.goal_ids:
                continue
            z = pt[6][2]
            for centre, _half in self.world.bodies[other].extra.get("surfaces", []):
                if abs(z - centre[2]) <= self.config.surface_tolerance:
                    return True
        return False

    def _footprint_distance(self, body: int, xy: np.ndarray) -> float:
        lo, hi = self.world.aabb(body)
        d = np.maximum(np.maximum(lo[:2] - xy, 0.0), xy - hi[:2])
        return float(np.linalg.norm(d))
