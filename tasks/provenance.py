"""Where a result came from: the package version and the git commit of the code that made it
(written into run folders and checked between a Ray driver and its workers)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

PROVENANCE_KEYS = ("helios_version", "git_commit")
ARCHIVED_COMMIT_FILE = ".helios-commit"
"""Written at the root of a commit's files extracted with ``git archive`` (``tools.commit_tree``:
``unchanged``, ``bench agent --agent-baseline``), which have no ``.git``: the commit they are."""


def git_commit() -> str:
    """The commit the code is checked out at; for extracted files, the commit their
    :data:`ARCHIVED_COMMIT_FILE` names; else ``unknown`` (no git, not a checkout)."""
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5,
                             cwd=Path(__file__).resolve().parent)
        if out.stdout.strip():
            return out.stdout.strip()
    except (OSError, subprocess.SubprocessError):
        pass
    try:
        named = (Path(__file__).resolve().parents[1] / ARCHIVED_COMMIT_FILE).read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError):
        return "unknown"
    return named if re.fullmatch(r"[0-9a-f]{40}", named) else "unknown"


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
