"""The simulator's side of what came through the SDK from a fake Spot.

Simulated perception (``sim.perception.FrameAnalyzer``) and the episode judge
(``tasks.metrics.EpisodeJudge``) read ground truth from a sim backend: the world, and the
instance segmentation of the frame an observation was rendered from. Through the SDK an agent's
:class:`~robots.hal.Observation` is rebuilt by ``SdkSpotBackend`` from the image service (JPEG
colour, 16-bit depth, poses from the shot's frame snapshot), a different object with its own
``frame_id``. :class:`FakeSimView` links each such observation to the frame the fake rendered for
it, so the same simulated detector and judge work unchanged over the SDK; the agent only ever
sees the HAL.

Linking is by camera pose: the fake publishes ``odom`` as its world frame (the odom edge of its
kinematic tree is the inverse of the body's world pose), so an SDK observation's ``T_world_cam``
(odom -> hand colour sensor) equals the rendered frame's world pose to float precision.

Every simulator access holds the fake's ``sim_lock``: the fake's robot and RPC threads use the
same PyBullet client (not thread-safe).
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from robots.hal import Observation

_KEPT = 16      # linked observations (the fake and its simulator keep 16 frames too)


class FakeSimView:
    """What ``FrameAnalyzer`` and ``EpisodeJudge`` use of a sim backend (``world``, ``config``,
    ``frame_for``, ``segmentation_for``, ``held_body``, ``last_release``, ``collision_events``),
    for observations the SDK backend made from the fake's images. Observations must be linked
    (:meth:`link`, or :meth:`watch` on the HAL backend) as they arrive: perception hands over only
    the ``rgb`` array, and the link is what maps it back to a rendered frame."""

    def __init__(self, fake):
        self.fake = fake
        self._linked: OrderedDict[int, tuple[Observation, Observation]] = OrderedDict()   # sdk id -> (sdk, fake)

    # ------------------------------------------------------------------ the simulator's state
    @property
    def sim_lock(self):
        return self.fake.sim_lock

    @property
    def world(self):
        return self.fake.sim.world

    @property
    def config(self):
        return self.fake.sim.config

    @property
    def held_body(self) -> int | None:
        with self.sim_lock:
            return self.fake.sim.held_body

    @property
    def last_release(self):
        with self.sim_lock:
            return self.fake.sim.last_release

    @property
    def collision_events(self) -> list:
        with self.sim_lock:
            return list(self.fake.sim.collision_events)

    # ------------------------------------------------------------------ linking SDK observations
    def link(self, obs: Observation) -> Observation:
        """The fake's rendered frame that SDK observation ``obs`` was made from (remembered for
        :meth:`frame_for`). KeyError when the fake no longer keeps it (more than 16 frames ago)."""
        hit = self._linked.get(obs.frame_id)
        if hit is not None and hit[0] is obs:
            return hit[1]
        with self.sim_lock:
            frame = self.fake.find_frame(obs.T_world_cam)
        if frame is None:
            raise KeyError(f"no frame of the fake Spot was rendered at the camera pose of SDK observation {obs.frame_id}")
        self._linked[obs.frame_id] = (obs, frame)
        while len(self._linked) > _KEPT:
            self._linked.popitem(last=False)
        return frame

    def watch(self, backend) -> "LinkingBackend":
        """``backend`` (the SDK HAL) with every observation linked as it is returned."""
        return LinkingBackend(backend, self)

    # ------------------------------------------------------------------ the sim backend's sim-only ports
    def frame_for(self, rgb: np.ndarray) -> tuple[Observation, np.ndarray]:
        """(rendered frame, its segmentation) for the ``rgb`` array of a linked SDK observation.
        The rendered frame carries the exact camera pose and float depth the simulated detector's
        error model expects, as on the sim backend."""
        for sdk, frame in reversed(self._linked.values()):
            if sdk.rgb is rgb:
                with self.sim_lock:
                    return frame, self.fake.sim.segmentation_for(frame)
        raise KeyError("this image is not one of the recent SDK observations linked to the fake Spot's frames")

    def segmentation_for(self, obs: Observation) -> np.ndarray:
        """Ground-truth segmentation of an SDK observation (or of one of the fake's own frames)."""
        frame = self.link(obs)
        with self.sim_lock:
            return self.fake.sim.segmentation_for(frame)


class LinkingBackend:
    """A HAL backend whose observations are linked to the fake's frames as they are returned;
    every other call goes straight to the wrapped backend."""

    def __init__(self, backend, view: FakeSimView):
        self._backend = backend
        self._view = view

    def observe(self) -> Observation:
        obs = self._backend.observe()
        self._view.link(obs)
        return obs

    def __getattr__(self, name: str):
        return getattr(self._backend, name)


class LockedJudge:
    """An episode judge whose every look at the simulator holds the fake's ``sim_lock`` (it reads
    and, at the end, steps the world the fake's threads also use)."""

    def __init__(self, judge, lock):
        self._judge = judge
        self._lock = lock

    def on_observation(self, obs: Observation) -> None:
        with self._lock:
            self._judge.on_observation(obs)

    def after_command(self, name: str, result=None) -> None:
        with self._lock:
            self._judge.after_command(name, result)

    def finalize(self, limit_hit: bool):
        with self._lock:
            return self._judge.finalize(limit_hit)

    def __getattr__(self, name: str):
        return getattr(self._judge, name)
