"""A headless Chromium for tests, driven over the DevTools protocol on a pipe (standard library
only: ``--remote-debugging-pipe`` reads NUL-separated JSON on fd 3 and answers on fd 4).

    exe, why = find_or_install_browser()
    with Browser(exe) as b:
        page = b.load(Path("report/index.html"))
        page.images, page.errors, page.links, page.resources
        b.screenshot(Path("shot.png"))

``find_or_install_browser`` installs Debian's ``chromium`` package when none is on PATH and this
user may (root, or password-less sudo; ``HELIOS_NO_BROWSER_INSTALL=1`` forbids it) and otherwise
says why there is none, for one clear skip message.
"""

from __future__ import annotations

import base64
import json
import os
import select
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome", "headless_shell")


def find_browser() -> str | None:
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    return None


def find_or_install_browser(timeout: float = 900.0) -> tuple[str | None, str]:
    """(browser executable or None, why there is none)."""
    exe = find_browser()
    if exe:
        return exe, ""
    if os.environ.get("HELIOS_NO_BROWSER_INSTALL"):
        return None, "no Chromium on PATH and HELIOS_NO_BROWSER_INSTALL is set (apt-get install chromium)"
    if not shutil.which("apt-get"):
        return None, "no Chromium on PATH and no apt-get to install Debian's chromium package"
    if os.geteuid() == 0:
        sudo: list[str] = []
    elif shutil.which("sudo") and subprocess.run(["sudo", "-n", "true"], capture_output=True).returncode == 0:
        sudo = ["sudo", "-n"]
    else:
        return None, "no Chromium on PATH and this user cannot install packages (run: apt-get install chromium)"
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    install = [*sudo, "apt-get", "install", "-y", "--no-install-recommends", "chromium"]
    try:
        done = subprocess.run(install, capture_output=True, env=env, timeout=timeout)
        if done.returncode != 0:
            subprocess.run([*sudo, "apt-get", "update", "-qq"], capture_output=True, env=env, timeout=timeout)
            done = subprocess.run(install, capture_output=True, env=env, timeout=timeout)
    except subprocess.TimeoutExpired:
        return None, f"installing Debian's chromium took over {timeout:.0f} s"
    exe = find_browser()
    if exe:
        return exe, ""
    tail = done.stderr.decode(errors="replace").strip().splitlines()[-1:] or ["no message"]
    return None, f"installing Debian's chromium failed: {tail[0]}"


# Run as ``python -c _PIPES_THEN_EXEC R W BROWSER ARGS...``: BROWSER ARGS... with pipe ends R and W
# (passed with ``pass_fds``) as its fds 3 and 4, which ``--remote-debugging-pipe`` reads and writes.
# Both are first copied above 100, out of the way of 3 and 4 (R or W may be one of them).
_PIPES_THEN_EXEC = ("import fcntl, os, sys\n"
                    "r, w = int(sys.argv[1]), int(sys.argv[2])\n"
                    "a, b = fcntl.fcntl(r, fcntl.F_DUPFD, 100), fcntl.fcntl(w, fcntl.F_DUPFD, 100)\n"
                    "os.dup2(a, 3)\n"
                    "os.dup2(b, 4)\n"
                    "for fd in {r, w, a, b} - {3, 4}:\n"
                    "    os.close(fd)\n"
                    "os.execv(sys.argv[3], sys.argv[3:])")
"""Not a ``preexec_fn`` (it was, until 2026-12-06): with one, ``subprocess`` must fork() instead of
vfork(), and the fork of a pytest process in which gRPC is alive (an xdist worker after fake-Spot
tests) can abort in the child before exec (gRPC's fork support meets the epoll fd that
``close_fds`` closed: SIGABRT, exit -6; see ``_python_with_default_hangup`` in
``tests/test_spot_realtime_faults.py``, where ``tools spot``'s child was fixed the same way).
``tests/test_subprocess_rules.py`` keeps ``preexec_fn`` out of tests/ and the packages."""


@dataclass
class PageResult:
    url: str
    images: list[dict]                        # src, complete, naturalWidth, naturalHeight
    links: list[str]                          # hrefs as the browser resolved them
    resources: list[str]                      # every URL the page loaded (performance entries)
    errors: list[str] = field(default_factory=list)   # console errors, exceptions, failed loads


