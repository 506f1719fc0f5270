"""The PyBullet world: one DIRECT-mode physics client per ``World`` object, deterministic settings,
a registry of named bodies, a simulation clock, and the settle test used for drops.

No global simulator handle exists anywhere in the project: code that touches physics receives the
``World`` it acts on. Two ``World`` objects in one process are independent (separate clients).

Cost model (measured on the 2-core target machine, see ``tools bench sim``): physics is stepped only
while something dynamic happens (arm tracking, grasp, carry, drop, settle); pure base navigation
is kinematic and only advances the clock (``advance``), with collision queries along the way.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
from dataclasses import dataclass, field
from typing import Iterable

import numpy as np

from helios.schema import require_range
from robots.transforms import pose_to_transform


@dataclass(frozen=True)
class PhysicsConfig:
    timestep: float = 1.0 / 240.0        # s; PyBullet's default and the rate its contact model is tuned for
    solver_iterations: int = 50           # more than the default 10: stable grasp constraints and stacking
    gravity: float = -9.81                # m/s^2 along z
    enable_sleeping: bool = True          # resting objects cost (almost) nothing per step

    def __post_init__(self) -> None:
        require_range(self, "timestep", 1e-5, 0.1)
        require_range(self, "solver_iterations", 1, 10000)
        require_range(self, "gravity", -100.0, 100.0)


@dataclass(frozen=True)
class SettleConfig:
    """OVMM's "at rest" test: linear < 5e-3 m/s and angular < 5e-2 rad/s for 50 consecutive steps."""

    linear_speed: float = 5e-3    # m/s
    angular_speed: float = 5e-2   # rad/s
    consecutive_steps: int = 50
    max_time: float = 5.0         # s of simulated time before giving up

    def __post_init__(self) -> None:
        require_range(self, "linear_speed angular_speed", 0.0, 100.0, lo_open=True)
        require_range(self, "consecutive_steps", 1, 100000)
        require_range(self, "max_time", 0.0, 3600.0, lo_open=True)


@dataclass(frozen=True)
class WorldConfig:
    physics: PhysicsConfig = PhysicsConfig()
    settle: SettleConfig = SettleConfig()


# Body kinds: what a body *is* for collision accounting and metrics.
GROUND, STRUCTURE, FURNITURE, OBJECT, ROBOT = "ground", "structure", "furniture", "object", "robot"


# Client calls that change what a camera sees; the World logs them so a render worker process can
# rebuild an identical visual scene (same body and shape ids) by replaying them in order.
VISUAL_CALLS = frozenset({
    "createCollisionShape", "createCollisionShapeArray", "createVisualShape", "createVisualShapeArray",
    "createMultiBody", "loadURDF", "changeVisualShape", "removeBody",
})


# Client calls that move bodies: the one named by the first argument, or (None) any body.
MOVING_CALLS = {"resetBasePositionAndOrientation": 0, "resetJointState": 0, "resetJointStateMultiDof": 0,
                "resetJointStatesMultiDof": 0, "resetJointStates": 0, "removeBody": 0,
                "stepSimulation": None, "resetSimulation": None}


class _LoggedClient:
    """A BulletClient proxy that records visual-scene calls (name, args, kwargs) before forwarding,
    and tells ``moved`` which body a call may move (None: any), so cached boxes can be refreshed."""

    def __init__(self, client, log: list, moved=None):
        self._client = client
        self._log = log
        self._moved = moved

    def __getattr__(self, name: str):
        attr = getattr(self._client, name)
        if name in VISUAL_CALLS:
            call = attr

            def logged(*args, **kwargs):
                self._log.append((name, args, kwargs))
                return call(*args, **kwargs)

            attr = logged
        if name in MOVING_CALLS and self._moved is not None:
            inner, which, moved = attr, MOVING_CALLS[name], self._moved

            def moving(*args, **kwargs):
                moved(args[which] if which is not None and args else None)
                return inner(*args, **kwargs)

            attr = moving
        # Cache the bound call: BulletClient builds a new partial (through inspect) on every
        # lookup, which was ~10% of an episode's wall time in collision checks.
        if name != "disconnect":     # BulletClient marks itself closed on that lookup
            self.__dict__[name] = attr
        return attr


@dataclass
class BodyInfo:
    """Registry entry for a body: its name, semantic category (e.g. 'mug', 'table') and kind."""

    body_id: int
    name: str
    category: str
    kind: str
    link_names: dict[int, str] = field(default_factory=dict)
    extra: dict = field(default_factory=dict)


@contextlib.contextmanager
def quiet_native_stdout():
    """Silence C-level prints on file descriptors 1 and 2 (PyBullet writes a build banner on import
    and "argv[0]=" on every connect, which would flood the logs of long trial batches)."""
    fds = []
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
            fds.append(stream.fileno())
        except (AttributeError, OSError, ValueError):   # not a real file (e.g. captured): leave it
            pass
    saved = [os.dup(fd) for fd in fds]
    try:
        with open(os.devnull, "wb") as devnull:
            for fd in fds:
                os.dup2(devnull.fileno(), fd)
            yield
    finally:
        for fd, copy in zip(fds, saved):
            os.dup2(copy, fd)
            os.close(copy)


