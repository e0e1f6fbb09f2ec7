"""Mesh reading, validation errors, topology tables, welding and normalisation."""

import numpy as np
import pytest
import trimesh

from ncflow.errors import InputError
from ncflow.geometry.mesh import enclosed_volume, orientation, validate_mesh, weld_vertices
from ncflow.geometry.normalize import fit_normalization
from ncflow.geometry.topology import close_boundary, mesh_topology
from ncflow.io.meshes import load_mesh, save_mesh
from ncflow.synthetic.shapes import capsule, sphere, tube

TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"


def write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    "name, text, message",
    [
        ("empty.obj", "v 0 0 0\nv 1 0 0\n", "no faces"),
        ("line.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\nf 1 2\n", "line 5: a face of 2 corners"),
        ("line.off", "OFF\n3 2 0\n0 0 0\n1 0 0\n1 1 0\n3 0 1 2\n2 0 1\n", "fewer than 3 corners"),
        ("nan.obj", "v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN or infinite"),
        ("inf.off", "OFF\n3 1 0\n0 0 inf\n1 0 0\n0 1 0\n3 0 1 2\n", "NaN or infinite"),
        ("range.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n", "out of range"),
        ("range.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n", "out of range"),
        ("degenerate.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\nf 1 1 4\n", "none of its 2 faces has an area"),
        ("garbage.ply", "this is not a ply file at all\n", "cannot read mesh"),
        ("mesh.xyz", "0 0 0\n", "unsupported mesh format"),
    ],
)
def test_bad_files_raise_one_line_errors_naming_the_file(tmp_path, name, text, message):
    path = write(tmp_path, name, text)
    with pytest.raises(InputError) as err:
        load_mesh(path)
    msg = str(err.value)
    assert message in msg
    assert str(path) in msg
    assert "\n" not in msg


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        load_mesh(tmp_path / "nope.obj")
    with pytest.raises(InputError, match="is a directory"):
        load_mesh(tmp_path)


def test_validate_arrays_directly():
    v, f = sphere(1)
    validate_mesh(v, f)
    with pytest.raises(InputError, match="out of range"):
        validate_mesh(v, f - 1)
    with pytest.raises(InputError, match="all vertices coincide"):
        validate_mesh(np.zeros_like(v), f)


@pytest.mark.parametrize("scale", [1e29, 1e-29])
def test_coordinates_float32_outputs_hold_are_accepted(scale):
    v, f = sphere(1)  # radius 1: coordinates up to 1, 2 across
    validate_mesh(v * scale, f)


@pytest.mark.parametrize(
    "scale, message",
    # the unit sphere's bounding box is 2√3 = 3.46 across
    [
        (1e31, r"big.ply: coordinates as large as 1e\+31: beyond ±1e\+30"),
        (1e-31, "big.ply: the mesh is only 3.46e-31 across"),
    ],
)
def test_coordinates_float32_outputs_cannot_hold_are_refused(scale, message):
    v, f = sphere(1)
    with pytest.raises(InputError, match=message):
        validate_mesh(v * scale, f, name="big.ply")


def test_float_face_indices_are_one_line_error():
    from ncflow.geometry.mesh import _check_finite_and_range  # validate_mesh's annotation refuses them first in tests

    v, f = sphere(1)
    with pytest.raises(InputError, match="^m: face indices must be integers, got float64"):
        _check_finite_and_range(v, f.astype(float), "m")


def test_orientation_outward_inward_and_undecided():
    v, f = sphere(2)
    assert orientation(v, f) == 1 and orientation(v, f[:, ::-1]) == -1
    # an open surface (a capsule without one cap's faces) is closed before its volume is taken
    cv, cf = capsule(n_around=10, n_along=6)
    open_f = cf[~np.any(cv[cf][:, :, 2] > 1.2, axis=1)]
    assert open_f.shape[0] < cf.shape[0]
    assert orientation(cv, open_f) == 1 and orientation(cv, open_f[:, ::-1]) == -1
    # a flat sheet encloses nothing: no side to tell
    g = np.stack(np.meshgrid(np.arange(4.0), np.arange(4.0), indexing="ij"), -1).reshape(-1, 2)
    sheet_v = np.column_stack([g, np.zeros(len(g))])
    sheet_f = np.array([[i * 4 + j, i * 4 + j + 1, i * 4 + j + 4] for i in range(3) for j in range(3)])
    assert orientation(sheet_v, sheet_f) == 0 and orientation(sheet_v, sheet_f[:, ::-1]) == 0
    # a tenth of the faces wound against the rest: the side most of the volume comes from
    mixed = f.copy()
    flip = np.random.default_rng(0).random(len(f)) < 0.1
    mixed[flip] = mixed[flip][:, ::-1]
    assert orientation(v, mixed) == 1
    # ... wherever the mesh lies: a contiguous cap of a fifth of the area reversed, far from the origin
    cap = f[v[f].mean(axis=1)[:, 2] > 0.6]
    patched = np.concatenate([f[v[f].mean(axis=1)[:, 2] <= 0.6], cap[:, ::-1]])
    assert 0.1 < len(cap) / len(f) < 0.3
    for offset in ([0, 0, 0], [0, 0, 10.0], [0, 0, -1e3], [5e3, 0, 0]):
        assert orientation(v + np.array(offset), patched) == 1
        assert orientation(v + np.array(offset), patched[:, ::-1]) == -1


