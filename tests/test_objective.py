"""The objective and the training step that the matcher runs (ncflow.matcher.objective / train).

The step must be exactly: objective (losses + tissue + optim.mdmm) → the configured optimiser with the pose's
learning rate scaled through optax.multi_transform → the sign ascent of optim.mdmm on the multipliers.
"""

import dataclasses
import itertools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ncflow.config import apply_overrides, preset, validate_config
from ncflow.geometry.mesh import Mesh
from ncflow.matcher.objective import LEASH_SAMPLES, Arrays, Settings, constraint_term, objective
from ncflow.matcher.place import place
from ncflow.matcher.prepare import DTYPE, prepare
from ncflow.matcher.stages import build_stages
from ncflow.matcher.targets import TargetMeasure, target_measures
from ncflow.matcher.train import build_optimizer, held_phases, init_params, make_step, parameter_labels
from ncflow.optim.mdmm import Multipliers, multiplier_rate, update_multipliers
from ncflow.skeleton import Skeleton
from ncflow.skeleton.kinematics import rest_pose
from ncflow.synthetic.shapes import bend, capsule


def _config(**overrides):
    items = [
        "flow.width=16",
        "flow.depth=2",
        "flow.gso_width=8",
        "flow.gso_depth=1",
        "sampling.bone_samples=6",
        "sampling.tissue_samples=0",
        "weights.tissue=0",
        "sampling.surface_edges=64",
        "compress=none",
        "placement=none",  # the objective is what is tested: the rest pose, the target as given
        "pose_search=false",
    ] + [f"{k}={v}" for k, v in overrides.items()]
    return validate_config(apply_overrides(preset("fast"), items))


@pytest.fixture(scope="module")
def problem():
    vs, fs = capsule(radius=0.4, length=3.0, n_around=8, n_along=10)
    vt, ft = capsule(radius=0.4, length=3.0, n_around=9, n_along=9, diagonal="left")
    skel = Skeleton.from_arrays(np.array([[0, 0, -1.6], [0, 0, 0.0], [0, 0, 1.6]]), np.array([-1, 0, 1]))
    cfg = _config()
    # the fast preset's "auto" phase at σ 0.5 and 0.1 on this coarse capsule (median edge 0.4 normalised):
    # Normal Cycles, then the four-point Varifold — with the first phase, all three data terms
    cfg = dataclasses.replace(cfg, phases=(cfg.phases[0], dataclasses.replace(cfg.phases[1], sigmas=(0.5, 0.1))))
    prob = prepare(Mesh(vs, fs, "s"), Mesh(bend(vt, 50.0), ft, "t"), skel, cfg)
    stages = build_stages(cfg, prob.working_edge)
    return cfg, prob, stages, target_measures(prob, place(prob, cfg), stages, cfg)


def test_constraint_term_matches_brute_force():
    g_ep = jnp.asarray([0.5e-3, 2e-3, 0.1e-3])
    g_tr = jnp.asarray([3e-3, 0.0, 1e-3])
    lam = jnp.asarray([[1.0, 2.0, 3.0], [0.5, 0.0, 4.0]])
    pw = jnp.asarray([1.0, 0.7])
    cfg = _config(**{"constraints.eps": 1e-3, "constraints.margin": 0.5, "constraints.damping": 10.0})
    s = Settings.from_config(cfg, "varifold", 100, 0)
    aim, tau, w = 0.5e-3, cfg.constraints.trajectory_weight, cfg.constraints.weight

    def m(g, lam_):
        gam = np.maximum(np.asarray(g) - aim, 0.0)
        return np.mean(np.asarray(lam_) * gam + 0.5 * 10.0 * gam**2)

    expected = w * (1.0 * m(g_ep, lam[0]) + 0.7 * tau * m(g_tr, lam[1]))
    assert float(constraint_term(g_ep, g_tr, lam, pw, s)) == pytest.approx(expected, rel=1e-12)
    soft = dataclasses.replace(s, mode="soft")
    expected_soft = cfg.constraints.soft_weight * (
        np.mean(np.asarray(g_ep)) / 1e-3 + 0.7 * tau * np.mean(np.asarray(g_tr)) / 1e-3
    )
    assert float(constraint_term(g_ep, g_tr, lam, pw, soft)) == pytest.approx(expected_soft, rel=1e-12)


