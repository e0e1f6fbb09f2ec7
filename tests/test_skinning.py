"""Skeleton-driven flow field (ncflow.flow.skinning): blended rigid bone velocities + a Flow-Net."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ncflow.config import apply_overrides, preset
from ncflow.errors import InputError
from ncflow.flow import (
    SkinnedField,
    bone_velocities,
    flow_points,
    integrate,
    make_flow_field,
    skinning_weights,
    time_grid,
)
from ncflow.flow.bone_weights import core_gate, skin_contact, surface_skinning_weights
from ncflow.skeleton import Skeleton, rigid_reference, sample_bones
from ncflow.skeleton.dualquat import quat_from_rotvec
from ncflow.skeleton.kinematics import Pose, bone_motions, move_bone_points, rest_pose

# a bent chain with a side branch: 4 bones of length 1 (and 0.8)
POSITIONS = np.array([[0, 0, 0], [0, 0, 1.0], [0, 0, 2.0], [0, 0.8, 2.0], [1.0, 0, 1.0]])
PARENTS = np.array([-1, 0, 1, 2, 1])


def _skeleton():
    return Skeleton.from_arrays(POSITIONS, PARENTS)


def _pose(skel):
    rot = jnp.stack(
        [
            quat_from_rotvec(jnp.asarray(v, jnp.float64))
            for v in [[0.3, 0, 0], [0, 1.2, 0], [0.0, 0, 0.9], [0, 0, 0], [0, 0, 0]]
        ]
    )
    return Pose(rot, jnp.asarray([0.1, 0.2, -0.1]))


def _residual(alpha=0.0):
    return make_flow_field(jax.random.key(0), width=8, depth=1, alpha=alpha, dtype=jnp.float64)


def test_weights_partition_unity_and_pick_the_nearest_bone():
    skel = _skeleton()
    heads = jnp.asarray(POSITIONS[skel.bones[:, 0]])
    tails = jnp.asarray(POSITIONS[skel.bones[:, 1]])
    x = jnp.asarray(np.random.default_rng(0).normal(size=(50, 3)))
    w = skinning_weights(x, heads, tails, 0.05)
    np.testing.assert_allclose(np.sum(w, 1), 1.0, rtol=1e-12)
    # brute force: softmax of -distance/width, distance to the segment by dense sampling
    s = np.linspace(0, 1, 20001)
    pts = heads[:, None, :] + s[None, :, None] * (tails - heads)[:, None, :]  # (B, S, 3)
    d = np.min(np.linalg.norm(np.asarray(x)[:, None, None, :] - np.asarray(pts)[None], axis=-1), axis=-1)
    ref = np.exp(-(d - d.min(1, keepdims=True)) / 0.05)
    np.testing.assert_allclose(np.asarray(w), ref / ref.sum(1, keepdims=True), atol=2e-3)
    # the middle of each bone's axis belongs to that bone: its neighbours are >= 0.4 away, weight <= e^-8
    mid = 0.5 * (heads + tails)
    np.testing.assert_allclose(np.asarray(skinning_weights(mid, heads, tails, 0.05)), np.eye(skel.n_bones), atol=4e-4)


def test_bone_velocities_are_the_time_derivative_of_the_bone_motions():
    skel, pose = _skeleton(), _pose(_skeleton())
    t = 0.37
    # compiled: one program, not one per operation
    r, c, dr, dc = jax.jit(lambda pose, t: bone_velocities(skel, pose, t))(pose, t)
    p = jnp.asarray(np.random.default_rng(1).normal(size=(skel.n_bones, 3, 3)))  # 3 rest points per bone

    def at(s):
        return move_bone_points(bone_motions(skel, pose, s), p)

    x, dx = jax.jit(lambda t: jax.jvp(at, (t,), (jnp.ones_like(t),)))(jnp.asarray(t))  # autodiff reference
    np.testing.assert_allclose(np.asarray(jnp.einsum("bij,bnj->bni", r, p) + c[:, None]), np.asarray(x), atol=1e-12)
    v = jnp.einsum("bij,bkj,bnk->bni", dr, r, x - c[:, None]) + dc[:, None]
    np.testing.assert_allclose(np.asarray(v), np.asarray(dx), atol=1e-5)


def test_rest_pose_gives_the_residual_field():
    skel = _skeleton()
    res = _residual(alpha=0.3)
    field = SkinnedField(res, skel, width=0.05, dtype=jnp.float64)
    x = jnp.asarray(np.random.default_rng(2).normal(size=(40, 3)))
    for t in (0.0, 0.4, 1.0):
        np.testing.assert_allclose(np.asarray(field(x, t)), np.asarray(res(x, t)), atol=1e-14)
    # and the weights are those of the rest skeleton at any time
    rest = skinning_weights(x, jnp.asarray(POSITIONS[skel.bones[:, 0]]), jnp.asarray(POSITIONS[skel.bones[:, 1]]), 0.05)
    np.testing.assert_allclose(np.asarray(field.weights(x, 0.7)), np.asarray(rest), atol=1e-12)


@pytest.mark.parametrize("interp", ["sclerp", "slerp"])
def test_points_near_a_bone_axis_move_rigidly_with_it(interp):
    skel = _skeleton()
    pose = _pose(skel)
    field = SkinnedField(_residual(), skel, pose, width=0.02, interp=interp, dtype=jnp.float64)
    # points on the 30 %-70 % section of each bone, up to 0.05 from the axis
    rng = np.random.default_rng(3)
    a, b = POSITIONS[skel.bones[:, 0]], POSITIONS[skel.bones[:, 1]]
    z = rng.uniform(0.3, 0.7, size=(skel.n_bones, 12, 1))
    pts = a[:, None] + z * (b - a)[:, None] + 0.05 * rng.uniform(-1, 1, size=(skel.n_bones, 12, 3)) / np.sqrt(3)
    errors = []
    for n_times in (3, 10, 20):
        xs = jax.jit(lambda p, n=n_times: flow_points(field, p, n))(jnp.asarray(pts.reshape(-1, 3)))
        xs = xs.reshape(n_times, *pts.shape)
        ref = jax.jit(lambda p, t: rigid_reference(skel, pose, p, t, interp))(
            jnp.asarray(pts), time_grid(n_times, jnp.float64)
        )
        errors.append(float(jnp.max(jnp.linalg.norm(xs - ref, axis=-1))))
    # the bones' motions are stepped in closed form: what is left is the neighbours' weight (≤ e^-10 of
    # theirs), on any grid (the Heun recursion on the velocities was 0.016 off at T = 10)
    assert max(errors) < 1e-3, errors


def test_points_of_one_bone_keep_its_rigid_motion_through_large_turns():
    """A chain curled by 90° at each of three joints (its last bone turns 270°), flowed on a coarse grid:
    points in a bone's core move with that bone to 1e-5 (no integrator error: the rigid core's weights are
    the bone's alone; measured 1e-14, and 3e-6 with "current" weights), in every weight mode, where the
    Heun recursion on the velocities left the last bone's samples hundreds of tolerances off at T = 10.
    """
    pos = np.array([[0, 0, 0], [0, 0, 1.0], [0, 0, 2.0], [0, 0, 3.0], [0, 0, 3.7]])
    skel = Skeleton.from_arrays(pos, np.array([-1, 0, 1, 2, 3]))
    turns = [[0, 0, 0], [np.pi / 2, 0, 0], [np.pi / 2, 0, 0], [np.pi / 2, 0, 0], [0, 0, 0]]
    pose = Pose(jnp.stack([quat_from_rotvec(jnp.asarray(v, jnp.float64)) for v in turns]), jnp.zeros(3))
    samples = sample_bones(skel, jax.random.key(0), 20, radius=0.1, dtype=jnp.float64)
    pts = jnp.asarray(samples.flat())
    for mode in ("current", "start", "surface"):
        field = SkinnedField(
            _residual(alpha=0.3), skel, pose, 0.05, dtype=jnp.float64, weight_mode=mode, core=0.1 * skel.bone_lengths
        )
        for n_times in (3, 10):
            xs = eqx.filter_jit(lambda f, p, n=n_times: flow_points(f, p, n))(field, pts)
            ref = rigid_reference(skel, field.swing_pose(), samples.points, time_grid(n_times, jnp.float64))
            err = float(jnp.max(jnp.linalg.norm(xs.reshape(ref.shape) - ref, axis=-1)))
            assert err < 1e-5, (mode, n_times, err)


def _turn(deg):
    return quat_from_rotvec(jnp.asarray([0, 0, np.radians(deg)]))


def _miss_at_the_end(skel, pose, bone, p):
    """How far each weight mode leaves point p (on ``bone``) from that bone's rigid motion at t = 1."""
    pts = np.zeros((skel.n_bones, 1, 3))
    pts[bone] = p
    ref = jax.jit(lambda p: rigid_reference(skel, pose, p, jnp.asarray([1.0])))(jnp.asarray(pts))[0, bone]
    miss = {}
    for mode in ("start", "current"):
        field = SkinnedField(_residual(alpha=0.0), skel, pose, width=0.05, dtype=jnp.float64, weight_mode=mode)
        end = jax.jit(lambda x, f=field: flow_points(f, x, 40)[-1])(jnp.asarray(p))
        miss[mode] = float(np.linalg.norm(np.asarray(end - ref)))
    return ref, miss


