"""The intake step (ncflow.geometry.repair) against brute-force references, and every step after it on
imperfect meshes: decimation, the self-overlap test, closing holes, edge tables, the readers."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mesh_checks import brute_edge_faces, brute_fans, check_repaired
from ncflow.errors import InputError
from ncflow.geometry.decimate import decimate
from ncflow.geometry.mesh import face_areas, repaired_mesh
from ncflow.geometry.overlap import self_overlap
from ncflow.geometry.repair import repair_mesh, weld_groups
from ncflow.geometry.topology import close_boundary, mesh_topology
from ncflow.io.meshes import load_mesh
from ncflow.synthetic.defects import DEFECTS, defective_mesh
from ncflow.synthetic.shapes import capsule, sphere, tube


def assert_same_surface(rep, vertices, faces):
    """Each repaired face is its input face: the same corner positions (in turn, reversed when flipped)."""
    got = rep.vertices[rep.faces]
    want = np.asarray(vertices)[np.asarray(faces)[rep.face_origin]]
    want = np.where(rep.flipped[:, None, None], want[:, ::-1], want)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(rep.vertices, np.asarray(vertices)[rep.vertex_origin])


def test_a_clean_mesh_comes_back_as_it_is():
    v, f = capsule(n_around=12, n_along=10)
    rep = repair_mesh(v, f)
    assert not rep.changed and rep.summary() is None
    np.testing.assert_array_equal(rep.vertices, v)
    np.testing.assert_array_equal(rep.faces, f)
    np.testing.assert_array_equal(rep.vertex_origin, np.arange(len(v)))
    np.testing.assert_array_equal(rep.face_origin, np.arange(len(f)))
    # an open mesh (a tube: two boundary loops) too
    v, f = tube(n_around=10, n_along=6)
    rep = repair_mesh(v, f)
    assert not rep.changed and np.array_equal(rep.faces, f)


def test_a_triangle_soup_is_welded_back_into_its_mesh():
    v, f = sphere(2)
    soup_v, soup_f = v[f].reshape(-1, 3), np.arange(3 * len(f)).reshape(-1, 3)
    rep = repair_mesh(soup_v, soup_f)
    assert rep.counts["welded"] == len(soup_v) - len(v)
    assert rep.summary().startswith(f"welded {len(soup_v) - len(v)} vertices lying where another does")
    assert_same_surface(rep, soup_v, soup_f)
    # the same closed surface: every edge in two faces, the sphere's vertex count, no boundary
    assert rep.vertices.shape == v.shape and check_repaired(rep.vertices, rep.faces) is None
    assert not mesh_topology(rep.faces, len(rep.vertices)).has_boundary
    # each welded vertex stands for the first of its copies
    first = {tuple(p): i for i, p in reversed(list(enumerate(soup_v.tolist())))}
    assert [first[tuple(p)] for p in rep.vertices.tolist()] == rep.vertex_origin.tolist()


def test_zero_area_duplicate_and_unreferenced_are_dropped_and_counted():
    v, f = sphere(1)
    extra_v = np.concatenate([v, [[5.0, 5.0, 5.0]]])  # a vertex in no face
    # a repeated corner, three collinear corners (zero area, distinct indices), a duplicate either way round
    collinear = np.concatenate([extra_v, [0.5 * (v[f[0, 0]] + v[f[0, 1]])]])
    mid = len(collinear) - 1
    faces = np.concatenate([f, [[0, 0, 1], [f[0, 0], mid, f[0, 1]], f[3], f[4, ::-1]]])
    rep = repair_mesh(collinear, faces)
    assert rep.counts["degenerate"] == 2 and rep.counts["duplicate"] == 2 and rep.counts["unreferenced"] == 1
    np.testing.assert_array_equal(rep.face_origin, np.arange(len(f)))
    np.testing.assert_array_equal(rep.faces, f)  # the mid vertex and the stray one are left out
    assert "dropped 2 zero-area faces; dropped 2 duplicate faces" in rep.summary()
    assert rep.summary().endswith("left out 1 vertices in no face")


def test_fins_and_crowded_edges_are_split_to_at_most_two_faces_an_edge():
    v, f = sphere(2)
    topo = mesh_topology(f)
    e = topo.edges[::23][:12]
    tips = v[e].mean(1) * 1.4
    n = len(v)
    # 12 fins, the first 4 edges with a second fin (four faces), and 6 fins on one edge (eight faces)
    fins = np.c_[e, n + np.arange(12)]
    second = np.c_[e[:4], n + 12 + np.arange(4)]
    many = np.c_[np.repeat(e[11:12], 6, axis=0), n + 16 + np.arange(6)]
    vv = np.concatenate([v, tips, tips[:4] * 1.1, v[:6] * 1.3 + 0.1])
    ff = np.concatenate([f, fins, second, many])
    edges = brute_edge_faces(ff)
    rep = repair_mesh(vv, ff)
    assert rep.counts["nonmanifold_edges"] == sum(len(fs) > 2 for fs in edges.values()) == 12
    assert check_repaired(rep.vertices, rep.faces) is None
    assert max(len(fs) for fs in brute_edge_faces(rep.faces).values()) <= 2
    assert_same_surface(rep, vv, ff)
    # the sphere's own faces stay one closed surface: its edges keep their two faces
    body = rep.face_origin < len(f)
    sub = brute_edge_faces(rep.faces[body])
    assert all(len(fs) == 2 for fs in sub.values())
    # what comes out of the intake step is taken by every later step
    closed_v, closed_f = close_boundary(rep.vertices, rep.faces)
    assert max(len(fs) for fs in brute_edge_faces(closed_f).values()) <= 2
    mesh_topology(closed_f, len(closed_v))


def test_a_pinched_vertex_gets_one_copy_per_fan():
    v, f = sphere(1)
    n = len(v)
    apex = v[0] * 1.5
    tet_v = np.concatenate([v, [apex + [0.1, 0, 0], apex + [0, 0.1, 0], apex + [0, 0, 0.1]]])
    tet_f = np.concatenate([f, [[0, n, n + 1], [0, n + 1, n + 2], [0, n + 2, n], [n, n + 2, n + 1]]])
    assert brute_fans(tet_f, 0) == 2
    rep = repair_mesh(tet_v, tet_f)
    assert rep.counts["nonmanifold_vertices"] == 1 and rep.counts["split_vertices"] == 1
    assert (rep.vertex_origin == 0).sum() == 2  # vertex 0 and its copy, at one place
    assert all(brute_fans(rep.faces, k) == 1 for k in range(len(rep.vertices)))
    assert_same_surface(rep, tet_v, tet_f)


def test_a_patch_wound_against_its_neighbours_is_turned():
    v, f = capsule(n_around=12, n_along=10)
    turned = f.copy()
    turned[:40] = turned[:40, ::-1]
    rep = repair_mesh(v, turned)
    assert rep.counts["reoriented"] == 40 and rep.flipped[:40].all() and not rep.flipped[40:].any()
    # turned back the way the rest of the surface winds: the capsule's faces, corners in turn
    np.testing.assert_array_equal(rep.faces[40:], f[40:])
    for got, want in zip(rep.faces[:40], f[:40]):
        assert list(got) in [list(np.roll(want, k)) for k in range(3)]
    # most of the area wins: the whole mesh reversed stays reversed
    assert not repair_mesh(v, f[:, ::-1]).changed


def test_weld_tolerance_joins_near_vertices_only_when_asked():
    v, f = sphere(1)
    soup_v = v[f].reshape(-1, 3)
    soup_v = soup_v + np.random.default_rng(0).normal(scale=1e-9, size=soup_v.shape)
    soup_f = np.arange(len(soup_v)).reshape(-1, 3)
    assert repair_mesh(soup_v, soup_f).counts["welded"] == 0
    rep = repair_mesh(soup_v, soup_f, weld_tolerance=1e-6)
    assert rep.counts["welded"] == len(soup_v) - len(v) and len(rep.vertices) == len(v)
    # groups: the first vertex of each, chained through neighbours
    groups = weld_groups(np.array([[0.0, 0, 0], [0.4, 0, 0], [0.8, 0, 0], [3.0, 0, 0]]), 0.5)
    np.testing.assert_array_equal(groups, [0, 0, 0, 3])
    with pytest.raises(InputError, match="weld tolerance must be in"):
        repair_mesh(v, f, weld_tolerance=0.5)


def test_small_components_are_left_out_only_when_asked():
    v, f = sphere(2)
    small_v, small_f = sphere(0, radius=0.1)
    vv = np.concatenate([v, small_v + 3.0])
    ff = np.concatenate([f, small_f + len(v)])
    share = face_areas(small_v, small_f).sum() / face_areas(vv, ff).sum()
    assert not repair_mesh(vv, ff).changed
    rep = repair_mesh(vv, ff, min_component=2 * share)
    assert rep.counts["small_components"] == 1 and rep.counts["small_component_faces"] == len(small_f)
    np.testing.assert_array_equal(rep.faces, f)
    assert not repair_mesh(vv, ff, min_component=0.5 * share).changed


def test_a_mesh_of_many_pieces_each_under_the_share_keeps_its_largest():
    """300 separate triangles, each under 0.5 % of the area: the largest stays, the rest are left out."""
    corners = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    scale = np.linspace(1.0, 1.2, 300)
    v = np.concatenate([corners * s + [3.0 * i, 0, 0] for i, s in enumerate(scale)])
    f = np.arange(v.shape[0]).reshape(-1, 3)
    rep = repair_mesh(v, f, min_component=0.005)
    np.testing.assert_array_equal(rep.face_origin, [299])
    assert rep.counts["small_components"] == 299 and rep.counts["small_component_faces"] == 299


def test_fins_torn_off_by_the_split_are_small_components():
    """Fins on a closed surface: the split tears each off as a component of its own, so a share above
    theirs leaves exactly the surface's own faces, and none leaves them all."""
    v, f = capsule(n_around=14, n_along=12)
    dv, df, _ = defective_mesh(v, f, ["fins"], seed=5)
    everything = repair_mesh(dv, df)
    assert everything.counts["small_components"] == 0 and everything.faces.shape[0] == df.shape[0]
    rep = repair_mesh(dv, df, min_component=0.05)
    np.testing.assert_array_equal(np.sort(rep.face_origin), np.arange(f.shape[0]))
    assert rep.counts["small_component_faces"] == df.shape[0] - f.shape[0]
    assert check_repaired(rep.vertices, rep.faces) is None
    assert face_areas(rep.vertices, rep.faces).sum() == pytest.approx(face_areas(v, f).sum(), rel=1e-12)


