"""Optimisers, schedules and MDMM (DESIGN.md "Optimiser", "Constraints (MDMM)"; reference-notes §9–10)."""

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from ncflow.optim import (
    adabelief_cautious,
    ascend_multipliers,
    init_multipliers,
    mdmm_term,
    multiplier_ceiling,
    multiplier_rate,
    soft_constraint_term,
    update_multipliers,
    vectoradam_cautious,
    violation,
    warmup_constant,
    warmup_cosine,
)

RNG = np.random.default_rng(0)
SHAPES = {"w": (4, 3), "b": (5,), "alpha": (), "m": (2, 6)}
TARGET = {k: RNG.normal(size=s) for k, s in SHAPES.items()}
CURV = {k: RNG.uniform(0.5, 3.0, size=s) for k, s in SHAPES.items()}
NOISE = [{k: 2.0 * RNG.normal(size=s) for k, s in SHAPES.items()} for _ in range(6)]


def _grad_np(theta, step):
    """Gradient of Σ ½ d (θ − θ*)² plus a per-step perturbation (sign flips exercise the mask)."""
    return {k: CURV[k] * (theta[k] - TARGET[k]) + NOISE[step][k] for k in theta}


def _np_reference(theta, n_steps, lr, wd, clip, moment):
    """NumPy transcription of the update chain (reference-notes §10.1); ``moment`` is 'belief' or
    'vector'. Returns the parameter trajectory, the kept fractions seen by the mask and whether
    each step was clipped."""
    b1, b2 = 0.9, 0.999
    eps = 1e-16 if moment == "belief" else 1e-8
    theta = {k: np.array(v, dtype=float) for k, v in theta.items()}
    m = {k: np.zeros_like(v) for k, v in theta.items()}
    s = {
        k: (np.zeros(v.shape[:-1] + (1,)) if moment == "vector" and v.ndim and v.shape[-1] == 3 else np.zeros_like(v))
        for k, v in theta.items()
    }
    traj, fracs, clipped = [], [], []
    for t in range(1, n_steps + 1):
        g = _grad_np(theta, t - 1)
        norm = np.sqrt(sum(np.sum(v**2) for v in g.values()))
        clipped.append(norm >= clip)
        if norm >= clip:
            g = {k: v * clip / norm for k, v in g.items()}
        new = {}
        for k in theta:
            pooled = moment == "vector" and theta[k].ndim and theta[k].shape[-1] == 3
            m[k] = b1 * m[k] + (1 - b1) * g[k]
            if moment == "belief":
                s[k] = b2 * s[k] + (1 - b2) * (g[k] - m[k]) ** 2 + eps
            elif pooled:
                s[k] = b2 * s[k] + (1 - b2) * np.sum(g[k] ** 2, axis=-1, keepdims=True)
            else:
                s[k] = b2 * s[k] + (1 - b2) * g[k] ** 2
            u = (m[k] / (1 - b1**t)) / (np.sqrt(s[k] / (1 - b2**t)) + eps)
            agree = np.sum(u * g[k], axis=-1, keepdims=True) if pooled else u * g[k]
            keep = (agree > 0).astype(float)
            frac = keep.mean()
            fracs.append(frac)
            u = u * keep / max(frac, 1e-3)
            u = u + wd * theta[k]
            new[k] = theta[k] - lr(t - 1) * u
        theta = new
        traj.append(theta)
    return traj, np.array(fracs), np.array(clipped)


def _run_optax(opt, theta, n_steps):
    params = {k: jnp.asarray(v) for k, v in theta.items()}
    state = opt.init(params)
    noise = {k: jnp.asarray(np.stack([n[k] for n in NOISE])) for k in SHAPES}
    curv = {k: jnp.asarray(v) for k, v in CURV.items()}
    target = {k: jnp.asarray(v) for k, v in TARGET.items()}

    @jax.jit
    def run(params, state):
        def body(carry, step):
            p, st = carry
            g = {k: curv[k] * (p[k] - target[k]) + noise[k][step] for k in p}
            u, st = opt.update(g, st, p)
            p = optax.apply_updates(p, u)
            return (p, st), p

        return jax.lax.scan(body, (params, state), jnp.arange(n_steps))[1]

    return run(params, state)