class World:
    """A PyBullet physics client with deterministic settings and a body registry."""

    def __init__(self, config: WorldConfig = WorldConfig()):
        with quiet_native_stdout():
            import pybullet
            from pybullet_utils.bullet_client import BulletClient

            self._raw_client = BulletClient(connection_mode=pybullet.DIRECT)
        self.config = config
        self.pb = pybullet
        self.visual_log: list[tuple[str, tuple, dict]] = []
        self.client = _LoggedClient(self._raw_client, self.visual_log, self._body_moved)
        self.time = 0.0
        self.steps = 0
        self.bodies: dict[int, BodyInfo] = {}
        self._static_aabbs: dict[int, tuple] = {}
        self._joint_counts: dict[int, int] = {}
        self._movable: set[int] = set()
        self._aabb_table: _AabbTable | None = None
        self._closed = False
        self._reset_physics()
        self.ground_id = self._add_ground()

    # ---------------------------------------------------------------- setup
    def _reset_physics(self) -> None:
        c, ph = self.client, self.config.physics
        c.resetSimulation()
        c.setPhysicsEngineParameter(fixedTimeStep=ph.timestep, numSolverIterations=ph.solver_iterations,
                                    deterministicOverlappingPairs=1, enableFileCaching=0)
        c.setGravity(0.0, 0.0, ph.gravity)

    def _add_ground(self) -> int:
        """The floor: a collision plane at z = 0. Cameras draw it analytically (``sim.camera``)."""
        c = self.client
        col = c.createCollisionShape(self.pb.GEOM_PLANE)
        # A body without a visual gets its collision shape drawn (an infinite checker plane, one
        # huge triangle pair: slow in TinyRenderer). A tiny visual buried under the floor avoids it.
        hidden = c.createVisualShape(self.pb.GEOM_SPHERE, radius=0.001, visualFramePosition=[0, 0, -1.0])
        gid = c.createMultiBody(0.0, col, hidden, basePosition=[0, 0, 0])
        c.changeDynamics(gid, -1, lateralFriction=0.9)
        self.register(gid, "ground", "floor", GROUND)
        return gid

    def register(self, body_id: int, name: str, category: str, kind: str, **extra) -> BodyInfo:
        if any(info.name == name for info in self.bodies.values()):
            raise ValueError(f"a body named {name!r} already exists in this world")
        info = BodyInfo(body_id, name, category, kind, extra=dict(extra))
        self.bodies[body_id] = info
        self._aabb_table = None
        if kind == OBJECT and self.config.physics.enable_sleeping:
            self.client.changeDynamics(body_id, -1, activationState=self.pb.ACTIVATION_STATE_ENABLE_SLEEPING)
        return info

    def body(self, name: str) -> BodyInfo:
        for info in self.bodies.values():
            if info.name == name:
                return info
        raise KeyError(f"no body named {name!r}; known: {sorted(i.name for i in self.bodies.values())}")

    def bodies_of_kind(self, *kinds: str) -> list[BodyInfo]:
        return [b for b in self.bodies.values() if b.kind in kinds]

    # ---------------------------------------------------------------- time
    def step(self, n: int = 1) -> None:
        """Advance physics by ``n`` fixed steps."""
        for _ in range(n):
            self.client.stepSimulation()
        self.steps += n
        self.time += n * self.config.physics.timestep

    def advance(self, dt: float) -> None:
        """Advance the clock without stepping physics (kinematic phases where nothing is dynamic)."""
        if dt < 0 or not math.isfinite(dt):
            raise ValueError(f"cannot advance the clock by {dt}")
        self.time += dt

    @property
    def timestep(self) -> float:
        return self.config.physics.timestep

    # ---------------------------------------------------------------- state queries
    def pose(self, body_id: int) -> np.ndarray:
        pos, orn = self.client.getBasePositionAndOrientation(body_id)
        return pose_to_transform(pos, orn)

    def position(self, body_id: int) -> np.ndarray:
        return np.array(self.client.getBasePositionAndOrientation(body_id)[0])

    def velocity(self, body_id: int) -> tuple[float, float]:
        """(linear speed m/s, angular speed rad/s) of a body's base."""
        lin, ang = self.client.getBaseVelocity(body_id)
        return float(np.linalg.norm(lin)), float(np.linalg.norm(ang))

    def aabb(self, body_id: int, link: int = -1) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self.client.getAABB(body_id, link)
        return np.array(lo), np.array(hi)

    def body_aabb(self, body_id: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """AABB (lo, hi) of a body's base and all its links, as float tuples (cheap to compare).

        Bodies with a fixed base (mass 0) and no joints cannot move under physics, so theirs is
        computed once; nothing in the testbed teleports such a body after building the scene
        (call :meth:`forget_aabb` if you do).
        """
        cached = self._static_aabbs.get(body_id)
        if cached is not None:
            return cached
        c = self.client
        n_links = self._joint_counts.get(body_id)
        if n_links is None:
            n_links = self._joint_counts[body_id] = c.getNumJoints(body_id)
        lo, hi = c.getAABB(body_id, -1)
        if n_links:
            boxes = [c.getAABB(body_id, link) for link in range(n_links)]
            lo = tuple(map(min, lo, *(b[0] for b in boxes)))
            hi = tuple(map(max, hi, *(b[1] for b in boxes)))
        box = (tuple(lo), tuple(hi))
        if body_id not in self._movable:      # asked once per body: mass and joints do not change
            if n_links == 0 and c.getDynamicsInfo(body_id, -1)[0] == 0.0:
                self._static_aabbs[body_id] = box
            else:
                self._movable.add(body_id)
        return box

    def forget_aabb(self, body_id: int) -> None:
        """Drop a cached static AABB (after moving a fixed body by hand)."""
        self._static_aabbs.pop(body_id, None)
        self._aabb_table = None

    def bodies_overlapping(self, lo, hi, skip=()) -> list[int]:
        """Ids, in registration order, of the non-ground bodies whose AABB (see :meth:`body_aabb`)
        overlaps the box ``lo``-``hi`` (touching counts), except those in ``skip``.

        The same answer as testing each body's ``body_aabb`` in turn, but with the fixed bodies'
        boxes in one array: a kinematic walk asks this at every 50 ms pose, against ~60 bodies."""
        table = self._aabb_table
        if table is None:
            table = self._aabb_table = self._build_aabb_table()
        asked = np.ones(len(table.ids), dtype=bool)
        for body_id in skip:
            row = table.row_of.get(body_id)
            if row is not None:
                asked[row] = False
        rows = [row for row in table.moving_rows if asked[row] and not table.fresh[row]]
        if rows:
            boxes = [self.body_aabb(int(table.ids[row])) for row in rows]
            table.lo[rows] = [b[0] for b in boxes]
            table.hi[rows] = [b[1] for b in boxes]
            table.fresh[rows] = True         # until a step or a reset may move them again
        lo = np.asarray(lo, dtype=float)
        hi = np.asarray(hi, dtype=float)
        overlap = asked & ~((table.hi < lo).any(axis=1) | (table.lo > hi).any(axis=1))
        return table.ids[overlap].tolist()

    def _body_moved(self, body_id) -> None:
        """Client hook: ``body_id`` (None: any body) may have moved; its cached box is stale."""
        table = getattr(self, "_aabb_table", None)
        if table is None:
            return
        if body_id is None:
            table.fresh[:] = False
        else:
            row = table.row_of.get(body_id)
            if row is not None:
                table.fresh[row] = False

    def _build_aabb_table(self) -> "_AabbTable":
        ids = [b.body_id for b in self.bodies.values() if b.kind != GROUND]
        boxes = [self.body_aabb(i) for i in ids]
        lo = np.array([b[0] for b in boxes], dtype=float).reshape(-1, 3)
        hi = np.array([b[1] for b in boxes], dtype=float).reshape(-1, 3)
        moving = [row for row, i in enumerate(ids) if i not in self._static_aabbs]
        return _AabbTable(np.array(ids, dtype=np.int64), lo, hi, moving, {i: row for row, i in enumerate(ids)},
                          np.ones(len(ids), dtype=bool))

    def is_at_rest(self, body_id: int) -> bool:
        s = self.config.settle
        lin, ang = self.velocity(body_id)
        return lin < s.linear_speed and ang < s.angular_speed

    def settle(self, body_ids: Iterable[int], max_time: float | None = None) -> tuple[bool, float]:
        """Step until every body has been at rest for the configured number of consecutive steps.

        Returns (settled, simulated seconds spent).
        """
        ids = list(body_ids)
        s = self.config.settle
        max_steps = int(round((max_time if max_time is not None else s.max_time) / self.timestep))
        run = 0
        for i in range(max_steps):
            self.step()
            run = run + 1 if all(self.is_at_rest(b) for b in ids) else 0
            if run >= s.consecutive_steps:
                return True, (i + 1) * self.timestep
        return False, max_steps * self.timestep

    def contacts(self, body_a: int, body_b: int | None = None, link_a: int | None = None) -> list:
        """Contact points from the last physics step (PyBullet tuples)."""
        kwargs = {"bodyA": body_a}
        if body_b is not None:
            kwargs["bodyB"] = body_b
        if link_a is not None:
            kwargs["linkIndexA"] = link_a
        return list(self.client.getContactPoints(**kwargs))

    def object_poses(self) -> dict[str, np.ndarray]:
        """Pose of every movable object by name (for determinism checks and metrics)."""
        return {b.name: self.pose(b.body_id) for b in self.bodies_of_kind(OBJECT)}

    # ---------------------------------------------------------------- teardown
    def close(self) -> None:
        if not self._closed:
            self._closed = True
            try:
                self._raw_client.disconnect()
            except Exception:  # already disconnected (e.g. interpreter shutdown)
                pass

    def __enter__(self) -> "World":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class _AabbTable:
    """Every non-ground body's AABB as arrays; rows of bodies that can move are refreshed per query."""

    ids: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    moving_rows: list[int]
    row_of: dict[int, int]
    fresh: np.ndarray        # (N,) bool: the row's box is current (no step or reset since it was read)