def test_start_weights_let_a_curling_limb_reach_another_limb():
    # a chain along x: bone 0 of length 1, a short bone 1, bone 2 of length 1; joints 1 and 2 turn 90°
    # each, so bone 2 ends parallel to bone 0, 0.1 above it (a fingertip curled onto the palm)
    skel = Skeleton.from_arrays([[0, 0, 0], [1.0, 0, 0], [1.1, 0, 0], [2.1, 0, 0]], [-1, 0, 1, 2])
    one = jnp.asarray([1.0, 0, 0, 0])
    pose = Pose(jnp.stack([one, _turn(90), _turn(90), one]), jnp.zeros(3))
    p = np.array([[1.6, 0.06, 0.0]])  # on bone 2's side that ends up facing bone 0
    ref, miss = _miss_at_the_end(skel, pose, 2, p)
    np.testing.assert_allclose(np.asarray(ref), [[0.5, 0.04, 0.0]], atol=1e-9)  # 0.04 from bone 0
    # weights of the start: the point rides bone 2 all the way (the integrator's error only) ...
    assert miss["start"] < 6e-3, miss
    # ... weights of the current place: the resting bone 0 takes the point over as it comes near
    assert miss["current"] > 2.5e-2 and miss["current"] > 5 * miss["start"], miss


def test_start_weights_let_a_folding_bone_reach_its_parent():
    # two bones of one joint: the second folds back by 178° onto the first
    skel = Skeleton.from_arrays([[0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]], [-1, 0, 1])
    one = jnp.asarray([1.0, 0, 0, 0])
    pose = Pose(jnp.stack([one, _turn(178), one]), jnp.zeros(3))
    p = np.array([[1.5, 0.03, 0.0]])
    ref, miss = _miss_at_the_end(skel, pose, 1, p)
    c, s = np.cos(np.radians(178.0)), np.sin(np.radians(178.0))
    np.testing.assert_allclose(np.asarray(ref), [[1 + 0.5 * c - 0.03 * s, 0.5 * s + 0.03 * c, 0.0]], atol=1e-9)
    assert miss["start"] < 6e-3, miss  # fixed weights: the point rides its bone
    assert miss["current"] > 2.5e-2 and miss["current"] > 5 * miss["start"], miss  # taken over near the end


