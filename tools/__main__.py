"""``python -m tools <command>``: see ``tools.cli``."""

import sys

try:
    from tools.cli import main
except KeyboardInterrupt:               # Ctrl-C while the command line's modules load: one line, not a traceback
    print("interrupted", file=sys.stderr)
    raise SystemExit(130) from None

# Guarded: multiprocessing's spawn start method re-imports the main module in worker processes.
if __name__ == "__main__":
    raise SystemExit(main())
