"""Where a result came from: the package version and the git commit of the code that made it
(written into run folders and checked between a Ray driver and its workers)."""

from __future__ import annotations

import subprocess
from pathlib import Path

PROVENANCE_KEYS = ("helios_version", "git_commit")


def git_commit() -> str:
    """The commit the code is checked out at, or ``unknown`` (no git, not a checkout)."""
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5,
                             cwd=Path(__file__).resolve().parent)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def differs(made, now) -> bool:
    """Whether two provenance values (a version or a commit) are both known and differ; None and
    ``unknown`` (no git, not a checkout, a hand-written file) never count as a difference."""
    return made not in (None, "unknown") and now not in (None, "unknown") and made != now


def package_version() -> str:
    from helios import __version__

    return __version__


def provenance() -> dict:
    """``{"helios_version": ..., "git_commit": ...}`` (the header of a run folder's config.yaml)."""
    return {"helios_version": package_version(), "git_commit": git_commit()}
