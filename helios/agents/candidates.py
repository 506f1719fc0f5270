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
