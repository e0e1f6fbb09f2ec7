"""Fuzzing the file readers: every input gives a result or one InputError line, never another exception.

Each reader is fed two kinds of files, written into a scratch folder: random bytes or text, and
mutations of a valid small file (byte flips, cut, repeated and inserted spans, numbers replaced by
extreme ones, and for JSON a value anywhere in the tree replaced or removed; the mutations find far
more than random input, which mostly fails at the first byte). A reader must return or raise
:class:`~ncflow.errors.InputError` whose message is one line naming the file and quoting little of
it; any other exception fails the test. Library warnings (overflow in a cast, an odd GLB version,
an invalid escape in an ``.npy`` header) are expected on such input and ignored here.

Examples per reader (``max_examples`` of each test, multiplied by the environment variable
``NCFLOW_FUZZ_SCALE`` for a longer hunt, e.g. 20; at scale 1 the whole file runs in about 25 s on
2 cores):

=====================================================  ==========  =========
reader                                                 mutations   random
=====================================================  ==========  =========
``load_mesh`` OBJ                                      300         60
``load_mesh`` PLY (ASCII)                              300         60
``load_mesh`` OFF                                      300         60
``load_skeleton`` TGF                                  500         100
``load_skeleton`` JSON                                 500         100
``load_gltf_skin`` + ``pose`` + ``gltf_skeleton``      600 .gltf   60
  + ``gltf_animations``                                200 .glb    (shared)
``load_mesh`` glTF (.gltf) / GLB                       200 / 200   60 (shared)
``load_ground_truth`` .vts / .txt                      150 / 150   100
``load_ground_truth`` .npy / .npz                      200 / 200   (shared)
``load_mano`` .npz (arrays replaced / bytes mutated)   300         60
``load_mano`` .pkl (bytes mutated)                     300         (shared)
=====================================================  ==========  =========

In all 4,800 examples (about 25 s); a run at scale 20 (96,000 examples, 6.5 min) found nothing more.
"""

from __future__ import annotations

import base64
import io
import json
import os
import pickle
import re
import struct

import numpy as np
import pytest
import scipy.sparse
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ncflow.errors import InputError
from ncflow.geometry.mesh import Mesh
from ncflow.io.gltf.animation import gltf_animations
from ncflow.io.gltf.skins import gltf_skeleton, load_gltf_skin
from ncflow.io.ground_truth import load_ground_truth
from ncflow.io.mano import load_mano
from ncflow.io.meshes import load_mesh
from ncflow.io.skeletons import load_skeleton
from ncflow.synthetic.shapes import sphere

FUZZ_SCALE = float(os.environ.get("NCFLOW_FUZZ_SCALE", "1"))

pytestmark = pytest.mark.filterwarnings(
    "ignore::RuntimeWarning",
    "ignore::UserWarning",
    "ignore::DeprecationWarning",  # see the module docstring
)


def fuzz(n: int):
    """Hypothesis settings for ``n`` examples (times ``NCFLOW_FUZZ_SCALE``): no deadline, no example database."""
    return settings(
        max_examples=max(1, int(n * FUZZ_SCALE)),
        deadline=None,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much],
    )


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


def check(read, path, *args) -> None:
    """``read(path, *args)`` returns, or raises a short one-line InputError naming ``path``."""
    try:
        read(path, *args)
    except InputError as exc:
        msg = str(exc)
        assert "\n" not in msg, msg
        assert str(path) in msg, msg
        assert len(msg) - len(str(path)) < 400, msg


def write(workdir, name: str, data: bytes | str):
    path = workdir / name
    path.write_bytes(data.encode("utf-8", "surrogatepass") if isinstance(data, str) else data)
    return path


# ----------------------------------------------------------------------------------------------
# mutations


EXTREME_NUMBERS = [
    "0",
    "-1",
    "-0",
    "1e-320",
    "1e309",
    "-1e309",
    "nan",
    "inf",
    "2147483647",
    "2147483648",
    "4294967295",
    "4294967296",
    "9223372036854775807",
    "9223372036854775808",
    "-9223372036854775809",
    "18446744073709551616",
    "1099511627776",
    "9" * 40,
    "1" * 5000,
    "0.5",
    "1e5",
]
NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


