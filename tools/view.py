"""Open a rerun recording (``.rrd``) in the rerun viewer when this machine can show one; otherwise
print how to view it elsewhere. Never waits for input or a window in CI.

    python -m tools view runs/val200/recordings/val-00000.rrd
    python -m tools view FILE.rrd --print      # only print the instructions
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from pathlib import Path


RRD_MAGIC = b"RRF"
"""Every .rrd file starts with ``RRF`` and a format digit (rerun-sdk 0.41 writes ``RRF2``; older
versions ``RRF0``/``RRF1``): the rerun log encoder's file header."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="a .rrd recording (e.g. from `tools trials --record N` or `tools demo`)")
    parser.add_argument("--print", dest="print_only", action="store_true",
                        help="do not start a viewer; print how to view the file")


def find_viewer() -> str | None:
    """The ``rerun`` executable next to this Python (the rerun-sdk package ships it), or on PATH."""
    here = Path(sys.executable).with_name("rerun")
    if here.is_file() and os.access(here, os.X_OK):
        return str(here)
    return shutil.which("rerun")


def display_available() -> bool:
    """A desktop session can show a window (and this is not a CI job)."""
    if os.environ.get("CI"):
        return False
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def instructions(path: Path, viewer: str | None) -> str:
    size = path.stat().st_size / 1e6
    cmd = "rerun" if viewer is None else Path(viewer).name
    lines = [f"{path} ({size:.1f} MB) is a rerun recording; no viewer can be shown here "
             f"({'no display' if viewer else 'the rerun viewer is not installed'}). To view it:",
             f"  - on a machine with a display and rerun-sdk==0.41.0 (pip install rerun-sdk==0.41.0): {cmd} {path.name}",
             f"  - or in a browser: {cmd} --web-viewer {path}  (serves on localhost; forward the port over ssh)",
             f"  - check it without a viewer: {cmd} rrd verify {path}  /  {cmd} rrd stats {path}"]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from tools.cli import CliError

    if not args.file.strip():            # Path("") is "." (the current folder): say what is wrong instead
        raise CliError("recording path must not be empty")
    path = Path(args.file)
    if path.is_dir():
        raise CliError(f"recording {str(path)!r} is a folder, not a .rrd file")
    if not path.is_file():
        raise CliError(f"recording {str(path)!r} {'is not a regular file' if path.exists() else 'does not exist'}")
    if path.suffix != ".rrd":
        raise CliError(f"{str(path)!r} is not a rerun recording (expected a .rrd file)")
    with path.open("rb") as fh:
        head = fh.read(len(RRD_MAGIC) + 1)
    if not (head.startswith(RRD_MAGIC) and head[len(RRD_MAGIC):].isdigit()):
        raise CliError(f"{str(path)!r} is not a rerun recording: it does not start with a .rrd header "
                       f"({RRD_MAGIC.decode()}0-{RRD_MAGIC.decode()}2; a damaged or truncated file?)")
    viewer = find_viewer()
    if args.print_only or viewer is None or not display_available() or not sys.stdin.isatty():
        print(instructions(path, viewer))
        return 0
    print(f"opening {path} with {viewer} (close the viewer window to return)", flush=True)
    return subprocess.call([viewer, str(path)], stdin=subprocess.DEVNULL)