def test_nothing_left_is_a_one_line_error_naming_the_file():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]])
    with pytest.raises(InputError, match=r"^bad\.obj: none of its 2 faces has an area"):
        repair_mesh(v, np.array([[0, 1, 2], [0, 0, 3]]), name="bad.obj")


def test_check_repaired_finds_each_defect():
    v, f = sphere(1)
    assert check_repaired(v, f) is None
    assert check_repaired(v, np.concatenate([f, [[0, 0, 1]]])) == "a face with a repeated corner"
    assert check_repaired(v, np.concatenate([f, f[:1]])) == "an edge in 3 faces"
    assert check_repaired(np.concatenate([v, v[:1]]), f) == "1 vertices in no face"


@pytest.mark.parametrize("defect", DEFECTS)
def test_every_defect_of_the_corpus_is_repaired(defect):
    v, f = capsule(n_around=14, n_along=12)
    dv, df, origin = defective_mesh(v, f, [defect], seed=3)
    rep = repair_mesh(dv, df)
    # a floor fragment is a clean component of its own: kept as it is (min_component leaves it out)
    assert rep.changed == (not defect.startswith("fragment"))
    assert check_repaired(rep.vertices, rep.faces) is None
    assert_same_surface(rep, dv, df)
    # the capsule's own surface is all there: its area (the extra geometry adds, never removes)
    kept_area = face_areas(rep.vertices, rep.faces).sum()
    assert kept_area >= face_areas(v, f).sum() * (1 - 1e-9) - face_areas(dv, df)[face_areas(dv, df) < 1e-14].sum()


