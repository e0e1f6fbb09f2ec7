"""Skin-weight transfer with inpainting (retarget/weights.py) and the cotangent Laplacian (geometry/laplacian.py).

References: potpourri3d's cotangent Laplacian and vertex areas (an independent implementation), a
dense Laplacian built from angles (arccos) with the inpainting solved as a dense KKT system, and the
analytic cases the energy ``trace(Wᵀ Q W)``, ``Q = −L + L M⁻¹ L``, must reproduce: constants
everywhere, linear functions two rings inside a flat region.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ncflow.errors import InputError
from ncflow.geometry.laplacian import cotangent_laplacian, lumped_mass, mollified_lengths
from ncflow.geometry.mesh import vertex_normals
from ncflow.retarget.weights import (
    inpaint_weights,
    limit_influences,
    skeleton_weights,
    transfer_skin_weights,
)


@pytest.fixture(scope="module")
def sphere():
    m = trimesh.creation.icosphere(subdivisions=2)
    v = np.asarray(m.vertices, dtype=np.float64) * np.array([1.0, 0.7, 1.4])  # not symmetric
    return v, np.asarray(m.faces, dtype=np.int64)


def _grid(n: int = 9, seed: int = 0):
    """A jittered planar grid in z = 0 (n × n vertices), triangles split along alternating diagonals."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float), indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1)
    interior = (x.ravel() > 0) & (x.ravel() < n - 1) & (y.ravel() > 0) & (y.ravel() < n - 1)
    v[interior, :2] += rng.uniform(-0.2, 0.2, size=(interior.sum(), 2))
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            faces += [(a, b, c), (a, c, d)] if (i + j) % 2 == 0 else [(a, b, d), (b, c, d)]
    return v, np.asarray(faces, dtype=np.int64)


