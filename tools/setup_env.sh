#!/usr/bin/env bash
# Create the project virtual environment and install everything the tests and the main job need.
# Idempotent: safe to re-run. Usage: bash tools/setup_env.sh [VENV_DIR]
set -euo pipefail
venv="${1:-.venv}"

say() { echo "[setup] $*"; }

# 1. Python >= 3.11 (rerun-sdk 0.41 and open3d 0.20 need it).
py=""
for cand in python3.11 python3 python; do
  if command -v "$cand" >/dev/null 2>&1 && "$cand" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)'; then
    py="$cand"; break
  fi
done
[ -n "$py" ] || { echo "[setup] error: Python >= 3.11 is required (found none on PATH)." >&2; exit 1; }

# 2. Open3D's native library needs Debian's libusb-1.0-0.
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  say "installing Debian package libusb-1.0-0 (needed by Open3D)"
  if [ "$(id -u)" = "0" ]; then sudo_cmd=""; elif command -v sudo >/dev/null 2>&1; then sudo_cmd="sudo"; else
    echo "[setup] error: libusb-1.0-0 is missing and this user cannot install packages; run 'apt-get install libusb-1.0-0' as root." >&2; exit 1
  fi
  export DEBIAN_FRONTEND=noninteractive
  $sudo_cmd apt-get install -y --no-install-recommends libusb-1.0-0 >/dev/null 2>&1 || {
    $sudo_cmd apt-get update -qq >/dev/null && $sudo_cmd apt-get install -y --no-install-recommends libusb-1.0-0 >/dev/null
  }
fi

# 2b. Debian's chromium: tests/test_report_browser.py loads the trial report in headless Chromium
#     (about 100 MB, ~20 s). Optional: where it cannot be installed, that test tries once more
#     and otherwise skips with one message. HELIOS_NO_BROWSER_INSTALL=1 leaves it out.
have_browser=""
for b in chromium chromium-browser google-chrome google-chrome-stable chrome headless_shell; do
  command -v "$b" >/dev/null 2>&1 && { have_browser="$b"; break; }
done
if [ -z "$have_browser" ] && [ -z "${HELIOS_NO_BROWSER_INSTALL:-}" ] && command -v apt-get >/dev/null 2>&1; then
  if [ "$(id -u)" = "0" ]; then sudo_cmd=""; elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
    sudo_cmd="sudo -n"; else sudo_cmd="none"; fi
  if [ "$sudo_cmd" != "none" ]; then
    say "installing Debian package chromium (headless browser for the report's browser test)"
    export DEBIAN_FRONTEND=noninteractive
    $sudo_cmd apt-get install -y --no-install-recommends chromium >/dev/null 2>&1 || {
      $sudo_cmd apt-get update -qq >/dev/null 2>&1 && $sudo_cmd apt-get install -y --no-install-recommends chromium >/dev/null 2>&1
    } || say "warning: could not install chromium; the browser test will skip"
  fi
fi

# 3. Virtual environment + pinned dependencies (torch==2.13.0 is the local CPU wheel).
# A venv that already serves another checkout (an editable install of this project from a folder
# that still exists) is refused: pip install -e would silently re-point it here, and the other
# checkout would go on running this one's code.
if [ -x "$venv/bin/python" ]; then
  served=$("$venv/bin/python" -I - <<'PY' 2>/dev/null || true
import importlib.metadata as md, json, urllib.parse
try:
    text = md.distribution("helios-testbed").read_text("direct_url.json") or "{}"
except md.PackageNotFoundError:
    raise SystemExit
url = json.loads(text).get("url", "")
if url.startswith("file://"):
    print(urllib.parse.unquote(url[len("file://"):]))    # pip writes the path percent-encoded
PY
)
  if [ -n "$served" ] && [ -d "$served" ] && [ "$(cd "$served" && pwd -P)" != "$(pwd -P)" ]; then
    echo "[setup] error: $venv already serves the checkout at $served; installing would re-point it to $(pwd -P). Give this checkout its own venv (make VENV=.venv-here ...) or remove $venv first." >&2
    exit 1
  fi
fi
if [ ! -x "$venv/bin/python" ]; then
  say "creating $venv with $py"
  "$py" -m venv "$venv"
fi
say "installing the project and its extras into $venv (first run takes a few minutes)"
# (grep drops this machine's harmless "Location ... is ignored" notices about optional local indexes)
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check -e '.[all]' 2>&1 \
  | { grep -v "^WARNING: Location 'file://" || true; }
"$venv/bin/python" - <<'PY'
import importlib
mods = ["numpy", "scipy", "torch", "cv2", "pybullet", "open3d", "ruckig", "rerun", "yaml", "bosdyn.client"]
for m in mods:
    importlib.import_module(m)
import torch
assert "+cpu" in torch.__version__ or not torch.version.cuda, f"unexpected torch build {torch.__version__}"
print("[setup] ok:", ", ".join(mods))
PY