meshes = st.sampled_from(["sphere", "capsule", "tube"])


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    kind=meshes,
    defects=st.lists(st.sampled_from(DEFECTS), min_size=1, max_size=4),
    seed=st.integers(0, 2**16),
    crowd=st.integers(0, 6),
)
def test_random_soups_fins_and_fragments_repair_to_a_mesh_every_step_takes(kind, defects, seed, crowd):
    v, f = {"sphere": sphere(1), "capsule": capsule(n_around=8, n_along=6), "tube": tube(n_around=8, n_along=5)}[kind]
    dv, df, _ = defective_mesh(v, f, defects, seed=seed)
    rng = np.random.default_rng(seed)
    if crowd:  # random extra faces on existing vertices: fans glued at random, edges of many faces
        df = np.concatenate([df, rng.integers(0, len(dv), size=(crowd * 4, 3))])
    rep = repair_mesh(dv, df)
    assert check_repaired(rep.vertices, rep.faces) is None
    assert_same_surface(rep, dv, df)
    closed_v, closed_f = close_boundary(rep.vertices, rep.faces)
    assert mesh_topology(closed_f, len(closed_v)).edge_faces.shape[1] == 4
    work = decimate(rep.vertices, rep.faces, max(10, len(rep.vertices) // 3))
    assert check_repaired(work.vertices, work.faces) is None or len(rep.vertices) <= 10
    np.testing.assert_array_equal(work.vertices, rep.vertices[work.kept])
    assert 0.0 <= self_overlap(rep.vertices, rep.faces, max_vertices=len(rep.vertices) // 3 + 4) <= 1.0


def test_decimating_a_mesh_with_fewer_faces_than_its_budget_keeps_it():
    """The traceback of issue 48: a soup's vertex count is over the budget, its face count is not."""
    v, f = sphere(2)
    soup_v, soup_f = v[f].reshape(-1, 3), np.arange(3 * len(f)).reshape(-1, 3)
    work = decimate(soup_v, soup_f, len(f))  # 3F vertices > budget, F faces < 2 x budget
    np.testing.assert_array_equal(work.vertices, soup_v)
    np.testing.assert_array_equal(work.faces, soup_f)
    # vertices in no face are left out
    extra = np.concatenate([v, v[:5] + 9.0])
    work = decimate(extra, f, len(v) - 2)
    assert work.vertices.shape[0] <= len(v) and work.kept.max() < len(v)
    assert 0.0 <= self_overlap(soup_v, soup_f, max_vertices=100) <= 1.0


def test_decimation_output_is_repaired():
    v, f = capsule(n_around=40, n_along=40)
    work = decimate(v, f, 300)
    assert check_repaired(work.vertices, work.faces) is None
    np.testing.assert_array_equal(work.vertices, v[work.kept])


def test_readers_take_repairable_files_and_the_intake_names_what_it_did(tmp_path):
    text = (
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nv 0 0 -1\nv 0.5 0.5 0.5\nv 9 9 9\n"
        "f 1 2 3\nf 2 1 4\nf 1 2 5\nf 2 1 6\nf 1 2 7\nf 1 1 2\nf 1 2 3\n"
    )
    path = tmp_path / "fins.obj"
    path.write_text(text)
    mesh = load_mesh(path)  # an edge of five faces, a degenerate and a duplicate face, a stray vertex
    assert mesh.n_vertices == 8 and mesh.n_faces == 7
    clean, rep = repaired_mesh(mesh)
    assert check_repaired(clean.vertices, clean.faces) is None
    assert clean.name == str(path) and np.array_equal(clean.file_index, rep.vertex_origin)
    assert rep.counts["nonmanifold_edges"] == 1 and rep.counts["degenerate"] == 1 and rep.counts["duplicate"] == 1
    assert rep.counts["unreferenced"] == 1


def test_points_of_the_input_are_carried_to_the_repaired_mesh():
    v, f = sphere(2)
    rng = np.random.default_rng(4)
    # a turned patch, a duplicate and a zero-area face: a point on each lands at the same place
    faces = np.concatenate([f[:30, ::-1], f[30:], f[5:6], [[f[0, 0], f[0, 0], f[0, 1]]]])
    rep = repair_mesh(v, faces)
    face = rng.integers(0, len(faces), 200)
    face[:3] = [2, len(faces) - 2, len(faces) - 1]
    bary = rng.dirichlet(np.ones(3), 200)
    got_face, got_bary = rep.points_from_input(v, faces, face, bary)
    want = np.einsum("nk,nkd->nd", bary, v[faces[face]])
    got = np.einsum("nk,nkd->nd", got_bary, rep.vertices[rep.faces[got_face]])
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_geodesic_errors_on_a_soup_are_those_of_the_welded_source():
    from ncflow.evaluate import geodesic_errors
    from ncflow.geometry.mesh import Mesh

    v, f = sphere(2)
    soup = Mesh(v[f].reshape(-1, 3), np.arange(3 * len(f)).reshape(-1, 3), "soup.ply")
    rng = np.random.default_rng(5)
    pf, gf = rng.integers(0, len(f), 50), rng.integers(0, len(f), 50)
    pb, gb = rng.dirichlet(np.ones(3), 50), rng.dirichlet(np.ones(3), 50)
    clean = geodesic_errors(Mesh(v, f), pf, pb, gf, gb, method="heat")
    np.testing.assert_allclose(geodesic_errors(soup, pf, pb, gf, gb, method="heat"), clean, rtol=1e-9)
    assert np.all(np.isfinite(clean))  # on the soup as given, every pair would be apart (+inf)


@pytest.mark.parametrize("some_edges", [False, True])
def test_vertex_components_match_a_brute_force_flood_fill(some_edges):
    """With ``joined``, only the kept face edges (corner k to corner k + 1) join their vertices."""
    from ncflow.geometry.topology import vertex_components

    rng = np.random.default_rng(7)
    faces = rng.integers(0, 40, size=(25, 3))
    joined = rng.random((25, 3)) < 0.5 if some_edges else None
    labels = vertex_components(faces, 45, joined)  # vertices 40–44 and unreferenced ones: components of their own
    neighbours = {i: set() for i in range(45)}
    for i, (a, b, c) in enumerate(faces.tolist()):
        for k, (x, y) in enumerate(((a, b), (b, c), (c, a))):
            if joined is None or joined[i, k]:
                neighbours[x].add(y)
                neighbours[y].add(x)
    for start in range(45):
        seen, todo = {start}, [start]
        while todo:
            for n in neighbours[todo.pop()] - seen:
                seen.add(n)
                todo.append(n)
        assert {i for i in range(45) if labels[i] == labels[start]} == seen
