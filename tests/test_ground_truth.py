"""Ground-truth readers: every format parses, every bad file gives one clear line naming it."""

import numpy as np
import pytest

from ncflow.errors import InputError
from ncflow.evaluate import (
    GroundTruth,
    load_ground_truth,
    read_index_file,
    save_ground_truth,
    surface_points,
)
from ncflow.geometry.mesh import Mesh
from ncflow.synthetic.shapes import sphere


@pytest.fixture
def pair():
    v, f = sphere(1)  # 42 vertices, 80 faces
    src = Mesh(v, f, name="src.obj")
    rng = np.random.default_rng(0)
    perm = rng.permutation(len(v))
    tgt = Mesh(v[perm] * 1.1, f, name="tgt.obj")  # arbitrary geometry; only sizes matter
    return src, tgt, perm


def points_of(gt: GroundTruth, src: Mesh):
    return surface_points(src.vertices, src.faces, gt.face, gt.bary)


def write_lines(path, values):
    path.write_text("\n".join(str(x) for x in values) + "\n")
    return path


def one_line(exc_info) -> str:
    msg = str(exc_info.value)
    assert "\n" not in msg
    return msg


# ----------------------------------------------------------------------------------------------
# Formats that parse


def test_identity(pair):
    src, tgt, _ = pair
    gt = load_ground_truth("identity", src, tgt)
    assert gt.complete and gt.n_target == tgt.n_vertices
    np.testing.assert_allclose(points_of(gt, src), src.vertices)
    np.testing.assert_allclose(gt.bary.sum(1), 1.0)
    assert set(np.unique(gt.bary)) == {0.0, 1.0}
    # the chosen face contains the vertex
    assert np.all(np.any(src.faces[gt.face] == np.arange(src.n_vertices)[:, None], axis=1))


def test_vts_one_based(pair, tmp_path):
    src, tgt, perm = pair
    p = write_lines(tmp_path / "map.vts", perm + 1)
    gt = load_ground_truth(p, src, tgt)
    np.testing.assert_allclose(points_of(gt, src), src.vertices[perm])
    assert gt.complete and gt.name == str(p)


def test_index_txt_and_npy_zero_based(pair, tmp_path):
    src, tgt, perm = pair
    txt = tmp_path / "p2p_tgt_to_src.txt"
    txt.write_text("# comment line\n" + "\n".join(str(i) for i in perm) + "\n\n")
    npy = tmp_path / "map.npy"
    np.save(npy, perm.astype(np.int32))
    for p in (txt, npy):
        gt = load_ground_truth(p, src, tgt)
        np.testing.assert_allclose(points_of(gt, src), src.vertices[perm])
    # an integral float array is accepted, a 1-based text file can be read with fmt="vts"
    np.save(npy, perm.astype(np.float64))
    np.testing.assert_allclose(points_of(load_ground_truth(npy, src, tgt), src), src.vertices[perm])
    one = write_lines(tmp_path / "kid01_ref.txt", perm + 1)
    np.testing.assert_allclose(points_of(load_ground_truth(one, src, tgt, fmt="vts"), src), src.vertices[perm])


def test_npz_face_bary_roundtrip(pair, tmp_path):
    src, tgt, _ = pair
    rng = np.random.default_rng(1)
    face = rng.integers(0, src.n_faces, tgt.n_vertices)
    bary = rng.dirichlet([1, 1, 1], tgt.n_vertices).astype(np.float32)  # float32 rounding is tolerated
    p = tmp_path / "map_tgt_to_src.npz"
    np.savez(p, face=face, bary=bary)
    gt = load_ground_truth(p, src, tgt)
    np.testing.assert_array_equal(gt.face, face)
    np.testing.assert_allclose(gt.bary, bary, atol=1e-6)
    np.testing.assert_allclose(gt.bary.sum(1), 1.0, rtol=1e-15)
    out = tmp_path / "sub" / "gt.npz"
    save_ground_truth(out, gt)
    with np.load(out) as z:
        assert sorted(z.files) == ["bary", "face"]
    back = load_ground_truth(out, src, tgt)
    np.testing.assert_array_equal(back.face, gt.face)
    np.testing.assert_allclose(back.bary, gt.bary)


