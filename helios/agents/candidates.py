"""Candidates: what the agent may act on, built from the map (HELIOS) or from detections it
trusts (the trusting baseline).

A candidate of class c is an instance "whose class is" c (the paper's sets A, G, B): its most
likely class is c and its class score S_c reaches the role's threshold (cs_a for the start
receptacle, cs_g for the target object, cs_b for the goal receptacle); ``DecisionConfig.
candidate_class = "score_only"`` drops the first test. A target-object candidate must also rest on
a start-receptacle candidate (``AgentConfig.require_start_support``), since the task says "move X
*from* Y". Candidates are ordered by Psi, best first, which is the order the paper's decision
rule examines them in.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from helios.agents.config import AgentConfig
from helios.agents.observer import Observer
from helios.agents.target import Target
from helios.config import HeliosConfig
from helios.maps.instances import Instance


def is_candidate(inst: Instance, cls: str, threshold: float, method: HeliosConfig) -> bool:
    """The instance counts as a candidate of class ``cls`` (see the module doc)."""
    if inst.class_scores.get(cls, 0.0) < threshold:
        return False
    return method.decision.candidate_class == "score_only" or inst.class_name == cls


def still_candidate(observer: Observer, instance_id: int, cls: str, method: HeliosConfig) -> bool:
    """Whether the instance still exists and is still a candidate pick location of class ``cls``."""
    inst = next((i for i in observer.instances() if i.id == instance_id), None)
    return inst is not None and is_candidate(inst, cls, method.search.cs_start_receptacle, method)


def candidate_targets(observer: Observer, cls: str, config: AgentConfig, method: HeliosConfig,
                      failures: Counter) -> list[Target]:
    """Candidates for the object (or goal receptacle) class, best Psi first; candidates that
    failed ``max_failures_per_candidate`` times are left out."""
    if not config.flags.object_map:
        return [t for t in observer.trusted[cls] if failures[t.key] < config.max_failures_per_candidate]
    decision = method.decision
    cs = decision.cs_object if cls == observer.object_class else decision.cs_goal_receptacle
    out = []
    for inst in observer.instances():
        key = ("instance", inst.id)
        if not is_candidate(inst, cls, cs, method) or failures[key] >= config.max_failures_per_candidate:
            continue
        if cls == observer.object_class and config.require_start_support and \
                not rests_on_start_receptacle(observer, inst, config, method):
            continue
        points = observer.map.objects.means[inst.gaussian_indices].cpu().numpy().astype(float)
        out.append(Target(key, inst.centre, inst.footprint_xy, inst.max_height, inst.psi[cls], points, inst.id))
    return sorted(out, key=lambda t: -t.psi)


def rests_on_start_receptacle(observer: Observer, obj: Instance, config: AgentConfig, method: HeliosConfig) -> bool:
    """The object candidate rests on (or right next to) a start-receptacle candidate."""
    cs = method.search.cs_start_receptacle
    for inst in observer.instances():
        if inst.id == obj.id or not is_candidate(inst, observer.start_class, cs, method):
            continue
        d = np.min(np.linalg.norm(inst.footprint_xy - obj.centre[:2], axis=1))
        if d <= config.support_radius:
            return True
    return False


@dataclass
class SearchedLocations:
    """Candidate pick locations whose local search is over. The paper marks a location visited
    "after performing local search" and never searches it again. A search can end without a single
    view: each gaze point unreachable from where the robot stands (most often "blocked", a robot
    wedged at the edge of the known floor where an exploration step left it, so every plan fails
    at its first move and the whole queue is used up in an instant). That search never looked at
    the location. With ``retries`` > 0 (``AgentConfig.unviewed_search_retries``) such a location
    stays a candidate, up to ``retries`` searches without a view, and is offered again once the
    robot stands ``distance`` m or more from where the last of them ended (never at once: the
    robot would be as wedged as before). ``retries = 0``: visited after any search (the paper read
    literally)."""

    retries: int = 0
    distance: float = 1.0
    visited: set[int] = field(default_factory=set)
    unviewed: dict[int, tuple[int, np.ndarray]] = field(default_factory=dict)
    """instance -> (searches of it that took no view, robot position when the last one ended)"""

    def close(self, instance_id: int, views: int, here) -> bool:
        """The local search of ``instance_id`` ended after taking ``views`` views with the robot at
        ``here``; True if the location is now visited, False if it stays a candidate."""
        if views > 0 or self.retries == 0:
            self.visited.add(instance_id)
            return True
        count = self.unviewed.get(instance_id, (0, None))[0] + 1
        if count > self.retries:
            self.visited.add(instance_id)
            return True
        self.unviewed[instance_id] = (count, np.array(here, dtype=float))
        return False

    def is_open(self, instance_id: int, here) -> bool:
        """Whether the location may be offered to the global objective with the robot at ``here``."""
        if instance_id in self.visited:
            return False
        entry = self.unviewed.get(instance_id)
        return entry is None or float(np.linalg.norm(np.asarray(here, dtype=float) - entry[1])) >= self.distance
