"""Point-cloud files (ncflow.io.points): round trips of every format, hostile inputs, mesh/cloud dispatch."""

import numpy as np
import pytest
from numpy.lib import format as npf

from ncflow.errors import InputError
from ncflow.geometry.cloud import MIN_POINTS, PointCloud
from ncflow.geometry.mesh import Mesh
from ncflow.io.meshes import save_mesh
from ncflow.io.points import MAX_POINTS, is_point_cloud_file, load_points, load_target, save_points
from ncflow.synthetic.shapes import sphere

N = 500


@pytest.fixture
def cloud():
    rng = np.random.default_rng(20240611)
    points = rng.normal(size=(N, 3)) * [1.0, 2.0, 0.5] + [3.0, -1.0, 0.25]
    normals = rng.normal(size=(N, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return points, normals


def error_of(path, reader=load_points, *words):
    """The message of the InputError ``reader(path)`` raises: one line, naming the file and ``words``."""
    with pytest.raises(InputError) as info:
        reader(path)
    msg = str(info.value)
    assert "\n" not in msg
    assert path.name in msg, msg
    for w in words:
        assert w in msg, msg
    return msg


def text_rows(table, sep=" "):
    return [sep.join(repr(float(x)) for x in row) for row in table]


def ascii_ply(path, table, names, extra=""):
    header = ["ply", "format ascii 1.0", "comment hand-written", f"element vertex {len(table)}"]
    header += [f"property double {n}" for n in names]
    path.write_text("\n".join(header) + "\n" + extra + "end_header\n" + "\n".join(text_rows(table)) + "\n")
    return path


# ----------------------------------------------------------------------------------------------
# round trips


def test_xyz_and_txt_round_trips_with_comments_blank_lines_and_commas(tmp_path, cloud):
    points, normals = cloud
    rows = text_rows(np.hstack([points, normals]))
    lines = ["# scanner output", "# x y z nx ny nz", ""] + rows[:200] + ["", "   ", "# a pause"] + rows[200:]
    p6 = tmp_path / "scan.xyz"
    p6.write_text("\n".join(lines) + "\n")
    got = load_points(p6)
    assert isinstance(got, PointCloud) and got.name == str(p6)
    assert got.points.dtype == np.float64 and got.normals.dtype == np.float64
    np.testing.assert_array_equal(got.points, points)  # repr round-trips a float64 exactly
    np.testing.assert_array_equal(got.normals, normals)

    p3 = tmp_path / "scan.txt"
    p3.write_text("#header\r\n" + "\r\n".join(", ".join(r.split()) for r in text_rows(points)) + "\r\n")
    got = load_points(p3)
    np.testing.assert_array_equal(got.points, points)
    assert got.normals is None

    tabs = tmp_path / "tabs.XYZ"
    tabs.write_text("\n".join("\t".join(f"{x:.6f}" for x in row) for row in points))  # no final newline
    np.testing.assert_allclose(load_points(tabs).points, points, atol=5e-7, rtol=0)


def test_npy_round_trips(tmp_path, cloud):
    points, normals = cloud
    np.save(tmp_path / "p3.npy", points)
    np.save(tmp_path / "p6.npy", np.asfortranarray(np.hstack([points, normals]).astype(np.float32)))
    ints = np.random.default_rng(3).integers(-1000, 1000, size=(N, 3)).astype(np.int32)
    np.save(tmp_path / "ints.npy", ints)
    got = load_points(tmp_path / "p3.npy")
    np.testing.assert_array_equal(got.points, points)
    assert got.normals is None
    got = load_points(tmp_path / "p6.npy")
    np.testing.assert_array_equal(got.points, points.astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal(got.normals, normals.astype(np.float32).astype(np.float64))
    got = load_points(tmp_path / "ints.npy")
    assert got.points.dtype == np.float64
    np.testing.assert_array_equal(got.points, ints)


def test_ascii_ply_by_hand(tmp_path, cloud):
    points, normals = cloud
    colours = np.random.default_rng(5).integers(0, 256, size=(N, 3))
    table = np.hstack([points, colours, normals])
    path = ascii_ply(tmp_path / "scan.ply", table, ["x", "y", "z", "red", "green", "blue", "nx", "ny", "nz"])
    got = load_points(path)
    np.testing.assert_array_equal(got.points, points)
    np.testing.assert_array_equal(got.normals, normals)

    bare = ascii_ply(
        tmp_path / "bare.ply", points, "xyz", extra="element face 0\nproperty list uchar int vertex_indices\n"
    )
    got = load_points(bare)
    np.testing.assert_array_equal(got.points, points)
    assert got.normals is None


def test_binary_ply_round_trip_through_save_points(tmp_path, cloud):
    points, normals = cloud
    save_points(tmp_path / "out" / "with.ply", points, normals)  # the folder is created
    save_points(tmp_path / "without.ply", points)
    got = load_points(tmp_path / "out" / "with.ply")
    np.testing.assert_array_equal(got.points, points.astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal(got.normals, normals.astype(np.float32).astype(np.float64))
    raw = (tmp_path / "without.ply").read_bytes()
    assert raw.startswith(b"ply\nformat binary_little_endian 1.0\n") and b"element face" not in raw
    assert len(raw.split(b"end_header\n", 1)[1]) == N * 3 * 4  # float32 x y z only
    got = load_points(tmp_path / "without.ply")
    np.testing.assert_allclose(got.points, points, rtol=1e-7, atol=1e-6)
    assert got.normals is None
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left behind


def test_big_endian_binary_ply_by_hand(tmp_path, cloud):
    points, normals = cloud
    header = f"ply\nformat binary_big_endian 1.0\nelement vertex {N}\n"
    header += "".join(f"property double {n}\n" for n in ("x", "y", "z", "nx", "ny", "nz")) + "end_header\n"
    path = tmp_path / "big.ply"
    path.write_bytes(header.encode() + np.hstack([points, normals]).astype(">f8").tobytes())
    got = load_points(path)
    np.testing.assert_array_equal(got.points, points)
    np.testing.assert_array_equal(got.normals, normals)


def test_obj_round_trips(tmp_path, cloud):
    points, normals = cloud
    v = [f"v {x!r} {y!r} {z!r} 0.5 0.25 1.0" for x, y, z in points.tolist()]  # vertex colours after xyz
    vn = [f"vn {x!r} {y!r} {z!r}" for x, y, z in normals.tolist()]
    path = tmp_path / "with.obj"
    path.write_text("# scan\no scan\nmtllib nowhere.mtl\n" + "\n".join(v[:10] + vn + v[10:]) + "\nvt 0 0\n")
    got = load_points(path)
    np.testing.assert_array_equal(got.points, points)
    np.testing.assert_array_equal(got.normals, normals)
    fewer = tmp_path / "fewer.obj"
    fewer.write_text("\n".join(v + vn[:-1]) + "\n")  # one normal short: not per point
    got = load_points(fewer)
    np.testing.assert_array_equal(got.points, points)
    assert got.normals is None
    none = tmp_path / "none.obj"
    none.write_text("\n".join(v) + "\n")
    assert load_points(none).normals is None


def test_normals_zero_length_kept_all_zero_dropped(tmp_path, cloud):
    points, normals = cloud
    some = normals.copy()
    some[::7] = 0.0
    np.save(tmp_path / "some.npy", np.hstack([points, some]))
    np.testing.assert_array_equal(load_points(tmp_path / "some.npy").normals, some)
    np.save(tmp_path / "zero.npy", np.hstack([points, np.zeros_like(points)]))
    assert load_points(tmp_path / "zero.npy").normals is None


# ----------------------------------------------------------------------------------------------
# bad and hostile inputs


def test_text_column_errors_name_the_line(tmp_path, cloud):
    points, normals = cloud
    rows = text_rows(points)
    mixed = tmp_path / "mixed.xyz"
    mixed.write_text("# c\n\n" + "\n".join(rows[:5] + text_rows(np.hstack([points[5:6], normals[5:6]])) + rows[6:]))
    error_of(mixed, load_points, "line 8", "6 values", "first data line has 3")
    for k in (4, 5):
        path = tmp_path / f"cols{k}.txt"
        path.write_text("\n".join(" ".join(["1.5"] * k) for _ in range(200)))
        error_of(path, load_points, "line 1", f"{k} values", "expected 3")
    words = tmp_path / "words.xyz"
    words.write_text("\n".join(rows[:3] + ["1.0 abc 2.0"] + rows[3:]))
    error_of(words, load_points, "line 4", "'abc' is not a number")
    nan = tmp_path / "nan.xyz"
    nan.write_text("\n".join(rows[:9] + ["nan 1 2"] + rows[9:]))
    error_of(nan, load_points, "line 10", "NaN or infinite")


def test_clouds_that_show_no_body(tmp_path, cloud):
    points, _ = cloud
    few = tmp_path / "few.xyz"
    few.write_text("\n".join(text_rows(np.tile(points[: MIN_POINTS - 1], (4, 1)))))
    error_of(few, load_points, f"only {MIN_POINTS - 1} distinct points")
    flat = points.copy()
    flat[:, 2] = 0.5 * flat[:, 0] - flat[:, 1]  # a tilted plane
    np.save(tmp_path / "flat.npy", flat)
    error_of(tmp_path / "flat.npy", load_points, "plane")


def test_npy_refusals(tmp_path, cloud):
    points, _ = cloud
    for name, arr, words in [
        ("four.npy", np.hstack([points, points[:, :1]]), ("shape (N, 3) or (N, 6)", "(500, 4)")),
        ("flat.npy", points.ravel(), ("shape (N, 3) or (N, 6)",)),
        ("deep.npy", points[:, :, None], ("shape (N, 3) or (N, 6)",)),
        ("strings.npy", points.astype(str), ("floats or integers", "<U")),
        ("bools.npy", points > 0, ("floats or integers", "bool")),
        ("complex.npy", points.astype(complex), ("floats or integers",)),
    ]:
        np.save(tmp_path / name, arr)
        error_of(tmp_path / name, load_points, *words)
    nan = points.copy()
    nan[17, 1] = np.nan
    np.save(tmp_path / "nan.npy", nan)
    error_of(tmp_path / "nan.npy", load_points, "row 17")


class _Trap:
    """Unpickling this would create the file ``marker``."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (open, (str(self.marker), "w"))


def test_npy_pickles_are_never_loaded(tmp_path):
    marker = tmp_path / "unpickled"
    arr = np.empty((200, 3), dtype=object)
    arr[:] = _Trap(marker)
    np.save(tmp_path / "trap.npy", arr, allow_pickle=True)
    error_of(tmp_path / "trap.npy", load_points, "floats or integers", "object")
    assert not marker.exists()


def test_npy_header_limits_checked_before_reading(tmp_path):
    huge = tmp_path / "huge.npy"
    with open(huge, "wb") as fh:  # declares 5 000 001 points but holds 24 bytes
        npf.write_array_header_1_0(fh, {"descr": "<f8", "fortran_order": False, "shape": (MAX_POINTS + 1, 3)})
        fh.write(b"\0" * 24)
    error_of(huge, load_points, "more than the limit")
    short = tmp_path / "short.npy"
    with open(short, "wb") as fh:
        npf.write_array_header_1_0(fh, {"descr": "<f8", "fortran_order": False, "shape": (1000, 3)})
        fh.write(b"\0" * 24)
    error_of(short, load_points, "truncated")
    (tmp_path / "junk.npy").write_bytes(b"\x93NUMPY\x01\x00garbage")
    error_of(tmp_path / "junk.npy", load_points, "malformed .npy header")


@pytest.mark.parametrize("suffix", [".xyz", ".txt", ".npy", ".ply", ".obj"])
def test_empty_files(tmp_path, suffix):
    path = tmp_path / f"empty{suffix}"
    path.write_bytes(b"")
    error_of(path, load_points)
    comments = tmp_path / f"comments{suffix}"
    comments.write_text("# nothing here\n\n")
    error_of(comments, load_points)


def test_meshes_through_load_points(tmp_path):
    v, f = sphere(1)
    save_mesh(tmp_path / "ball.ply", v, f)
    error_of(tmp_path / "ball.ply", load_points, "has 80 faces: a mesh, not a point cloud")
    save_mesh(tmp_path / "ball.obj", v, f)
    error_of(tmp_path / "ball.obj", load_points, "a mesh, not a point cloud")
    save_mesh(tmp_path / "ball.stl", v, f)
    error_of(tmp_path / "ball.stl", load_points, "unsupported point cloud format '.stl'")


def test_broken_ply_and_obj(tmp_path, cloud):
    points, normals = cloud
    save_points(tmp_path / "whole.ply", points, normals)
    data = (tmp_path / "whole.ply").read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[:-100])
    error_of(tmp_path / "cut.ply", load_points, "truncated")
    nan_ply = ascii_ply(tmp_path / "nan.ply", np.vstack([points[:3], [[np.nan, 0, 0]], points[3:]]), "xyz")
    error_of(nan_ply, load_points, "vertex 3", "not a finite")
    no_z = ascii_ply(tmp_path / "noz.ply", points[:, :2], "xy")
    error_of(no_z, load_points, "no z property")
    (tmp_path / "text.ply").write_text("hello\n")
    error_of(tmp_path / "text.ply", load_points, "not a PLY file")
    bad_v = tmp_path / "bad.obj"
    v_lines = [f"v {r}" for r in text_rows(points)]
    bad_v.write_text("\n".join(v_lines[:6] + ["v 1.0 x 2.0"] + v_lines[6:]))
    error_of(bad_v, load_points, "line 7", "not a number")
    nan_v = tmp_path / "nanv.obj"
    nan_v.write_text("\n".join(f"v {r}" for r in text_rows(points[:2])) + "\nv 1 inf 2\nv 1 2\n")
    error_of(nan_v, load_points, "line 4", "at least 3 numbers")
    nan_v.write_text("\n".join(f"v {r}" for r in text_rows(points[:2])) + "\nv 1 inf 2\n")
    error_of(nan_v, load_points, "line 3", "NaN or infinite")


def test_save_points_refuses_bad_arrays(tmp_path, cloud):
    points, normals = cloud
    with pytest.raises(InputError, match="non-finite"):
        save_points(tmp_path / "nan.ply", np.vstack([points, [[np.nan, 0, 0]]]))
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        save_points(tmp_path / "short.ply", points, normals[:-1])
    assert not list(tmp_path.iterdir())


# ----------------------------------------------------------------------------------------------
# point cloud or mesh


def test_is_point_cloud_file_and_load_target(tmp_path, cloud):
    points, normals = cloud
    v, f = sphere(2)
    for suffix in (".ply", ".obj", ".stl", ".off", ".glb"):
        save_mesh(tmp_path / f"ball{suffix}", v, f)
        assert not is_point_cloud_file(tmp_path / f"ball{suffix}")
    save_points(tmp_path / "scan.ply", points, normals)
    ascii_ply(tmp_path / "zero.ply", points, "xyz", extra="element face 0\nproperty list uchar int vertex_indices\n")
    (tmp_path / "scan.obj").write_text("# v 1 2 3\n" + "\n".join(f"v {r}" for r in text_rows(points)) + "\n")
    (tmp_path / "hidden_face.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n  f 1 2 3\n")
    (tmp_path / "no_v.obj").write_text("# only a comment\nvt 0 0\n")
    (tmp_path / "junk.ply").write_bytes(b"\x00\xff" * 100)
    (tmp_path / "folder.ply").mkdir()
    for name in ("scan.ply", "zero.ply", "scan.obj", "any.xyz", "ANY.TXT", "any.npy"):
        assert is_point_cloud_file(tmp_path / name), name
    for name in ("hidden_face.obj", "no_v.obj", "junk.ply", "folder.ply", "missing.ply", "missing.obj", "a.gltf"):
        assert not is_point_cloud_file(tmp_path / name), name

    mesh = load_target(tmp_path / "ball.ply")
    assert isinstance(mesh, Mesh) and mesh.faces.shape == f.shape
    np.testing.assert_allclose(mesh.vertices, v, atol=1e-6)
    scan = load_target(tmp_path / "scan.ply")
    assert isinstance(scan, PointCloud)
    np.testing.assert_allclose(scan.points, points, atol=1e-6)
    np.testing.assert_allclose(scan.normals, normals, atol=1e-7)
    assert isinstance(load_target(tmp_path / "scan.obj"), PointCloud)
    error_of(tmp_path / "missing.ply", load_target, "no such file")
    error_of(tmp_path / "missing.xyz", load_target, "no such file")
