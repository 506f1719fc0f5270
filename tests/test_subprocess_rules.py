"""No ``preexec_fn`` in the tests, their helpers or the packages (the Python files of tests/,
helios/, robots/, sim/, tasks/ and tools/).

A ``preexec_fn`` makes ``subprocess`` fork() instead of vfork(), and the forked copy of a pytest
process in which gRPC is alive (an xdist worker after fake-Spot tests) can abort before it execs:
gRPC's fork support meets the epoll fd that ``close_fds`` closed, SIGABRT, exit -6 (2026-12-05,
``tools spot``'s child in ``tests/test_spot_realtime_faults.py``; 2026-12-06, the headless
Chromium of ``tests/browser.py``). Do what the child needs in a ``python -c`` shim that then
``os.execv``s the real program (both files show one), or with ``start_new_session``,
``process_group``, ``pass_fds`` where those are all it did.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("tests", "helios", "robots", "sim", "tasks", "tools")


def preexec_fn_uses(root: Path = ROOT) -> list[str]:
    """``file:line`` of every call that passes ``preexec_fn`` (as a keyword; a comment or a string
    that names it does not count)."""
    out = []
    for folder in FOLDERS:
        for path in sorted((root / folder).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
            for node in ast.walk(tree):
                if isinstance(node, ast.keyword) and node.arg == "preexec_fn":
                    out.append(f"{path.relative_to(root)}:{node.value.lineno}")
    return out


def test_no_subprocess_is_started_with_a_preexec_fn():
    bad = preexec_fn_uses()
    assert not bad, "preexec_fn forks a process that may hold gRPC (see this file's docstring): " + ", ".join(bad)


def test_the_check_sees_a_preexec_fn_and_not_its_name_in_words(tmp_path):
    (tmp_path / "tests").mkdir()
    (tmp_path / "tools").mkdir()
    (tmp_path / "tests" / "helper.py").write_text(
        "import subprocess\n# not a preexec_fn\nX = 'preexec_fn'\n"
        "p = subprocess.Popen(['true'],\n                     preexec_fn=lambda: None)\n")
    (tmp_path / "tools" / "ok.py").write_text("import subprocess\nsubprocess.run(['true'], start_new_session=True)\n")
    assert preexec_fn_uses(tmp_path) == ["tests/helper.py:5"]
