"""The trial report in a real browser (issue 20): headless Chromium loads the report of a small
run and every episode page, every image resolves, the console shows no errors, nothing is
fetched from outside the report folder, and a screenshot is written.

Chromium comes from Debian's ``chromium`` package: ``tools/setup_env.sh`` installs it, and this
test installs it itself when it is missing and the user may (``tests/browser.py``); with no way
to get a browser it is skipped with one message saying why.
"""

from __future__ import annotations

from pathlib import Path
from urllib.parse import unquote, urlparse

import numpy as np
import pytest

from browser import Browser, find_or_install_browser
from tools.report import FIGURES


@pytest.fixture(scope="session")          # session, like picture_runs, so that a skip comes first
def browser_exe():
    exe, why = find_or_install_browser()
    if exe is None:
        pytest.skip(f"browser test skipped: no headless Chromium can be had here ({why})")
    return exe


def _local(url: str) -> Path | None:
    u = urlparse(url)
    return Path(unquote(u.path)) if u.scheme == "file" else None


def test_the_report_loads_in_a_browser_with_every_image_and_no_errors(browser_exe, picture_runs, tmp_path):
    from PIL import Image

    report = picture_runs["root"] / "report"
    pages = [report / "index.html"] + [report / p.page for ps in picture_runs["report"]["pages"].values() for p in ps]
    assert len(pages) == 3
    with Browser(browser_exe) as browser:
        for page in pages:
            seen = browser.load(page)
            assert seen.errors == [], (page, seen.errors)
            assert seen.images, page
            for img in seen.images:
                assert img["complete"] and img["naturalWidth"] > 0 and img["naturalHeight"] > 0, (page, img)
                assert img["src"].startswith(("file:", "data:image/png")), img["src"]
                local = _local(img["src"])
                assert local is None or report.resolve() in local.resolve().parents, img["src"]   # offline, inside
            for link in seen.links:                     # every link is a file of the report folder
                target = _local(link)
                assert target is not None and target.is_file() and report.resolve() in target.resolve().parents, link
            assert all(r.startswith(("file:", "data:")) for r in seen.resources), seen.resources
            if page.name == "index.html":
                shot = browser.screenshot(tmp_path / "report.png")
        index_images = browser.load(report / "index.html").images
    failed = sum(not r["success"] for r in picture_runs["records"].values())
    assert failed and len(index_images) == len(FIGURES) + failed      # the plots and a thumbnail per failed episode
    pixels = np.asarray(Image.open(shot).convert("RGB"))
    assert pixels.shape[0] > 1000 and pixels.shape[1] >= 800 and pixels.std() > 20      # the page, not a blank