def test_npz_partial_with_target_index(pair, tmp_path):
    src, tgt, _ = pair
    ti = np.array([3, 0, 7])
    p = tmp_path / "partial.npz"
    np.savez(p, face=np.array([1, 2, 3]), bary=np.full((3, 3), 1 / 3), target_index=ti)
    gt = load_ground_truth(p, src, tgt)
    assert not gt.complete
    np.testing.assert_array_equal(gt.target_index, ti)
    save_ground_truth(tmp_path / "again.npz", gt)
    back = load_ground_truth(tmp_path / "again.npz", src, tgt)
    np.testing.assert_array_equal(back.target_index, ti)


def test_template_pair(pair, tmp_path):
    src, tgt, _ = pair
    # template point k sits on source vertex s[k] and target vertex t[k]; target vertex 5 listed twice
    s = np.array([10, 11, 12, 13]) + 1
    t = np.array([5, 6, 5, 40]) + 1
    ps, pt = write_lines(tmp_path / "src.vts", s), write_lines(tmp_path / "tgt.vts", t)
    gt = load_ground_truth((ps, pt), src, tgt)
    np.testing.assert_array_equal(gt.target_index, [5, 6, 40])
    np.testing.assert_allclose(points_of(gt, src), src.vertices[[10, 11, 13]])  # first line wins
    assert not gt.complete


def test_read_index_file(tmp_path):
    p = tmp_path / "a.txt"
    p.write_text("1\n 2 \n3.0\n")
    np.testing.assert_array_equal(read_index_file(p), [1, 2, 3])


# ----------------------------------------------------------------------------------------------
# Errors: one line, naming the file


def test_wrong_number_of_entries(pair, tmp_path):
    src, tgt, perm = pair
    for name, data in (("short.vts", perm[:-1] + 1), ("short.txt", perm[:-1])):
        p = write_lines(tmp_path / name, data)
        with pytest.raises(InputError) as ei:
            load_ground_truth(p, src, tgt)
        msg = one_line(ei)
        assert str(p) in msg and f"expected {tgt.n_vertices}" in msg and f"got {tgt.n_vertices - 1}" in msg
    p = tmp_path / "short.npz"
    np.savez(p, face=np.zeros(3, int), bary=np.full((3, 3), 1 / 3))
    with pytest.raises(InputError, match=rf"short\.npz.*expected {tgt.n_vertices}.*got 3"):
        load_ground_truth(p, src, tgt)


def test_identity_size_mismatch(pair):
    src, _, _ = pair
    v, f = sphere(2)
    with pytest.raises(InputError, match="source has 42, target has 162"):
        load_ground_truth("identity", src, Mesh(v, f))


def test_index_out_of_range(pair, tmp_path):
    src, tgt, perm = pair
    bad = perm + 1
    bad[4] = 0  # 0 is not a 1-based index
    p = write_lines(tmp_path / "bad.vts", bad)
    with pytest.raises(InputError) as ei:
        load_ground_truth(p, src, tgt)
    msg = one_line(ei)
    assert str(p) in msg and "line 5" in msg and "out of range [1, 42]" in msg
    bad = perm.copy()
    bad[0] = 42
    p = tmp_path / "bad.npy"
    np.save(p, bad)
    with pytest.raises(InputError, match=r"bad\.npy: entry 0: source vertex 42 is out of range \[0, 41\]"):
        load_ground_truth(p, src, tgt)
    q = tmp_path / "face.npz"
    np.savez(q, face=np.full(42, src.n_faces), bary=np.full((42, 3), 1 / 3))
    with pytest.raises(InputError, match=r"face\.npz: entry 0 is source face 80, out of range \[0, 79\]"):
        load_ground_truth(q, src, tgt)


def test_bad_barycentrics(pair, tmp_path):
    src, tgt, _ = pair
    n = tgt.n_vertices
    bary = np.full((n, 3), 1 / 3)
    bary[2] = [0.5, 0.5, 0.3]
    p = tmp_path / "sum.npz"
    np.savez(p, face=np.zeros(n, int), bary=bary)
    with pytest.raises(InputError, match=r"sum\.npz: barycentric coordinates of entry 2 sum to 1\.3, not 1"):
        load_ground_truth(p, src, tgt)
    bary[2] = [1.2, -0.2, 0.0]
    np.savez(p, face=np.zeros(n, int), bary=bary)
    with pytest.raises(InputError, match=r"entry 2 have a negative component -0\.2"):
        load_ground_truth(p, src, tgt)
    bary[2] = [np.nan, 0.5, 0.5]
    np.savez(p, face=np.zeros(n, int), bary=bary)
    with pytest.raises(InputError, match=r"sum\.npz: 1 barycentric rows are NaN"):
        load_ground_truth(p, src, tgt)


