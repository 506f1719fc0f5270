"""``python -m tools <command>``: see ``tools.cli``."""

from tools.cli import main

# Guarded: multiprocessing's spawn start method re-imports the main module in worker processes.
if __name__ == "__main__":
    raise SystemExit(main())
