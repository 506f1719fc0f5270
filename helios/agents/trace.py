"""What a HELIOS agent knows, read out for the per-episode pictures of a trial report.

Two read-only views of an agent's public attributes (nothing here changes the agent, so an
episode ends the same with pictures on or off). Both accept any agent and return None when it
has no such state (the oracle, scripted agents):

- :func:`latest_detection`: the newest frame the agent has processed and its kept detections of
  one class (the trial instrumentation keeps the frame where the target was first detected);
- :func:`snapshot`: at the end of an episode, the occupancy map (obstacle / explored cells and
  the grid geometry), the frontiers the global objectives chose (with their values), the object
  candidates with their Psi for the task's classes, the phase and the end of the agent's log.
"""

from __future__ import annotations

import numpy as np

LOG_LINES = 15          # the end of the agent's log kept in a snapshot


def latest_detection(agent, class_name: str):
    """(frame, masks) of the newest frame ``agent`` processed: the frame (an Observation) and the
    boolean masks of its kept detections of ``class_name`` (maybe none); None for an agent
    without an observer or before its first frame."""
    observer = getattr(agent, "observer", None)
    obs = getattr(observer, "last_obs", None)
    if obs is None:
        return None
    masks = [d.mask for d in getattr(observer, "last_detections", ()) if d.class_name == class_name]
    return obs, masks


def snapshot(agent) -> dict | None:
    """The agent's state at the end of an episode for the top-down picture; None without a map.

    Keys: ``cell_size``, ``origin_xy`` (world x, y of cell (0, 0)'s corner), ``obstacle`` and
    ``explored`` (bool arrays indexed [row (y), col (x)]; the agent's own arrays, not copies),
    ``explored_bounds`` ((row0, row1, col0, col1) half-open, or None), ``frontiers`` ({"pick": [(x,
    y, value)], "place": [...]} in the order chosen), ``candidates`` (dicts with ``id``,
    ``class_name``, ``xy``, ``psi``: {class: Psi} for the task's classes), ``phase``, ``log``."""
    hmap = getattr(agent, "map", None)
    if hmap is None:
        return None
    geo, occ = hmap.geometry, hmap.occupancy
    classes = [c for c in dict.fromkeys((getattr(agent, "object_class", None), getattr(agent, "start_class", None),
                                         getattr(agent, "goal_class", None))) if c]
    frontiers = {}
    for key, attr in (("pick", "pick_objective"), ("place", "place_objective")):
        objective = getattr(agent, attr, None)
        chosen = getattr(objective, "chosen_frontiers", None) or []
        frontiers[key] = [(float(xy[0]), float(xy[1]), float(v)) for xy, v in chosen]
    candidates = []
    observer = getattr(agent, "observer", None)
    if observer is not None:
        for inst in observer.instances():
            if inst.class_name not in classes:
                continue
            candidates.append({"id": int(inst.id), "class_name": inst.class_name,
                               "xy": [float(inst.centre[0]), float(inst.centre[1])],
                               "psi": {c: round(float(inst.psi[c]), 3) for c in classes if c in inst.psi}})
        for cls, targets in (getattr(observer, "trusted", None) or {}).items():
            for t in targets:                       # the trusting baseline: detections taken as they come
                candidates.append({"id": -1, "class_name": cls, "xy": [float(t.centre[0]), float(t.centre[1])],
                                   "psi": {cls: round(float(t.psi), 3)}})
    phase = getattr(agent, "phase", None)
    return {"cell_size": float(geo.cell_size), "origin_xy": (float(geo.origin_x), float(geo.origin_y)),
            "obstacle": np.asarray(occ.obstacle, dtype=bool), "explored": np.asarray(occ.explored, dtype=bool),
            "explored_bounds": occ.explored_bounds, "frontiers": frontiers, "candidates": candidates,
            "phase": getattr(phase, "value", None if phase is None else str(phase)),
            "log": [str(line) for line in list(getattr(agent, "log", []) or [])[-LOG_LINES:]]}