def _first_stage(problem):
    """(config, arrays, first stage, its target and ⟨Y, Y⟩, objective settings, initial parameters)."""
    cfg, prob, stages, targets = problem
    arrays = Arrays.from_problem(prob)
    st = stages[0]
    target, yy, _ = targets[(st.metric, st.sigma, st.phase_config.sigma_normal)]
    s = Settings.from_config(cfg, st.metric, int(arrays.edges.shape[0]), 0)
    return cfg, arrays, st, target, yy, s, init_params(jax.random.key(0), cfg, arrays.skeleton)


def stage_objective(params, arrays, settings, st, target, yy, lam, key):
    """The objective of stage ``st`` (Varifold normal scale 0.5, both constraint weights 1) at the rest pose."""
    return objective(
        params,
        rest_pose(arrays.skeleton, DTYPE),
        (target,),
        0,
        jnp.asarray(st.sigma, DTYPE),
        jnp.asarray(0.5, DTYPE),
        jnp.asarray(yy, DTYPE),
        jnp.asarray([1.0, 1.0], DTYPE),
        lam,
        key,
        arrays=arrays,
        settings=settings,
    )


def test_objective_at_identity_flow_is_the_data_term_plus_nothing(problem):
    """At the first step the flow is ~identity: bones are rigid (g ≈ 0), so no constraint cost."""
    cfg, arrays, st, target, yy, s, params = _first_stage(problem)
    zero_flow = eqx.tree_at(lambda p: p.flow.residual.alpha, params, jnp.zeros_like(params.flow.residual.alpha))
    # compiled as the training step compiles it (run op by op, each operation is a program)
    run = eqx.filter_jit(lambda p, lam, key: stage_objective(p, arrays, s, st, target, yy, lam, key))
    total, aux = run(zero_flow, jnp.zeros((2, 2), DTYPE), jax.random.key(1))
    # with the residual off and the pose at rest the flow is the identity: the data term is the
    # normalised Varifold distance of the rest source to the target, every bone exactly rigid
    from ncflow.measures.registry import get_metric

    metric = get_metric(st.metric)
    x = metric.represent(arrays.source, arrays.topology)
    direct = float(metric.distance(x, target.measure, st.sigma, 0.5)) / yy
    assert float(aux["data"]) == pytest.approx(direct, rel=1e-4)
    np.testing.assert_allclose(np.asarray(aux["g_ep"]), 0.0, atol=1e-10)
    assert float(aux["constraint"]) == pytest.approx(0.0, abs=1e-10)
    assert float(total) == pytest.approx(float(aux["data"]) + cfg.weights.surface * float(aux["surface"]), rel=1e-6)


def test_data_term_reads_only_what_the_target_shows(problem):
    """A target measure's source weights ω restrict the flowed source's measure in the data term
    (:func:`ncflow.measures.partial.restrict`): the term equals the restricted measure's distance, brute
    force, for each metric; ω ≡ 1 gives the whole one."""
    from ncflow.matcher.objective import _data_term
    from ncflow.measures.partial import restrict
    from ncflow.measures.registry import get_metric

    cfg, prob, stages, targets = problem
    arrays = Arrays.from_problem(prob)
    firsts = {}
    for st in stages:
        firsts.setdefault(st.metric, st)
    upper = (np.asarray(arrays.source)[:, 2] > 0.0).astype(np.float32)
    for m, st in firsts.items():
        target, yy, _ = targets[(st.metric, st.sigma, st.phase_config.sigma_normal)]
        metric = get_metric(m)
        values = []
        for w in (upper, np.ones_like(upper)):
            got = _data_term(
                (m,), 0, arrays.source, arrays, (TargetMeasure(target.measure, jnp.asarray(w)),), st.sigma, 0.5, yy
            )
            x = restrict(metric.represent(arrays.source, arrays.topology), arrays.topology, w)
            assert float(got) == pytest.approx(float(metric.distance(x, target.measure, st.sigma, 0.5)) / yy, rel=1e-4)
            values.append(float(got))
        assert abs(values[0] - values[1]) > 1e-2 * abs(values[1])