def _articulated_reference(field, skel, x0, weights):
    """Where scipy's adaptive RK45 takes x0 (N, 3) by dx/dt = Σ_b w_b ξ_b(t)(x) of ``field``'s bones at t = 1,
    ``weights(x, t)`` → (N, B) (numpy): the oracle of the integrator's articulated part.
    """
    from scipy.integrate import solve_ivp

    motion = jax.jit(lambda t: bone_velocities(skel, field.swing_pose(), t))  # compiled once: called thousands of times

    def rhs(t, y):
        x = y.reshape(-1, 3)
        r, c, dr, dc = (np.asarray(a) for a in motion(t))
        xi = np.einsum("bij,bkj,nbk->nbi", dr, r, x[:, None, :] - c[None]) + dc[None]  # (N, B, 3) bone velocities
        return np.einsum("nb,nbi->ni", weights(x, t), xi).reshape(-1)

    return solve_ivp(rhs, (0.0, 1.0), np.asarray(x0).reshape(-1), rtol=1e-9, atol=1e-11).y[:, -1].reshape(-1, 3)


@pytest.mark.parametrize("mode", ["start", "current", "surface"])
def test_skinned_flow_matches_an_independent_ode_solution(mode):
    """The flow of the articulated part against scipy's adaptive RK45 on dx/dt = Σ_b w_b ξ_b(t)(x),
    with w_b taken at the start x(0) (with the normals there: "surface"), or at the current x(t) (the
    field's own weight function).
    """
    skel, pose = _skeleton(), _pose(_skeleton())
    field = SkinnedField(_residual(alpha=0.0), skel, pose, width=0.3, dtype=jnp.float64, weight_mode=mode)
    x0 = np.array([[0.1, 0.05, 1.0], [0.0, 0.3, 1.9], [0.5, -0.1, 1.1], [0.05, 0.0, 0.4]])  # near joints
    n0 = np.array([[-1.0, 0, 0], [0, 0, 1.0], [-1.0, 0, 0], [0, 1.0, 0]])
    bones = jnp.asarray(POSITIONS[skel.bones[:, 0]]), jnp.asarray(POSITIONS[skel.bones[:, 1]])
    rest = skinning_weights(jnp.asarray(x0), *bones, 0.3)
    assert np.all(np.asarray(rest).max(1) < 0.95)  # the test exercises blending
    if mode == "surface":
        plain, rest = rest, surface_skinning_weights(jnp.asarray(x0), jnp.asarray(n0), *bones, 0.3)
        assert np.abs(np.asarray(rest) - np.asarray(plain)).max() > 0.3  # the normals change the weights

    current = jax.jit(lambda x, t: field.weights(x, t))  # compiled once: the solver calls it thousands of times
    start = np.asarray(rest)
    ref = _articulated_reference(
        field,
        skel,
        x0,
        (lambda x, t: np.asarray(current(jnp.asarray(x), t))) if mode == "current" else (lambda x, t: start),
    )
    ends = [jax.jit(lambda x, n=n: flow_points(field, x, n, normals=n0)[-1])(jnp.asarray(x0)) for n in (20, 40)]
    errors = [float(np.abs(np.asarray(end) - ref).max()) for end in ends]
    # the bones' motions are stepped in closed form and blended per step: first order where weights blend
    assert errors[0] < 5e-3, errors
    assert errors[1] < errors[0] / 1.7, errors


def test_anchored_points_take_their_anchors_weights_and_a_stencil_moves_by_one_affine_map():
    """integrate(..., anchors=A) with start weights: each point moves by dx/dt = Σ_b w_b(A) ξ_b(t)(x), the
    weights of its anchor (scipy's RK45 on that system as the oracle); a tissue stencil anchored at its
    centre then moves by one affine map of space (exactly, with the residual off), where unanchored it
    does not.
    """
    from ncflow.flow import integrate

    skel, pose = _skeleton(), _pose(_skeleton())
    field = SkinnedField(_residual(alpha=0.0), skel, pose, width=0.3, dtype=jnp.float64, weight_mode="start")
    x0 = np.array([[0.1, 0.05, 1.0], [0.0, 0.3, 1.9], [0.5, -0.1, 1.1], [0.05, 0.0, 0.4]])
    anchors = x0[[1, 2, 3, 0]]  # every point anchored at another one
    bones = jnp.asarray(POSITIONS[skel.bones[:, 0]]), jnp.asarray(POSITIONS[skel.bones[:, 1]])
    w = np.asarray(skinning_weights(jnp.asarray(anchors), *bones, 0.3))
    ref = _articulated_reference(field, skel, x0, lambda x, t: w)
    end = np.asarray(integrate(field, jnp.asarray(x0), 40, anchors=jnp.asarray(anchors))[0][-1])
    assert np.abs(end - ref).max() < 3e-3
    unanchored = np.asarray(integrate(field, jnp.asarray(x0), 40)[0][-1])
    assert np.abs(unanchored - ref).max() > 10 * np.abs(end - ref).max()  # the anchors changed the weights

    # a stencil p, p + δe_m and a fifth point p + δ Σ c_m e_m, all anchored at p (between two bones)
    p, delta, c = np.array([0.05, 0.1, 1.05]), 0.05, np.array([0.3, -0.2, 0.5])
    pts = np.vstack([p, p + delta * np.eye(3), p + delta * c])
    for anchored in (True, False):
        anchors = jnp.tile(p, (5, 1)) if anchored else None
        xs = np.asarray(integrate(field, jnp.asarray(pts), 10, anchors=anchors)[0][-1])
        miss = np.abs(xs[4] - (xs[0] + c @ (xs[1:4] - xs[0]))).max()
        assert miss < 1e-10 if anchored else miss > 1e-5, (anchored, miss)