def _canonical(tri):
    """A triangle's corners rotated to start at the smallest (its winding kept)."""
    k = tri.index(min(tri))
    return tuple(tri[k:] + tri[:k])


def test_obj_vertices_are_the_files_whatever_else_it_holds(tmp_path):
    text = (
        "# materials, groups, normals, texture coordinates, colours, comments, continuations\n"
        "mtllib nowhere.mtl\no body\nv 0 0 0 1 0 0\nv 1 0 0\n  v 0 1 0\nv 1 1 0\nv 2 0 0\n"
        "vt 0 0\nvn 0 0 1\ng a\nusemtl skin\nf 1/1/1 2/1/1 3/1/1 # the first\nusemtl cloth\ns 1\n"
        "f 2//1 4//1 \\\n 3//1\nf -4 -1 -2\nl 1 2\n"
    )
    m = load_mesh(write(tmp_path, "rich.obj", text), validate=False)
    np.testing.assert_array_equal(m.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [2, 0, 0]])
    assert m.faces.tolist() == [[0, 1, 2], [1, 3, 2], [1, 4, 3]] and m.notes == ()
    np.testing.assert_array_equal(m.file_index, np.arange(5))


QUAD_V = "0 0 0\n1 0 0\n1 1 0\n0 1 0\n0.5 1.5 0\n2 0 0\n"  # a quad, a pentagon on it, a triangle


@pytest.mark.parametrize(
    "name, text",
    [
        ("poly.obj", "".join(f"v {ln}\n" for ln in QUAD_V.splitlines()) + "f 1 2 3 4\nf 4 3 5\nf 2 6 3\nf 1 2 6 3 5\n"),
        (
            "poly.ply",
            "ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 4\nproperty list uchar int vertex_indices\nend_header\n"
            + QUAD_V
            + "4 0 1 2 3\n3 3 2 4\n3 1 5 2\n5 0 1 5 2 4\n",
        ),
    ],
)
def test_polygons_are_split_into_triangles_and_counted(tmp_path, name, text):
    m = load_mesh(write(tmp_path, name, text), validate=False)  # the faces overlap: only the split is tested
    # quad (0 1 2 3) along the diagonal from its first corner, pentagon (0 1 5 2 4) as a fan from it
    expected = [[0, 1, 2], [2, 3, 0], [3, 2, 4], [1, 5, 2], [0, 1, 5], [0, 5, 2], [0, 2, 4]]
    assert sorted(map(_canonical, m.faces.tolist())) == sorted(map(_canonical, expected))  # winding kept
    np.testing.assert_allclose(m.vertices, np.array([ln.split() for ln in QUAD_V.splitlines()], float))
    (note,) = m.notes
    assert note.startswith("2 of 4 faces have [4, 5] corners: split into triangles")


def test_binary_ply_polygons_split_and_counted(tmp_path):
    path = tmp_path / "quads.ply"
    header = (
        "ply\nformat binary_little_endian 1.0\nelement vertex 6\nproperty float x\nproperty float y\n"
        "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
    )
    body = np.array([ln.split() for ln in QUAD_V.splitlines()], "<f4").tobytes()
    for quad in ([0, 1, 2, 3], [1, 5, 4, 2]):
        body += bytes([4]) + np.array(quad, "<i4").tobytes()
    path.write_bytes(header.encode() + body)
    m = load_mesh(path, validate=False)
    assert sorted(m.faces.tolist()) == [[0, 1, 2], [1, 5, 4], [2, 3, 0], [4, 2, 1]]
    assert m.notes[0].startswith("its 2 faces became 4 triangles: polygons split")