@pytest.mark.parametrize("moment", ["belief", "vector"])
def test_optimiser_matches_numpy_reference(moment):
    rng = np.random.default_rng(11)
    theta0 = {k: rng.normal(size=s) for k, s in SHAPES.items()}
    sched = warmup_cosine(0.1, 0.01, 2, 6)
    lr = lambda s: float(sched(s))  # noqa: E731
    wd, clip = 0.05, 18.0  # clip active in some steps only (gradient norms ≈ 16–20)
    make = adabelief_cautious if moment == "belief" else vectoradam_cautious
    opt = make(sched, weight_decay=wd, clip_norm=clip)
    traj = _run_optax(opt, theta0, 6)
    ref, fracs, clipped = _np_reference(theta0, 6, lr, wd, clip, moment)
    assert clipped.any() and not clipped.all()
    for step in range(6):
        for k in SHAPES:
            np.testing.assert_allclose(np.asarray(traj[k][step]), ref[step][k], rtol=1e-12, atol=1e-14)
    # the mask both dropped components and kept some in the steps compared
    assert np.any((fracs > 0) & (fracs < 1)) and np.any(fracs == 0)
    # the first step has lr(0) = 0 under the warm-up: nothing moves
    for k in SHAPES:
        np.testing.assert_array_equal(np.asarray(traj[k][0]), theta0[k])


def test_adabelief_first_step_is_sign_like_and_default_clip():
    # Defaults (clip 0.5, eps = eps_root = 1e-16, wd 1e-4), first step: with c the clipped gradient,
    # m̂ = c and ŝ = ((0.9 c)²·0.001 + 1e-16)/0.001, so u = c/(√(0.81 c² + 1e-13) + 1e-16) ≈ 1.111·sign(g)
    # (reference-notes §10.1); every component agrees in sign with g, so the mask keeps all.
    g = np.array([10.0, -0.001, 0.2, -4.0])
    theta = np.array([1.0, -2.0, 0.5, 3.0])
    opt = adabelief_cautious(1.0)
    params = {"a": jnp.asarray(theta)}
    u, _ = opt.update({"a": jnp.asarray(g)}, opt.init(params), params)
    c = g * 0.5 / np.linalg.norm(g)
    expected = -(c / (np.sqrt(0.81 * c**2 + 1e-13) + 1e-16) + 1e-4 * theta)
    np.testing.assert_allclose(np.asarray(u["a"]), expected, rtol=1e-12)
    np.testing.assert_allclose(np.abs(expected[[0, 2, 3]]), 1 / 0.9, rtol=1e-3)


def test_float32_params_stay_float32():
    params = {"w": jnp.ones((3, 3), jnp.float32), "s": jnp.asarray(0.1, jnp.float32)}
    grads = jax.tree.map(lambda p: 0.5 * p, params)
    for opt in (adabelief_cautious(warmup_cosine(1e-3, 1e-4, 5, 10)), vectoradam_cautious(1e-3)):
        state = opt.init(params)
        u, state = jax.jit(opt.update)(grads, state, params)
        assert all(x.dtype == jnp.float32 for x in jax.tree.leaves(u))
        assert all(x.dtype in (jnp.float32, jnp.int32) for x in jax.tree.leaves(state))