def test_an_anchored_tissue_stencil_between_touching_limbs_is_not_torn():
    """A fingertip bone resting 0.2 above its palm bone (a U-shaped chain) lifts by 90°: a tissue stencil
    midway between them, its points' weights taken where they start, is torn by the weights' jump
    between the limbs; anchored at its centre its velocity is one blend of two rigid velocities with
    fixed weights, itself rigid, so it turns by half the angle unbent (energy 0 but for the integrator's
    per-step blends of finite turns).
    """
    from ncflow.flow import integrate
    from ncflow.losses import split_stencil, tissue_frame_energy, tissue_stencil

    skel = Skeleton.from_arrays([[0, 0, 0], [1.0, 0, 0], [1.0, 0.2, 0], [0.2, 0.2, 0]], [-1, 0, 1, 2])
    one = jnp.asarray([1.0, 0, 0, 0], jnp.float64)
    pose = Pose(jnp.stack([one, one, quat_from_rotvec(jnp.asarray([0, 0, -np.pi / 2])), one]), jnp.zeros(3))
    field = SkinnedField(_residual(alpha=0.0), skel, pose, width=0.05, dtype=jnp.float64, weight_mode="start")
    centre, delta = jnp.asarray([[0.6, 0.1, 0.0]]), 0.01
    stencil = tissue_stencil(centre, delta)
    energy = {}
    for anchored in (False, True):
        xs = integrate(field, stencil, 10, anchors=jnp.tile(centre, (4, 1)) if anchored else None)[0]
        energy[anchored] = float(tissue_frame_energy(split_stencil(xs)[1][-1], delta)[0])
    assert energy[True] < 0.01 and energy[False] > 10.0, energy


def test_pose_gradient_is_finite_at_rest_and_moves_the_points():
    skel = _skeleton()
    pts = jnp.asarray(np.random.default_rng(4).normal(scale=0.3, size=(30, 3)) + [0, 0, 1.5])
    goal = pts + jnp.asarray([0.1, 0.0, 0.0])

    def loss(pose):
        f = SkinnedField(_residual(), skel, pose, width=0.05, dtype=jnp.float64)
        return jnp.sum((flow_points(f, pts, 10)[-1] - goal) ** 2)

    grad = jax.jit(jax.grad(loss))(rest_pose(skel, jnp.float64))
    assert all(bool(jnp.all(jnp.isfinite(g))) for g in jax.tree_util.tree_leaves(grad))
    # a pure x-shift is explained by the root translation: its gradient is -2 Σ 0.1 = -6 along x
    np.testing.assert_allclose(np.asarray(grad.translation), [-6.0, 0.0, 0.0], atol=1e-9)


def test_configuration_of_the_skinned_field():
    assert preset("fast").flow.skinning and not preset("paper").flow.skinning
    with pytest.raises(InputError, match="div_free needs flow.skinning=false"):
        apply_overrides(preset("fast"), ["flow.div_free=true"])
    cfg = apply_overrides(preset("fast"), ["flow.div_free=true", "flow.skinning=false"])
    assert cfg.flow.div_free and not cfg.flow.skinning
    with pytest.raises(InputError, match="skinning_width"):
        apply_overrides(preset("fast"), ["flow.skinning_width=0"])
    with pytest.raises(ValueError):
        SkinnedField(_residual(), _skeleton(), width=0.0)


def test_div_free_switch_turns_the_skinned_field_off():
    import argparse

    from ncflow.cli.options import add_config_arguments, config_from_args

    p = argparse.ArgumentParser()
    add_config_arguments(p)
    assert config_from_args(p.parse_args([])).flow.skinning
    cfg = config_from_args(p.parse_args(["--div-free"]))
    assert cfg.flow.div_free and not cfg.flow.skinning


def test_swing_pose_removes_the_twist_of_single_child_joints_only():
    skel = _skeleton()  # joint 0: one child (axis z); joint 1: two children; joint 2: one child (axis y)
    rot = jnp.stack(
        [
            quat_from_rotvec(jnp.asarray(v, jnp.float64))
            for v in [[0.2, 0, 0.7], [0, 0.4, 0.5], [0.3, 0.6, 0.0], [0, 0, 0.3], [0, 0, 0]]
        ]
    )
    pose = Pose(rot, jnp.asarray([0.1, 0.0, 0.0]))
    swing = SkinnedField(_residual(), skel, pose, dtype=jnp.float64).swing_pose()
    q = np.asarray(rot)
    expected = q.copy()
    expected[0, 3] = 0.0  # the z part of joint 0's vector part
    expected[2, 2] = 0.0  # the y part of joint 2's
    np.testing.assert_allclose(np.asarray(swing.rotations), expected, atol=1e-15)
    np.testing.assert_allclose(np.asarray(swing.translation), [0.1, 0.0, 0.0])
    # the trained twist parameter gets no gradient through the field
    x = jnp.asarray(np.random.default_rng(5).normal(scale=0.3, size=(20, 3)) + [0, 0, 0.5])

    def speed(p):
        return jnp.sum(SkinnedField(_residual(), skel, p, dtype=jnp.float64)(x, 0.5) ** 2)

    grad = jax.jit(jax.grad(speed))(pose)
    assert abs(float(grad.rotations[0, 3])) < 1e-12 and abs(float(grad.rotations[0, 1])) > 1e-6


