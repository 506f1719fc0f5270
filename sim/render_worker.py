"""Render hand-camera frames in a second process, so streaming them (recordings, frame listeners)
overlaps with physics instead of stalling it.

PyBullet holds the GIL and one client cannot be shared, so the worker is a separate process with
its own DIRECT client. It rebuilds the visual scene by replaying the World's log of visual calls in
order (so body and shape ids, and therefore segmentation ids, are identical), and for each frame
receives the poses of everything that moves plus the robot's joints. Frames come back in order and
are bit-identical to rendering in the main process (``tests/test_sim_camera.py`` checks this).
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from collections import deque
from multiprocessing.connection import Connection
from typing import Any

from sim.camera import CameraConfig, RenderedFrame, decode, raw_render


def _worker_main(conn) -> None:
    from sim.world import quiet_native_stdout

    with quiet_native_stdout():
        import pybullet
        from pybullet_utils.bullet_client import BulletClient

        client = BulletClient(connection_mode=pybullet.DIRECT)
    conn.send(("ready",))
    try:
        while True:
            msg = conn.recv()
            kind = msg[0]
            if kind == "replay":
                for name, args, kwargs in msg[1]:
                    getattr(client, name)(*args, **kwargs)
            elif kind == "render":
                _, poses, joints, request, config = msg
                for body, pos, orn in poses:
                    client.resetBasePositionAndOrientation(body, pos, orn)
                for body, index, q in joints:
                    client.resetJointState(body, index, q)
                rgba, zbuf, seg = raw_render(client, pybullet, request)
                frame = decode(rgba, zbuf, seg, request, config)
                conn.send((frame.rgb, frame.depth, frame.segmentation))
            elif kind == "stop":
                break
    except (EOFError, KeyboardInterrupt):
        pass
    finally:
        client.disconnect()


class RenderWorker:
    """An asynchronous renderer mirroring one World. Results come back in submission order."""

    def __init__(self, world, max_in_flight: int = 64):
        # A fresh interpreter (not fork: rerun/torch threads' locks would be copied mid-use; not
        # multiprocessing spawn: it re-imports the caller's __main__, which fails from stdin or a
        # notebook) talking over a socket pair.
        parent, child = socket.socketpair()
        self._proc = subprocess.Popen([sys.executable, "-m", "sim.render_worker", str(child.fileno())],
                                      pass_fds=(child.fileno(),), env=dict(os.environ))
        child.close()
        self._conn = Connection(parent.detach())
        self._world = world
        self._sent = 0
        self._pending: deque[Any] = deque()
        self._max_in_flight = max_in_flight
        self._closed = False
        try:
            ready = self._conn.poll(30.0) and self._conn.recv() == ("ready",)
        except (EOFError, OSError):
            ready = False
        if not ready:
            self.close()
            raise RuntimeError("the render worker process failed to start (run `python -m sim.render_worker` "
                               "to see why) ")

    def _sync(self) -> None:
        log = self._world.visual_log
        if self._sent < len(log):
            self._conn.send(("replay", log[self._sent:]))
            self._sent = len(log)

    def submit(self, poses, joints, request: dict, config: CameraConfig, meta: Any) -> list[tuple[Any, RenderedFrame]]:
        """Queue a frame; returns any frames that had to be collected to respect ``max_in_flight``."""
        done = []
        while len(self._pending) >= self._max_in_flight:
            done.append(self._receive())
        self._sync()
        self._conn.send(("render", poses, joints, request, config))
        self._pending.append(meta)
        return done

    def _receive(self) -> tuple[Any, RenderedFrame]:
        rgb, depth, seg = self._conn.recv()
        return self._pending.popleft(), RenderedFrame(rgb, depth, seg)

    def poll(self, block: bool = False) -> list[tuple[Any, RenderedFrame]]:
        """Frames finished so far (all pending ones when ``block``), oldest first."""
        out = []
        while self._pending and (block or self._conn.poll()):
            out.append(self._receive())
        return out

    @property
    def pending(self) -> int:
        return len(self._pending)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._conn.send(("stop",))
        except (BrokenPipeError, OSError):
            pass
        try:
            self._proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait(timeout=5)
        self._conn.close()


def moving_state(world, robot_id: int, joint_indices: list[int]) -> tuple[list, list]:
    """Poses of the robot and all movable objects, and the robot's joint angles (what a frame needs)."""
    from sim.world import OBJECT

    c = world.client
    poses = []
    for body in [robot_id] + [b.body_id for b in world.bodies_of_kind(OBJECT)]:
        pos, orn = c.getBasePositionAndOrientation(body)
        poses.append((body, pos, orn))
    states = c.getJointStates(robot_id, joint_indices)
    joints = [(robot_id, i, float(s[0])) for i, s in zip(joint_indices, states)]
    return poses, joints


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit("usage: python -m sim.render_worker FD  (started by RenderWorker, not by hand)")
    _worker_main(Connection(int(sys.argv[1])))