@st.composite
def mutated(draw, seed: bytes) -> bytes:
    """A few random edits of ``seed``: byte changes, cut / repeated / inserted spans, numbers replaced."""
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["byte", "cut", "repeat", "insert", "number", "number", "number"]))
        i = draw(st.integers(0, max(len(data) - 1, 0)))
        j = min(len(data), i + draw(st.integers(0, 24)))
        if op == "byte" and data:
            data[i] = draw(st.integers(0, 255))
        elif op == "cut":
            del data[i:j]
        elif op == "repeat":
            data[i:i] = bytes(data[i:j]) * draw(st.integers(1, 3))
        elif op == "insert":
            data[i:i] = draw(st.binary(max_size=8) | st.sampled_from([b"\n", b" ", b"#", b"\x00", b"-"]))
        else:
            numbers = list(NUMBER.finditer(bytes(data)))
            if numbers:
                m = numbers[draw(st.integers(0, len(numbers) - 1))]
                data[m.start() : m.end()] = draw(st.sampled_from(EXTREME_NUMBERS)).encode()
    return bytes(data)


JSON_VALUES = st.one_of(
    st.sampled_from([0, -1, 1, 2, 3, 4, 5, 2**31, 2**32, 2**40, 2**63, 2**64, -(2**63) - 1, 10**30]),
    st.integers(-10, 10),
    st.floats(allow_nan=False),
    st.sampled_from([None, True, False, "", "x", "SCALAR", "VEC4", "MAT4", "LINEAR", "CUBICSPLINE", "../x.bin"]),
    st.sampled_from(["n" * 3000, 10**4000, 1e300, -1e-300]),
    st.lists(st.integers(-3, 10), max_size=5),
    st.builds(dict),  # fresh objects: a shared one could be put inside itself
    st.builds(lambda: [[[[[]]]]]),
)


def _json_slots(value, out: list) -> list:
    """Every (container, key) of a JSON tree."""
    if isinstance(value, dict):
        for k, v in value.items():
            out.append((value, k))
            _json_slots(v, out)
    elif isinstance(value, list):
        for k, v in enumerate(value):
            out.append((value, k))
            _json_slots(v, out)
    return out


@st.composite
def mutated_json(draw, seed: dict) -> str:
    """``seed`` with a few values anywhere in the tree replaced or removed (keys kept JSON-valid)."""
    doc = json.loads(json.dumps(seed))
    for _ in range(draw(st.integers(1, 3))):
        slots = _json_slots(doc, [])
        if not slots:
            break
        container, key = slots[draw(st.integers(0, len(slots) - 1))]
        if isinstance(container, dict) and draw(st.booleans()) and draw(st.booleans()):
            del container[key]
        else:
            container[key] = draw(JSON_VALUES)
    return json.dumps(doc)  # NaN / Infinity included: Python's json reads them


# ----------------------------------------------------------------------------------------------
# meshes (OBJ, PLY, OFF)

TETRA = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
TETRA_FACES = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
MESH_SEEDS = {
    ".obj": "# tetra\n"
    + "".join(f"v {x} {y} {z}\n" for x, y, z in TETRA)
    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in TETRA_FACES),
    ".ply": "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
    "element face 4\nproperty list uchar int vertex_indices\nend_header\n"
    + "".join(f"{x} {y} {z}\n" for x, y, z in TETRA)
    + "".join(f"3 {a} {b} {c}\n" for a, b, c in TETRA_FACES),
    ".off": "OFF\n4 4 6\n"
    + "".join(f"{x} {y} {z}\n" for x, y, z in TETRA)
    + "".join(f"3 {a} {b} {c}\n" for a, b, c in TETRA_FACES),
}
MESH_TEXT = st.text(alphabet=st.sampled_from(list("0123456789 \n\t-.eE#/vfnlpyOFFelementvertexfaceproperty")))


@pytest.mark.parametrize("suffix", sorted(MESH_SEEDS))
def test_mesh_seeds_are_valid(workdir, suffix):
    assert load_mesh(write(workdir, "seed" + suffix, MESH_SEEDS[suffix])).n_faces == 4


@pytest.mark.parametrize("suffix", sorted(MESH_SEEDS))
@fuzz(300)
@given(data=st.data())
def test_fuzz_mesh_mutations(workdir, suffix, data):
    check(load_mesh, write(workdir, "m" + suffix, data.draw(mutated(MESH_SEEDS[suffix].encode()))))


