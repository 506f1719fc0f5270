"""Run the command line in this process (no interpreter start-up and imports per call, ~1 s each):
``run_cli(argv) -> (exit code, stdout, stderr)``. A few tests still start ``python -m tools`` as a
subprocess to check the real entry point; everything else about a command's exit code and its
messages is the same through ``tools.cli.main``."""

from __future__ import annotations

import contextlib
import io

from tools.cli import main


def run_cli(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main(argv)
        except SystemExit as exc:           # argparse
            rc = exc.code if isinstance(exc.code, int) else 2
    return rc, out.getvalue(), err.getvalue()