def _dense_laplacian(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reference (L, lumped mass) from the corner angles (arccos of unit edge vectors), dense loops."""
    n = v.shape[0]
    lap = np.zeros((n, n))
    mass = np.zeros(n)
    for tri in f:
        for c in range(3):
            i, j, k = tri[c], tri[(c + 1) % 3], tri[(c + 2) % 3]
            e1, e2 = v[j] - v[i], v[k] - v[i]
            angle = np.arccos(np.clip(e1 @ e2 / np.linalg.norm(e1) / np.linalg.norm(e2), -1, 1))
            w = 0.5 / np.tan(angle)  # weighs the opposite edge (j, k)
            lap[j, k] += w
            lap[k, j] += w
        area = 0.5 * np.linalg.norm(np.cross(v[tri[1]] - v[tri[0]], v[tri[2]] - v[tri[0]]))
        mass[tri] += area / 3
    lap -= np.diag(lap.sum(1))
    return lap, mass


def test_laplacian_matches_potpourri3d(sphere):
    pp3d = pytest.importorskip("potpourri3d")
    v, f = sphere
    lap = cotangent_laplacian(v, f).toarray()
    np.testing.assert_allclose(lap, -pp3d.cotan_laplacian(v, f).toarray(), atol=1e-12)  # pp3d: positive diagonal
    np.testing.assert_allclose(lumped_mass(v, f), pp3d.vertex_areas(v, f), rtol=1e-12)
    np.testing.assert_allclose(lap, lap.T, atol=1e-14)
    np.testing.assert_allclose(lap.sum(1), 0.0, atol=1e-12)


def test_degenerate_triangles_stay_positive_semidefinite():
    v, f = _grid(5)
    # a flat triangle inside the mesh: vertex 12 moved onto the edge between the two other corners
    # of one of its triangles; and a separate zero-area triangle (three collinear vertices)
    tri = f[np.flatnonzero((f == 12).any(1))[0]]
    a, b = tri[tri != 12]
    v[12] = 0.5 * (v[a] + v[b])
    v = np.concatenate([v, [[10.0, 0, 0], [11.0, 0, 0], [12.0, 0, 0]]])
    f = np.concatenate([f, [[25, 26, 27]]])
    assert np.linalg.norm(np.cross(v[a] - v[12], v[b] - v[12])) < 1e-15  # degenerate up to rounding
    lengths = mollified_lengths(v, f)
    slack = lengths.sum(1, keepdims=True) - 2 * lengths
    assert slack.min() > 0  # every triangle strictly valid after mollification
    lap = cotangent_laplacian(v, f).toarray()
    assert np.all(np.isfinite(lap))
    eig = np.linalg.eigvalsh(-lap)
    assert eig.min() > -1e-9 * eig.max()
    np.testing.assert_allclose(lap @ np.ones(v.shape[0]), 0.0, atol=1e-9)
    assert np.all(lumped_mass(v, f) > 0)
    known = np.ones(v.shape[0], dtype=bool)
    known[[6, 12, 13]] = False
    out = inpaint_weights(v, f, np.where(known, 1.0, 0.0)[:, None], known)
    np.testing.assert_allclose(out, 1.0, atol=1e-9)  # constants survive the degenerate triangle


def test_inpainting_equals_dense_kkt_solve(sphere):
    v, f = sphere
    rng = np.random.default_rng(1)
    n = v.shape[0]
    values = rng.uniform(0, 1, size=(n, 3))
    known = rng.uniform(size=n) > 0.3
    ours = inpaint_weights(v, f, values, known)
    # reference: dense angle-based L, M on the mesh scaled to unit bounding-box diagonal;
    # minimise trace(Xᵀ Q X) subject to X_K = values_K through the KKT system
    vs = v / np.linalg.norm(np.ptp(v, axis=0))
    lap, mass = _dense_laplacian(vs, f)
    q = -lap + lap @ np.diag(1 / mass) @ lap
    kk = np.flatnonzero(known)
    c = np.zeros((kk.size, n))
    c[np.arange(kk.size), kk] = 1.0
    kkt = np.block([[2 * q, c.T], [c, np.zeros((kk.size, kk.size))]])
    rhs = np.concatenate([np.zeros((n, 3)), values[kk]])
    ref = np.linalg.solve(kkt, rhs)[:n]
    np.testing.assert_allclose(ours, ref, atol=1e-9)
    np.testing.assert_array_equal(ours[known], values[known])


def test_constants_stay_constant(sphere):
    v, f = sphere
    n = v.shape[0]
    known = np.zeros(n, dtype=bool)
    known[::7] = True
    c = np.array([0.2, 0.5, 0.3])
    values = np.where(known[:, None], c, np.random.default_rng(2).uniform(size=(n, 3)))
    np.testing.assert_allclose(inpaint_weights(v, f, values, known), np.tile(c, (n, 1)), atol=1e-10)


def test_linear_field_reproduced_inside_flat_region():
    v, f = _grid(11)
    n = v.shape[0]
    linear = 0.3 + 0.7 * v[:, 0] - 0.2 * v[:, 1]
    # unknown: the vertices at least 3 grid steps from the border (their 2-ring is interior)
    ix, iy = np.divmod(np.arange(n), 11)
    unknown = (ix >= 3) & (ix <= 7) & (iy >= 3) & (iy <= 7)
    values = np.where(unknown, 0.0, linear)
    out = inpaint_weights(v, f, values, ~unknown)
    np.testing.assert_allclose(out, linear, atol=1e-10)


def test_component_without_known_vertex_keeps_its_values(sphere):
    v, f = sphere
    n = v.shape[0]
    v2 = np.concatenate([v, v + [5.0, 0, 0]])
    f2 = np.concatenate([f, f + n])
    rng = np.random.default_rng(3)
    values = rng.uniform(size=(2 * n, 2))
    known = np.zeros(2 * n, dtype=bool)
    known[:n:3] = True  # the second sphere has no known vertex
    out = inpaint_weights(v2, f2, values, known)
    np.testing.assert_array_equal(out[n:], values[n:])
    # Q is block diagonal: the first sphere's solution does not depend on the second's values
    second_known = known.copy()
    second_known[n:] = True
    np.testing.assert_allclose(out[:n], inpaint_weights(v2, f2, values, second_known)[:n], atol=1e-12)
    assert np.abs(out[:n] - values[:n])[~known[:n]].min() > 0  # the first sphere was inpainted


def _rigid(v, angle=0.4, shift=(0.3, -0.2, 0.5)):
    c, s = np.cos(angle), np.sin(angle)
    r = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    return v @ r.T + np.asarray(shift)


def test_transfer_identity_map_keeps_weights(sphere):
    v, f = sphere
    n = v.shape[0]
    rng = np.random.default_rng(4)
    w = rng.uniform(size=(n, 5))
    w /= w.sum(1, keepdims=True)
    target = _rigid(v)  # the flowed source is the target itself
    corner = np.zeros(n, dtype=np.int64)
    face = np.array([np.flatnonzero((f == i).any(1))[0] for i in range(n)])
    bary = np.zeros((n, 3))
    for i in range(n):
        corner[i] = int(np.flatnonzero(f[face[i]] == i)[0])
        bary[i, corner[i]] = 1.0
    out, reliable = transfer_skin_weights(w, v, f, target, target, f, face, bary)
    assert reliable.all()
    np.testing.assert_allclose(out, w, atol=1e-12)


def test_transfer_inpaints_unreliable_vertices(sphere):
    v, f = sphere
    n = v.shape[0]
    target = _rigid(v)
    face = np.array([np.flatnonzero((f == i).any(1))[0] for i in range(n)])
    bary = np.zeros((n, 3))
    bary[np.arange(n), [int(np.flatnonzero(f[face[i]] == i)[0]) for i in range(n)]] = 1.0
    # smooth weights of two joints, plus garbage on a cap of the source, which is moved far away
    # (distance) or turned inside out (normals) on the flowed source
    s = 0.5 + 0.5 * np.tanh(v[:, 2])
    w = np.stack([s, 1 - s], 1)
    cap = v[:, 0] > 0.6
    garbage = w.copy()
    garbage[cap] = [[0.0, 1.0]]
    far = target.copy()
    far[cap] += [0.0, 0.0, 2.0]
    out, reliable = transfer_skin_weights(garbage, v, f, far, target, f, face, bary)
    # a target wound the other way (inside out, which the match turns) is read with its faces turned
    out_r, reliable_r = transfer_skin_weights(garbage, v, f, far, target, f[:, ::-1], face, bary)
    np.testing.assert_array_equal(reliable_r, reliable)
    np.testing.assert_allclose(out_r, out, atol=1e-12)
    # the cap is unreliable (too far), and so is its border ring, whose flowed triangles are
    # stretched towards the moved cap (normals turned by more than 30°); nothing else
    ring = np.zeros(n, dtype=bool)
    ring[f[cap[f].any(1)].reshape(-1)] = True
    assert np.all(~reliable[cap]) and np.all(reliable[~ring])
    assert np.all(out >= 0)
    np.testing.assert_allclose(out.sum(1), 1.0, atol=1e-12)
    np.testing.assert_array_equal(out[reliable], w[reliable])
    # inpainting recovers the smooth field much better than the garbage it replaced
    assert np.abs(out[cap] - w[cap]).max() < 0.25 * np.abs(garbage[cap] - w[cap]).max()
    # opposite normals: the cap of the flowed source mirrored through its own plane x = const
    flipped = target.copy()
    centre = target[cap].mean(0)
    normal = np.array([np.cos(0.4), np.sin(0.4), 0.0])  # the rotated x axis
    flipped[cap] -= 2 * np.outer((target[cap] - centre) @ normal, normal)
    _, reliable2 = transfer_skin_weights(garbage, v, f, flipped, target, f, face, bary, max_distance=10.0)
    assert (~reliable2).sum() > 0 and np.all(cap[~reliable2])
    # thresholds that accept everything keep every carried row
    out3, all_ok = transfer_skin_weights(
        garbage, v, f, far, target, f, face, bary, max_distance=10.0, max_normal_angle=180.0
    )
    assert all_ok.all()
    np.testing.assert_allclose(out3, garbage, atol=1e-12)


def test_transfer_rejects_bad_weights(sphere):
    v, f = sphere
    n = v.shape[0]
    face = np.zeros(n, dtype=np.int64)
    bary = np.full((n, 3), 1 / 3)
    w = np.ones((n, 2))
    w[3, 0] = -0.5
    with pytest.raises(InputError, match="non-negative"):
        transfer_skin_weights(w, v, f, v, v, f, face, bary)
    w = np.ones((n, 2))
    w[5] = 0
    with pytest.raises(InputError, match="no skin weight"):
        transfer_skin_weights(w, v, f, v, v, f, face, bary)


def test_limit_influences_against_sorting():
    rng = np.random.default_rng(5)
    w = rng.uniform(size=(200, 9)) * (rng.uniform(size=(200, 9)) > 0.4)
    w[0] = [0, 0, 0, 0, 0, 0, 0, 0, 1.0]  # one influence only: padded
    w[w.sum(1) == 0, 0] = 1.0
    joints, weights = limit_influences(w, 4)
    np.testing.assert_allclose(weights.sum(1), 1.0, atol=1e-12)
    assert np.all(weights >= 0) and joints.dtype.kind == "i"
    for i in range(w.shape[0]):
        top = np.sort(w[i])[::-1][:4]
        np.testing.assert_allclose(weights[i], top / top.sum(), atol=1e-12)
        used = weights[i] > 0
        np.testing.assert_allclose(w[i, joints[i, used]], top[used], atol=0)
    assert joints[0, 0] == 8 and np.all(joints[0, 1:] == 0) and np.all(weights[0, 1:] == 0)


def test_vertex_normals_point_outwards(sphere):
    v, f = sphere
    n = vertex_normals(v, f)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    assert np.all(np.einsum("ij,ij->i", n, v) > 0)


def test_skeleton_weights_go_to_the_joint_that_moves_the_bone():
    # chain 0 → 1 → 2 along x, plus a branch 0 → 3 along y; points near the middle of each bone
    joints = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0], [0.0, 1.0, 0]])
    parents = np.array([-1, 0, 1, 0])
    points = np.array([[0.5, 0.05, 0], [1.5, 0.05, 0], [0.05, 0.5, 0], [1.0, 0.02, 0]])
    w = skeleton_weights(points, joints, parents, width=0.05)
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-6)
    assert w[0, 0] > 0.99 and w[1, 1] > 0.99 and w[2, 0] > 0.99  # bones (0→1) and (0→3) both move with joint 0
    np.testing.assert_allclose(w[:, [2, 3]], 0.0, atol=1e-6)  # leaves move nothing
    assert 0.2 < w[3, 0] < 0.8  # at the elbow: a blend of joints 0 and 1
    # independent reference: softmax of the distances to the segments, summed per parent joint
    seg_a, seg_b = joints[parents[1:]], joints[1:]
    d = np.empty((points.shape[0], 3))
    for b in range(3):
        u = np.clip((points - seg_a[b]) @ (seg_b[b] - seg_a[b]) / np.sum((seg_b[b] - seg_a[b]) ** 2), 0, 1)
        d[:, b] = np.linalg.norm(points - (seg_a[b] + u[:, None] * (seg_b[b] - seg_a[b])), axis=1)
    soft = np.exp(-(d - d.min(1, keepdims=True)) / 0.05)
    soft /= soft.sum(1, keepdims=True)
    ref = np.zeros((points.shape[0], 4))
    np.add.at(ref.T, parents[1:], soft.T)
    np.testing.assert_allclose(w, ref, atol=1e-5)  # median bone length is 1: τ = 0.05
    # with the skin's normals: a bone in front of the skin is left out (the match's "surface" weights)
    up = np.tile([0.0, 1.0, 0.0], (4, 1))
    np.testing.assert_allclose(skeleton_weights(points, joints, parents, 0.05, up), w, atol=1e-6)  # all behind
    down = up.copy()
    down[1] = [0.0, -1.0, 0.0]  # point 1 faces bone (1→2) from above: that bone is in front of its skin
    seen = skeleton_weights(points, joints, parents, 0.05, down)
    assert w[1, 1] > 0.99 and seen[1, 0] > 0.99  # the only bone not in front, (0→3), moves with joint 0
    np.testing.assert_allclose(np.delete(seen, 1, axis=0), np.delete(w, 1, axis=0), atol=1e-6)