def test_one_step_for_every_metric_picks_the_stage_data_term(problem):
    """The training compiles one step for the Varifold, Normal Cycle and four-point Varifold stages: ``which``
    selects the data term, and each equals the single-metric objective's (everything else is the same)."""
    cfg, prob, stages, targets = problem
    arrays = Arrays.from_problem(prob)
    firsts = {}
    for st in stages:
        firsts.setdefault(st.metric, st)
    assert set(firsts) == {"varifold", "normal-cycles", "varifold-q4"}
    names = tuple(firsts)
    both = Settings.from_config(cfg, names, int(arrays.edges.shape[0]), 0)
    params = init_params(jax.random.key(0), cfg, arrays.skeleton)
    tg = {m: targets[(st.metric, st.sigma, st.phase_config.sigma_normal)] for m, st in firsts.items()}

    def data(settings, which, stage_targets, st):
        @eqx.filter_jit
        def run(stage_targets, which, sigma, sigma_n, yy):
            return objective(
                params,
                rest_pose(arrays.skeleton, DTYPE),
                stage_targets,
                which,
                sigma,
                sigma_n,
                yy,
                jnp.asarray([1.0, 1.0], DTYPE),
                jnp.zeros((2, arrays.skeleton.n_bones), DTYPE),
                jax.random.key(1),
                arrays=arrays,
                settings=settings,
            )[1]["data"]

        sigmas = (st.sigma, st.phase_config.sigma_normal, tg[st.metric][1])
        return float(run(stage_targets, jnp.asarray(which, jnp.int32), *(jnp.asarray(v, DTYPE) for v in sigmas)))

    values = []
    for i, (m, st) in enumerate(firsts.items()):
        alone = Settings.from_config(cfg, m, int(arrays.edges.shape[0]), 0)
        single = data(alone, 0, (tg[m][0],), st)
        shared = data(both, i, tuple(tg[n][0] for n in names), st)
        assert shared == pytest.approx(single, rel=1e-5)  # float32 training: only the fusion differs
        values.append(single)
    for a, b in itertools.combinations(values, 2):  # three different terms were picked
        assert abs(a - b) > 1e-3 * abs(a)


def test_step_runs_the_multiplier_rule_of_optim_mdmm(problem):
    cfg, arrays, st, target, yy, s, params = _first_stage(problem)
    lam = jnp.asarray([[0.3, 0.0], [0.1, 0.2]], DTYPE)
    mult = Multipliers(lam, jnp.asarray([[1e-3, 0.0], [2e-4, 0.0]], DTYPE))
    cw = jnp.asarray([1.0, 0.0], DTYPE)  # trajectory constraints off in this phase: they must not move
    opt = build_optimizer(cfg)
    step = make_step(arrays, s, opt, cfg.constraints)
    new, _, state, new_mult, aux = step(
        params,
        rest_pose(arrays.skeleton, DTYPE),
        opt.init(eqx.filter(params, eqx.is_inexact_array)),
        mult,
        (target,),
        jnp.asarray(0, jnp.int32),
        jnp.asarray(st.sigma, DTYPE),
        jnp.asarray(0.5, DTYPE),
        jnp.asarray(yy, DTYPE),
        cw,
        jnp.asarray(1.0, DTYPE),
        jnp.asarray(1e-3, DTYPE),
        jnp.asarray(0.5, DTYPE),
        jax.random.key(3),
    )
    g = jnp.stack([aux["g_ep"], aux["g_tr"]])
    c = cfg.constraints
    expected = update_multipliers(
        mult,
        g,
        s.aim,
        multiplier_rate(c.multiplier_lr, 0.5),
        jnp.asarray([[1.0], [0.0]], DTYPE),
        decay=c.multiplier_average,
    )
    for got, want, before in zip(new_mult, expected, mult, strict=True):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
        np.testing.assert_array_equal(np.asarray(got[1]), np.asarray(before[1]))
    assert float(state.hyperparams["learning_rate"]) == pytest.approx(1e-3)  # the injected rate


def test_optimizer_scales_the_pose_through_multi_transform(problem):
    """Same gradients, pose scale 1 vs 4: pose leaves move 4× as far, network leaves identically, the
    frozen width and cores not at all."""
    cfg, prob, _, _ = problem
    params = eqx.filter(init_params(jax.random.key(0), cfg, prob.skeleton_normalized), eqx.is_inexact_array)
    rng = np.random.default_rng(0)
    grads = jax.tree_util.tree_map(lambda a: jnp.asarray(rng.normal(size=a.shape), a.dtype), params)
    moved = {}
    for scale in (1.0, 4.0):
        c = dataclasses.replace(cfg, flow=dataclasses.replace(cfg.flow, pose_lr_scale=scale))
        opt = build_optimizer(c)
        state = opt.init(params)
        state = state._replace(hyperparams={**state.hyperparams, "learning_rate": jnp.asarray(1e-2, DTYPE)})
        moved[scale], _ = jax.jit(opt.update)(grads, state, params)
    flat_labels = jax.tree_util.tree_leaves(parameter_labels(params))
    assert flat_labels.count("pose") == 2 and "net" in flat_labels  # rotations + translation
    assert flat_labels.count("frozen") == 2  # the bone weights' width τ and the rigid cores: arrays, never trained
    for lab, a, b in zip(flat_labels, jax.tree_util.tree_leaves(moved[1.0]), jax.tree_util.tree_leaves(moved[4.0])):
        a, b = np.asarray(a), np.asarray(b)
        if lab == "frozen":
            assert np.all(a == 0) and np.all(b == 0)  # even under a random gradient
            continue
        assert np.abs(a).max() > 0
        if lab == "pose":
            np.testing.assert_allclose(b, 4.0 * a, rtol=1e-6)
        else:
            np.testing.assert_array_equal(a, b)