def _rotation(seed):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def test_vectoradam_rotation_equivariant_adabelief_not():
    rng = np.random.default_rng(1)
    rot = _rotation(2)
    params = {"v": rng.normal(size=(6, 3)), "b": rng.normal(size=(3,)), "w": rng.normal(size=(4, 5))}
    grads = [{k: rng.normal(size=v.shape) for k, v in params.items()} for _ in range(5)]

    def rotated(tree):
        return {k: (v @ rot.T if k in ("v", "b") else v) for k, v in tree.items()}

    def updates(opt, p, gs):
        p = {k: jnp.asarray(v) for k, v in p.items()}
        state, out, update = opt.init(p), [], jax.jit(opt.update)
        for g in gs:
            u, state = update({k: jnp.asarray(v) for k, v in g.items()}, state, p)
            p = optax.apply_updates(p, u)
            out.append({k: np.asarray(v) for k, v in u.items()})
        return out

    opt = vectoradam_cautious(0.01, weight_decay=1e-2)
    plain = updates(opt, params, grads)
    turned = updates(opt, rotated(params), [rotated(g) for g in grads])
    for u, ur in zip(plain, turned):
        np.testing.assert_allclose(ur["v"], u["v"] @ rot.T, rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(ur["b"], u["b"] @ rot.T, rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(ur["w"], u["w"], rtol=1e-10, atol=1e-14)
    # the row-pooled second moment differs from per-component Adam
    assert np.max(np.abs(plain[0]["v"])) > 0 and not np.allclose(
        np.abs(plain[-1]["v"]), np.abs(updates(optax.adam(0.01), params, grads)[-1]["v"])
    )
    # per-component AdaBelief is not equivariant
    ab = adabelief_cautious(0.01)
    a_plain = updates(ab, params, grads)[-1]["v"]
    a_turned = updates(ab, rotated(params), [rotated(g) for g in grads])[-1]["v"]
    assert np.max(np.abs(a_turned - a_plain @ rot.T)) > 1e-3


@pytest.mark.parametrize("make", [adabelief_cautious, vectoradam_cautious])
def test_optimisers_minimise_quadratic(make):
    rng = np.random.default_rng(12)
    target = {"v": jnp.asarray(rng.normal(size=(8, 3))), "w": jnp.asarray(rng.normal(size=(3, 4)))}
    curv = {"v": jnp.asarray(rng.uniform(0.2, 5.0, (8, 3))), "w": jnp.asarray(rng.uniform(0.2, 5.0, (3, 4)))}

    def loss(p):
        return sum(0.5 * jnp.sum(curv[k] * (p[k] - target[k]) ** 2) for k in p)

    opt = make(warmup_cosine(0.05, 1e-4, 10, 400), weight_decay=0.0)
    p0 = {k: jnp.zeros_like(v) for k, v in target.items()}

    @jax.jit
    def run(p):
        def body(c, _):
            p, st = c
            u, st = opt.update(jax.grad(loss)(p), st, p)
            return (optax.apply_updates(p, u), st), None

        return jax.lax.scan(body, (p, opt.init(p)), None, length=400)[0][0]

    p = run(p0)
    assert float(loss(p)) < 1e-4 * float(loss(p0))


# ---------------------------------------------------------------------------------------------
# Schedules


def test_warmup_cosine_values():
    s = warmup_cosine(3e-3, 1e-4, 100, 2000)
    expected = {0: 0.0, 1: 3e-5, 50: 1.5e-3, 100: 3e-3, 575: 2.5753048e-3, 1050: 1.55e-3, 2000: 1e-4, 2600: 1e-4}
    for step, val in expected.items():
        assert float(s(step)) == pytest.approx(val, rel=1e-6, abs=1e-12), step
    assert float(s(jnp.asarray(50, jnp.int32))) == pytest.approx(1.5e-3)  # traced int counts work
    with pytest.raises(ValueError):
        warmup_cosine(1.0, 0.0, 10, 10)


def test_warmup_constant_values():
    s = warmup_constant(3e-3, 100)
    for step, val in {0: 0.0, 25: 7.5e-4, 99: 2.97e-3, 100: 3e-3, 5000: 3e-3}.items():
        assert float(s(step)) == pytest.approx(val, rel=1e-9, abs=1e-15)
    assert float(warmup_constant(2.0, 0)(0)) == 2.0


def test_each_phase_restarts_its_own_schedule():
    """The training calls each phase's schedule with the phase's own step (matcher.stages.phase_schedule):
    the paper preset's three phases, each warmed up from 0 again."""
    from ncflow.config import preset
    from ncflow.matcher.stages import phase_schedule

    phases = [phase_schedule(p) for p in preset("paper").phases]
    expected = {
        (0, 0): 0.0,
        (0, 50): 1.5e-3,
        (0, 1999): 3e-3,
        (1, 0): 0.0,
        (1, 50): 1.5e-3,
        (1, 100): 3e-3,
        (1, 1050): 1.55e-3,
        (1, 1999): 1.0000198e-4,
        (2, 0): 0.0,
        (2, 50): 5e-5,
        (2, 999): 1e-4,
        (2, 2000): 1e-4,  # continues after the end
    }
    for (phase, step), val in expected.items():
        assert phases[phase](step) == pytest.approx(val, rel=1e-6, abs=1e-12), (phase, step)
    # inside an optimiser: the first update of a warming-up phase is exactly zero
    opt = adabelief_cautious(warmup_constant(1.0, 1))
    p = {"a": jnp.ones(3)}
    st = opt.init(p)
    norms = []
    for _ in range(2):
        u, st = opt.update({"a": jnp.asarray([1.0, -1.0, 2.0])}, st, p)
        norms.append(float(jnp.abs(u["a"]).max()))
    assert norms[0] == 0.0 and norms[1] > 0


# ---------------------------------------------------------------------------------------------
# MDMM


def test_mdmm_term_values_and_gradients():
    g = jnp.asarray([0.5, 0.1, 2.0])
    lam = jnp.asarray([1.0, 2.0, 3.0])
    np.testing.assert_allclose(np.asarray(violation(g, 0.2)), [0.3, 0.0, 1.8], atol=1e-15)
    # Σ λΓ + δ/2 Σ Γ² with δ = 2: (0.3 + 0 + 5.4) + (0.09 + 0 + 3.24) = 9.03
    assert float(mdmm_term(g, lam, 0.2, damping=2.0)) == pytest.approx(9.03, rel=1e-12)
    assert float(mdmm_term(g, lam, 0.2, damping=2.0, reduction="mean")) == pytest.approx(3.01, rel=1e-12)
    d_lam = jax.grad(lambda l: mdmm_term(g, l, 0.2, 2.0))(lam)
    np.testing.assert_allclose(np.asarray(d_lam), [0.3, 0.0, 1.8], atol=1e-15)
    d_g = jax.grad(lambda gg: mdmm_term(gg, lam, 0.2, 2.0))(g)  # λ + δΓ where violated
    np.testing.assert_allclose(np.asarray(d_g), [1.6, 0.0, 6.6], atol=1e-14)
    assert float(soft_constraint_term(g, jnp.asarray([1.0, 10.0, 0.5]))) == pytest.approx(2.5, rel=1e-12)
    assert float(soft_constraint_term(g, 2.0, reduction="mean")) == pytest.approx(1.733333333333, rel=1e-10)


# Toy problem: minimise ‖x − a‖², a = (2, 1), s.t. g₀ = x₀² ≤ ε = 0.25 (active; KKT point
# x = (0.5, 1), λ* = 3) and g₁ = 0.01 x₁² ≤ ε (inactive at the solution).
A = jnp.asarray([2.0, 1.0])
EPS = 0.25


def _f(x):
    return jnp.sum((x - A) ** 2)


def _g(x):
    return jnp.stack([x[0] ** 2, 0.01 * x[1] ** 2])


def test_sign_ascent_rule_values_projection_and_mask():
    lam = jnp.asarray([[0.0, 0.3, 1.0], [0.05, 2.0, 0.0]])
    g = jnp.asarray([[0.5, 0.1, 0.2], [0.0, 0.9, 0.3]])
    # λ + η·a·sign(g − 0.2), projected on λ ≥ 0; row 1 inactive (a = 0) stays where it is
    out = ascend_multipliers(lam, g, 0.2, 0.1, jnp.asarray([[1.0], [0.0]]))
    np.testing.assert_allclose(np.asarray(out), [[0.1, 0.2, 1.0], [0.05, 2.0, 0.0]], atol=1e-15)
    # a satisfied constraint releases its multiplier down to 0, never below
    np.testing.assert_allclose(np.asarray(ascend_multipliers(jnp.asarray([0.05]), jnp.asarray([0.0]), 0.2, 0.1)), [0.0])
    # the step does not depend on the size of the violation (unlike the proportional rule λ + ηΓ)
    big = ascend_multipliers(jnp.zeros(2), jnp.asarray([0.21, 1e6]), 0.2, 0.1)
    np.testing.assert_allclose(np.asarray(big), [0.1, 0.1], atol=1e-15)
    # the ramp: 0 at the start, 2η at the end, mean η over the run
    progress = np.linspace(0.0, 1.0, 1001)
    rates = np.asarray(multiplier_rate(0.3, jnp.asarray(progress)))
    assert rates[0] == 0.0 and rates[-1] == pytest.approx(0.6, rel=1e-12)
    assert rates.mean() == pytest.approx(0.3, rel=1e-12)


def test_mdmm_sign_ascent_reaches_kkt_point_soft_penalty_violates():
    rate = 0.005

    @jax.jit
    def run(x, lam):
        def body(c, _):
            x, lam = c
            x = x - 0.01 * jax.grad(lambda y: _f(y) + mdmm_term(_g(y), lam, EPS, damping=0.0))(x)
            lam = ascend_multipliers(lam, _g(x), EPS, rate)
            return (x, lam), lam

        return jax.lax.scan(body, (x, lam), None, length=4000)

    (x, lam), lams = run(jnp.zeros(2), jnp.zeros(2))
    g = np.asarray(_g(x))
    assert abs(g[0] - EPS) <= 1e-3 and g[1] <= EPS  # the active constraint is held at ε
    np.testing.assert_allclose(np.asarray(x), [0.5, 1.0], atol=1e-3)  # the KKT point
    # Γ = max(g − ε, 0) acts only while g > ε, so x chatters on the boundary and λ settles (within
    # one step η) at a value above the KKT multiplier 3 whose duty cycle gives the force of λ* = 3
    tail = np.asarray(lams[-500:, 0])
    assert tail.std() <= 2 * rate and tail.mean() > 3.0
    assert float(lam[1]) == 0.0 and float(jnp.min(lams)) >= 0.0  # the inactive one never moves

    @jax.jit
    def run_soft(x):
        def body(x, _):
            return x - 0.02 * jax.grad(lambda y: _f(y) + soft_constraint_term(_g(y), 0.1))(x), None

        return jax.lax.scan(body, x, None, length=3000)[0]

    xs = run_soft(jnp.zeros(2))
    assert float(xs[0]) == pytest.approx(2.0 / 1.1, rel=1e-6)  # minimiser of (x₀−2)² + 0.1 x₀²
    assert float(_g(xs)[0]) > 10 * EPS  # violated by a factor > 10


def _multiplier_rule_np(lam, g_mean, g, target, rate, active, decay):
    """The rule of update_multipliers, one constraint at a time, in plain Python floats."""
    out = []
    for lk, mk, gk, ak in zip(*(map(float, a) for a in (lam, g_mean, g, active)), strict=True):
        if ak == 0:
            out.append((lk, mk))
            continue
        mk = decay * mk + (1 - decay) * gk
        sign = float(mk > target) - float(mk < target)
        out.append((max(0.0, lk + rate * ak * sign), mk))
    return [np.array(c) for c in zip(*out, strict=True)]


@pytest.mark.parametrize("decay", [0.9, 0.5, 0.0])
def test_multiplier_rule_matches_a_plain_python_loop(decay):
    rng = np.random.default_rng(5)
    n = 6
    active = np.array([1.0, 1.0, 1.0, 1.0, 0.0, 1.0])
    state = init_multipliers(jnp.zeros(n, jnp.float64))
    lam, g_mean = np.zeros(n), np.zeros(n)
    longest, run = 0, np.zeros(n)
    for d in range(60):
        g = rng.exponential(size=n) * np.array([0.1, 0.5, 1.0, 2.0, 3.0, 0.9])
        rate = 0.05 * d / 60
        state = update_multipliers(state, jnp.asarray(g), 0.8, rate, jnp.asarray(active), decay=decay)
        lam, g_mean = _multiplier_rule_np(lam, g_mean, g, 0.8, rate, active, decay)
        for got, want in zip(state, (lam, g_mean), strict=True):
            np.testing.assert_allclose(np.asarray(got), want, rtol=1e-12, atol=1e-15)
        run = np.where(g_mean > 0.8, run + 1, 0)
        longest = max(longest, run.max())
    assert np.all(np.asarray(state.lam)[4] == 0.0) and np.asarray(state.g_mean)[4] == 0.0  # inactive: frozen
    assert longest > 5 and np.asarray(state.lam).max() > 0.5  # long streaks and real ascents were exercised


def test_an_always_violated_multiplier_ends_at_the_ceiling():
    """Violated at every step, the ramped sign ascent ends at multiplier_ceiling (its brute-force sum), with
    or without the running mean (g ≫ target: the mean is above it from the first step)."""
    n, lr = 400, 1.0
    plain = jnp.zeros(1, jnp.float64)
    state = init_multipliers(jnp.zeros(1, jnp.float64))
    for d in range(n):
        plain = ascend_multipliers(plain, jnp.ones(1, jnp.float64), 0.0, multiplier_rate(lr, d / n))
        state = update_multipliers(state, jnp.ones(1, jnp.float64), 1e-3, multiplier_rate(lr, d / n))
    assert multiplier_ceiling(lr, n) == pytest.approx(sum(2.0 * lr * d / n for d in range(n)), rel=1e-12)
    assert float(plain[0]) == pytest.approx(multiplier_ceiling(lr, n), rel=1e-5)
    assert float(state.lam[0]) == pytest.approx(multiplier_ceiling(lr, n), rel=1e-5)
    assert float(state.g_mean[0]) > 1e-3  # above the target at the end: still violated


def _noisy_constraint_run(decay: float, n_steps: int = 20000, seed: int = 0):
    """Minimise −x subject to E[g] ≤ ε with g estimated each step as x·Z, Z ~ Exp(1) (mean 1, median
    ln 2: skewed, as a few-sample estimate of a mean squared distance): MDMM descent on x with the
    multiplier rule at a fixed rate; returns the mean of x over the last half (E[g] = x·1)."""
    rng = np.random.default_rng(seed)
    z = jnp.asarray(rng.exponential(size=n_steps))

    def body(c, zk):
        x, st = c
        g = x * zk
        grad = -1.0 + (st.lam + violation(g, EPS)) * zk * (g > EPS)
        x = x - 1e-4 * grad
        st = update_multipliers(st, g, EPS, 0.05, decay=decay)
        return (x, st), x[0]

    init = (jnp.zeros(1, jnp.float64), init_multipliers(jnp.zeros(1, jnp.float64)))
    _, xs = jax.jit(lambda c: jax.lax.scan(body, c, z))(init)
    return float(np.mean(np.asarray(xs)[n_steps // 2 :]))


def test_the_running_mean_holds_the_mean_of_a_noisy_constraint_the_raw_sign_its_median():
    """Read on each step's noisy estimate (decay 0) the sign ascent settles where the estimate's median is
    ε: E[g] = ε / ln 2 ≈ 1.44 ε. Read on the running mean (decay 0.9) it settles near E[g] = ε."""
    raw = _noisy_constraint_run(0.0) / EPS
    averaged = _noisy_constraint_run(0.9) / EPS
    assert raw == pytest.approx(1.0 / np.log(2.0), rel=0.1)
    assert averaged == pytest.approx(1.0, rel=0.1)
