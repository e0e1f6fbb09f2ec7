"""The atomic-write helper (``ncflow.io.atomic``) and the one mesh writer's precision flag (``save_mesh``).

References are independent of the code under test: bytes and text compared literally, PLY files
decoded by hand with NumPy from the header's declared layout, OBJ coordinates parsed with
``float``, float32 rounding from ``numpy.float32``, the strict JSON text from ``json.dumps`` with
the converter the result writer used before the JSON helpers were merged.
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import numpy as np
import pytest
import trimesh

import ncflow.io.atomic as atomic
from ncflow.errors import InputError
from ncflow.io.arrays import dumps_strict, json_safe
from ncflow.io.atomic import atomic_path, atomic_write_bytes, atomic_write_text
from ncflow.io.meshes import save_mesh


def _entries(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


@pytest.fixture
def mesh():
    """An icosphere (162 vertices) with coordinates that float32 cannot hold exactly."""
    m = trimesh.creation.icosphere(subdivisions=2)
    rng = np.random.default_rng(7)
    v = np.asarray(m.vertices, dtype=np.float64) * np.array([1.0, 0.8, 1.3]) + np.pi
    v = v + rng.normal(scale=1e-3, size=v.shape)
    return v, np.asarray(m.faces, dtype=np.int64)


def _read_ply_by_hand(path: Path) -> tuple[np.ndarray, np.ndarray, str]:
    """Decode a binary little-endian PLY (x, y, z of one type; uchar-count int faces) from its header."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii")
    assert "format binary_little_endian 1.0" in header
    nv = int(re.search(r"element vertex (\d+)", header).group(1))
    nf = int(re.search(r"element face (\d+)", header).group(1))
    kinds = re.findall(r"property (float|double) [xyz]", header)
    assert len(kinds) == 3 and len(set(kinds)) == 1
    vt = "<f4" if kinds[0] == "float" else "<f8"
    verts = np.frombuffer(data, dtype=vt, count=3 * nv, offset=end).reshape(nv, 3)
    rec = np.frombuffer(data, dtype=[("n", "u1"), ("idx", "<i4", (3,))], count=nf, offset=end + verts.nbytes)
    assert np.all(rec["n"] == 3)
    assert end + verts.nbytes + rec.nbytes == len(data)
    return verts.astype(np.float64), rec["idx"].astype(np.int64), header


# ----------------------------------------------------------------------------------------------
# atomic writes


def test_atomic_write_bytes_and_text_write_exactly(tmp_path):
    payload = bytes(range(256)) * 3 + b"\x00\r\n\n"
    atomic_write_bytes(tmp_path / "blob.bin", payload)
    assert (tmp_path / "blob.bin").read_bytes() == payload
    text = 'a\nb ε 1.5\n{\n "x": [1, 2]\n}\n'
    atomic_write_text(tmp_path / "t.json", text)
    assert (tmp_path / "t.json").read_bytes() == text.encode()
    atomic_write_text(tmp_path / "t.json", "shorter\n")  # replaces, no leftover bytes
    assert (tmp_path / "t.json").read_bytes() == b"shorter\n"
    assert _entries(tmp_path) == ["blob.bin", "t.json"]  # no temporary files left


def test_writer_error_leaves_no_partial_file_and_keeps_the_old_one(tmp_path):
    target = tmp_path / "out.txt"
    with pytest.raises(OSError, match="disk full"):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half of the new con")
            raise OSError(28, "disk full")
    assert _entries(tmp_path) == []  # neither the destination nor a temporary file

    target.write_bytes(b"the earlier file\n")
    with pytest.raises(OSError, match="disk full"):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half of the new con")
            raise OSError(28, "disk full")
    assert target.read_bytes() == b"the earlier file\n"
    assert _entries(tmp_path) == ["out.txt"]