class Browser:
    """One headless Chromium; ``load`` a local file, then read what it saw."""

    def __init__(self, exe: str, width: int = 1280, height: int = 1000, timeout: float = 60.0):
        self.timeout = timeout
        self.profile = tempfile.mkdtemp(prefix="helios-chromium-")
        to_chrome_r, self._w = os.pipe()
        self._r, from_chrome_w = os.pipe()
        args = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run",
                "--no-default-browser-check", "--disable-extensions", "--remote-debugging-pipe",
                f"--user-data-dir={self.profile}", f"--window-size={width},{height}", "about:blank"]
        # the protocol's fds 3 (commands in) and 4 (answers out), set by a shim that then execs the
        # browser (see _PIPES_THEN_EXEC: no preexec_fn)
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _PIPES_THEN_EXEC, str(to_chrome_r), str(from_chrome_w), *args],
            pass_fds=(to_chrome_r, from_chrome_w), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL)
        os.close(to_chrome_r)
        os.close(from_chrome_w)
        self._buf = b""
        self._id = 0
        self._events: list[dict] = []
        try:
            target = self._send("Target.createTarget", {"url": "about:blank"})["targetId"]
            self._session = self._send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
            for domain in ("Page", "Runtime", "Log"):
                self._send(f"{domain}.enable", session=True)
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ protocol
    def _send(self, method: str, params: dict | None = None, session: bool = False) -> dict:
        self._id += 1
        msg: dict = {"id": self._id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = self._session
        os.write(self._w, json.dumps(msg).encode() + b"\0")
        end = time.monotonic() + self.timeout
        while True:
            m = self._read(end)
            if m.get("id") == self._id:
                if "error" in m:
                    raise RuntimeError(f"{method}: {m['error']}")
                return m.get("result", {})
            self._events.append(m)

    def _read(self, end: float) -> dict:
        while b"\0" not in self._buf:
            left = end - time.monotonic()
            if left <= 0:
                raise TimeoutError("the browser did not answer in time")
            ready, _, _ = select.select([self._r], [], [], left)
            if ready:
                chunk = os.read(self._r, 1 << 20)
                if not chunk:
                    raise EOFError("the browser closed its DevTools pipe (did it start?)")
                self._buf += chunk
        msg, _, self._buf = self._buf.partition(b"\0")
        return json.loads(msg)

    def _wait_for(self, method: str) -> dict:
        for i, e in enumerate(self._events):
            if e.get("method") == method:
                return self._events.pop(i)
        end = time.monotonic() + self.timeout
        while True:
            m = self._read(end)
            if m.get("method") == method:
                return m
            self._events.append(m)

    def _eval(self, expression: str):
        r = self._send("Runtime.evaluate", {"expression": expression, "returnByValue": True, "awaitPromise": True},
                       session=True)
        if "exceptionDetails" in r:
            raise RuntimeError(f"evaluate failed: {r['exceptionDetails']}")
        return r["result"].get("value")

    # ------------------------------------------------------------------ use
    def load(self, path: Path) -> PageResult:
        """Open a local file, wait for its load event (images included) and report what happened."""
        self._events = [e for e in self._events if e.get("method") != "Page.loadEventFired"]
        url = Path(path).resolve().as_uri()
        nav = self._send("Page.navigate", {"url": url}, session=True)
        if nav.get("errorText"):
            return PageResult(url, [], [], [], [f"navigation failed: {nav['errorText']}"])
        self._wait_for("Page.loadEventFired")
        self._eval("new Promise(r => setTimeout(r, 50))")      # late console messages
        images = self._eval("Array.from(document.images).map(i => ({src: i.src, complete: i.complete, "
                            "naturalWidth: i.naturalWidth, naturalHeight: i.naturalHeight}))")
        links = self._eval("Array.from(document.links).map(a => a.href)")
        resources = self._eval("performance.getEntriesByType('resource').map(e => e.name)")
        errors = []
        for e in self._events:
            method, p = e.get("method"), e.get("params", {})
            if method == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
                errors.append("console: " + " ".join(str(a.get("value", a.get("description", ""))) for a in p["args"]))
            elif method == "Runtime.exceptionThrown":
                errors.append(f"exception: {p.get('exceptionDetails', {}).get('text')}")
            elif method == "Log.entryAdded" and p.get("entry", {}).get("level") == "error":
                entry = p["entry"]
                errors.append(f"{entry.get('source')}: {entry.get('text')} {entry.get('url', '')}".strip())
        self._events = []
        return PageResult(url, images, links, resources, errors)

    def screenshot(self, path: Path, max_height: int = 8000) -> Path:
        """The whole page (up to ``max_height`` CSS pixels) as a PNG."""
        size = self._send("Page.getLayoutMetrics", session=True)["cssContentSize"]
        clip = {"x": 0, "y": 0, "width": size["width"], "height": min(size["height"], max_height), "scale": 1}
        shot = self._send("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": True, "clip": clip},
                          session=True)
        Path(path).write_bytes(base64.b64decode(shot["data"]))
        return Path(path)

    def close(self) -> None:
        try:
            self._send("Browser.close")
        except Exception:  # noqa: BLE001 - closing anyway
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        for fd in (self._w, self._r):
            try:
                os.close(fd)
            except OSError:
                pass
        shutil.rmtree(self.profile, ignore_errors=True)

    def __enter__(self) -> "Browser":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
