"""The compiled scores of the articulated pose search (:mod:`ncflow.matcher.pose_search`).

The source is summarised by area-weighted oriented Diracs (:func:`~ncflow.matcher.placement.surface_diracs`),
each carried by the skeleton-driven field's bone weights w_b (the same softmax of distances to the
bones as :class:`~ncflow.flow.SkinnedField`): for a pose, a Dirac moves to Σ_b w_b M_b(x) and its normal
to the normalised Σ_b w_b R_b n, M_b the bone's rigid motion from rest
(:func:`~ncflow.skeleton.kinematics.bone_motions` at t = 1, twist of one-child joints removed as the field
does). The score of a pose is the normalised Varifold distance to the target, the data term of the first
stage. :class:`PoseScorer` holds one source's Diracs and the compiled programs that score, expand and
refine batches of poses; every batch has a fixed shape (padding rows scored +inf without being computed),
so one program serves every joint and every placement.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import Float, Int

from ncflow.flow.bone_weights import skinning_weights, surface_skinning_weights
from ncflow.flow.skinning import swing_only
from ncflow.matcher.placement import surface_diracs
from ncflow.measures.partial import VIEW_STRENGTH, facing_weights, occlusion_cover, view_direction, view_strength
from ncflow.measures.varifold import Varifold, varifold_inner
from ncflow.skeleton import Skeleton
from ncflow.skeleton.dualquat import dq_rotation, dq_translation, quat_mul, quat_normalize, quat_to_matrix
from ncflow.skeleton.kinematics import Pose, bone_motions, forward_kinematics, joint_positions, rest_pose

DTYPE = jnp.float32


def joined(*parts: tuple[Varifold, float]) -> Varifold:
    """One measure of several, each weighted by its factor: ⟨X, Σ_k f_k Y_k⟩ is one kernel sum."""
    return Varifold(
        jnp.concatenate([p.centers for p, _ in parts]),
        jnp.concatenate([p.normals for p, _ in parts]),
        jnp.concatenate([f * p.weights for p, f in parts]),
    )


def skinned(skeleton: Skeleton, weights, x: Varifold, pose: Pose) -> Varifold:
    """The Diracs ``x`` moved by the bones of ``pose`` with their bone ``weights`` (N, B)."""
    m = bone_motions(skeleton, swing_only(skeleton, pose), jnp.asarray(1.0, pose.rotations.dtype))
    r, c = quat_to_matrix(dq_rotation(m)), dq_translation(m)  # (B, 3, 3), (B, 3)
    centers = jnp.einsum("nb,bij,nj->ni", weights, r, x.centers) + weights @ c
    normals = jnp.einsum("nb,bij,nj->ni", weights, r, x.normals)
    normals = normals / jnp.maximum(jnp.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)
    return Varifold(centers, normals, x.weights)


def facing(x: Varifold, y: Varifold) -> Varifold:
    """``x`` with its weights times its :func:`~ncflow.measures.partial.facing_weights` against ``y`` (all
    ones unless ``y`` is a view from one side).
    """
    return Varifold(x.centers, x.normals, x.weights * facing_weights(x.normals, y))


def unhidden(x: Varifold, y: Varifold, spacing) -> Varifold:
    """``x`` with its weights times exp(−2 c), c its :func:`~ncflow.measures.partial.occlusion_cover` by the
    target's Diracs ``y`` along the view's camera direction (samples of spacing ``spacing``): what lies
    behind the surface a view shows is not in the view. ``x`` unchanged unless ``y`` is a view.
    """
    c, strength = view_direction(y)

    def hidden(_):
        return jnp.exp(
            -2.0 * occlusion_cover(x.centers, y.centers, (y.weights > 0).astype(x.weights.dtype), c, spacing)
        )

    w = jax.lax.cond(strength > VIEW_STRENGTH, hidden, lambda _: jnp.ones_like(x.weights), None)
    return Varifold(x.centers, x.normals, x.weights * w)


def distance(skeleton: Skeleton, pose: Pose, sigma, src, y: Varifold, yy, occlusion: bool = False):
    """The normalised Varifold distance d(X(pose), Y) / ⟨Y, Y⟩ of the skinned Diracs ``src`` = (x, w); against
    a target seen from one side only the source Diracs facing its camera count
    (:func:`ncflow.measures.partial.facing_weights`: the far side a single view cannot show is not
    asked to vanish), and with ``occlusion`` only those not behind the view's surface (:func:`unhidden`).
    """
    x, w = src
    xs = facing(skinned(skeleton, w, x, pose), y)
    if occlusion:
        xs = unhidden(xs, y, jnp.sqrt(jnp.sum(x.weights) / x.weights.shape[0]))
    return (varifold_inner(xs, xs, sigma, 0.5) - 2.0 * varifold_inner(xs, y, sigma, 0.5) + yy) / yy


def scores(skeleton: Skeleton, poses: Pose, active, sigma, src, y: Varifold, occlusion: bool = False):
    """Each pose's distance (``occlusion``: :func:`distance`'s), +inf without computing it where ``active`` is
    False (padding rows: the shapes are fixed so that one program serves every joint and placement).
    lax.map, not vmap: a batch of blocked kernel sums runs ~6× faster one after the other on CPU, and the
    cond then skips the padding's work.
    """
    inf, yy = jnp.asarray(jnp.inf, DTYPE), varifold_inner(y, y, sigma, 0.5)
    return jax.lax.map(
        lambda pa: jax.lax.cond(
            pa[1], lambda p: distance(skeleton, p, sigma, src, y, yy, occlusion), lambda p: inf, pa[0]
        ),
        (poses, active),
    )


def hypotheses(rotations, translations, hyp, hyp_child, j, c, n_real, n_h):
    """Every beam pose × every local rotation pair of joint j and its child c, and which are real."""
    nb, nh = rotations.shape[0], hyp.shape[0]
    rot = jnp.repeat(rotations, nh, axis=0)
    rot = rot.at[:, j].set(quat_mul(rot[:, j], jnp.tile(hyp, (nb, 1))))
    rot = rot.at[:, c].set(quat_mul(rot[:, c], jnp.tile(hyp_child, (nb, 1))))
    active = jnp.repeat(jnp.arange(nb) < n_real, nh) & jnp.tile(jnp.arange(nh) < n_h, nb)
    return Pose(rot, jnp.repeat(translations, nh, axis=0)), active


def expand_part(skeleton, src, rotations, translations, hyp, hyp_child, j, c, sigma, y, n_real, n_h, moving, mask):
    """Every beam pose × every local rotation of joint j and its child c, scored, where joint j moves only
    the Diracs ``moving`` (``mask`` 0 on padding): each beam pose's other Diracs S are posed once, and a
    hypothesis adds the moved ones M to its distance, ⟨S,S⟩ − 2⟨S,Y⟩ + ⟨M, 2S − 2Y + M⟩ + ⟨Y,Y⟩ (the same
    sum without the pairs of S that do not change): O(|M|·N) a hypothesis instead of O(N²). Whole weights,
    also against a view: :func:`distance`'s facing weights, measured here too, found worse poses (a view
    of a quadruped: 12 % of the view's points more than 0.2 √area from their true source point on a
    nearest-point map to the posed source, against none).
    """
    x, w = src
    nb, nh = rotations.shape[0], hyp.shape[0]
    cand, active = hypotheses(rotations, translations, hyp, hyp_child, j, c, n_real, n_h)
    yy = varifold_inner(y, y, sigma, 0.5)
    rest_w = x.weights.at[moving].set(0.0)
    part, part_w = Varifold(x.centers[moving], x.normals[moving], x.weights[moving] * mask), w[moving]

    def beam_static(pose):
        xs = skinned(skeleton, w, x, pose)
        xs = Varifold(xs.centers, xs.normals, rest_w)
        const = varifold_inner(xs, joined((xs, 1.0), (y, -2.0)), sigma, 0.5)
        return xs.centers, xs.normals, const

    def nothing(pose):
        return jnp.zeros_like(x.centers), jnp.zeros_like(x.normals), jnp.zeros((), DTYPE)

    centers, normals, const = jax.lax.map(
        lambda pa: jax.lax.cond(pa[1], beam_static, nothing, pa[0]),
        (Pose(rotations, translations), jnp.arange(nb) < n_real),
    )

    def one(mb):
        pose, b = mb
        m = skinned(skeleton, part_w, part, pose)
        others = joined((Varifold(centers[b], normals[b], rest_w), 2.0), (y, -2.0), (m, 1.0))
        return (const[b] + varifold_inner(m, others, sigma, 0.5) + yy) / yy

    inf = jnp.asarray(jnp.inf, DTYPE)
    return cand, jax.lax.map(
        lambda pa: jax.lax.cond(pa[1], one, lambda mb: inf, pa[0]),
        ((cand, jnp.arange(nb * nh) // nh), active),
    )


def expand_chain(skeleton, src, pose: Pose, chain, hyp, active, sigma, y, moving, mask):
    """Each row of ``hyp`` (H, L, 4) set as the local rotations of the joints ``chain`` (L,) of one ``pose``,
    scored (+inf where ``active`` is False), the chain moving only the Diracs ``moving`` (``mask`` 0 on
    padding): the others are posed once, as in :func:`expand_part`. A chain padded by repeating its last
    joint (and that joint's rotation) sets that joint twice to one value.
    """
    x, w = src
    yy = varifold_inner(y, y, sigma, 0.5)
    rest_w = x.weights.at[moving].set(0.0)
    part, part_w = Varifold(x.centers[moving], x.normals[moving], x.weights[moving] * mask), w[moving]
    xs = skinned(skeleton, w, x, pose)
    xs = Varifold(xs.centers, xs.normals, rest_w)
    const = varifold_inner(xs, joined((xs, 1.0), (y, -2.0)), sigma, 0.5)

    def one(q):
        m = skinned(skeleton, part_w, part, Pose(pose.rotations.at[chain].set(q), pose.translation))
        return (const + varifold_inner(m, joined((xs, 2.0), (y, -2.0), (m, 1.0)), sigma, 0.5) + yy) / yy

    inf = jnp.asarray(jnp.inf, DTYPE)
    return jax.lax.map(lambda qa: jax.lax.cond(qa[1], one, lambda q: inf, qa[0]), (hyp, active))


def refine(skeleton, src, pose: Pose, sigma, y, yy, steps: int) -> Pose:
    """``steps`` Adam steps (rate 0.01) of the pose down the distance, its rotations kept unit."""
    opt = optax.adam(0.01)
    state = opt.init(pose)

    def body(carry, _):
        p, st = carry
        g = jax.grad(lambda q: distance(skeleton, q, sigma, src, y, yy))(p)
        u, st = opt.update(g, st, p)
        p = optax.apply_updates(p, u)
        return (Pose(p.rotations / jnp.linalg.norm(p.rotations, axis=-1, keepdims=True), p.translation), st), None

    return jax.lax.scan(body, (pose, state), None, length=steps)[0][0]


class PoseScorer:
    """One source's Diracs and the compiled programs of the pose search against any target's.

    Args:
        skeleton: the source skeleton (normalised coordinates, as the training uses it).
        source_vertices: (V, 3) normalised source vertices.
        source_faces: (F, 3) source faces.
        skinning_width: τ of the bone weights (as :class:`~ncflow.flow.SkinnedField`).
        n_search: Diracs per surface in the discrete search (``coarse``).
        n_refine: Diracs per surface in the refinement (``fine``).
        refine_steps: gradient steps per refinement scale.
        seed: seed of the face sampling.
        skin_aware: bone weights that leave out the bones in front of a sample's skin
            (:func:`~ncflow.flow.bone_weights.surface_skinning_weights`) instead of the field's.
    """

    def __init__(
        self,
        skeleton: Skeleton,
        source_vertices: Float[np.ndarray, "V 3"],
        source_faces: Int[np.ndarray, "F 3"],
        skinning_width: float,
        *,
        n_search: int,
        n_refine: int,
        refine_steps: int,
        seed: int,
        skin_aware: bool = False,
    ):
        self.skeleton, self.seed, self.n_search, self.n_refine = skeleton, seed, n_search, n_refine
        bones = np.asarray(skeleton.bones)
        pos = np.asarray(skeleton.positions, DTYPE)
        weights = jax.jit(surface_skinning_weights if skin_aware else skinning_weights)  # one program each

        def source_diracs(n, offset):
            x = surface_diracs(source_vertices, source_faces, n, seed + offset)
            heads, tails = pos[bones[:, 0]], pos[bones[:, 1]]
            if skin_aware:
                return x, weights(x.centers, x.normals, heads, tails, skinning_width).astype(DTYPE)
            return x, weights(x.centers, heads, tails, skinning_width).astype(DTYPE)

        self.coarse, self.fine = source_diracs(n_search, 2), source_diracs(n_refine, 4)
        self.rest = rest_pose(skeleton, DTYPE)
        self.rest_stack = Pose(np.asarray(self.rest.rotations)[None], np.asarray(self.rest.translation)[None])
        coarse, fine = self.coarse, self.fine
        self.score_fine = jax.jit(lambda poses, active, s, y: scores(skeleton, poses, active, s, fine, y))
        self.score_coarse = jax.jit(lambda poses, active, s, y: scores(skeleton, poses, active, s, coarse, y))
        # a view's facings (its front or its back) are told apart by what the view can show (occlusion)
        self.score_seen = jax.jit(lambda poses, active, s, y: scores(skeleton, poses, active, s, fine, y, True))

        @jax.jit
        def expand(rotations, translations, hyp, hyp_child, j, c, sigma, y, n_real, n_h):
            cand, active = hypotheses(rotations, translations, hyp, hyp_child, j, c, n_real, n_h)
            return cand, scores(skeleton, cand, active, sigma, coarse, y)

        self.expand = expand  # every beam pose × every local rotation pair of joint j and child c, scored
        self.expand_part = jax.jit(lambda *args: expand_part(skeleton, coarse, *args))
        self.expand_chain = jax.jit(lambda *args: expand_chain(skeleton, fine, *args))
        # rows not ``active`` (copies of the rest pose filling the fixed shape) are returned as they are
        self.refine_all = jax.jit(
            lambda poses, active, s, y: jax.lax.map(
                lambda pa: jax.lax.cond(
                    pa[1],
                    lambda p: refine(skeleton, fine, p, s, y, varifold_inner(y, y, s, 0.5), refine_steps),
                    lambda p: p,
                    pa[0],
                ),
                (poses, active),
            )
        )
        self.pose_joints = jax.jit(jax.vmap(lambda p: joint_positions(forward_kinematics(skeleton, p))))
        # beams that differ only by twists the score cannot see are one pose: canonical, the same joints
        self.canonical = jax.jit(jax.vmap(lambda p: unit_swing(skeleton, p)))

    def score_compared(self, poses: Pose, active, sigma: float, y: Varifold):
        """The scores placements are compared by: :attr:`score_seen`'s against a single view, else
        :attr:`score_fine`'s (the same numbers; a target that is no view does not compile the other program).
        """
        score = self.score_seen if float(view_strength(y)) > VIEW_STRENGTH else self.score_fine
        return score(poses, active, sigma, y)

    def target_diracs(self, target_vertices, target_faces) -> tuple[Varifold, Varifold]:
        """The target's Diracs for the search and for the refinement."""
        return (
            surface_diracs(target_vertices, target_faces, self.n_search, self.seed + 3),
            surface_diracs(target_vertices, target_faces, self.n_refine, self.seed + 5),
        )


def unit_swing(skeleton: Skeleton, pose: Pose) -> Pose:
    """The score cannot see the twist of one-child joints (the field moves by the swing alone): dropped,
    and the rotations made unit as the kinematics does (a twist of 180° leaves a zero swing, the identity).
    """
    pose = swing_only(skeleton, pose)
    return Pose(quat_normalize(pose.rotations), pose.translation)
