"""Serve a fake Spot (the demo scene) from its own process, e.g. for tests that freeze or kill the
robot (SIGSTOP / SIGKILL) while a client is connected:

    BOSDYN_CLIENT_USERNAME=u BOSDYN_CLIENT_PASSWORD=p python -m robots.spot.fake_spot.serve PKI_DIR \\
        [--seed N] [--time-scale S]

It makes a throwaway CA and server certificate in ``PKI_DIR``, accepts exactly the credentials in
the environment, prints one JSON line ``{"port": ..., "ca": ...}`` on stdout once it listens, and
serves until its standard input closes or it is terminated.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading

from robots.spot.sdk_config import PASSWORD_ENV, USERNAME_ENV


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m robots.spot.fake_spot.serve", description=__doc__.split("\n")[0])
    parser.add_argument("pki_dir", help="folder for the throwaway CA and server certificate")
    parser.add_argument("--seed", type=int, default=0, help="demo scene seed")
    parser.add_argument("--time-scale", type=float, default=None,
                        help="wall seconds per robot second (1 = real time; default: as fast as possible)")
    args = parser.parse_args(argv)
    user, password = os.environ.get(USERNAME_ENV, ""), os.environ.get(PASSWORD_ENV, "")
    if not user or not password:
        print(f"set {USERNAME_ENV} and {PASSWORD_ENV}: the credentials the fake accepts", file=sys.stderr)
        return 2
    from robots.spot.fake_spot.launch import start_demo_fake

    demo = start_demo_fake(args.pki_dir, user, password, seed=args.seed, time_scale=args.time_scale)
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    threading.Thread(target=lambda: (sys.stdin.read(), done.set()), daemon=True).start()
    print(json.dumps({"port": demo.port, "ca": str(demo.pki.ca_cert)}), flush=True)
    try:
        done.wait()
    except KeyboardInterrupt:
        pass
    finally:
        demo.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
