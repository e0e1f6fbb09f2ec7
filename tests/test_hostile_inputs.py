"""Hostile input files: every reader refuses them with one InputError line naming the file.

One regression test per finding of the security review of the file readers (crafted files are
written here into ``tmp_path``):

1. a MANO ``.pkl`` cannot run code (restricted unpickler) but real MANO-like pickles still load;
2. glTF resource URIs and trimesh resources stay inside the file's folder, regular files only;
3. sizes are checked against the file before allocating (glTF accessors, ``.npy`` / ``.npz``);
4. scene-graph instancing cannot multiply a mesh without bound;
5. skeleton validation is linear, joints are limited, TGF ids and JSON numbers are checked;
6. a malformed MANO ``.npz`` names the key.
"""

from __future__ import annotations

import base64
import io
import json
import os
import pickle
import struct
import sys
import time
import tracemalloc
import types
import zipfile

import numpy as np
import pytest
import scipy.sparse

from ncflow.errors import InputError
from ncflow.geometry.mesh import Mesh
from ncflow.geometry.skeleton import MAX_JOINTS, Skeleton, merge_zero_length_bones, validate_skeleton
from ncflow.io.files import read_npz_arrays
from ncflow.io.gltf.animation import gltf_animations
from ncflow.io.gltf.document import load_document
from ncflow.io.gltf.skins import _skeleton_parents, gltf_skeleton, load_gltf_skin, pose_gltf
from ncflow.io.ground_truth import load_ground_truth
from ncflow.io.mano import load_mano
from ncflow.io.meshes import MAX_MESH_INSTANCES, _confined_resolver, load_mesh, mesh_instance_counts
from ncflow.io.skeletons import load_skeleton
from ncflow.synthetic.shapes import sphere

# ----------------------------------------------------------------------------------------------
# helpers


def one_line(exc_info, path=None, *words) -> str:
    """The message, checked to be one line naming ``path`` and holding ``words``."""
    msg = str(exc_info.value)
    assert "\n" not in msg
    if path is not None:
        assert str(path) in msg, msg
    for w in words:
        assert w in msg, msg
    return msg


def gltf_document(buffer_uri: str | None = None, n_mesh_nodes: int = 1, skinned: bool = True) -> tuple[dict, bytes]:
    """A skinned triangle (two joints) as glTF JSON and its buffer; ``buffer_uri`` None embeds the buffer."""
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype="<f4").tobytes()
    indices = np.array([0, 1, 2, 0], dtype="<u2").tobytes()  # padded to 8 bytes
    joints = np.array([[0, 1, 0, 0]] * 3, dtype="u1").tobytes()
    weights = np.array([[0.5, 0.5, 0, 0]] * 3, dtype="<f4").tobytes()
    blob = positions + indices + joints + weights
    views, offset = [], 0
    for part in (positions, indices, joints, weights):
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(part)})
        offset += len(part)
    views[1]["byteLength"] = 6
    accessors = [
        {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
        {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"},
        {"bufferView": 2, "componentType": 5121, "count": 3, "type": "VEC4"},
        {"bufferView": 3, "componentType": 5126, "count": 3, "type": "VEC4"},
    ]
    attributes = {"POSITION": 0}
    if skinned:
        attributes.update(JOINTS_0=2, WEIGHTS_0=3)
    nodes = [{"name": "root", "children": [1]}, {"name": "tip", "translation": [0, 1, 0]}]
    mesh_nodes = [{"mesh": 0, **({"skin": 0} if skinned else {})} for _ in range(n_mesh_nodes)]
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, *range(2, 2 + n_mesh_nodes)]}],
        "nodes": nodes + mesh_nodes,
        "meshes": [{"primitives": [{"attributes": attributes, "indices": 1}]}],
        "buffers": [{"byteLength": len(blob)}],
        "bufferViews": views,
        "accessors": accessors,
    }
    if skinned:
        doc["skins"] = [{"joints": [0, 1]}]
    doc["buffers"][0]["uri"] = buffer_uri or "data:application/octet-stream;base64," + base64.b64encode(blob).decode()
    return doc, blob