def test_textured_obj_polygons_split_as_the_matched_mesh(tmp_path):
    from ncflow.io.obj_uv import read_obj_uv

    text = (
        "".join(f"v {ln}\n" for ln in QUAD_V.splitlines())
        + "".join(f"vt {0.1 * k} {0.2 * k}\n" for k in range(8))
        + "f 1/1 2/2 3/3 4/4\nf 4/5 3/3 5/6\nf 2/2 6/7 3/8 # a seam: vertex 3 with another UV\n"
    )
    path = write(tmp_path, "tex.obj", text)
    textured, plain = read_obj_uv(path), load_mesh(path, validate=False)
    np.testing.assert_array_equal(textured.faces, plain.faces)
    np.testing.assert_array_equal(textured.vertices, plain.vertices)
    assert textured.faces.tolist() == [[0, 1, 2], [0, 2, 3], [3, 2, 4], [1, 5, 2]]
    assert textured.uv_faces.tolist() == [[0, 1, 2], [0, 2, 3], [4, 2, 5], [1, 6, 7]]


def test_off_polygons_split_when_all_one_size(tmp_path):
    m = load_mesh(write(tmp_path, "quads.off", "OFF\n6 2 0\n" + QUAD_V + "4 0 1 2 3\n4 1 5 4 2\n"), validate=False)
    assert sorted(m.faces.tolist()) == [[0, 1, 2], [1, 5, 4], [2, 3, 0], [4, 2, 1]]
    assert m.notes[0].startswith("2 of 2 faces have [4] corners")
    tri_quad = load_mesh(write(tmp_path, "tq.off", "OFF\n6 2 0\n" + QUAD_V + "4 0 1 2 3\n3 1 5 2\n"), validate=False)
    assert sorted(tri_quad.faces.tolist()) == [[0, 1, 2], [1, 5, 2], [2, 3, 0]]
    mixed = write(tmp_path, "mixed.off", "OFF\n6 2 0\n" + QUAD_V + "4 0 1 2 3\n5 0 1 5 2 4\n")
    with pytest.raises(InputError, match="mixed.off: polygons of several sizes in an OFF file"):
        load_mesh(mixed)


def test_obj_line_endings_all_read_alike(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 \\\n 3\n"
    meshes = [
        load_mesh(write(tmp_path, f"{k}.obj", text.replace("\n", end)), validate=False)
        for k, end in enumerate(["\n", "\r\n", "\r"])
    ]
    for m in meshes:
        assert m.faces.tolist() == [[0, 1, 2], [1, 3, 2]] and m.n_vertices == 4


def test_text_mesh_that_is_not_utf8_is_read(tmp_path):
    v, f = capsule(n_around=8, n_along=5)
    plain = tmp_path / "plain.obj"
    save_mesh(plain, v, f)
    latin = tmp_path / "latin.obj"
    latin.write_bytes("# exporté par un logiciel\n".encode("latin-1") + plain.read_bytes())
    a, b = load_mesh(plain), load_mesh(latin)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)


def test_random_bytes_as_a_mesh_are_one_line_error(tmp_path):
    path = tmp_path / "noise.obj"
    path.write_bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    with pytest.raises(InputError, match="noise.obj: no faces"):
        load_mesh(path)


def test_roundtrip_keeps_vertex_order(tmp_path):
    v, f = capsule(n_around=10, n_along=6)
    perm = np.random.default_rng(0).permutation(len(v))
    v2, f2 = v[perm], np.argsort(perm)[f]
    for suffix in [".obj", ".ply", ".off"]:
        path = tmp_path / f"m{suffix}"
        save_mesh(path, v2, f2)
        m = load_mesh(path)
        np.testing.assert_allclose(m.vertices, v2, atol=1e-6)
        np.testing.assert_array_equal(m.faces, f2)


def test_stl_is_welded_into_one_surface(tmp_path):
    v, f = sphere(1)
    path = tmp_path / "s.stl"
    save_mesh(path, v, f)
    m = load_mesh(path)  # an STL stores 3 vertices per face; welding restores the 42 vertices
    assert m.n_vertices == len(v) and m.n_faces == len(f)
    assert not mesh_topology(m.faces).has_boundary
    np.testing.assert_allclose(m.vertices[m.faces], v[f], atol=1e-6)