@pytest.mark.parametrize("suffix", sorted(MESH_SEEDS))
@fuzz(60)
@given(text=MESH_TEXT)
def test_fuzz_mesh_random_text(workdir, suffix, text):
    check(load_mesh, write(workdir, "r" + suffix, text))


# ----------------------------------------------------------------------------------------------
# skeletons (TGF, JSON)

TGF_SEED = "1 0 0 0\n2 0 1 0\n3 0 2 0\n4 1 1 0\n#\n1 2\n2 3\n2 4\n#\n"
JSON_SKELETON_SEED = {
    "names": ["root", "spine", "head", "arm"],
    "parents": [-1, 0, 1, 1],
    "positions": [[0, 0, 0], [0, 1, 0], [0, 2, 0], [1, 1, 0]],
    "radii": [None, 0.1, 0.2, None],
}


def test_skeleton_seeds_are_valid(workdir):
    assert load_skeleton(write(workdir, "seed.tgf", TGF_SEED)).n_joints == 4
    assert load_skeleton(write(workdir, "seed.json", json.dumps(JSON_SKELETON_SEED))).n_joints == 4


@fuzz(500)
@given(data=st.data())
def test_fuzz_tgf_mutations(workdir, data):
    check(load_skeleton, write(workdir, "m.tgf", data.draw(mutated(TGF_SEED.encode()))))


@fuzz(100)
@given(text=st.text(alphabet=st.sampled_from(list("0123456789 \n-.e#")), max_size=200) | st.text(max_size=100))
def test_fuzz_tgf_random_text(workdir, text):
    check(load_skeleton, write(workdir, "r.tgf", text))


@fuzz(500)
@given(data=st.data())
def test_fuzz_json_skeleton_mutations(workdir, data):
    if data.draw(st.booleans()):
        text = data.draw(mutated_json(JSON_SKELETON_SEED))
    else:
        text = data.draw(mutated(json.dumps(JSON_SKELETON_SEED).encode()))
    check(load_skeleton, write(workdir, "m.json", text))


@fuzz(100)
@given(value=st.recursive(JSON_VALUES, lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(), c, max_size=4)))
def test_fuzz_json_skeleton_random(workdir, value):
    check(load_skeleton, write(workdir, "r.json", json.dumps(value)))


# ----------------------------------------------------------------------------------------------
# glTF (.gltf with an embedded data-URI buffer)


def gltf_seed() -> dict:
    """A skinned triangle: two joints, inverse bind matrices and a two-key rotation clip."""
    parts = [
        np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], "<f4"),  # 0 POSITION
        np.array([0, 1, 2, 0], "<u2"),  # 1 indices (3 used)
        np.array([[0, 1, 0, 0]] * 3, "u1"),  # 2 JOINTS_0
        np.array([[0.5, 0.5, 0, 0]] * 3, "<f4"),  # 3 WEIGHTS_0
        np.stack([np.eye(4), np.eye(4) - np.outer(np.eye(4)[1], np.eye(4)[3])]).astype("<f4").transpose(0, 2, 1),
        # 4 inverse bind matrices, column-major (joint 1 bound at y = 1)
        np.array([0.0, 1.0], "<f4"),  # 5 keyframe times
        np.array([[0, 0, 0, 1], [0, 0, 0.7071068, 0.7071068]], "<f4"),  # 6 rotations
    ]
    blob, views = b"", []
    for p in parts:
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": p.nbytes})
        blob += p.tobytes()
    kinds = [(5126, "VEC3", 3), (5123, "SCALAR", 3), (5121, "VEC4", 3), (5126, "VEC4", 3), (5126, "MAT4", 2)]
    kinds += [(5126, "SCALAR", 2), (5126, "VEC4", 2)]
    accessors = [{"bufferView": i, "componentType": c, "type": t, "count": n} for i, (c, t, n) in enumerate(kinds)]
    accessors[0].update(min=[0, 0, 0], max=[1, 1, 0])
    accessors[5].update(min=[0], max=[1])
    return {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 2]}],
        "nodes": [
            {"name": "root", "children": [1]},
            {"name": "tip", "translation": [0, 1, 0], "rotation": [0, 0, 0, 1], "scale": [1, 1, 1]},
            {"name": "hand", "mesh": 0, "skin": 0},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "JOINTS_0": 2, "WEIGHTS_0": 3}, "indices": 1}]}],
        "skins": [{"joints": [0, 1], "inverseBindMatrices": 4}],
        "animations": [
            {
                "name": "bend",
                "samplers": [{"input": 5, "output": 6, "interpolation": "LINEAR"}],
                "channels": [{"sampler": 0, "target": {"node": 1, "path": "rotation"}}],
            }
        ],
        "buffers": [
            {"byteLength": len(blob), "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}
        ],
        "bufferViews": views,
        "accessors": accessors,
    }


