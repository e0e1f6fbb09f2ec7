"""The headless Chromium the viewer's browser tests drive (Debian's ``chromium``; .ci/run installs it): the
``browser`` fixture, the ``browser_test`` mark that skips without it, and :class:`Page`, a page whose every
request is recorded (and refused unless it is the page itself) with its console errors."""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np
import pytest

CHROMIUM = next((p for p in ("/usr/bin/chromium", shutil.which("chromium") or "") if p and Path(p).exists()), None)
ARGS = [
    "--no-sandbox",
    "--headless=new",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
browser_test = pytest.mark.skipif(
    CHROMIUM is None, reason="no chromium binary (Debian's chromium package; .ci/run installs it)"
)


@pytest.fixture(scope="module")
def browser():
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield b
        b.close()


class Page:
    """A page with every request recorded (and refused unless it is the page itself) and every console error."""

    def __init__(self, browser, path: Path, hash_: str = "", **options):
        self.page = browser.new_page(viewport={"width": 960, "height": 540}, **options)
        self.url = path.resolve().as_uri()
        self.requests: list[str] = []
        self.errors: list[str] = []
        self.page.on("console", lambda m: self.errors.append(m.text) if m.type == "error" else None)
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.page.route("**/*", self._route)
        self.page.goto(self.url + hash_)
        deadline = time.monotonic() + 30
        # polled from here: the page's Content-Security-Policy forbids the eval of wait_for_function
        while not self.page.evaluate("window.ncflowViewer && (window.ncflowViewer.ready || window.ncflowViewer.error)"):
            assert time.monotonic() < deadline, "the viewer did not start"
            time.sleep(0.05)
        assert self.page.evaluate("window.ncflowViewer.error") is None

    def _route(self, route):
        self.requests.append(route.request.url)
        if route.request.url == self.url:
            route.continue_()
        else:
            route.abort()

    def pixels(self) -> np.ndarray:
        from io import BytesIO

        from matplotlib.image import imread

        shot = self.page.locator("#ncv-canvas").screenshot()
        return (imread(BytesIO(shot), format="png")[..., :3] * 255).round()
