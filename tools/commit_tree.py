"""Another commit's code as a folder, for the commands that run it beside this working tree
(``bench agent --agent-baseline``, ``unchanged``): the commit is resolved with ``git rev-parse``
and extracted with ``git archive`` (tracked files only, no ``.git``), and the extracted code runs
with this checkout's interpreter and packages (``PYTHONPATH`` puts the folder first).

Every git call has a timeout and a one-line error naming the flag or argument it came from.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

from tasks.provenance import ARCHIVED_COMMIT_FILE
from tools.cli import CliError

ROOT = Path(__file__).resolve().parents[1]
GIT_TIMEOUT_S = 30
ARCHIVE_TIMEOUT_S = 120


def resolve_commit(ref: str, what: str) -> str | None:
    """The full hash of commit ``ref`` of this checkout; None when ``ref`` names no commit. A
    checkout without git (or git that does not answer within its timeout) is a CliError naming
    ``what`` (the flag or argument the reference came from)."""
    try:
        done = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--verify", "--quiet", f"{ref}^{{commit}}"],
                              capture_output=True, text=True, timeout=GIT_TIMEOUT_S)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise CliError(f"{what} {ref!r}: git is not usable here ({exc})") from None
    commit = done.stdout.strip()
    return commit or None


def commit_has_file(commit: str, path: str, what: str) -> bool:
    """Whether ``commit`` holds the file ``path`` (relative to the repository root), asked of git
    without extracting anything, so a commit too old for a command is refused before any work."""
    try:
        done = subprocess.run(["git", "-C", str(ROOT), "cat-file", "-e", f"{commit}:{path}"],
                              capture_output=True, text=True, timeout=GIT_TIMEOUT_S)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise CliError(f"{what} ({commit[:12]}): git is not usable here ({exc})") from None
    return done.returncode == 0


def extract_commit(commit: str, tree: Path, what: str) -> Path:
    """Write the files of ``commit`` into the (new or empty) folder ``tree``; CliError naming
    ``what`` when git or tar fails or does not finish within its timeout."""
    tree.mkdir(parents=True, exist_ok=True)
    try:
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", commit], capture_output=True,
                                 timeout=ARCHIVE_TIMEOUT_S)
        if archive.returncode != 0:
            raise CliError(f"{what} ({commit[:12]}): git archive failed: "
                           f"{archive.stderr.decode(errors='replace')[:200]}")
        subprocess.run(["tar", "-x", "-C", str(tree)], input=archive.stdout, check=True, timeout=ARCHIVE_TIMEOUT_S)
        (tree / ARCHIVED_COMMIT_FILE).write_text(commit + "\n", encoding="ascii")   # its runs record the commit
    except subprocess.TimeoutExpired as exc:
        raise CliError(f"{what} ({commit[:12]}): extracting the commit did not finish within "
                       f"{exc.timeout:g} s") from None
    except (OSError, subprocess.CalledProcessError) as exc:
        raise CliError(f"{what} ({commit[:12]}): could not extract the commit into {str(tree)!r} ({exc})") from None
    return tree
