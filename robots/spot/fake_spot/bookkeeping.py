"""The fake Spot's bookkeeping records, which the robot (``server.FakeSpot``) and the code that
serves and executes its commands (``servicer``, ``protocol``, ``sim_execution``) all name: the
state of a software e-stop endpoint (:class:`Endpoint`), a robot command and its progress
(:class:`Command`), and the names of the e-stop levels.

They live apart, at the bottom of the package, so that ``server.py`` can import the modules that
serve and execute commands without any of them importing ``server.py`` (no import cycles:
``tests/test_layering.py``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from bosdyn.api import estop_pb2

STOP_LEVEL_NAMES = {estop_pb2.ESTOP_LEVEL_CUT: "CUT", estop_pb2.ESTOP_LEVEL_SETTLE_THEN_CUT: "SETTLE_THEN_CUT",
                     estop_pb2.ESTOP_LEVEL_NONE: "NONE"}


_UINT64 = (1 << 64) - 1


@dataclass
class Endpoint:
    """A registered software e-stop endpoint: the stop level it asserts, when it last checked in
    with a valid response (the clock of its ``timeout``), and the challenge it must answer next.

    The challenge-response rule is the SDK's: ``EstopEndpoint`` answers a challenge ``c`` with
    ``response_from_challenge(c) = ctypes.c_ulonglong(~c).value``, the 64-bit complement of ``c``
    (``bosdyn/client/estop.py``, bosdyn-client 5.2.0), and ``estop.proto`` says a check-in "must
    include [the] response to [the] previous challenge" after the first one, which sets neither.
    ``challenge`` is None until the robot has issued one (the first check-in is then accepted as
    it is)."""

    proto: estop_pb2.EstopEndpoint
    level: int = estop_pb2.ESTOP_LEVEL_CUT
    last_checkin: float = field(default_factory=time.monotonic)
    challenge: int | None = None

    def answers(self, challenge: int, response: int) -> bool:
        """Whether a check-in's (challenge, response) answers the challenge issued last."""
        if self.challenge is None:
            return True
        return challenge == self.challenge and response == (~self.challenge) & _UINT64


@dataclass
class Command:
    """A robot command and its progress. ``state``: queued | running | done | overridden | frozen |
    timed_out (its end time passed first) | hung."""

    id: int
    kind: str                      # stand, sit, stop, safe_power_off, se2, arm_joint, arm_cartesian,
    request: object                # arm_gaze, arm_named, arm_stop, claw, pick
    state: str = "queued"
    success: bool = False          # meaningful once done
    detail: str = ""
    extra: dict = field(default_factory=dict)