def with_keyframes(doc: dict, blob: bytes, times: np.ndarray) -> dict:
    """``doc`` (from :func:`gltf_document`) with accessors 4 (the float32 ``times``) and 5 (as many
    identity rotations) appended to its embedded buffer, for animation samplers."""
    rotations = np.tile(np.array([0, 0, 0, 1], "<f4"), (times.size, 1))
    for part, ctype in ((times.astype("<f4").tobytes(), "SCALAR"), (rotations.tobytes(), "VEC4")):
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(part)})
        doc["accessors"].append(
            {"bufferView": len(doc["bufferViews"]) - 1, "componentType": 5126, "count": times.size, "type": ctype}
        )
        blob += part
    doc["buffers"][0] = {"byteLength": len(blob), "uri": "data:;base64," + base64.b64encode(blob).decode()}
    return doc


def write_gltf(path, doc: dict):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc))
    return path


# ----------------------------------------------------------------------------------------------
# 1. MANO pickles run no code


class _RunsCode:
    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


class _WritesFile:
    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (exec, (f"open({self.marker!r}, 'w').write('owned')",))


@pytest.mark.parametrize("payload", [_RunsCode, _WritesFile])
def test_mano_pickle_refuses_code_execution(tmp_path, payload):
    marker = tmp_path / "owned"
    path = tmp_path / "MANO_RIGHT.pkl"
    path.write_bytes(pickle.dumps({"v_template": payload(marker)}, protocol=2))
    with pytest.raises(InputError) as ei:
        load_mano(path)
    one_line(ei, path, "refusing to load", "global")
    assert "system" in str(ei.value) or "exec" in str(ei.value)
    assert not marker.exists()


def test_mano_pickle_cannot_allocate_through_numpy(tmp_path):
    big = b"J\x00\x00\x02\x00"  # BININT 131072: an array of 131072**2 float64 (128 GiB)
    calls = [
        b"cnumpy\nndarray\n" + big + big + b"\x86\x81",  # NEWOBJ: ndarray((131072, 131072))
        b"cnumpy.core.multiarray\n_reconstruct\ncnumpy\nndarray\n" + big + big + b"\x86U\x01b\x87R",
        b"cnumpy.core.multiarray\n_reconstruct\ncbuiltins\nbytearray\n" + big + b"\x85U\x01b\x87R",
    ]
    for k, call in enumerate(calls):
        path = tmp_path / f"alloc{k}.pkl"
        path.write_bytes(b"\x80\x02}U\nv_template" + call + b"s.")
        exc, peak = refused_with_peak(lambda p=path: load_mano(p))
        assert peak < 5 * 2**20 and str(path) in str(exc), str(exc)


def test_mano_pickle_with_lying_lengths_or_shared_lists(tmp_path):
    path = tmp_path / "lies.pkl"
    path.write_bytes(b"\x80\x04\x8e" + struct.pack("<Q", 2**40) + b"abc.")  # BINBYTES8 of 1 TiB, 3 bytes given
    exc, peak = refused_with_peak(lambda: load_mano(path))
    assert peak < 5 * 2**20 and "lies.pkl" in str(exc)
    row = [0.0] * 1000
    shared = [row] * 1000  # a pickle stores this in a few KiB; as an array it is 8 MB, nested again 8 GB
    arr = _mano_arrays()
    arr["v_template"] = [shared] * 1000
    path.write_bytes(pickle.dumps(arr, protocol=2))
    assert path.stat().st_size < 200_000
    with pytest.raises(InputError) as ei:
        load_mano(path)
    one_line(ei, path, "'v_template' is not an array")


def _mano_arrays(nv: int = 6, nj: int = 16) -> dict:
    rng = np.random.default_rng(1)
    parents = [-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14][:nj]
    weights = rng.random((nv, nj))
    return {
        "v_template": rng.random((nv, 3)),
        "faces": np.array([[0, 1, 2], [2, 3, 4], [3, 4, 5]]),
        "weights": weights / weights.sum(1, keepdims=True),
        "J_regressor": rng.random((nj, nv)),
        "kintree_table": np.array([[2**32 - 1] + parents[1:], list(range(nj))], dtype=np.int64),
        "posedirs": rng.random((nv, 3, 9 * (nj - 1))),
        "shapedirs": rng.random((nv, 3, 10)),
        "hands_components": rng.random((45, 45)),
        "hands_mean": rng.random(45),
        "hands_coeffs": rng.random((4, 45)),
    }