def test_skinning_products_ask_for_full_float32_precision(dot_precisions):
    # the point-to-bone distances are expanded |x|² − 2⟨x, a⟩ + |a|²: in TF32 (a GPU's default for
    # float32 products) they lose the weights of points near a bone; see measures/kernels.py
    skel = _skeleton()
    x = jnp.asarray(np.random.default_rng(2).normal(size=(7, 3)), jnp.float32)

    def speed(pose):
        return jnp.sum(SkinnedField(_residual(), skel, pose, width=0.05, dtype=jnp.float32)(x, 0.4) ** 2)

    found = dot_precisions(str(jax.make_jaxpr(jax.value_and_grad(speed))(rest_pose(skel, jnp.float32))))
    skinning = [p for p in found if p != "None"]
    assert len(skinning) >= 4 and all(p == "(Precision.HIGHEST, Precision.HIGHEST)" for p in skinning), found


def test_the_compiled_field_does_not_depend_on_the_skeleton_positions_or_the_width():
    """Two skeletons of one shape with other joint positions and bone-weight widths lower to the same
    program (their arrays are arguments: :func:`ncflow.jit.cache.share_executables`, set for the tests
    as for users), so a second character reuses the first one's compiled executables; another
    tree of joints is another program (the comparison can fail).
    """
    moved = POSITIONS + np.array([[0.0, 0.0, 0.0], [0.1, 0, 0.2], [0, 0.3, 0.1], [0, 0.1, 0], [0.2, 0, 0]])
    x = jnp.asarray(np.random.default_rng(0).normal(size=(16, 3)), jnp.float32)

    def program(positions, width, parents=PARENTS):
        skel = Skeleton.from_arrays(positions, parents)
        field = SkinnedField(_residual(), skel, _pose(skel), width=width, dtype=jnp.float32)
        return eqx.filter_jit(lambda f, p: f(p, 0.3)).lower(field, x).as_text()

    first = program(POSITIONS, 0.05)
    assert program(moved, 0.08) == first
    assert program(POSITIONS, 0.05, np.array([-1, 0, 1, 2, 0])) != first


def test_core_gate_against_dense_segment_sampling():
    skel = _skeleton()
    heads = jnp.asarray(POSITIONS[skel.bones[:, 0]])
    tails = jnp.asarray(POSITIONS[skel.bones[:, 1]])
    radius = jnp.asarray([0.1, 0.15, 0.08, 0.12])
    x = jnp.asarray(np.random.default_rng(7).uniform(-0.3, 1.3, size=(400, 3)) * [1, 1, 2])
    gate = np.asarray(core_gate(x, heads, tails, radius, 2.5 * radius))
    # brute force: the core segment is the 10 %–90 % part of each bone
    s = np.linspace(0.1, 0.9, 40001)
    pts = np.asarray(heads)[:, None, :] + s[None, :, None] * np.asarray(tails - heads)[:, None, :]
    d = np.min(np.linalg.norm(np.asarray(x)[:, None, None, :] - pts[None], axis=-1), axis=-1)  # (N, B)
    q = np.min(d / np.asarray(radius), axis=1)
    u = np.clip((q - 1.0) / 1.5, 0.0, 1.0)
    np.testing.assert_allclose(gate, u * u * (3 - 2 * u), atol=1e-6)
    assert np.any(gate == 0.0) and np.any(gate == 1.0) and np.any((gate > 0.05) & (gate < 0.95))


def test_a_rigid_core_moves_the_bone_samples_with_the_skeleton_alone():
    """Inside the cores the Flow-Net is switched off: bone samples flow exactly as with no Flow-Net at
    all (both weight modes), while points beyond (1 + ramp) core radii get the whole Flow-Net. With wider
    bone weights the blend near a joint carries a few samples just past their core, where the Flow-Net
    fades back in: a leak of under 1 % of its motion.
    """
    skel, pose = _skeleton(), _pose(_skeleton())
    rho = 0.1
    core = rho * skel.bone_lengths
    samples = sample_bones(skel, jax.random.key(3), 12, radius=rho, dtype=jnp.float64).flat()
    flow = eqx.filter_jit(lambda f, p: flow_points(f, p, 10))
    for mode in ("current", "start"):
        for width, leak in ((0.02, 1e-4), (0.05, 1e-3)):
            gated = SkinnedField(
                _residual(alpha=0.3), skel, pose, width, dtype=jnp.float64, weight_mode=mode, core=core
            )
            bare = eqx.tree_at(lambda f: f.residual.alpha, gated, jnp.zeros((), jnp.float64))
            free = SkinnedField(_residual(alpha=0.3), skel, pose, width, dtype=jnp.float64, weight_mode=mode)
            without = flow(bare, samples)
            np.testing.assert_allclose(np.asarray(flow(gated, samples)), np.asarray(without), rtol=0, atol=leak)
            assert float(jnp.max(jnp.abs(flow(free, samples) - without))) > 0.1  # the Flow-Net does move them
    far = jnp.asarray([[0.0, 0.6, 0.5], [0.6, 0.6, 2.0], [-0.7, 0.0, 1.5]])  # ≥ 0.5 from every core segment
    gated = SkinnedField(_residual(alpha=0.3), skel, pose, 0.05, dtype=jnp.float64, core=core)
    free = SkinnedField(_residual(alpha=0.3), skel, pose, 0.05, dtype=jnp.float64)
    np.testing.assert_allclose(np.asarray(gated(far, 0.0)), np.asarray(free(far, 0.0)), atol=1e-14)
    with pytest.raises(ValueError, match="4 radii"):
        SkinnedField(_residual(), skel, core=core[:3])


