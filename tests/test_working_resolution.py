"""Training on a working-resolution copy of the source, outputs at full resolution (issue 17)."""

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from ncflow.geometry.decimate import decimate
from ncflow.geometry.mesh import Mesh
from ncflow.matcher.steps import Matcher
from ncflow.skeleton import Skeleton
from ncflow.synthetic.shapes import bend, capsule
from test_matcher import small_config


def _capsule(n_around, n_along):
    return capsule(radius=0.4, length=3.0, n_around=n_around, n_along=n_along)


def test_decimation_keeps_original_vertices_and_a_closed_surface():
    v, f = _capsule(40, 60)
    d = decimate(v, f, 500)
    assert 400 <= d.vertices.shape[0] <= 520
    np.testing.assert_array_equal(d.vertices, v[d.kept])  # made of the source's own vertices
    assert np.unique(d.kept).size == d.kept.size
    m = trimesh.Trimesh(d.vertices, d.faces, process=False)
    assert m.is_watertight and m.is_winding_consistent and m.euler_number == 2
    full = trimesh.Trimesh(v, f, process=False)
    assert abs(m.volume - full.volume) < 0.03 * full.volume
    # every working vertex lies on the source, and the source is near the working surface
    assert cKDTree(d.vertices).query(v)[0].max() < 0.2  # the capsule is 3.8 long


def test_small_source_is_used_as_it_is():
    v, f = _capsule(12, 18)
    d = decimate(v, f, 3000)
    np.testing.assert_array_equal(d.vertices, v)
    np.testing.assert_array_equal(d.faces, f)
    np.testing.assert_array_equal(d.kept, np.arange(v.shape[0]))


@pytest.fixture(scope="module")
def result():
    vs, fs = _capsule(30, 50)  # 1502 vertices, trained on ~400
    vt, ft = capsule(radius=0.4, length=3.0, n_around=26, n_along=44, diagonal="left")
    skel = Skeleton.from_arrays(np.array([[0, 0, -1.6], [0, 0, 0.0], [0, 0, 1.6]]), np.array([-1, 0, 1]))
    m = Matcher(
        Mesh(vs, fs, "source"),
        Mesh(bend(vt, 60.0), ft, "target"),
        skel,
        # no rigid placement or pose search: the bent capsule needs neither, and what is tested here is
        # the step from the working copy to the full-resolution outputs
        small_config(steps=(8, 8), working_vertices=400, placement="none", pose_search="false"),
        quiet=True,
    )
    return m, m.run()


def test_outputs_are_at_full_resolution_and_consistent_with_the_full_meshes(result):
    m, res = result
    src, tgt = m.setup.source, m.setup.target
    assert m.setup.working.vertices.shape[0] < 0.35 * src.n_vertices
    assert res.metrics["n_source_vertices"] == src.n_vertices
    assert res.metrics["n_working_vertices"] == m.setup.working.vertices.shape[0]
    maps = res.maps
    assert maps["p2p_src_to_tgt"].shape == (src.n_vertices,)
    assert maps["p2p_tgt_to_src"].shape == (tgt.n_vertices,)
    assert maps["map_face"].shape == (tgt.n_vertices,)
    assert maps["p2p_src_to_tgt"].max() < tgt.n_vertices and maps["p2p_tgt_to_src"].max() < src.n_vertices
    assert maps["map_face"].max() < src.faces.shape[0]
    # the (face, bary) map names points of the full-resolution rest source (normalised coordinates)
    pts = np.einsum("nk,nkd->nd", maps["map_bary"], m.setup.source_vertices[src.faces[maps["map_face"]]])
    np.testing.assert_allclose(pts, maps["map_points"], atol=1e-9)
    # and the foot points lie on the full-resolution flowed source: each target vertex is that far
    flowed = np.einsum("nk,nkd->nd", maps["map_bary"], res.deformed_source[src.faces[maps["map_face"]]])
    d = np.linalg.norm(flowed - tgt.vertices, axis=1) * m.setup.normalization.scale
    np.testing.assert_allclose(d, maps["dist_tgt_to_src"] * 1.0, rtol=1e-6, atol=1e-6)
    assert res.frames.shape == (5, src.n_vertices, 3) and np.all(np.isfinite(res.frames))


def test_full_flow_reproduces_the_working_flow_at_shared_vertices(result):
    """The field is trained on the working vertices; flowed at full resolution, the vertices the two
    meshes share land exactly where the working mesh's do."""
    m, res = result
    kept = m.setup.working.kept
    working_user = m.setup.normalization.invert(m.setup.working.vertices)
    np.testing.assert_allclose(working_user, m.setup.source.vertices[kept], atol=1e-12)
    np.testing.assert_allclose(res.flow(working_user), res.deformed_source[kept], atol=1e-5)
    assert np.linalg.norm(res.deformed_source - m.setup.source.vertices, axis=1).max() > 0.3  # it moved
