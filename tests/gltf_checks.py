"""Every GLB ncflow writes is checked by the Khronos glTF validator (``gltf-validator`` from the npm
registry, pinned in ``tests/khronos/package.json``; ``.ci/run`` installs it with ``npm ci --prefix
tests/khronos``). Where Node.js or the package is missing the checks are skipped, unless
``NCFLOW_REQUIRE_GLTF_VALIDATOR=1`` (set by ``.ci/run`` once the install worked) makes that a failure.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

KHRONOS = Path(__file__).resolve().parent / "khronos"


def validator_missing() -> str | None:
    """Why the validator cannot run here, or None when it can."""
    if shutil.which("node") is None:
        return "Node.js is not installed"
    if not (KHRONOS / "node_modules" / "gltf-validator").is_dir():
        return f"the glTF validator is not installed (npm ci --prefix {KHRONOS})"
    return None


def validate_gltf(*paths: str | os.PathLike) -> list[dict]:
    """The validator's report of each file: ``errors``, ``warnings``, ``infos`` (counts) and
    ``messages`` ([severity, code, JSON pointer, text], severity 0 = error).
    """
    why = validator_missing()
    if why is not None:
        if os.environ.get("NCFLOW_REQUIRE_GLTF_VALIDATOR") == "1":
            pytest.fail(f"the Khronos glTF validator is required here: {why}")
        pytest.skip(why)
    done = subprocess.run(
        ["node", str(KHRONOS / "validate.js"), *map(str, paths)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    reports = [json.loads(line) for line in done.stdout.splitlines() if line.strip()]
    assert len(reports) == len(paths)
    return reports


def assert_valid_gltf(*paths: str | os.PathLike) -> None:
    """Every file passes the Khronos validator with no errors and no warnings."""
    for report in validate_gltf(*paths):
        assert report["errors"] == 0 and report["warnings"] == 0, (report["file"], report["messages"])
