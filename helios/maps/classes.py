"""The per-episode class set: the task's classes plus one "other/background" class.

HELIOS fixes the classes at the start of an episode (object, start receptacle, goal receptacle)
and adds a background class that absorbs every re-observed pixel nobody detected; the Dirichlet
concentrations of every Gaussian are indexed by this set.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

from helios.maps.inputs import MapInputError


class UnknownClassError(MapInputError):
    """A class name that is not part of this episode's class set."""


@dataclass(frozen=True)
class ClassSet:
    """Ordered class names; the background class is always last."""

    names: tuple[str, ...]

    @staticmethod
    def from_task(task_classes: Sequence[str], background: str = "other") -> "ClassSet":
        """Task classes in order (duplicates merged, e.g. start == goal receptacle) + background."""
        if isinstance(task_classes, str):
            raise MapInputError(f"task classes must be a sequence of names, got the string {task_classes!r}")
        names: list[str] = []
        for name in task_classes:
            if not isinstance(name, str) or not name.strip():
                raise MapInputError(f"class names must be non-empty strings, got {name!r}")
            if name == background:
                raise MapInputError(f"task class {name!r} clashes with the background class name")
            if name not in names:
                names.append(name)
        if not names:
            raise MapInputError("at least one task class is needed")
        return ClassSet(tuple(names) + (background,))

    def __len__(self) -> int:
        return len(self.names)

    @property
    def background(self) -> str:
        return self.names[-1]

    @property
    def background_index(self) -> int:
        return len(self.names) - 1

    @property
    def task_classes(self) -> tuple[str, ...]:
        return self.names[:-1]

    def index(self, name: str) -> int:
        """Index of ``name``; UnknownClassError naming the valid classes otherwise."""
        try:
            return self.names.index(name)
        except ValueError:
            raise UnknownClassError(
                f"unknown class {name!r}; this episode's classes are {', '.join(map(repr, self.names))}") from None