def test_nan_and_non_integers_in_index_files(pair, tmp_path):
    src, tgt, perm = pair
    p = tmp_path / "nan.npy"
    arr = perm.astype(float)
    arr[3] = np.nan
    np.save(p, arr)
    with pytest.raises(InputError, match=r"nan\.npy: 1 entries are NaN \(first: entry 3\)"):
        load_ground_truth(p, src, tgt)
    t = tmp_path / "words.txt"
    t.write_text("1\n2\nthree\n")
    with pytest.raises(InputError, match=r"words\.txt: line 3: not a number: 'three'"):
        load_ground_truth(t, src, tgt)
    t.write_text("1\n2 5\n")
    with pytest.raises(InputError, match=r"line 2: expected one vertex index per line, got 2 values"):
        load_ground_truth(t, src, tgt)
    t.write_text("1\n2.5\n")
    with pytest.raises(InputError, match=r"line 2: expected an integer vertex index, got 2\.5"):
        load_ground_truth(t, src, tgt)


def test_missing_arrays_and_unreadable_files(pair, tmp_path):
    src, tgt, _ = pair
    p = tmp_path / "nobary.npz"
    np.savez(p, face=np.zeros(42, int), other=np.zeros(3))
    with pytest.raises(InputError) as ei:
        load_ground_truth(p, src, tgt)
    assert one_line(ei) == f"{p}: missing array 'bary' (found: face, other)"
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"\x00\x01not a zip")
    with pytest.raises(InputError, match=r"junk\.npz: cannot read \.npz archive \(not a zip file\)"):
        load_ground_truth(junk, src, tgt)
    junk = tmp_path / "junk.npy"
    junk.write_bytes(b"garbage")
    with pytest.raises(InputError, match=r"junk\.npy: cannot read \.npy array \(not a NumPy \.npy file\)"):
        load_ground_truth(junk, src, tgt)
    binary = tmp_path / "bin.txt"
    binary.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(InputError, match=r"bin\.txt: cannot read text"):
        load_ground_truth(binary, src, tgt)
    with pytest.raises(InputError, match=r"nothere\.vts: no such file"):
        load_ground_truth(tmp_path / "nothere.vts", src, tgt)
    empty = tmp_path / "empty.txt"
    empty.write_text("\n# nothing\n")
    with pytest.raises(InputError, match=r"empty\.txt: no vertex indices"):
        load_ground_truth(empty, src, tgt)
    two_d = tmp_path / "twod.npy"
    np.save(two_d, np.zeros((42, 2), int))
    with pytest.raises(InputError, match=r"twod\.npy: expected a 1-D array of vertex indices, got shape \(42, 2\)"):
        load_ground_truth(two_d, src, tgt)


def test_format_selection_errors(pair, tmp_path):
    src, tgt, _ = pair
    with pytest.raises(InputError, match=r"map\.csv: cannot tell the ground-truth format from the suffix '\.csv'"):
        load_ground_truth(tmp_path / "map.csv", src, tgt)
    with pytest.raises(InputError, match="unknown ground-truth format 'json'"):
        load_ground_truth(tmp_path / "map.txt", src, tgt, fmt="json")
    with pytest.raises(InputError, match="template maps differ in length"):
        load_ground_truth((write_lines(tmp_path / "a.vts", [1, 2]), write_lines(tmp_path / "b.vts", [1])), src, tgt)
    with pytest.raises(InputError, match=r"b\.vts: line 1: target vertex 99 is out of range \[1, 42\]"):
        load_ground_truth((tmp_path / "a.vts", write_lines(tmp_path / "b.vts", [99, 1])), src, tgt)


def test_unused_source_vertex_is_an_error(tmp_path):
    v, f = sphere(1)
    v = np.concatenate([v, [[5.0, 5.0, 5.0]]])  # vertex 42 is in no face
    src, tgt = Mesh(v, f), Mesh(v, f)
    p = write_lines(tmp_path / "m.txt", np.arange(43)[::-1])
    with pytest.raises(InputError, match=r"m\.txt: ground truth: vertex 42 belongs to no face"):
        load_ground_truth(p, src, tgt)
