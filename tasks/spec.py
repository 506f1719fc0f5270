"""Language task specs: "Move (object) from (start_receptacle) to (goal_receptacle)".

Parsing is strict about structure and vocabulary and forgiving about style: case, articles
("the", "a", "an"), surrounding whitespace, a trailing period and underscores for spaces are
accepted; anything else gets one error that says what was expected and, for unknown categories,
lists the valid ones (with a close match when there is one).
"""

from __future__ import annotations

import difflib
import re
from dataclasses import dataclass
from typing import Iterable

from helios.schema import short_repr
from sim.scenes.catalog import OBJECT_CATEGORIES, RECEPTACLE_CATEGORIES

_PATTERN = re.compile(r"^\s*move\s+(?P<obj>.+?)\s+from\s+(?P<start>.+?)\s+to\s+(?P<goal>.+?)\s*\.?\s*$", re.IGNORECASE)
_ARTICLE = re.compile(r"^(the|a|an)\s+", re.IGNORECASE)


class TaskSpecError(ValueError):
    """A task string is malformed or names an unknown category."""


@dataclass(frozen=True)
class TaskSpec:
    object: str
    start_receptacle: str
    goal_receptacle: str

    def __post_init__(self) -> None:
        _check(self.object, OBJECT_CATEGORIES, "object", str(self))
        _check(self.start_receptacle, RECEPTACLE_CATEGORIES, "start receptacle", str(self))
        _check(self.goal_receptacle, RECEPTACLE_CATEGORIES, "goal receptacle", str(self))

    def __str__(self) -> str:
        return f"Move the {self.object} from the {self.start_receptacle} to the {self.goal_receptacle}"

    @property
    def classes(self) -> tuple[str, str, str]:
        """The task's three search classes, in the order the map uses them."""
        return (self.object, self.start_receptacle, self.goal_receptacle)


def _normalise(phrase: str) -> str:
    phrase = _ARTICLE.sub("", phrase.strip()).replace("_", " ")
    return re.sub(r"\s+", " ", phrase).lower()


def _check(name: str, valid: Iterable[str], role: str, task: str) -> None:
    valid = tuple(valid)
    if name not in valid:
        close = difflib.get_close_matches(name, valid, n=1) if len(name) <= 100 else []
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        # the task is quoted only when it adds something to the name (and both are shortened)
        context = f" in task {short_repr(task, 100)}" if len(task) <= 200 else ""
        raise TaskSpecError(f"unknown {role} {short_repr(name, 80)}{context}{hint}; valid {role}s: {', '.join(valid)}")


def parse_task(text: str) -> TaskSpec:
    """Parse "Move the mug from the stool to the table" into a :class:`TaskSpec`."""
    if not isinstance(text, str) or not text.strip():
        raise TaskSpecError("empty task; expected \"Move <object> from <start receptacle> to <goal receptacle>\"")
    m = _PATTERN.match(text)
    if not m:
        raise TaskSpecError(f"malformed task {short_repr(text, 100)}; expected \"Move <object> from <start receptacle> to "
                            f"<goal receptacle>\", e.g. \"Move the mug from the stool to the table\"")
    parts = {k: _normalise(v) for k, v in m.groupdict().items()}
    if any(" from " in f" {v} " or " to " in f" {v} " for v in parts.values()):
        raise TaskSpecError(f"malformed task {short_repr(text, 100)}: 'from' and 'to' must each appear exactly once")
    return TaskSpec(parts["obj"], parts["start"], parts["goal"])
