"""What a skill (pick, place) reports back: it carries out one attempt through the HAL and
returns an outcome; it never calls back into the agent, which decides what the outcome means
(next phase, or one more failure on that candidate)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SkillOutcome:
    ok: bool
    reason: str = ""
    """Why it failed, for the episode log ("" when ok)."""
    attempted: bool = False
    """The skill reached the robot's grasp / place command (a pick attempt counts against
    ``AgentConfig.max_pick_attempts`` only then)."""