@pytest.mark.parametrize("protocol", [0, 2, 4, 5])
def test_mano_pickle_with_arrays_sparse_and_chumpy_still_loads(tmp_path, monkeypatch, protocol):
    arr = _mano_arrays()
    chumpy, ch_mod = types.ModuleType("chumpy"), types.ModuleType("chumpy.ch")

    class Ch:
        def __init__(self, x):
            self.x = x

    Ch.__module__, Ch.__qualname__ = "chumpy.ch", "Ch"
    ch_mod.Ch, chumpy.ch = Ch, ch_mod
    monkeypatch.setitem(sys.modules, "chumpy", chumpy)
    monkeypatch.setitem(sys.modules, "chumpy.ch", ch_mod)
    data = dict(arr)
    data["f"] = data.pop("faces").astype(np.uint32)
    data["shapedirs"] = Ch(arr["shapedirs"])
    data["v_template"] = Ch(Ch(arr["v_template"]))
    data["J_regressor"] = scipy.sparse.csc_matrix(arr["J_regressor"])
    data["weights"] = scipy.sparse.csr_matrix(arr["weights"])
    data["bs_style"] = "lbs"
    path = tmp_path / "MANO_RIGHT.pkl"
    path.write_bytes(pickle.dumps(data, protocol=protocol))
    monkeypatch.delitem(sys.modules, "chumpy")
    monkeypatch.delitem(sys.modules, "chumpy.ch")
    model = load_mano(path)
    for key in ("v_template", "weights", "J_regressor", "posedirs", "shapedirs", "hands_components"):
        np.testing.assert_array_equal(getattr(model, key), arr[key])
    np.testing.assert_array_equal(model.faces, arr["faces"])
    np.testing.assert_array_equal(model.parents, [-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14])


def test_mano_pickle_sparse_matrix_with_out_of_range_indices(tmp_path):
    arr = _mano_arrays()
    bad = scipy.sparse.csc_matrix(arr["J_regressor"])
    bad.indices = bad.indices.copy()
    bad.indices[0] = 10**6  # would be written outside the dense array
    arr["J_regressor"] = bad
    path = tmp_path / "bad_sparse.pkl"
    path.write_bytes(pickle.dumps(arr, protocol=2))
    with pytest.raises(InputError) as ei:
        load_mano(path)
    one_line(ei, path, "'J_regressor'", "sparse")


# ----------------------------------------------------------------------------------------------
# 6. malformed MANO .npz


def _malformed(key, value):
    def change(arr):
        if value is None:
            del arr[key]
        else:
            arr[key] = value
        return arr

    return change


@pytest.mark.parametrize(
    "change, key",
    [
        (_malformed("posedirs", None), "posedirs"),
        (_malformed("weights", np.zeros((6, 3))), "weights"),
        (_malformed("v_template", np.array([["a", "b", "c"]] * 6)), "v_template"),
        (_malformed("kintree_table", np.arange(16)), "kintree_table"),
        (_malformed("kintree_table", np.zeros((2, 16), dtype=np.int64)), "kintree_table"),
        (_malformed("posedirs", np.full((6, 3, 135), np.nan)), "posedirs"),
        (_malformed("faces", np.array([[0, 1, 99]])), "faces"),
        (_malformed("faces", np.array([[0.5, 1, 2]])), "faces"),
        (_malformed("J_regressor", np.zeros((16, 6), dtype=complex)), "J_regressor"),
        (_malformed("hands_coeffs", np.zeros((4, 7))), "hands_coeffs"),
        (_malformed("v_template", np.zeros(())), "v_template"),
    ],
)
def test_malformed_mano_npz_names_file_and_key(tmp_path, change, key):
    path = tmp_path / "mano.npz"
    np.savez(path, **change(_mano_arrays()))
    with pytest.raises(InputError) as ei:
        load_mano(path)
    one_line(ei, path, key)


def test_mano_npz_with_object_array_is_refused(tmp_path):
    arr = _mano_arrays()
    arr["v_template"] = np.array([object()] * 3, dtype=object)
    path = tmp_path / "mano.npz"
    np.savez(path, **arr)
    with pytest.raises(InputError) as ei:
        load_mano(path)
    one_line(ei, path, "object arrays")


# ----------------------------------------------------------------------------------------------
# 2. glTF and trimesh resources stay inside the file's folder


SECRET_SIZE = 12345


@pytest.fixture
def model_dir(tmp_path):
    """``tmp_path/model`` for the glTF; ``tmp_path/secret.bin`` (SECRET_SIZE bytes) outside it."""
    (tmp_path / "secret.bin").write_bytes(b"s" * SECRET_SIZE)
    (tmp_path / "model" / "sub").mkdir(parents=True)
    return tmp_path / "model"