def test_rigid_core_setting():
    from ncflow.matcher.objective import bone_cores
    from ncflow.matcher.train import init_params

    cfg = preset("fast")
    assert cfg.flow.rigid_core == 1.0
    with pytest.raises(InputError, match="rigid_core"):
        apply_overrides(cfg, ["flow.rigid_core=-1"])
    skel = _skeleton()
    core, outer = bone_cores(skel, 0.1, 1.0)
    np.testing.assert_allclose(core, 0.1 * skel.bone_lengths)
    np.testing.assert_allclose(outer, 0.2 * skel.bone_lengths)
    # a bone nowhere inside has no core
    core, outer = bone_cores(skel, 0.1, 1.0, inside=np.array([1.0, 0.0, 0.3, 1.0]))
    np.testing.assert_allclose(core, [0.1, 0.0, 0.08, 0.1])
    np.testing.assert_allclose(outer, [0.2, 0.0, 0.16, 0.2])
    # a thin limb's samples (and so its core) are narrowed to end the ramp at its flesh
    from ncflow.matcher.prepare import bone_radii

    flesh = np.array([1.0, 1.0, 1.0, 0.1])
    np.testing.assert_allclose(bone_radii(cfg, skel, flesh), [0.1, 0.1, 0.1, 0.05])
    off = apply_overrides(cfg, ["flow.rigid_core=0"])
    np.testing.assert_allclose(bone_radii(off, skel, flesh), 0.1)
    params = init_params(jax.random.key(0), cfg, skel)
    expected = np.column_stack([0.1 * skel.bone_lengths, 0.2 * skel.bone_lengths, np.full(4, 0.1), np.full(4, 0.9)])
    np.testing.assert_allclose(np.asarray(params.flow.core), expected, rtol=1e-6)
    off = init_params(jax.random.key(0), apply_overrides(cfg, ["flow.rigid_core=0"]), skel)
    assert off.flow.core is None


