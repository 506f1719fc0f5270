"""Command-line tools: ``python -m tools <command>`` (demo, bench, ...).

Importing the package pins NumPy, OpenBLAS, torch and OpenCV to one CPU code path (x86-64-v3)
before any of them loads, so results reproduce from machine to machine (``helios.runtime``;
``HELIOS_CPU=native`` opts out). Spawned worker processes inherit the pin with the environment.
"""

from helios.runtime import pin_cpu_dispatch

CPU_PIN_ERROR: str | None = None
"""Why the pin could not be set up (a ``HELIOS_CPU`` that is neither ``x86-64-v3`` nor ``native``);
``tools.cli.main`` then ends every command with this as its one ``error:`` line, exit status 2."""
try:
    CPU_PIN = pin_cpu_dispatch()
    """What the pin did in this process (``x86-64-v3``, or ``native (why)``)."""
except ValueError as _exc:
    CPU_PIN, CPU_PIN_ERROR = "not pinned (bad HELIOS_CPU)", str(_exc)
