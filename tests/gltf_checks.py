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

import numpy as np
import pygltflib
import pytest
from scipy.spatial.transform import Rotation

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


# ----------------------------------------------------------------------------------------------
# reading a GLB back with pygltflib (independently of ncflow's reader)


_DTYPES = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def accessor(gltf: pygltflib.GLTF2, index: int) -> np.ndarray:
    """An accessor's data as an (count, width) array (tightly packed views only)."""
    acc = gltf.accessors[index]
    view = gltf.bufferViews[acc.bufferView]
    dtype = np.dtype(_DTYPES[acc.componentType])
    width = _WIDTHS[acc.type]
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    assert view.byteStride is None and start % 4 == 0
    assert (acc.byteOffset or 0) + acc.count * width * dtype.itemsize <= view.byteLength
    data = np.frombuffer(gltf.binary_blob(), dtype=dtype, count=acc.count * width, offset=start)
    return data.reshape(acc.count, width)


def node_world(gltf: pygltflib.GLTF2) -> np.ndarray:
    """World transforms of all nodes from their TRS, composed down the children lists."""
    n = len(gltf.nodes)
    local = np.tile(np.eye(4), (n, 1, 1))
    for i, node in enumerate(gltf.nodes):
        r = Rotation.from_quat(node.rotation or [0, 0, 0, 1]).as_matrix()
        local[i, :3, :3] = r * np.asarray(node.scale or [1, 1, 1])
        local[i, :3, 3] = node.translation or [0, 0, 0]
    world = np.full((n, 4, 4), np.nan)

    def visit(i, parent):
        world[i] = parent @ local[i]
        for c in gltf.nodes[i].children or []:
            visit(c, world[i])

    for i in gltf.scenes[gltf.scene].nodes:
        visit(i, np.eye(4))
    return world


def skin_arrays(path):
    """(document, the first mesh's position, joints, weights, indices and inverse bind matrices)."""
    gltf = pygltflib.GLTF2().load_binary(str(path))
    prim = gltf.meshes[0].primitives[0]
    return gltf, {
        "position": accessor(gltf, prim.attributes.POSITION).astype(np.float64),
        "joints": accessor(gltf, prim.attributes.JOINTS_0).astype(np.int64),
        "weights": accessor(gltf, prim.attributes.WEIGHTS_0).astype(np.float64),
        "indices": accessor(gltf, prim.indices).reshape(-1, 3),
        "ibm": accessor(gltf, gltf.skins[0].inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1),
    }
