"""Command-line tools: ``python -m tools <command>`` (demo, bench, ...)."""