def test_surface_weights_leave_out_the_bones_in_front_of_the_skin():
    """Against a brute force in NumPy: each point's nearest point on every bone (a dense sampling of the
    segment), the bones on the outer side of its normal dropped, a softmax of −distance/width over the rest;
    a point with every bone in front gets the plain weights. The case it exists for: a fingertip bone resting
    on a palm's skin does not weigh on that skin, though it is the nearest bone."""
    rng = np.random.default_rng(4)
    heads, tails = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    x, n = rng.normal(size=(40, 3)) * 1.5, rng.normal(size=(40, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    width = 0.3
    args = (jnp.asarray(a) for a in (x, n, heads, tails))
    got = np.asarray(surface_skinning_weights(*args, width))
    t = np.linspace(0.0, 1.0, 20001)
    seg = heads[:, None] + t[None, :, None] * (tails - heads)[:, None]  # (B, T, 3)
    for i in range(x.shape[0]):
        d_all = np.linalg.norm(seg[None] - x[i, None, None], axis=-1)[0]  # (B, T)
        k = d_all.argmin(1)
        near = seg[np.arange(5), k] - x[i]
        d = np.linalg.norm(near, axis=1)
        behind = near @ n[i] <= 0.0
        keep = behind if behind.any() else np.ones(5, bool)
        w = np.where(keep, np.exp(-(d - d[keep].min()) / width), 0.0)
        np.testing.assert_allclose(got[i], w / w.sum(), atol=2e-4)
    palm_skin, up = np.array([[0.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.0]])
    palm = (np.array([-2.0, 0.0, -0.3]), np.array([2.0, 0.0, -0.3]))  # under the skin, 0.3 deep
    tip = (np.array([-0.5, 0.0, 0.2]), np.array([0.5, 0.0, 0.2]))  # resting on it, 0.2 above
    bones = [jnp.asarray(np.stack(p)) for p in zip(palm, tip)]
    w = np.asarray(surface_skinning_weights(jnp.asarray(palm_skin), jnp.asarray(up), *bones, 0.05))
    assert w[0, 0] == pytest.approx(1.0) and w[0, 1] < 1e-6
    plain = np.asarray(skinning_weights(jnp.asarray(palm_skin), *bones, 0.05))
    assert plain[0, 1] > 0.8  # the plain weights give that skin to the fingertip


def test_surface_weights_keep_the_skin_under_a_resting_fingertip_on_its_own_bone():
    """A fist in miniature: a palm bone 0.3 under the skin z = 0, a fingertip bone resting 0.2 above it.
    When the finger straightens, the palm's skin stays where its own (unmoving) bone holds it with the
    skin-aware weights of the start; the plain weights give it to the fingertip, which carries it off. Points
    without a normal (zero rows) take the plain weights, and a chunked flow gives the same as one piece.
    """
    skel = Skeleton.from_arrays([[0, 0, -0.3], [2.0, 0, -0.3], [2.0, 0, 0.2], [1.0, 0, 0.2]], [-1, 0, 1, 2])
    one = jnp.asarray([1.0, 0, 0, 0])
    pose = Pose(jnp.stack([one, one, _turn(90), one]), jnp.zeros(3))
    skin = np.array([[1.0, 0.0, 0.0], [1.3, 0.05, 0.0]])
    up = np.array([[0.0, 0, 1.0], [0.0, 0, 1.0]])
    ends = {}
    for mode, normals in (("surface", up), ("surface", np.zeros_like(up)), ("start", up)):
        field = SkinnedField(_residual(alpha=0.0), skel, pose, width=0.05, dtype=jnp.float64, weight_mode=mode)
        ends[mode, normals.any()] = np.asarray(flow_points(field, jnp.asarray(skin), 20, normals=normals)[-1])
    np.testing.assert_allclose(ends["surface", True], skin, atol=1e-9)  # the palm does not move
    assert np.linalg.norm(ends["start", True] - skin, axis=1).min() > 0.5  # carried off by the fingertip
    np.testing.assert_allclose(ends["surface", False], ends["start", True], atol=1e-12)
    field = SkinnedField(_residual(alpha=0.3), skel, pose, width=0.05, dtype=jnp.float64, weight_mode="surface")
    x = np.random.default_rng(1).normal(size=(37, 3)) * 0.5
    n = np.random.default_rng(2).normal(size=(37, 3))
    whole = np.asarray(flow_points(field, jnp.asarray(x), 10, normals=n))
    chunked = np.asarray(flow_points(field, jnp.asarray(x), 10, normals=n, chunk_size=8))
    np.testing.assert_allclose(chunked, whole, atol=1e-12)


def test_skin_contact_against_a_brute_force():
    """The share of the weight whose nearest bone (a dense sampling of each segment) is in front of its
    skin while another bone lies behind it (where every bone is in front the weights stay the plain ones)."""
    rng = np.random.default_rng(7)
    heads, tails = rng.normal(size=(4, 3)), rng.normal(size=(4, 3))
    x, n = rng.normal(size=(300, 3)) * 1.5, rng.normal(size=(300, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    w = rng.uniform(0.1, 1.0, size=300)
    t = np.linspace(0.0, 1.0, 4001)
    seg = heads[:, None] + t[None, :, None] * (tails - heads)[:, None]  # (B, T, 3)
    moved = np.zeros(300, bool)
    for i in range(300):
        d_all = np.linalg.norm(seg - x[i], axis=-1)  # (B, T)
        near = seg[np.arange(4), d_all.argmin(1)] - x[i]
        front = near @ n[i] > 0.0
        moved[i] = front[np.linalg.norm(near, axis=1).argmin()] and not front.all()
    expected = float(w @ moved / w.sum())
    assert 0.05 < expected < 0.95  # the draw exercises both cases
    assert skin_contact(x, n, w, heads, tails) == pytest.approx(expected, abs=2.0 / 300)


def test_core_weights_are_the_bones_own_inside_its_core_and_a_partition_of_unity():
    """Inside bone b's core the weights are e_b, though at the joint the other bones' core ramps reach
    the point (to 1e-4 where a ramp is at 0.8 of its height, e^{-0.2/κ}; 1e-11 at 0.5); beyond every outer
    radius they are the plain weights; rows sum to 1 and move continuously with x."""
    from ncflow.flow.bone_weights import core_memberships, core_weights

    skel = _skeleton()
    heads = jnp.asarray(POSITIONS[skel.bones[:, 0]])
    tails = jnp.asarray(POSITIONS[skel.bones[:, 1]])
    radius = 0.1 * np.asarray(skel.bone_lengths)
    core = jnp.asarray(np.column_stack([radius, 2.5 * radius, np.tile([0.1, 0.9], (skel.n_bones, 1))]))
    x = jnp.asarray([[0.0, 0.0, 0.9], [0.0, 0.0, 1.1], [0.0, 0.08, 1.12], [0.0, 0.6, 0.4], [0.0, -0.1, 1.0]])
    plain = skinning_weights(x, heads, tails, 0.3)
    w = np.asarray(core_weights(plain, x, heads, tails, core))
    m = np.asarray(core_memberships(x, heads, tails, core[:, 0], core[:, 1], core[:, 2:]))
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-12)
    assert m[2, 1] == 1.0 and 0.0 < m[2, 3] < 1.0  # in bone 1's core, in the ramp of the side bone's
    np.testing.assert_allclose(w[:2], np.eye(skel.n_bones)[[0, 1]], atol=1e-4)
    np.testing.assert_allclose(w[2], np.eye(skel.n_bones)[1], atol=1e-10)
    np.testing.assert_allclose(w[3], np.asarray(plain)[3], atol=1e-12)  # far from every core
    assert 0.0 < m[4].max() < 1.0 and np.all(np.abs(w[4] - np.asarray(plain)[4]) > 0)  # the joint: blended
    # continuity: a small step moves the weights a little
    step = np.asarray(core_weights(skinning_weights(x + 1e-6, heads, tails, 0.3), x + 1e-6, heads, tails, core))
    assert np.abs(step - w).max() < 1e-3
    assert core_weights(plain, x, heads, tails, None) is plain


def _sunk_fingertip():
    """A box body 4 × 1 × 1 (x from 0 to 4) with a chain of bones along its axis that leaves it at the
    far end, runs back above it (outside) and ends in a bone that dips through the top skin to 0.05 under
    it at x = 1: a fingertip sunk into the palm, as in a captured fist."""
    import trimesh

    box = trimesh.creation.box(extents=(4.0, 1.0, 1.0))
    box.apply_translation([2.0, 0.0, 0.0])
    for _ in range(4):
        box = box.subdivide()
    joints = [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [4.5, 0, 0], [1.4, 0, 1.5], [1.0, 0, 0.45]]
    skel = Skeleton.from_arrays(np.asarray(joints, float), [-1, 0, 1, 2, 3, 4, 5])
    return np.asarray(box.vertices), np.asarray(box.faces), skel


def test_skin_islands_take_the_palms_skin_off_a_sunk_fingertip():
    """The top skin over the sunk tip has the tip bone nearest and behind it, so the front test gives it
    to the tip; along the surface that patch is cut off from the tip's own chain, whose other bones lie
    outside (in front of every vertex). ``skin_islands`` leaves the tip bone out for exactly the vertices
    a brute force (dense segment sampling, the front test) gives to it, and nothing else; a chain without
    the sunk bone loses nothing. Turning the tip's joint then carries the patch off with the normals
    alone and leaves it in place with the islands (``surface_skin``'s columns)."""
    from ncflow.flow.islands import skin_islands, surface_skin
    from ncflow.geometry.mesh import outward_vertex_normals

    v, f, skel = _sunk_fingertip()
    n = outward_vertex_normals(v, f)
    heads, tails = skel.positions[skel.bones[:, 0]], skel.positions[skel.bones[:, 1]]
    t = np.linspace(0.0, 1.0, 2001)
    seg = heads[:, None] + t[None, :, None] * (tails - heads)[:, None]  # (B, T, 3)
    given = np.empty(len(v), int)
    for i in range(len(v)):
        d_all = np.linalg.norm(seg - v[i], axis=-1)
        near = seg[np.arange(len(heads)), d_all.argmin(1)] - v[i]
        d = np.where(near @ n[i] > 0.0, np.inf, np.linalg.norm(near, axis=1))
        given[i] = d.argmin()
    tip = int(np.nonzero((skel.bones == [5, 6]).all(1))[0][0])
    assert 10 < (given == tip).sum() < 0.05 * len(v)  # a patch of skin around the sunk end, nothing else
    assert np.all(np.abs(v[given == tip, 0] - 1.1) < 0.6) and np.all(v[given == tip, 2] > 0.2)
    out = skin_islands(v, f, n, heads, tails, skel.bone_hops <= 1)
    expected = np.zeros_like(out)
    expected[given == tip, tip] = True
    np.testing.assert_array_equal(out, expected)
    shift = np.array([5.0, -3.0, 2.0])  # the same in other units and elsewhere
    moved = skin_islands(v * 0.01 + shift, f, n, heads * 0.01 + shift, tails * 0.01 + shift, skel.bone_hops <= 1)
    np.testing.assert_array_equal(moved, expected)
    chain = Skeleton.from_arrays(skel.positions[:5], skel.parents[:5])
    h5, t5 = chain.positions[chain.bones[:, 0]], chain.positions[chain.bones[:, 1]]
    assert not skin_islands(v, f, n, h5, t5, chain.bone_hops <= 1).any()

    skin = surface_skin(v, f, skel.positions, skel.parents)
    np.testing.assert_allclose(skin[:, :3], n)
    np.testing.assert_array_equal(skin[:, 3:], expected.astype(float))
    one = jnp.asarray([1.0, 0, 0, 0])
    rotations = jnp.stack([one] * 5 + [_turn(90), one])  # the tip's joint turns
    pose = Pose(rotations, jnp.zeros(3))
    field = SkinnedField(_residual(alpha=0.0), skel, pose, width=0.05, dtype=jnp.float64, weight_mode="surface")
    patch = jnp.asarray(v[given == tip])
    moved = {}
    for name, normals in (("islands", skin[given == tip]), ("normals", n[given == tip])):
        end = np.asarray(flow_points(field, patch, 20, normals=normals)[-1])
        moved[name] = np.linalg.norm(end - v[given == tip], axis=1)
    assert moved["islands"].max() < 1e-6
    assert moved["normals"].min() > 0.3


def test_exported_skin_weights_leave_the_islands_bones_out():
    """``skeleton_weights`` (the rig's and the track's per-joint weights) reads ``surface_skin``'s columns as
    the field does: the patch over the sunk tip gets (almost) no weight from the tip's joint with them, and
    most of it from the outward normals alone (more than 0.4 everywhere, 0.75 on average)."""
    from ncflow.flow.islands import surface_skin
    from ncflow.geometry.mesh import outward_vertex_normals
    from ncflow.retarget.weights import skeleton_weights

    v, f, skel = _sunk_fingertip()
    skin = surface_skin(v, f, skel.positions, skel.parents)
    patch = skin[:, 3:].any(1)
    assert patch.sum() > 10
    with_islands = skeleton_weights(v, skel.positions, skel.parents, 0.05, skin)
    normals_only = skeleton_weights(v, skel.positions, skel.parents, 0.05, outward_vertex_normals(v, f))
    assert with_islands[patch, 5].max() < 1e-6  # bone 5 -> 6 moves with joint 5
    assert normals_only[patch, 5].min() > 0.4 and normals_only[patch, 5].mean() > 0.75
    np.testing.assert_allclose(with_islands[~patch], normals_only[~patch], atol=1e-6)


@pytest.mark.parametrize("mode", ["current", "surface"])
def test_rematerialised_steps_give_the_stored_steps_values_and_gradients(mode):
    """:func:`ncflow.flow.integrate` recomputes each step in the backward pass by default (``checkpoint``): on a
    skinned field with rigid cores (the closed-form bone steps, the gated Flow-Net) the states, the slopes and
    the gradients with respect to the network and the pose are those of the stored steps, to rounding.
    """
    skel = _skeleton()
    field = SkinnedField(
        _residual(alpha=0.3), skel, _pose(skel), 0.3, dtype=jnp.float64, weight_mode=mode, core=0.1 * skel.bone_lengths
    )
    rng = np.random.default_rng(3)
    x0 = jnp.asarray(rng.normal(size=(40, 3)) + POSITIONS.mean(0))
    normals = jnp.asarray(rng.normal(size=(40, 3)))

    def loss(f, checkpoint):
        xs, vs = integrate(f, x0, 6, checkpoint=checkpoint, normals=normals)
        return jnp.sum(jnp.sin(xs)) + 0.1 * jnp.sum(vs**2)

    value = {c: eqx.filter_jit(eqx.filter_value_and_grad(loss))(field, c) for c in (False, True)}
    assert float(value[True][0]) == pytest.approx(float(value[False][0]), rel=1e-13)
    grads = [jax.tree.leaves(eqx.filter(value[c][1], eqx.is_inexact_array)) for c in (False, True)]
    assert len(grads[0]) == len(grads[1]) > 2
    for a, b in zip(*grads, strict=True):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-10, atol=1e-12)
    pose_grad = np.asarray(value[True][1].pose.rotations)
    assert np.max(np.abs(pose_grad)) > 1e-3  # the pose is differentiated through the closed-form steps
