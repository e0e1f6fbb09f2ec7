"""Size buckets (ncflow.jit.buckets, geometry.topology.pad_topology): padded arrays represent the same
measures, draws take real rows only, and a padded objective equals the unpadded one.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ncflow.flow import FlowField
from ncflow.flow.integrate import flow_points, integrate
from ncflow.geometry.topology import mesh_topology, pad_topology
from ncflow.jit.buckets import bucket, draw_rows, pad_rows
from ncflow.measures.normal_cycles import normal_cycle, normal_cycle_inner
from ncflow.measures.varifold import varifold, varifold_inner
from ncflow.synthetic.shapes import capsule, sphere


def _open_capsule():
    v, f = capsule(radius=0.4, length=2.0, n_around=8, n_along=6)
    keep = v[f].mean(1)[:, 2] < 0.9  # cut the top off: a mesh with a boundary loop
    return v, f[keep]


@pytest.mark.parametrize("mesh", ["closed", "open"])
def test_padded_topology_gives_the_same_measures_and_gradients(mesh):
    """Degenerate faces/edges at vertex 0 and neighbour-less boundary vertices: every Normal Cycle and
    Varifold inner product against another mesh, and its gradient in the real vertices, is the
    unpadded one (brute force: the same functions on the unpadded tables)."""
    v, f = sphere(2) if mesh == "closed" else _open_capsule()
    topo = mesh_topology(f, v.shape[0])
    padded = pad_topology(topo, topo.faces.shape[0] + 13, topo.n_edges + 21, topo.boundary_vertices.size + 5)
    assert padded.n_edges == topo.n_edges + 21 and padded.faces.shape[0] == topo.faces.shape[0] + 13
    assert padded.has_boundary == topo.has_boundary
    if mesh == "closed":
        assert padded.boundary_vertices.size == 0  # a closed mesh gets no boundary terms
    other = jnp.asarray(v * 1.1 + 0.05)
    y_nc, y_vf = normal_cycle(other, topo), varifold(other, topo.faces)
    x = jnp.asarray(v)

    def energies(verts, t):
        return (
            normal_cycle_inner(normal_cycle(verts, t), y_nc, 0.4),
            normal_cycle_inner(normal_cycle(verts, t), normal_cycle(verts, t), 0.4),
            varifold_inner(varifold(verts, t.faces), y_vf, 0.4),
        )

    for k in range(3):
        ref, grad_ref = jax.jit(jax.value_and_grad(lambda p, k=k: energies(p, topo)[k]))(x)
        val, grad = jax.jit(jax.value_and_grad(lambda p, k=k: energies(p, padded)[k]))(x)
        assert float(val) == pytest.approx(float(ref), rel=1e-6)
        np.testing.assert_allclose(np.asarray(grad), np.asarray(grad_ref), rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError):
        pad_topology(topo, topo.faces.shape[0] - 1, topo.n_edges)


def test_pad_rows_keeps_inner_products():
    v, f = sphere(1)
    x = varifold(jnp.asarray(v), f)
    p = pad_rows(x, bucket(x.size, 8) + 8)
    assert p.size > x.size
    assert float(varifold_inner(p, p, 0.3)) == pytest.approx(float(varifold_inner(x, x, 0.3)), rel=1e-6)
    with pytest.raises(ValueError):
        pad_rows(x, x.size - 1)


def test_draw_rows_takes_real_rows_only():
    """With ``valid`` the draw is the real rows of the same permutation (all-real mask: the plain draw),
    never a padding row, never one twice; asking for more than the real rows puts the padding last."""
    valid = jnp.asarray(np.arange(64) < 50)
    key = jax.random.key(3)
    plain = np.asarray(draw_rows(key, 50, 30))
    np.testing.assert_array_equal(np.asarray(draw_rows(key, 50, 30, jnp.ones(50, bool))), plain)
    drawn = np.asarray(jax.jit(draw_rows, static_argnums=(1, 2))(key, 64, 30, valid))
    assert drawn.shape == (30,) and drawn.max() < 50 and len(set(drawn.tolist())) == 30
    everything = np.asarray(draw_rows(key, 64, 64, valid))
    assert sorted(everything[:50].tolist()) == list(range(50)) and sorted(everything[50:].tolist()) == list(
        range(50, 64)
    )


def test_flow_points_pads_to_a_bucket_and_returns_the_same_trajectories():
    """flow_points pads the points to a size bucket (one compiled program for similar sizes) and
    returns exactly the rows asked for, equal to integrating them alone."""
    field = FlowField(jax.random.key(0), width=16, depth=2, dtype=jnp.float32, alpha=1.0)
    pts = jax.random.normal(jax.random.key(1), (83, 3))
    assert bucket(83, 8) == 88
    out = flow_points(field, pts, 4)
    ref, _ = integrate(field, pts, 4)
    assert out.shape == (4, 83, 3)
    np.testing.assert_allclose(np.asarray(out), np.asarray(ref), rtol=1e-6, atol=1e-6)
    assert flow_points(field, pts[:0], 4).shape == (4, 0, 3)


def test_padded_training_objective_equals_the_unpadded_one():
    """The working source padded to its buckets (vertices, edges, faces; all edges in the ARAP term,
    rescaled to the real ones) gives the same loss and gradient as the unpadded arrays."""
    import equinox as eqx

    from ncflow.geometry.mesh import Mesh
    from ncflow.matcher.objective import Arrays, Settings
    from ncflow.matcher.place import place
    from ncflow.matcher.prepare import DTYPE, prepare
    from ncflow.matcher.stages import build_stages
    from ncflow.matcher.targets import target_measures
    from ncflow.matcher.train import init_params
    from ncflow.skeleton import Skeleton
    from ncflow.synthetic.shapes import bend
    from test_objective import _config, stage_objective

    vs, fs = capsule(radius=0.4, length=3.0, n_around=7, n_along=10)
    skel = Skeleton.from_arrays(np.array([[0, 0, -1.6], [0, 0, 0.0], [0, 0, 1.6]]), np.array([-1, 0, 1]))
    cfg = _config(**{"sampling.surface_edges": 0, "weights.surface": 1.0})
    prob = prepare(Mesh(vs, fs, "s"), Mesh(bend(vs, 50.0), fs, "t"), skel, cfg)
    stages = build_stages(cfg, prob.working_edge)
    targets = target_measures(prob, place(prob, cfg), stages, cfg)
    st = stages[-1]
    target, yy, _ = targets[(st.metric, st.sigma, st.phase_config.sigma_normal)]
    params = init_params(jax.random.key(0), cfg, prob.skeleton_normalized)
    results = []
    for pad in (False, True):
        arrays = Arrays.from_problem(prob, pad=pad)
        s = Settings.from_config(cfg, st.metric, arrays.n_edges, 0)
        assert s.n_edges == 0  # all edges

        def loss(p, arrays=arrays, s=s):
            return stage_objective(p, arrays, s, st, target, yy, jnp.ones((2, 2), DTYPE), jax.random.key(5))

        (total, aux), grads = eqx.filter_jit(eqx.filter_value_and_grad(loss, has_aux=True))(params)
        results.append((float(total), float(aux["surface"]), float(aux["data"]), grads))
        if pad:
            assert arrays.source.shape[0] == 88 and arrays.n_vertices == 86 and arrays.edges.shape[0] == 256
    (t0, s0, d0, g0), (t1, s1, d1, g1) = results
    assert s0 > 0 and d0 > 0
    assert t1 == pytest.approx(t0, rel=1e-5) and s1 == pytest.approx(s0, rel=1e-5) and d1 == pytest.approx(d0, rel=1e-5)
    for a, b in zip(
        jax.tree_util.tree_leaves(eqx.filter(g0, eqx.is_inexact_array)),
        jax.tree_util.tree_leaves(eqx.filter(g1, eqx.is_inexact_array)),
    ):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=5e-4, atol=1e-7)