GLTF_SEED = gltf_seed()


def glb_bytes(doc: dict) -> bytes:
    """``doc`` as a GLB: its data-URI buffer moved into the binary chunk."""
    doc = json.loads(json.dumps(doc))
    blob = base64.b64decode(doc["buffers"][0].pop("uri").split(",", 1)[1])
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    blob += b"\0" * (-len(blob) % 4)
    chunks = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(blob), b"BIN\0") + blob
    return b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks


GLB_SEED = glb_bytes(GLTF_SEED)


def read_gltf_everything(path) -> None:
    """Every glTF reader on one file: the skin, its poses, its skeleton, its clips."""
    rig = load_gltf_skin(path)
    rig.pose()
    if rig.animations:
        rig.pose(0.5)
        gltf_skeleton(rig, 0.5)
    gltf_skeleton(path)
    gltf_animations(path)


def test_gltf_seed_is_valid(workdir):
    for path in (write(workdir, "seed.gltf", json.dumps(GLTF_SEED)), write(workdir, "seed.glb", GLB_SEED)):
        read_gltf_everything(path)
        assert load_mesh(path).n_faces == 1


@fuzz(600)
@given(data=st.data())
def test_fuzz_gltf_mutations(workdir, data):
    if data.draw(st.integers(0, 3)):
        text = data.draw(mutated_json(GLTF_SEED))
    else:
        text = data.draw(mutated(json.dumps(GLTF_SEED).encode()))
    check(read_gltf_everything, write(workdir, "m.gltf", text))


@fuzz(200)
@given(data=st.data())
def test_fuzz_gltf_mesh_mutations(workdir, data):
    check(load_mesh, write(workdir, "mesh.gltf", data.draw(mutated_json(GLTF_SEED))))


@fuzz(200)
@given(data=st.data())
def test_fuzz_glb_mutations(workdir, data):
    path = write(workdir, "m.glb", data.draw(mutated(GLB_SEED)))
    check(read_gltf_everything, path)
    check(load_mesh, path)


@fuzz(60)
@given(raw=st.binary(max_size=200) | st.binary(max_size=100).map(lambda b: b"glTF" + b))
def test_fuzz_gltf_random_bytes(workdir, raw):
    check(read_gltf_everything, write(workdir, "r.gltf", raw))
    check(load_mesh, write(workdir, "r.glb", raw))


# ----------------------------------------------------------------------------------------------
# ground truth (.vts, .txt, .npy, .npz)

_V, _F = sphere(1)
SOURCE = Mesh(_V, _F, name="src.obj")
TARGET = Mesh(_V * 1.1, _F, name="tgt.obj")
_N = SOURCE.n_vertices


def _npy_bytes(array) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