def test_failed_write_inside_the_helpers_is_cleaned_up(tmp_path, monkeypatch):
    """An OSError half-way through ``write_bytes`` / ``write_text`` (a full disk) propagates unchanged."""
    target = tmp_path / "keep.bin"
    target.write_bytes(b"old")

    def half_then_fail(self, data):
        with open(self, "wb") as fh:
            fh.write(data[: len(data) // 2] if isinstance(data, bytes) else data[: len(data) // 2].encode())
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Path, "write_bytes", half_then_fail)
    monkeypatch.setattr(Path, "write_text", half_then_fail)
    with pytest.raises(OSError, match="No space left"):
        atomic_write_bytes(target, b"new content, longer than the old one")
    with pytest.raises(OSError, match="No space left"):
        atomic_write_text(target, "new content, longer than the old one")
    monkeypatch.undo()
    assert target.read_bytes() == b"old"
    assert _entries(tmp_path) == ["keep.bin"]


def test_failed_move_keeps_the_old_file(tmp_path, monkeypatch):
    target = tmp_path / "keep.txt"
    target.write_text("old\n")

    def no_replace(src, dst):
        raise OSError(13, "Permission denied")

    monkeypatch.setattr(atomic.os, "replace", no_replace)
    with pytest.raises(OSError, match="Permission denied"):
        atomic_write_text(target, "new\n")
    monkeypatch.undo()
    assert target.read_text() == "old\n"
    assert _entries(tmp_path) == ["keep.txt"]


def test_temporary_name_is_a_hidden_sibling_with_the_suffix(tmp_path):
    """Writers that choose the format or append a suffix from the name (np.savez) see the final suffix."""
    seen = []
    with atomic_path(tmp_path / "map.npz") as tmp:
        seen.append(tmp)
        assert tmp.parent == tmp_path and tmp.name.startswith(".map.") and tmp.suffix == ".npz"
        np.savez(tmp, face=np.arange(4), bary=np.full((4, 3), 1 / 3))
    assert _entries(tmp_path) == ["map.npz"]  # no "map.npz.npz", no temporary file
    with np.load(tmp_path / "map.npz") as z:
        assert np.array_equal(z["face"], np.arange(4)) and np.array_equal(z["bary"], np.full((4, 3), 1 / 3))
    with atomic_path(tmp_path / "map.npz") as tmp2:
        assert tmp2 != seen[0]  # a fresh name each time
        tmp2.write_bytes(b"")


def test_atomic_file_gets_the_usual_permissions(tmp_path):
    """The temporary file is created by the writer, so the result has the umask's mode (not mkstemp's 0600)."""
    umask = os.umask(0o022)
    os.umask(umask)
    atomic_write_text(tmp_path / "a.txt", "x")
    (tmp_path / "b.txt").write_text("x")
    assert (tmp_path / "a.txt").stat().st_mode == (tmp_path / "b.txt").stat().st_mode


# ----------------------------------------------------------------------------------------------
# the mesh writer's precision flag


def test_float64_ply_round_trips_exactly(tmp_path, mesh):
    v, f = mesh
    save_mesh(tmp_path / "m.ply", v, f, precision="float64")
    got_v, got_f, header = _read_ply_by_hand(tmp_path / "m.ply")
    assert "property double x" in header and "comment ncflow pair (float64 vertices)" in header
    assert np.array_equal(got_v, v)  # bit for bit
    assert np.array_equal(got_f, f)
    assert _entries(tmp_path) == ["m.ply"]


def test_float64_obj_round_trips_exactly(tmp_path, mesh):
    v, f = mesh
    save_mesh(tmp_path / "m.obj", v, f, precision="float64")
    lines = (tmp_path / "m.obj").read_text().splitlines()
    got_v = np.array([[float(x) for x in ln.split()[1:]] for ln in lines if ln.startswith("v ")])
    got_f = np.array([[int(x) - 1 for x in ln.split()[1:]] for ln in lines if ln.startswith("f ")])
    assert np.array_equal(got_v, v)
    assert np.array_equal(got_f, f)


@pytest.mark.parametrize("precision", [None, "float32"])
def test_float32_ply_rounds_to_float32(tmp_path, mesh, precision):
    v, f = mesh
    kwargs = {} if precision is None else {"precision": precision}  # float32 is the default
    save_mesh(tmp_path / "m.ply", v, f, **kwargs)
    got_v, got_f, header = _read_ply_by_hand(tmp_path / "m.ply")
    assert "property float x" in header
    rounded = v.astype(np.float32).astype(np.float64)
    assert np.array_equal(got_v, rounded)
    assert not np.array_equal(got_v, v)  # the coordinates need more than float32
    assert np.max(np.abs(got_v - v)) <= np.max(np.abs(v)) * 2.0**-24
    assert np.array_equal(got_f, f)


def test_float32_obj_keeps_eight_decimals(tmp_path, mesh):
    v, f = mesh
    save_mesh(tmp_path / "m.obj", v, f)
    lines = (tmp_path / "m.obj").read_text().splitlines()
    got_v = np.array([[float(x) for x in ln.split()[1:]] for ln in lines if ln.startswith("v ")])
    assert np.max(np.abs(got_v - v)) <= 0.5e-8 * (1 + 1e-9)


def test_float64_bytes_are_the_pair_writer_layout(tmp_path):
    """The float64 PLY is exactly header + little-endian doubles + (uchar 3, 3 × int32) per face."""
    v = np.array([[0.1, 0.2, 0.3], [1.0 / 3.0, -2.5, 1e-300], [math.pi, math.e, -0.0]])
    f = np.array([[0, 1, 2]])
    save_mesh(tmp_path / "t.ply", v, f, precision="float64")
    header = (
        b"ply\nformat binary_little_endian 1.0\ncomment ncflow pair (float64 vertices)\n"
        b"element vertex 3\nproperty double x\nproperty double y\nproperty double z\n"
        b"element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    )
    body = np.asarray(v, dtype="<f8").tobytes() + bytes([3]) + np.asarray([0, 1, 2], dtype="<i4").tobytes()
    assert (tmp_path / "t.ply").read_bytes() == header + body
    save_mesh(tmp_path / "t.obj", v, f, precision="float64")
    assert (tmp_path / "t.obj").read_text() == (
        "v 0.1 0.2 0.3\nv 0.3333333333333333 -2.5 1e-300\nv 3.141592653589793 2.718281828459045 -0.0\nf 1 2 3\n"
    )


def test_mesh_writer_refusals(tmp_path, mesh):
    v, f = mesh
    with pytest.raises(InputError, match="precision"):
        save_mesh(tmp_path / "m.ply", v, f, precision="float16")
    with pytest.raises(InputError, match=r"\.ply or \.obj"):
        save_mesh(tmp_path / "m.off", v, f, precision="float64")
    bad = v.copy()
    bad[5, 1] = np.nan
    for precision in ("float32", "float64"):
        with pytest.raises(InputError, match="non-finite"):
            save_mesh(tmp_path / "m.ply", bad, f, precision=precision)
    assert _entries(tmp_path) == []


def test_mesh_writer_failure_keeps_the_earlier_mesh(tmp_path, mesh, monkeypatch):
    v, f = mesh
    save_mesh(tmp_path / "m.ply", v, f)
    before = (tmp_path / "m.ply").read_bytes()

    def broken_export(self, file_obj=None, **kwargs):
        Path(file_obj).write_bytes(b"ply\nformat binary_little_endian 1.0\n")  # a truncated file
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(trimesh.Trimesh, "export", broken_export)
    with pytest.raises(OSError, match="No space left"):
        save_mesh(tmp_path / "m.ply", v + 1.0, f)
    assert (tmp_path / "m.ply").read_bytes() == before
    assert _entries(tmp_path) == ["m.ply"]


# ----------------------------------------------------------------------------------------------
# strict JSON


def _old_metrics_default(value):
    """The converter ``metrics.json`` was written with before the JSON helpers were merged."""
    if isinstance(value, np.generic):
        return value.item()
    if hasattr(value, "__array__"):
        return np.asarray(value).tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot write {type(value).__name__} to JSON")


def test_strict_json_text_matches_the_former_metrics_writer():
    import jax.numpy as jnp

    metrics = {
        "loss": np.float32(0.125),
        "n": np.int64(3),
        "arr": np.arange(3.0) / 3,
        "jax": jnp.arange(3.0) / 7,
        "jax0": jnp.float32(0.3),
        "tuple": (1, 2.5, "s"),
        "path": Path("/a/b"),
        "nested": {"ok": np.bool_(True), "list": [np.float64(1 / 3), None, "ε"], "ints": np.arange(3, dtype=np.int32)},
        5: "int key",
        0.5: "float key",
        "big": 2**70,
        "tiny": 5e-324,
    }
    expected = json.dumps(metrics, indent=1, default=_old_metrics_default, allow_nan=False, sort_keys=False) + "\n"
    safe, replaced = json_safe(metrics)
    assert replaced == []
    assert dumps_strict(safe) == expected


def test_strict_json_refuses_what_json_cannot_hold():
    with pytest.raises(TypeError, match="cannot write object to JSON"):
        dumps_strict({"x": object()})
    with pytest.raises(ValueError):
        dumps_strict({"x": float("nan")})  # json_safe must have replaced it
    safe, replaced = json_safe({"x": [1.0, float("inf")], "y": {"z": np.float32("nan")}})
    assert safe == {"x": [1.0, None], "y": {"z": None}} and replaced == ["x[1]", "y.z"]