def test_a_pose_rate_of_zero_holds_the_pose_and_nothing_else(problem):
    """The same step from the same state with pose rate 1 and 0: with 0 the skeleton-driven field's pose
    is exactly where it was, with 1 it moved; every network leaf moves identically in both."""
    cfg, arrays, st, target, yy, s, params = _first_stage(problem)
    opt = build_optimizer(cfg)
    step = make_step(arrays, s, opt, cfg.constraints)
    mult = Multipliers(jnp.zeros((2, arrays.skeleton.n_bones), DTYPE), jnp.zeros((2, arrays.skeleton.n_bones), DTYPE))
    state = opt.init(eqx.filter(params, eqx.is_inexact_array))
    stage = ((target,), jnp.asarray(0, jnp.int32), jnp.asarray(st.sigma, DTYPE), jnp.asarray(0.5, DTYPE))
    rest = (jnp.asarray(yy, DTYPE), jnp.asarray([1.0, 1.0], DTYPE))
    after = {}
    for rate in (0.0, 1.0):
        after[rate] = step(
            params,
            rest_pose(arrays.skeleton, DTYPE),
            state,
            mult,
            *stage,
            *rest,
            jnp.asarray(rate, DTYPE),
            jnp.asarray(1e-2, DTYPE),
            jnp.asarray(0.5, DTYPE),
            jax.random.key(3),
        )[0]
    before_pose = jax.tree_util.tree_leaves(params.flow.pose)
    for a, b in zip(jax.tree_util.tree_leaves(after[0.0].flow.pose), before_pose, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    moved = [
        np.abs(np.asarray(a) - np.asarray(b)).max()
        for a, b in zip(jax.tree_util.tree_leaves(after[1.0].flow.pose), before_pose, strict=True)
    ]
    assert max(moved) > 1e-4
    for a, b in zip(
        jax.tree_util.tree_leaves(after[0.0].flow.residual),
        jax.tree_util.tree_leaves(after[1.0].flow.residual),
        strict=True,
    ):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_the_pose_is_held_in_the_first_phase_only_where_the_limbs_touch():
    cfg = preset("fast")
    assert len(cfg.phases) == 2
    assert held_phases(cfg, "surface") == (0,)
    assert held_phases(cfg, "current") == () and held_phases(cfg, "start") == ()
    assert held_phases(apply_overrides(cfg, ["flow.hold_contact_pose=false"]), "surface") == ()
    one = dataclasses.replace(cfg, phases=cfg.phases[1:])  # a warm frame of a track: one phase, never held
    assert held_phases(one, "surface") == ()


class _Linear(eqx.Module):
    """A stand-in Flow-Net R(x, t) = (1 + t) x Aᵀ + c."""

    a: jax.Array
    c: jax.Array

    def __call__(self, x, t):
        return (1.0 + t) * (x @ self.a.T) + self.c


def test_the_leash_is_the_ungated_flow_net_at_the_bone_samples(problem):
    """L_leash = mean over grid times and the first LEASH_SAMPLES samples of each bone of ‖R(x, t_k)‖² / ε,
    R the Flow-Net before the rigid cores fade it: brute force at the samples the objective draws (they sit in
    their bones' cores, where the faded Flow-Net is 0, so at the rest pose they do not move); its weight adds
    exactly w · L_leash to the loss."""
    from ncflow.flow import time_grid
    from ncflow.skeleton import sample_bones

    cfg, arrays, st, target, yy, s, params = _first_stage(problem)
    assert cfg.flow.rigid_core > 0
    rng = np.random.default_rng(0)
    net = _Linear(jnp.asarray(0.01 * rng.normal(size=(3, 3)), DTYPE), jnp.asarray([0.002, -0.001, 0.003], DTYPE))
    p = eqx.tree_at(lambda q: q.flow.residual, params, net)
    key, lam = jax.random.key(3), jnp.zeros((2, 2), DTYPE)
    on = dataclasses.replace(s, leash_weight=0.5)
    total_on, aux_on = eqx.filter_jit(lambda q: stage_objective(q, arrays, on, st, target, yy, lam, key))(p)
    total_off, aux_off = eqx.filter_jit(lambda q: stage_objective(q, arrays, s, st, target, yy, lam, key))(p)

    kb = jax.random.split(key, 3)[0]
    bones = np.asarray(
        sample_bones(
            arrays.skeleton, kb, s.n_bone_samples, radius=arrays.radii, axial_range=arrays.ranges, dtype=DTYPE
        ).points
    )[:, :LEASH_SAMPLES].reshape(-1, 3)
    a, c = np.asarray(net.a, np.float64), np.asarray(net.c, np.float64)
    times = np.asarray(time_grid(s.n_times), np.float64)
    expected = np.mean([np.sum(((1 + t) * bones @ a.T + c) ** 2, axis=1) for t in times]) / s.eps
    assert float(aux_on["leash"]) == pytest.approx(expected, rel=1e-4)
    assert float(aux_off["leash"]) == 0.0  # weight 0: not computed
    assert float(total_on) - float(total_off) == pytest.approx(0.5 * expected, rel=1e-3)
    assert float(aux_on["data"]) == float(aux_off["data"])


def test_the_leash_setting():
    assert _config().flow.leash == 0.0  # off by default
    assert Settings.from_config(_config(**{"flow.leash": 0.3}), "varifold", 10, 0).leash_weight == 0.3
    # without the skeleton-driven field there is no Flow-Net to hold near the bones
    assert (
        Settings.from_config(_config(**{"flow.leash": 0.3, "flow.skinning": "false"}), "varifold", 10, 0).leash_weight
        == 0.0
    )
    from ncflow.errors import InputError

    with pytest.raises(InputError, match="leash"):
        _config(**{"flow.leash": -1})


def test_the_tissue_anchor_setting_follows_the_weight_mode():
    from ncflow.errors import InputError
    from ncflow.matcher.objective import tissue_anchored

    auto = _config(**{"flow.tissue_anchor": "auto"})
    assert [tissue_anchored(auto, m) for m in ("surface", "start", "current")] == [True, False, False]
    assert tissue_anchored(_config(**{"flow.tissue_anchor": "on"}), "current")
    assert not tissue_anchored(_config(**{"flow.tissue_anchor": "off"}), "surface")
    assert not tissue_anchored(_config(**{"flow.tissue_anchor": "on", "flow.skinning": "false"}), "surface")
    assert Settings.from_config(auto, "varifold", 10, 0, "surface").tissue_anchor
    assert not Settings.from_config(auto, "varifold", 10, 0).tissue_anchor
    with pytest.raises(InputError, match="tissue_anchor"):
        _config(**{"flow.tissue_anchor": "sometimes"})


def test_auto_stages_take_the_four_point_varifold_where_sigma_is_below_the_source_edge():
    """The fast preset's second phase (``metric = "auto"``): Normal Cycles at every σ on a fine source (a
    body's 0.12 median edge: the schedule of DESIGN.md, stage for stage), the four-point Varifold at the σ
    that MANO's 0.155 edge exceeds by more than 1.4×, at both on a coarser one; an explicit metric is kept."""
    from ncflow.matcher.stages import COARSE_EDGE, last_phase_stages

    cfg = preset("fast")

    def metrics(edge):
        return [(st.metric, st.sigma) for st in build_stages(cfg, edge)]

    assert metrics(0.12) == [("varifold", 0.25), ("normal-cycles", 0.25), ("normal-cycles", 0.1)]
    assert metrics(0.155) == [("varifold", 0.25), ("normal-cycles", 0.25), ("varifold-q4", 0.1)]
    assert metrics(0.4) == [("varifold", 0.25), ("varifold-q4", 0.25), ("varifold-q4", 0.1)]
    assert metrics(COARSE_EDGE * 0.1)[-1] == ("normal-cycles", 0.1)  # at the bound: still Normal Cycles
    assert [st.metric for st in last_phase_stages(cfg, 50, 3e-3, 0.155)] == ["normal-cycles", "varifold-q4"]
    fixed = dataclasses.replace(cfg, phases=(dataclasses.replace(cfg.phases[1], metric="normal-cycles"),))
    assert [st.metric for st in build_stages(fixed, 0.4)] == ["normal-cycles", "normal-cycles"]
    quad = dataclasses.replace(cfg, phases=(dataclasses.replace(cfg.phases[0], quadrature=4),))
    assert [st.metric for st in build_stages(quad)] == ["varifold-q4"]
    with pytest.raises(ValueError, match="median edge"):
        build_stages(cfg)
