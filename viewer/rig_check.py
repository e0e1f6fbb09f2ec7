"""Open a GLB written by ``ncflow rig`` in three.js (GLTFLoader) in headless Chromium; a developer check.

    cd viewer && npm ci && python rig_check.py rigged.glb

Bundles src/rig_check.js with esbuild (three.js from node_modules), loads the GLB into a SkinnedMesh,
and prints: bones, vertices, clips and tracks, the largest distance between the skinned bind pose
and the stored target (should be ~1e-7), and how far the clip's first key (the source pose) moves
the vertices. Exit status 1 on a loader or page error. Needs Node.js/npm and Debian's chromium.
"""

import base64
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from playwright.sync_api import sync_playwright

HERE = Path(__file__).resolve().parent


def main(glb: str) -> int:
    """Load ``glb`` in three.js, print the checks; 0 when the page reported no error."""
    with tempfile.TemporaryDirectory() as tmp:
        bundle = Path(tmp) / "bundle.js"
        subprocess.run(
            [str(HERE / "node_modules/.bin/esbuild"), str(HERE / "src/rig_check.js"), "--bundle", "--format=iife",
             f"--outfile={bundle}", "--log-level=warning"],
            check=True,
        )  # fmt: skip
        data = base64.b64encode(Path(glb).read_bytes()).decode()
        page_file = Path(tmp) / "page.html"
        page_file.write_text(
            f"<html><body><script>window.GLB_B64='{data}';</script><script>{bundle.read_text()}</script></body></html>"
        )
        errors: list[str] = []
        with sync_playwright() as p:
            browser = p.chromium.launch(
                executable_path="/usr/bin/chromium",
                args=["--no-sandbox", "--headless=new", "--disable-background-networking"],
            )
            page = browser.new_page()
            page.on("console", lambda m: errors.append(m.text) if m.type in ("error", "warning") else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(page_file.as_uri())
            page.wait_for_function("window.RESULT !== undefined", timeout=60000)
            result = page.evaluate("window.RESULT")
            browser.close()
    print(json.dumps(result, indent=1))
    for e in errors:
        print("page:", e, file=sys.stderr)
    return 1 if errors or "error" in result else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