def test_weld_vertices_keeps_first_occurrence_order():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 0], [0, 1, 0], [1, 0, 0]], float)
    f = np.array([[0, 1, 3], [2, 4, 3]])
    w, wf, first = weld_vertices(v, f)
    np.testing.assert_array_equal(first, [0, 1, 3])
    np.testing.assert_array_equal(wf, [[0, 1, 2], [0, 1, 2]])
    np.testing.assert_array_equal(w, v[[0, 1, 3]])


def test_topology_closed_open_counts():
    v, f = sphere(2)
    t = mesh_topology(f)
    assert t.n_edges == 3 * len(f) // 2 and not t.has_boundary
    assert np.all(t.edges[:, 0] < t.edges[:, 1])
    assert np.all(np.sort(t.edges.view("i8,i8"), axis=0) == t.edges.view("i8,i8"))
    # every interior edge of a consistently wound closed surface is run once each way
    assert np.all(t.edge_signs[:, :2].sum(1) == 0) and np.all(t.edge_faces[:, 2:] == -1)
    v, f = tube(n_around=10, n_along=4)
    t = mesh_topology(f)
    assert t.boundary_edges.sum() == 20 and t.boundary_vertices.size == 20
    assert t.boundary_neighbors.shape == (20, 2) and np.all(t.boundary_neighbors >= 0)
    # edge-face incidence agrees with a brute-force scan
    for e, (a, b) in enumerate(t.edges[:15]):
        faces = [i for i, tri in enumerate(f) if a in tri and b in tri]
        assert list(t.edge_faces[e][t.edge_faces[e] >= 0]) == faces


def test_enclosed_volume_closed_and_open():
    v, f = sphere(4)
    assert enclosed_volume(v, f) == pytest.approx(trimesh.Trimesh(v, f).volume, rel=1e-12)
    # an open tube is closed by fans to its loop centroids: the volume of the prism over the polygon
    v, f = tube(radius=0.5, length=2.0, n_around=16, n_along=5)
    polygon_area = 0.5 * 16 * 0.25 * np.sin(2 * np.pi / 16)
    assert enclosed_volume(v, f) == pytest.approx(polygon_area * 2.0, rel=1e-12)
    cv, cf = close_boundary(v, f)
    assert not mesh_topology(cf).has_boundary and trimesh.Trimesh(cv, cf, process=False).is_winding_consistent


def test_close_boundary_caps_every_loop_at_its_centroid():
    # a tube (two loops) beside a triangle soup of a sphere (one loop per face)
    tv, tf = tube(radius=0.5, length=2.0, n_around=7, n_along=4)
    sv, sf = sphere(1)
    soup_v = sv[sf].reshape(-1, 3) + 5.0
    v = np.concatenate([tv, soup_v])
    f = np.concatenate([tf, np.arange(soup_v.shape[0]).reshape(-1, 3) + tv.shape[0]])
    cv, cf = close_boundary(v, f)
    n_loops = 2 + sf.shape[0]
    assert cv.shape[0] == v.shape[0] + n_loops and not mesh_topology(cf).has_boundary
    np.testing.assert_array_equal(cv[: v.shape[0]], v)
    # brute force: each appended vertex is the mean of the loop vertices its cap triangles touch
    caps = cf[f.shape[0] :]
    for k in range(v.shape[0], cv.shape[0]):
        ring = np.unique(caps[caps[:, 2] == k][:, :2])
        np.testing.assert_allclose(cv[k], v[ring].mean(0), rtol=1e-12, atol=1e-12)
    assert {len(np.unique(caps[caps[:, 2] == k][:, :2])) for k in range(v.shape[0], cv.shape[0])} == {3, 7}


def test_normalization_is_reversible_and_hits_unit_ball_volume():
    v, f = capsule()
    v = v * 3.7 + np.array([1.0, -2.0, 5.0])
    norm = fit_normalization(v, f)
    vn = norm.apply(v)
    assert enclosed_volume(vn, f) == pytest.approx(4 * np.pi / 3, rel=1e-10)
    areas = np.linalg.norm(np.cross(vn[f][:, 1] - vn[f][:, 0], vn[f][:, 2] - vn[f][:, 0]), axis=1)
    np.testing.assert_allclose((vn[f].mean(1) * areas[:, None]).sum(0), 0.0, atol=1e-10)
    np.testing.assert_allclose(norm.invert(vn), v, atol=1e-12)