def _npz_bytes(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


GT_SEEDS = {
    ".vts": "".join(f"{i + 1}\n" for i in range(_N)).encode(),
    ".txt": ("# map\n" + "".join(f"{i}\n" for i in range(_N))).encode(),
    ".npy": _npy_bytes(np.arange(_N)),
    ".npz": _npz_bytes(face=np.arange(_N), bary=np.tile([0.2, 0.3, 0.5], (_N, 1)), target_index=np.arange(_N)),
}


def read_gt(path) -> None:
    load_ground_truth(path, SOURCE, TARGET)


def test_ground_truth_seeds_are_valid(workdir):
    for suffix, seed in GT_SEEDS.items():
        assert load_ground_truth(write(workdir, "seed" + suffix, seed), SOURCE, TARGET).face.shape == (_N,)


@pytest.mark.parametrize("suffix, n", [(".vts", 150), (".txt", 150), (".npy", 200), (".npz", 200)])
def test_fuzz_ground_truth_mutations(workdir, suffix, n):
    @fuzz(n)
    @given(data=st.data())
    def run(data):
        check(read_gt, write(workdir, "m" + suffix, data.draw(mutated(GT_SEEDS[suffix]))))

    run()


@fuzz(100)
@given(
    text=st.text(alphabet=st.sampled_from(list("0123456789 \n-.e#,nan")), max_size=300),
    suffix=st.sampled_from([".vts", ".txt"]),
)
def test_fuzz_ground_truth_random_text(workdir, text, suffix):
    check(read_gt, write(workdir, "r" + suffix, text))


# ----------------------------------------------------------------------------------------------
# MANO (.npz arrays, .pkl bytes)


def mano_seed() -> dict:
    nv, nj = 6, 16
    parents = [-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14]
    return {
        "v_template": np.arange(nv * 3, dtype=float).reshape(nv, 3),
        "faces": np.array([[0, 1, 2], [2, 3, 4], [3, 4, 5]]),
        "weights": np.full((nv, nj), 1.0 / nj),
        "J_regressor": np.full((nj, nv), 1.0 / nv),
        "kintree_table": np.array([[2**32 - 1] + parents[1:], list(range(nj))], dtype=np.int64),
        "posedirs": np.zeros((nv, 3, 9 * (nj - 1))),
        "shapedirs": np.zeros((nv, 3, 2)),
        "hands_components": np.eye(45),
        "hands_mean": np.zeros(45),
        "hands_coeffs": np.zeros((2, 45)),
    }


MANO_SEED = mano_seed()
MANO_PKL_SEED = pickle.dumps(
    {**MANO_SEED, "J_regressor": scipy.sparse.csc_matrix(MANO_SEED["J_regressor"]), "bs_style": "lbs"}, protocol=2
)
ARRAY_DTYPES = ["<f8", "<f4", "<i8", "<u4", "u1", "?", "<c8", "<U3", "S2", "<f2", ">f8", "V4", "<m8"]


@st.composite
def mano_arrays(draw) -> dict:
    """The seed model with a few arrays removed, reshaped, recast or replaced by random small arrays."""
    arrays = dict(MANO_SEED)
    for _ in range(draw(st.integers(1, 3))):
        key = draw(st.sampled_from(sorted(arrays) + ["f"]))
        op = draw(st.sampled_from(["delete", "random", "reshape", "cast", "poison"]))
        value = arrays.get(key, MANO_SEED["faces"])
        if op == "delete":
            arrays.pop(key, None)
        elif op == "random":
            shape = tuple(draw(st.lists(st.integers(0, 5), max_size=3)))
            arrays[key] = np.zeros(shape, dtype=draw(st.sampled_from(ARRAY_DTYPES)))
        elif op == "reshape":
            arrays[key] = value.reshape(-1) if draw(st.booleans()) else value.reshape(1, *value.shape)
        elif value.dtype.kind not in "biuf":
            continue  # a random array of strings, complex numbers, ...: neither cast nor poisoned
        elif op == "cast":
            arrays[key] = value.astype(draw(st.sampled_from(ARRAY_DTYPES[:6])))
        else:
            poisoned = value.astype(float).copy()
            if poisoned.size:
                k = draw(st.integers(0, poisoned.size - 1))
                poisoned.flat[k] = draw(st.sampled_from([np.nan, np.inf, -5, 1e300]))
            arrays[key] = poisoned
    return arrays


def test_mano_seeds_are_valid(workdir):
    assert load_mano(write(workdir, "seed.npz", _npz_bytes(**MANO_SEED))).n_joints == 16
    assert load_mano(write(workdir, "seed.pkl", MANO_PKL_SEED)).n_joints == 16


@fuzz(300)
@given(data=st.data())
def test_fuzz_mano_npz(workdir, data):
    if data.draw(st.integers(0, 3)):
        raw = _npz_bytes(**data.draw(mano_arrays()))
    else:
        raw = data.draw(mutated(_npz_bytes(**MANO_SEED)))
    check(load_mano, write(workdir, "m.npz", raw))


@fuzz(300)
@given(data=st.data())
def test_fuzz_mano_pkl(workdir, data):
    check(load_mano, write(workdir, "m.pkl", data.draw(mutated(MANO_PKL_SEED))))


@fuzz(60)
@given(raw=st.binary(max_size=300), suffix=st.sampled_from([".npz", ".pkl"]))
def test_fuzz_mano_random_bytes(workdir, raw, suffix):
    check(load_mano, write(workdir, "r" + suffix, raw))