@pytest.mark.parametrize(
    "uri",
    [
        "../secret.bin",
        "sub/../../secret.bin",
        "%2e%2e%2fsecret.bin",
        "sub%2F..%2F..%2Fsecret.bin",
        "..%5csecret.bin",
        "{root}/secret.bin",
        "file://{root}/secret.bin",
        "C:/secret.bin",
        "c:secret.bin",
        "\\\\server\\share\\secret.bin",
    ],
)
@pytest.mark.parametrize("reader", ["skin", "mesh", "animations"])
def test_gltf_uri_leaving_the_folder_is_refused(model_dir, uri, reader):
    uri = uri.format(root=model_dir.parent)
    doc, _ = gltf_document(buffer_uri=uri)
    doc["buffers"][0]["byteLength"] = SECRET_SIZE + 1  # would leak the secret's size if compared
    path = write_gltf(model_dir / "hand.gltf", doc)
    read = {"skin": load_gltf_skin, "mesh": load_mesh, "animations": gltf_animations}[reader]
    with pytest.raises(InputError) as ei:
        read(path)
    msg = one_line(ei, path, "refusing")
    assert str(SECRET_SIZE) not in msg


def test_gltf_image_uri_leaving_the_folder_is_refused(model_dir):
    doc, _ = gltf_document()
    doc["images"] = [{"uri": "../secret.bin"}]
    path = write_gltf(model_dir / "hand.gltf", doc)
    with pytest.raises(InputError) as ei:
        load_document(path)
    one_line(ei, path, "image 0: refusing")


def _special_files(model_dir):
    os.mkfifo(model_dir / "pipe.bin")
    (model_dir / "out.bin").symlink_to(model_dir.parent / "secret.bin")
    (model_dir / "zero.bin").symlink_to("/dev/zero")
    return {"pipe.bin": "not a regular file", "out.bin": "link out", "zero.bin": "link out", "sub": "not a regular"}


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs and symbolic links")
def test_gltf_buffer_that_is_a_fifo_device_folder_or_outward_link_is_refused(model_dir):
    for uri, words in _special_files(model_dir).items():
        doc, _ = gltf_document(buffer_uri=uri)
        path = write_gltf(model_dir / "hand.gltf", doc)
        with pytest.raises(InputError) as ei:
            load_gltf_skin(path)  # a FIFO would block here if it were opened for reading plainly
        msg = one_line(ei, path, "buffer 0", words)
        assert str(SECRET_SIZE) not in msg


def test_gltf_buffer_beside_the_file_still_loads(model_dir):
    doc, blob = gltf_document(buffer_uri="sub/my%20buffer.bin")
    (model_dir / "sub" / "my buffer.bin").write_bytes(blob)
    path = write_gltf(model_dir / "hand.gltf", doc)
    assert load_gltf_skin(path).positions.shape == (3, 3)
    (model_dir / "inside.bin").symlink_to(model_dir / "sub" / "my buffer.bin")
    doc, _ = gltf_document(buffer_uri="inside.bin")
    write_gltf(path, doc)
    assert load_mesh(path).n_vertices == 3


def test_gltf_short_external_buffer_does_not_leak_its_size(model_dir):
    doc, blob = gltf_document(buffer_uri="short.bin")
    (model_dir / "short.bin").write_bytes(blob[:17])
    path = write_gltf(model_dir / "hand.gltf", doc)
    with pytest.raises(InputError) as ei:
        load_gltf_skin(path)
    msg = one_line(ei, path, "shorter than its byteLength")
    assert "17" not in msg.replace(str(path), "")  # the temporary folder's name may hold a 17 (pytest-17)


