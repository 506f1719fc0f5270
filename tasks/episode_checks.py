"""Checks of an episode against the home it names, before anything runs.

An episode file can be well-formed (``tasks.episodes`` checks every field) and still describe an
episode that cannot run or would be scored as nonsense: a target instance the home does not
have, a receptacle of another category, a start pose outside the home. The home's layout is
plain data generated from the episode's scene seed (``sim.scenes.layout``, ~0.1 s, no physics),
so these checks run at the command-line boundary: a DatasetError naming the episode, never a
traceback from inside a worker and never a scored result.
"""

from __future__ import annotations

from typing import Callable, Iterable

from tasks.episodes import DatasetError, Episode


def check_episode_homes(episodes: Iterable[Episode], source: str = "",
                        progress: Callable[[int, int], None] | None = None) -> None:
    """Raise DatasetError for the first episode that does not fit the home its scene seed makes.
    ``progress(done, total)`` is called after each home generated (there are as many as scene seeds)."""
    from helios.schema import short_repr
    from sim.scenes.layout import generate_layout

    layouts: dict = {}
    where = f" in {source}" if source else ""
    episodes = list(episodes)
    homes = len({(ep.scene.seed, ep.scene.min_size, ep.scene.max_size) for ep in episodes})
    for ep in episodes:
        name = f"episode {short_repr(ep.episode_id, 60)}{where}"
        key = (ep.scene.seed, ep.scene.min_size, ep.scene.max_size)
        if key not in layouts:
            try:
                layouts[key] = generate_layout(ep.scene.seed, ep.scene.layout_config())
            except Exception as exc:  # noqa: BLE001 - any failure of the generator is this episode's fault
                raise DatasetError(f"{name}: its home (scene seed {ep.scene.seed}) cannot be generated: "
                                   f"{type(exc).__name__}: {short_repr(str(exc), 120)}") from None
            if progress is not None:
                progress(len(layouts), homes)
        problem = episode_problem(ep, layouts[key])
        if problem:
            raise DatasetError(f"{name}: {problem}; the episode file does not match this version of the "
                               f"scene generator")


def episode_problem(ep: Episode, layout) -> str | None:
    """Why ``ep`` does not fit ``layout`` (a ``sim.scenes.layout.HomeLayout``), or None."""
    from helios.schema import short_repr

    objects = {o.name: o for o in layout.objects}
    receptacles = {r.name: r for r in layout.receptacles}
    target = objects.get(ep.target_object)
    if target is None:
        return f"target object {short_repr(ep.target_object, 60)} is not in its home (scene {ep.scene.seed})"
    if target.category != ep.object_category:
        return f"target object {ep.target_object!r} is a {target.category}, not a {ep.object_category}"
    start = receptacles.get(ep.start_receptacle)
    if start is None:
        return f"start receptacle {short_repr(ep.start_receptacle, 60)} is not in its home (scene {ep.scene.seed})"
    if start.category != ep.start_receptacle_category:
        return f"start receptacle {ep.start_receptacle!r} is a {start.category}, not a {ep.start_receptacle_category}"
    if target.receptacle != ep.start_receptacle:
        return f"target object {ep.target_object!r} rests on {target.receptacle!r}, not on {ep.start_receptacle!r}"
    for goal in ep.goal_receptacles:
        rec = receptacles.get(goal)
        if rec is None:
            return f"goal receptacle {short_repr(goal, 60)} is not in its home (scene {ep.scene.seed})"
        if rec.category != ep.goal_receptacle_category:
            return f"goal receptacle {goal!r} is a {rec.category}, not a {ep.goal_receptacle_category}"
    x, y, _ = ep.robot_start
    if not (0.0 < x < layout.width and 0.0 < y < layout.depth):
        return (f"robot_start ({x:.6g}, {y:.6g}) is outside its home (0..{layout.width:.2f} m x "
                f"0..{layout.depth:.2f} m)")
    return None