def test_trimesh_resources_are_confined_to_the_mesh_folder(model_dir, monkeypatch):
    import trimesh.resolvers

    def never(self, name):
        raise AssertionError(f"trimesh's own resolver read {name!r}")

    monkeypatch.setattr(trimesh.resolvers.FilePathResolver, "get", never)
    (model_dir.parent / "secret.mtl").write_text("newmtl m\nmap_Kd ../secret.bin\n")
    obj = model_dir / "tri.obj"
    obj.write_text("mtllib ../secret.mtl\nusemtl m\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert load_mesh(obj).n_faces == 1  # the material library is never read
    resolver = _confined_resolver(obj)
    for name in ("../secret.mtl", str(model_dir.parent / "secret.mtl"), "sub/../../secret.bin"):
        with pytest.raises(FileNotFoundError):
            resolver.get(name)
    assert len(resolver.refused) == 3 and all("refusing" in r for r in resolver.refused)
    (model_dir / "sub" / "inside.mtl").write_text("newmtl m\n")
    assert resolver.namespaced("sub").get("inside.mtl") == b"newmtl m\n"
    with pytest.raises(FileNotFoundError):
        resolver.namespaced("..").get("secret.mtl")


def test_obj_reader_opens_only_its_file_and_bounds_its_size(tmp_path, monkeypatch):
    import builtins

    import ncflow.io.obj as obj_module

    (tmp_path / "secret.mtl").write_text("newmtl m\n")
    obj = tmp_path / "in" / "tri.obj"
    obj.parent.mkdir()
    obj.write_text("mtllib ../secret.mtl\nusemtl m\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    opened = []
    real_open = builtins.open

    def spy(file, *args, **kwargs):
        opened.append(os.fspath(file))
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", spy)
    assert load_mesh(obj).n_faces == 1
    assert {os.path.realpath(p) for p in opened if isinstance(p, str)} == {os.path.realpath(obj)}
    monkeypatch.setattr(builtins, "open", real_open)
    monkeypatch.setattr(obj_module, "MAX_OBJ_BYTES", 20)
    with pytest.raises(InputError, match=r"tri\.obj: is \d+ bytes, more than the limit of 20"):
        load_mesh(obj)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_input_file_that_is_a_fifo_is_refused(tmp_path):
    for name, read in (
        ("m.obj", load_mesh),
        ("s.tgf", load_skeleton),
        ("h.gltf", load_gltf_skin),
        ("m.npz", load_mano),
    ):
        os.mkfifo(tmp_path / name)
        with pytest.raises(InputError) as ei:
            read(tmp_path / name)
        one_line(ei, tmp_path / name, "not a regular file")


# ----------------------------------------------------------------------------------------------
# 3. sizes checked against the file before allocating


def refused_with_peak(fn) -> tuple[InputError, int]:
    """The InputError that ``fn()`` raises and the peak of memory traced meanwhile (NumPy arrays included)."""
    tracemalloc.start()
    try:
        fn()
    except InputError as exc:
        return exc, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    raise AssertionError("no InputError")


@pytest.mark.parametrize("with_view", [True, False])
@pytest.mark.parametrize("reader", ["skin", "mesh"])
def test_gltf_accessor_count_beyond_its_buffer_is_refused_before_allocating(tmp_path, with_view, reader):
    doc, _ = gltf_document()
    doc["accessors"][0]["count"] = 2**40
    if not with_view:
        del doc["accessors"][0]["bufferView"]
    path = write_gltf(tmp_path / "huge.gltf", doc)
    assert path.stat().st_size < 1200
    read = load_gltf_skin if reader == "skin" else load_mesh
    with pytest.raises(InputError) as ei:  # once untraced: the modules it imports are not the file's doing
        read(path)
    one_line(ei, path, "accessor 0")
    exc, peak = refused_with_peak(lambda: read(path))
    assert peak < 5 * 2**20 and str(exc) == str(ei.value)


def test_gltf_small_file_with_huge_count_reads_nothing(tmp_path):
    doc, _ = gltf_document()
    doc["accessors"][3]["count"] = 2**40
    path = write_gltf(tmp_path / "huge.gltf", doc)
    exc, peak = refused_with_peak(lambda: load_gltf_skin(path))
    assert peak < 5 * 2**20
    assert "reads past the end of its buffer view" in str(exc)


def test_gltf_buffer_view_beyond_its_buffer_is_refused(tmp_path):
    doc, _ = gltf_document()
    doc["bufferViews"][3]["byteLength"] = 10**12
    path = write_gltf(tmp_path / "view.gltf", doc)
    with pytest.raises(InputError) as ei:
        load_gltf_skin(path)
    one_line(ei, path, "bufferView 3 reaches past the end of buffer 0")


def _npz_with_member(path, name: str, payload: bytes, compress=zipfile.ZIP_DEFLATED):
    with zipfile.ZipFile(path, "w", compress) as zf:
        zf.writestr(name, payload)
    return path


def _npy_header(shape, dtype="<f8") -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": dtype, "fortran_order": False, "shape": shape})
    return buf.getvalue()


def test_npz_member_inflating_past_the_limit_is_refused_before_inflating(tmp_path):
    src = Mesh(*sphere(1))
    payload = _npy_header((2**20 // 2,)) + bytes(4 * 2**20)  # 4 MiB of zeros, a few KiB compressed
    path = _npz_with_member(tmp_path / "bomb.npz", "face.npy", payload)
    with zipfile.ZipFile(path, "a", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("bary.npy", payload)
    assert path.stat().st_size < 100_000
    with pytest.raises(InputError) as ei:
        load_ground_truth(path, src, src)
    one_line(ei, path, "over the limit")
    with pytest.raises(InputError, match="over the limit of 1000"):
        read_npz_arrays(path, max_bytes=1000)


def test_npy_header_declaring_more_than_the_file_holds_is_refused(tmp_path):
    src = Mesh(*sphere(1))
    npz = _npz_with_member(tmp_path / "lie.npz", "face.npy", _npy_header((100_000,)) + bytes(10))
    with zipfile.ZipFile(npz, "a") as zf:
        zf.writestr("bary.npy", _npy_header((2, 3)) + bytes(48))
    npy = tmp_path / "lie.npy"
    npy.write_bytes(_npy_header((2**28,), "<i8") + bytes(10))
    for path in (npz, npy):
        exc, peak = refused_with_peak(lambda p=path: load_ground_truth(p, src, src))
        assert peak < 5 * 2**20
        assert str(path) in str(exc) and "truncated" in str(exc), str(exc)


def test_npz_only_needed_keys_are_read(tmp_path):
    src = Mesh(*sphere(1))
    path = tmp_path / "gt.npz"
    n = src.n_vertices
    np.savez(path, face=np.zeros(n, int), bary=np.tile([1.0, 0, 0], (n, 1)), junk=np.array([object()]))
    assert load_ground_truth(path, src, src).face.shape == (n,)  # the object array is never read
    np.savez(path, face=np.zeros(n, int), bary=np.array([object()] * n))
    with pytest.raises(InputError) as ei:
        load_ground_truth(path, src, src)
    one_line(ei, path, "'bary'", "object arrays")


# ----------------------------------------------------------------------------------------------
# 4. scene-graph instancing


def test_one_mesh_instanced_by_5000_nodes_is_refused_quickly(tmp_path):
    doc, _ = gltf_document(n_mesh_nodes=5000, skinned=False)
    path = write_gltf(tmp_path / "many.gltf", doc)
    assert mesh_instance_counts(load_document(path)) == (5000, 5000)
    start = time.perf_counter()
    with pytest.raises(InputError) as ei:
        load_mesh(path)
    assert time.perf_counter() - start < 30.0  # a loose bound (about 1 s alone; 9 s seen beside a benchmark)
    one_line(ei, path, "5000 mesh instances", str(MAX_MESH_INSTANCES))
    doc, _ = gltf_document(n_mesh_nodes=3, skinned=False)  # a few instances still load
    assert load_mesh(write_gltf(tmp_path / "few.gltf", doc), weld=False).n_faces == 3


def test_one_clip_decoded_by_many_channels_is_refused(tmp_path):
    doc = with_keyframes(*gltf_document(), np.arange(2**16, dtype="<f4"))
    doc["animations"] = [
        {
            "samplers": [{"input": 4, "output": 5}] * 200,  # each channel its own sampler, the same 1.25 MiB
            "channels": [{"sampler": k, "target": {"node": 1, "path": "rotation"}} for k in range(200)],
        }
    ]
    path = write_gltf(tmp_path / "channels.gltf", doc)
    with pytest.raises(InputError) as ei:
        gltf_animations(path)
    one_line(ei, path, "times the file's buffers")
    doc["animations"][0]["channels"] = doc["animations"][0]["channels"][:2]  # a few channels are fine
    assert gltf_animations(write_gltf(path, doc))[0].n_channels == 2


def test_glb_instancing_is_refused_too(tmp_path):
    doc, blob = gltf_document(n_mesh_nodes=MAX_MESH_INSTANCES + 1, skinned=False)
    del doc["buffers"][0]["uri"]
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    blob += b"\0" * (-len(blob) % 4)
    chunks = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(blob), b"BIN\0") + blob
    path = tmp_path / "many.glb"
    path.write_bytes(b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks)
    with pytest.raises(InputError) as ei:
        load_mesh(path)
    one_line(ei, path, "mesh instances")


# ----------------------------------------------------------------------------------------------
# 5. skeletons: linear validation, joint limit, ids and numbers


def _chain(n: int) -> tuple[np.ndarray, np.ndarray]:
    positions = np.zeros((n, 3))
    positions[:, 1] = np.arange(n)
    return positions, np.arange(n) - 1


def test_skeleton_validation_is_linear_and_joints_are_limited(tmp_path):
    positions, parents = _chain(MAX_JOINTS)
    start = time.perf_counter()
    validate_skeleton(positions[::-1].copy(), np.where(parents < 0, -1, MAX_JOINTS - 1 - parents)[::-1].copy())
    skel = Skeleton.from_arrays(positions, parents)
    keep, _ = merge_zero_length_bones(positions, parents)
    assert time.perf_counter() - start < 3.0 and skel.n_joints == MAX_JOINTS and keep.size == MAX_JOINTS
    positions, parents = _chain(100_000)
    start = time.perf_counter()
    with pytest.raises(InputError, match="100000 joints, more than the 10000"):
        Skeleton.from_arrays(positions, parents)
    keep, _ = merge_zero_length_bones(positions, parents)  # linear, even beyond the limit
    assert keep.size == 100_000
    lines = [f"{j + 1} 0 {j} 0" for j in range(100_000)] + ["#"] + [f"{j} {j + 1}" for j in range(1, 100_000)]
    path = tmp_path / "chain.tgf"
    path.write_text("\n".join(lines))
    with pytest.raises(InputError) as ei:
        load_skeleton(path)
    one_line(ei, path, "more than 10000 nodes")
    assert time.perf_counter() - start < 5.0


def test_cycle_is_still_found(tmp_path):
    positions, parents = _chain(6)
    parents[2] = 4  # 2 -> 4 -> 3 -> 2
    with pytest.raises(InputError, match="cycle in the parent links"):
        validate_skeleton(positions, parents)


def test_gltf_joint_parents_under_a_deep_node_chain_are_linear():
    n = 100_000
    node_parents = np.arange(n) - 1
    joints = np.arange(n - 50, n)  # the joints hang under 99,950 plain nodes
    start = time.perf_counter()
    parents = _skeleton_parents(joints, node_parents, np.arange(n), np.arange(n))
    assert time.perf_counter() - start < 2.0
    np.testing.assert_array_equal(parents, np.arange(50) - 1)


@pytest.mark.parametrize(
    "node_line, words",
    [
        (f"{2**63} 0 0 0", "out of range"),
        ("-3 0 0 0", "out of range"),
        ("1.5 0 0 0", "expected 'id x y z'"),
        ("1e3 0 0 0", "expected 'id x y z'"),
        ("9" * 5000 + " 0 0 0", "too long"),
        ("1 0 0 0", "duplicate node id 1"),
    ],
)
def test_tgf_node_ids_out_of_range_or_duplicate(tmp_path, node_line, words):
    path = tmp_path / "bad.tgf"
    path.write_text(f"1 0 0 0\n7 0 1 0\n{node_line}\n#\n1 7\n")
    with pytest.raises(InputError) as ei:
        load_skeleton(path)
    msg = one_line(ei, path, words)
    assert len(msg) < len(str(path)) + 200


def test_tgf_edge_id_out_of_range(tmp_path):
    path = tmp_path / "edge.tgf"
    path.write_text(f"1 0 0 0\n2 0 1 0\n#\n1 {2**64}\n")
    with pytest.raises(InputError) as ei:
        load_skeleton(path)
    one_line(ei, path, "line 4", "out of range")


@pytest.mark.parametrize(
    "text, words",
    [
        ("[" * 100_000 + "]" * 100_000, "nested too deeply"),
        ('{"positions": [[0, 0, 0], [0, 1, 0]], "parents": [-1, ' + "1" * 5000 + "]}", "not valid JSON"),
        ('{"positions": [[0, 0, 0], [0, 1, 0]], "parents": [-1, ' + "1" * 4000 + "]}", "out of range"),
        ('{"positions": [[0, 0, 0], [1' + "0" * 400 + ', 1, 0]], "parents": [-1, 0]}', "'positions'"),
        ('{"positions": [[0, 0, 0], [0, 1, 0]], "parents": [-1, 0], "radii": [null, 1' + "0" * 400 + "]}", "radii"),
        ('{"positions": ' + "[" * 500 + "]" * 500 + ', "parents": []}', "positions"),
    ],
)
def test_json_skeleton_deep_nesting_and_long_numbers(tmp_path, text, words):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(InputError) as ei:
        load_skeleton(path)
    msg = one_line(ei, path, words)
    assert len(msg) < len(str(path)) + 200


@pytest.mark.parametrize("suffix", [".gltf", ".glb"])
@pytest.mark.parametrize("kind", ["deep", "digits"])
def test_gltf_json_deep_nesting_and_long_numbers(tmp_path, suffix, kind):
    doc, _ = gltf_document()
    text = json.dumps(doc)
    if kind == "deep":
        text = text[:-1] + ', "extras": ' + "[" * 100_000 + "]" * 100_000 + "}"
    else:
        text = text.replace('"count": 3', '"count": ' + "3" * 5000, 1)
    data = text.encode()
    if suffix == ".glb":
        data += b" " * (-len(data) % 4)
        data = b"glTF" + struct.pack("<II", 2, 20 + len(data)) + struct.pack("<I4s", len(data), b"JSON") + data
    path = tmp_path / f"bad{suffix}"
    path.write_bytes(data)
    for read in (load_gltf_skin, load_mesh, pose_gltf, gltf_animations, gltf_skeleton):
        with pytest.raises(InputError) as ei:
            read(path)
        msg = one_line(ei, path)
        assert len(msg) < len(str(path)) + 200


# ----------------------------------------------------------------------------------------------
# values quoted from a file are cut short (a review of every reader's messages, session 12)


def _bounded(exc_info, path) -> str:
    msg = one_line(exc_info, path)
    assert len(msg) - len(str(path)) < 400, msg
    return msg


def test_quoted_file_values_are_cut_short(tmp_path):
    from ncflow.io.ground_truth import read_index_file
    from ncflow.io.landmarks import read_landmarks
    from ncflow.io.obj_uv import read_obj_uv
    from ncflow.io.vertex_arrays import read_vertex_array

    huge = "7" * 4000  # Python reads integers of up to 4300 digits
    obj = tmp_path / "uv.obj"
    obj.write_text(f"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 {huge}/3\n")
    with pytest.raises(InputError) as ei:
        read_obj_uv(obj)
    assert "out of range" in _bounded(ei, obj)

    marks = tmp_path / "marks.json"
    marks.write_text(f'[{{"name": "tip", "vertex": {huge}}}]')
    with pytest.raises(InputError) as ei:
        read_landmarks(marks, 10)
    assert "out of range" in _bounded(ei, marks)

    off = tmp_path / "polygons.off"  # 300 faces of 300 different sizes
    sizes = range(4, 304)
    faces = "\n".join(f"{k} " + " ".join(str(i % 3) for i in range(k)) for k in sizes)
    off.write_text(f"OFF\n3 {len(sizes)} 0\n0 0 0\n1 0 0\n0 1 0\n{faces}\n")
    with pytest.raises(InputError) as ei:
        load_mesh(off)
    assert "polygons of several sizes" in _bounded(ei, off)
    obj_poly = tmp_path / "polygons.obj"  # the same as OBJ faces: split, and the note cut short
    obj_faces = "".join("f " + " ".join(str(i % 3 + 1) for i in range(k)) + "\n" for k in sizes)
    obj_poly.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n" + obj_faces)
    note = load_mesh(obj_poly, validate=False).notes[0]
    assert note.startswith("300 of 300 faces have [4, 5, 6, 7, 8, ...] corners") and len(note) < 400

    structured = np.zeros(3, dtype=[(f"field_{k:04d}", "<f8") for k in range(300)])  # a 9000-character dtype
    for name, read in (("values.npy", lambda p: read_vertex_array(p, 3)), ("index.npy", read_index_file)):
        path = tmp_path / name
        np.save(path, structured)
        with pytest.raises(InputError) as ei:
            read(path)
        assert "dtype" in _bounded(ei, path)


def test_clip_list_of_an_unknown_animation_is_cut_short(tmp_path):
    doc = with_keyframes(*gltf_document(), np.array([0.0, 1.0], "<f4"))
    doc["accessors"][4].update(min=[0.0], max=[1.0])
    clip = {
        "samplers": [{"input": 4, "output": 5}],
        "channels": [{"sampler": 0, "target": {"node": 1, "path": "rotation"}}],
    }
    doc["animations"] = [{**clip, "name": f"{k}" + "x" * 2000} for k in range(40)]
    path = write_gltf(tmp_path / "clips.gltf", doc)
    with pytest.raises(InputError) as ei:
        pose_gltf(path, time=0.5, animation="walk")
    msg = _bounded(ei, path)
    assert "no animation named 'walk'" in msg and "(40 clips)" in msg
