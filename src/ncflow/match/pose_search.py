"""Articulated initialisation: search the skeleton pose that best explains the target (issue 16; beyond
the paper, which starts every run at the rest pose).

The optimisation follows the local gradient of a kernel data term whose pull vanishes for parts
further apart than σ; a finger that must straighten by 90° or a leg that must swing forward is left
where the first stage cannot see it. Before the flow trains, this module searches (not only
descends) for the pose of the source skeleton whose skinned source best matches the target:

* the source is summarised by area-weighted oriented Diracs (:func:`~ncflow.match.placement.surface_diracs`),
  each carried by the skeleton-driven field's bone weights w_b (the same softmax of distances to the
  bones as :class:`~ncflow.flow.SkinnedField`): for a pose, a Dirac moves to Σ_b w_b M_b(x) and its
  normal to the normalised Σ_b w_b R_b n, M_b the bone's rigid motion from rest
  (:func:`~ncflow.skeleton.kinematics.bone_motions` at t = 1, twist of one-child joints removed as the field
  does);
* the score of a pose is the normalised Varifold distance to the target (the data term of the first stage);
* coarse to fine down the kinematic tree (root first, then each depth level), every joint that moves a
  bone tries a set of local rotations — bends of ±45°, ±90°, ±135° and 180° about the two axes
  across its bone, twists of ±90° and 180° about it, and no change — on top of each of the best
  ``beam`` poses found so far; all hypotheses of a joint are scored in one jitted batch and the best
  ``beam`` complete poses are kept, so a choice that only pays off once a later joint has moved
  (left and right limbs exchanged, a finger bent back) survives until it does;
* a joint's hypotheses move only the Diracs weighted on the bones below it (a finger's, a leg's:
  :func:`moving_diracs`), so the pairs between the others, the same for all its hypotheses, are
  summed once per beam pose and each hypothesis adds the pairs of the moved ones: O(|M|·N) instead
  of O(N²) a hypothesis (every joint's set padded to one size: one compiled program);
* limbs hanging from the same joint with the same shape (left and right legs, fingers;
  :func:`~ncflow.match.pose_hypotheses.exchangeable_limbs`) are also tried exchanged, each taking
  the other's bone directions (:func:`~ncflow.match.pose_hypotheses.exchanged`), before their own
  joints are searched: the legs of a walking animal swap between two poses, and bending one leg
  while the other is still in its place scores worse than leaving it;
* three such searches run — at σ = 0.3 without and with the exchanges, and at σ = 0.15, where
  fingers or legs side by side no longer blur into one — and their distinct survivors are refined
  by gradient descent on the same score: all of them at the coarse σ, then only the best few that
  are still distinct (scored at the finer σ; several survivors often end in one pose) at the finer
  σ — poses compared without the twists the field drops, which would make one pose look like
  several; the best one initialises the field's pose (and the per-step pose fit); the rest pose is kept
  when nothing explains the target better.

The ``paper`` preset (no skeleton-driven field) does not use it: there the pose only enters the
constraints, which are refitted at every step.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import Float, Int

from ncflow.flow.skinning import skinning_weights, swing_only
from ncflow.match.placement import surface_diracs
from ncflow.match.pose_hypotheses import chain_hypotheses, exchangeable_limbs, exchanged, world_frames
from ncflow.measures.varifold import Varifold, varifold_inner
from ncflow.skeleton import Skeleton
from ncflow.skeleton.dualquat import dq_rotation, dq_translation, quat_mul, quat_normalize, quat_to_matrix
from ncflow.skeleton.kinematics import Pose, bone_motions, forward_kinematics, joint_positions, rest_pose


@dataclasses.dataclass(frozen=True)
class PoseSearchResult:
    """The pose found and how much it explains.

    Attributes:
        pose: the best pose (rotations (J, 4) (w, x, y, z), translation (3,)), float32.
        score: its normalised data term d(X(pose), Y) / ⟨Y, Y⟩ at the finest σ (lower is better).
        rest_score: the same for the rest pose.
        hypotheses: number of poses scored.
    """

    pose: Pose
    score: float
    rest_score: float
    hypotheses: int

    def to_dict(self) -> dict:
        """JSON-ready summary (per-joint rotation angles in degrees)."""
        q = np.asarray(self.pose.rotations, np.float64)
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
        angles = np.degrees(2.0 * np.arccos(np.clip(np.abs(q[:, 0]), 0.0, 1.0)))
        return {
            "score": float(self.score),
            "rest_score": float(self.rest_score),
            "hypotheses": int(self.hypotheses),
            "joint_angles_degrees": angles.round(2).tolist(),
            "translation": np.asarray(self.pose.translation, np.float64).tolist(),
        }


def best_distinct(
    scores: Float[np.ndarray, " N"], joints: Float[np.ndarray, "N J 3"], count: int, distinct: float
) -> list[int]:
    """Indices of at most ``count`` poses, lowest finite score first, skipping any whose joints all
    lie within ``distinct`` of a pose already taken (the same pose found twice).
    """
    picked: list[int] = []
    for i in np.argsort(scores, kind="stable"):
        if np.isfinite(scores[i]) and len(picked) < count:
            if all(np.abs(joints[i] - joints[k]).max() > distinct for k in picked):
                picked.append(int(i))
    return picked


def _host(pose: Pose) -> Pose:
    """The pose in NumPy: the bookkeeping between the compiled programs (picking, stacking poses) runs
    on the host. With jax.numpy each operation and shape is one more program to compile, and on a cold
    run each waits seconds behind the training step compiling in its thread (:mod:`ncflow.jit.ahead`).
    """
    return jax.tree.map(np.asarray, pose)


def _picked(pose: Pose, rows) -> Pose:
    return jax.tree.map(lambda a: np.asarray(a)[rows], pose)


def _stacked(*poses: Pose) -> Pose:
    return jax.tree.map(lambda *a: np.concatenate([np.asarray(x) for x in a]), *poses)


def _completed(first: Pose, pooled: Pose) -> Pose:
    """``first``, then the rows of ``pooled`` past its length: one scorer serves both stacks."""
    n = first.rotations.shape[0]
    return _stacked(first, _picked(pooled, slice(n, None)))


def moving_diracs(skeleton: Skeleton, weights: Float[np.ndarray, "N B"], joint: int, tol: float) -> np.ndarray:
    """Indices of the Diracs that a rotation of ``joint`` moves by more than ``tol`` × the motion of
    its bones: those whose bone weights on the bones hanging from ``joint`` or below it sum above ``tol``.
    """
    parents = np.asarray(skeleton.parents)
    below = np.zeros(skeleton.n_joints, bool)
    below[joint] = True
    for level in skeleton.levels:
        for k in level:
            below[k] |= parents[k] >= 0 and below[parents[k]]
    return np.flatnonzero(np.asarray(weights)[:, below[parents[1:]]].sum(1) > tol)


def _joined(*parts: tuple[Varifold, float]) -> Varifold:
    """One measure of several, each weighted by its factor: ⟨X, Σ_k f_k Y_k⟩ is one kernel sum."""
    return Varifold(
        jnp.concatenate([p.centers for p, _ in parts]),
        jnp.concatenate([p.normals for p, _ in parts]),
        jnp.concatenate([f * p.weights for p, f in parts]),
    )


def _skinned(skeleton, weights, x: Varifold, pose: Pose) -> Varifold:
    m = bone_motions(skeleton, swing_only(skeleton, pose), jnp.asarray(1.0, pose.rotations.dtype))
    r, c = quat_to_matrix(dq_rotation(m)), dq_translation(m)  # (B, 3, 3), (B, 3)
    centers = jnp.einsum("nb,bij,nj->ni", weights, r, x.centers) + weights @ c
    normals = jnp.einsum("nb,bij,nj->ni", weights, r, x.normals)
    normals = normals / jnp.maximum(jnp.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)
    return Varifold(centers, normals, x.weights)


def _exchange_step(skeleton, beams: Pose, n_real: int, limbs, sigma, score, y, min_move: float = 0.25):
    """Each real beam pose and its copy with ``limbs`` exchanged
    (:func:`~ncflow.match.pose_hypotheses.exchanged`), scored; the best ``beam`` kept. A copy whose
    joints move by less than ``min_move`` × the limbs' length (two straight fingers side by side) is
    not a different hypothesis and is not kept. Returns the new beam, its number of distinct poses
    and the number of poses scored.
    """
    beam = beams.rotations.shape[0]
    a, b = limbs
    rot = np.asarray(beams.rotations, np.float64)
    length = skeleton.bone_lengths[np.concatenate([a[1:], b[1:]]) - 1].sum() / 2.0
    swapped, distinct = rot.copy(), np.zeros(beam, bool)
    for i in range(n_real):
        swapped[i] = exchanged(skeleton, rot[i], a, b)
        move = np.linalg.norm(world_frames(skeleton, swapped[i])[1] - world_frames(skeleton, rot[i])[1], axis=1).max()
        distinct[i] = move >= min_move * length
    if not distinct.any():
        return beams, n_real, 0
    beams = _host(beams)
    cand = _stacked(beams, Pose(swapped.astype(beams.rotations.dtype), beams.translation))
    s = np.array(score(cand, np.concatenate([np.arange(beam) < n_real, distinct]), sigma, y), np.float64)
    n_new = n_real + int(distinct.sum())
    keep = np.argsort(s, kind="stable")[: min(beam, n_new)]
    keep = np.concatenate([keep, np.repeat(keep[:1], beam - keep.size)])
    return _picked(cand, keep), min(beam, n_new), int(distinct.sum())


def search_pose(
    skeleton: Skeleton,
    source_vertices: Float[np.ndarray, "V 3"],
    source_faces: Int[np.ndarray, "F 3"],
    target_vertices: Float[np.ndarray, "W 3"],
    target_faces: Int[np.ndarray, "G 3"],
    *,
    skinning_width: float,
    **options,
) -> PoseSearchResult:
    """The pose of ``skeleton`` whose skinned source best matches the target (see the module docstring).

    Args:
        skeleton: the source skeleton (normalised coordinates, as the training uses it).
        source_vertices: (V, 3) normalised source vertices.
        source_faces: (F, 3) source faces.
        target_vertices: (W, 3) normalised, placed target vertices.
        target_faces: (G, 3) target faces.
        skinning_width: τ of the bone weights (as :class:`~ncflow.flow.SkinnedField`).
        **options: as :func:`search_poses`.
    """
    return search_poses(
        skeleton,
        source_vertices,
        source_faces,
        [target_vertices],
        target_faces,
        skinning_width=skinning_width,
        **options,
    )[0]


def search_poses(
    skeleton: Skeleton,
    source_vertices: Float[np.ndarray, "V 3"],
    source_faces: Int[np.ndarray, "F 3"],
    target_candidates: Sequence[Float[np.ndarray, "W 3"]],
    target_faces: Int[np.ndarray, "G 3"],
    *,
    skinning_width: float,
    searches: tuple[tuple[float, bool], ...] = ((0.3, False), (0.3, True), (0.15, False)),
    sigmas_refine: tuple[float, ...] = (0.3, 0.15),
    beam: int = 4,
    refined: int = 8,
    refined_fine: int = 3,
    distinct: float = 0.02,
    refine_steps: int = 100,
    moving_tol: float = 1e-3,
    n_search: int = 600,
    n_refine: int = 1200,
    seed: int = 0,
    discrete: bool = True,
    root_turns: bool = False,
) -> list[PoseSearchResult]:
    """:func:`search_pose` for several placements of one target (the same faces, vertices moved
    rigidly), compiled once; the scores are comparable (the same Diracs, moved, and ⟨Y, Y⟩ is
    invariant under rigid motions), so the lowest tells the placement that explains the target best.

    Args:
        skeleton: the source skeleton (normalised coordinates, as the training uses it).
        source_vertices: (V, 3) normalised source vertices.
        source_faces: (F, 3) source faces.
        target_candidates: C arrays (W, 3): the normalised target, placed in each candidate way.
        target_faces: (G, 3) target faces.
        skinning_width: τ of the bone weights (as :class:`~ncflow.flow.SkinnedField`).
        searches: the discrete searches run, each (kernel scale, whether limb exchanges are tried);
            their beams are refined together and the best refined pose wins.
        sigmas_refine: kernel scales of the gradient refinement, in turn.
        beam: number of complete poses kept between joints.
        refined: number of distinct poses of the pooled beams refined (the rest pose besides).
        refined_fine: number of distinct poses refined further at each finer scale of
            ``sigmas_refine``, best scored at that scale first (the others keep their pose).
        distinct: two poses whose joints all lie within this distance are one.
        refine_steps: gradient steps per refinement scale.
        moving_tol: in the discrete search, a Dirac whose bone weights below the joint tried sum to
            at most this is held where the beam pose puts it (:func:`moving_diracs`).
        n_search: Diracs per surface in the discrete search.
        n_refine: Diracs per surface in the refinement.
        seed: seed of the face sampling.
        discrete: run the discrete search (False: gradient descent from the rest pose alone, the
            baseline the search is measured against).
        root_turns: try the local rotations at the root as well (off: the global orientation is
            the placement's, :func:`~ncflow.match.placement.placement_candidates`; the refinement
            still turns the root a little).
    """
    dt = jnp.float32
    bones = np.asarray(skeleton.bones)
    pos = np.asarray(skeleton.positions, dt)
    weights = jax.jit(skinning_weights)  # one program, not one per operation and size

    def source_diracs(n, offset):
        x = surface_diracs(source_vertices, source_faces, n, seed + offset)
        return x, weights(x.centers, pos[bones[:, 0]], pos[bones[:, 1]], skinning_width).astype(dt)

    src_coarse, src_fine = source_diracs(n_search, 2), source_diracs(n_refine, 4)

    def distance(pose: Pose, sigma, src, y, yy):
        x, w = src
        xs = _skinned(skeleton, w, x, pose)
        return (varifold_inner(xs, xs, sigma, 0.5) - 2.0 * varifold_inner(xs, y, sigma, 0.5) + yy) / yy

    rest = rest_pose(skeleton, dt)
    rest_stack = Pose(np.asarray(rest.rotations)[None], np.asarray(rest.translation)[None])

    def scores(poses: Pose, active, sigma, src, y):
        """Each pose's distance, +inf without computing it where ``active`` is False (padding rows:
        the shapes are fixed so that one program serves every joint and placement). lax.map, not
        vmap: a batch of blocked kernel sums runs ~6× faster one after the other on CPU, and the
        cond then skips the padding's work.
        """
        inf, yy = jnp.asarray(jnp.inf, dt), varifold_inner(y, y, sigma, 0.5)
        return jax.lax.map(
            lambda pa: jax.lax.cond(pa[1], lambda p: distance(p, sigma, src, y, yy), lambda p: inf, pa[0]),
            (poses, active),
        )

    score_fine = jax.jit(lambda poses, active, s, y: scores(poses, active, s, src_fine, y))
    score_coarse = jax.jit(lambda poses, active, s, y: scores(poses, active, s, src_coarse, y))

    def hypotheses(rotations, translations, hyp, hyp_child, j, c, n_real, n_h):
        """Every beam pose × every local rotation pair of joint j and its child c, and which are real."""
        nb, nh = rotations.shape[0], hyp.shape[0]
        rot = jnp.repeat(rotations, nh, axis=0)
        rot = rot.at[:, j].set(quat_mul(rot[:, j], jnp.tile(hyp, (nb, 1))))
        rot = rot.at[:, c].set(quat_mul(rot[:, c], jnp.tile(hyp_child, (nb, 1))))
        active = jnp.repeat(jnp.arange(nb) < n_real, nh) & jnp.tile(jnp.arange(nh) < n_h, nb)
        return Pose(rot, jnp.repeat(translations, nh, axis=0)), active

    @jax.jit
    def expand(rotations, translations, hyp, hyp_child, j, c, sigma, y, n_real, n_h):
        """Every beam pose × every local rotation pair of joint j and its child c, and their scores
        (+inf, not computed, past the ``n_real`` real beam rows and the ``n_h`` real hypotheses).
        """
        cand, active = hypotheses(rotations, translations, hyp, hyp_child, j, c, n_real, n_h)
        return cand, scores(cand, active, sigma, src_coarse, y)

    @jax.jit
    def expand_part(rotations, translations, hyp, hyp_child, j, c, sigma, y, n_real, n_h, moving, mask):
        """:func:`expand` where joint j moves only the Diracs ``moving`` (``mask`` 0 on padding): each
        beam pose's other Diracs S are posed once, and a hypothesis adds the moved ones M to its
        distance, ⟨S,S⟩ − 2⟨S,Y⟩ + ⟨M, 2S − 2Y + M⟩ + ⟨Y,Y⟩ (the same sum without the pairs of S that
        do not change): O(|M|·N) a hypothesis instead of O(N²).
        """
        x, w = src_coarse
        nb, nh = rotations.shape[0], hyp.shape[0]
        cand, active = hypotheses(rotations, translations, hyp, hyp_child, j, c, n_real, n_h)
        yy = varifold_inner(y, y, sigma, 0.5)
        rest_w = x.weights.at[moving].set(0.0)
        part, part_w = Varifold(x.centers[moving], x.normals[moving], x.weights[moving] * mask), w[moving]

        def beam_static(pose):
            xs = _skinned(skeleton, w, x, pose)
            xs = Varifold(xs.centers, xs.normals, rest_w)
            const = varifold_inner(xs, _joined((xs, 1.0), (y, -2.0)), sigma, 0.5)
            return xs.centers, xs.normals, const

        def nothing(pose):
            return jnp.zeros_like(x.centers), jnp.zeros_like(x.normals), jnp.zeros((), dt)

        centers, normals, const = jax.lax.map(
            lambda pa: jax.lax.cond(pa[1], beam_static, nothing, pa[0]),
            (Pose(rotations, translations), jnp.arange(nb) < n_real),
        )

        def one(mb):
            pose, b = mb
            m = _skinned(skeleton, part_w, part, pose)
            others = _joined((Varifold(centers[b], normals[b], rest_w), 2.0), (y, -2.0), (m, 1.0))
            return (const[b] + varifold_inner(m, others, sigma, 0.5) + yy) / yy

        inf = jnp.asarray(jnp.inf, dt)
        return cand, jax.lax.map(
            lambda pa: jax.lax.cond(pa[1], one, lambda mb: inf, pa[0]),
            ((cand, jnp.arange(nb * nh) // nh), active),
        )

    opt = optax.adam(0.01)

    def refine(pose: Pose, sigma, y, yy):
        state = opt.init(pose)

        def body(carry, _):
            p, st = carry
            g = jax.grad(lambda q: distance(q, sigma, src_fine, y, yy))(p)
            u, st = opt.update(g, st, p)
            p = optax.apply_updates(p, u)
            return (Pose(p.rotations / jnp.linalg.norm(p.rotations, axis=-1, keepdims=True), p.translation), st), None

        return jax.lax.scan(body, (pose, state), None, length=refine_steps)[0][0]

    # rows not ``active`` (copies of the rest pose filling the fixed shape) are returned as they are
    refine_all = jax.jit(
        lambda poses, active, s, y: jax.lax.map(
            lambda pa: jax.lax.cond(pa[1], lambda p: refine(p, s, y, varifold_inner(y, y, s, 0.5)), lambda p: p, pa[0]),
            (poses, active),
        )
    )
    has_child = np.bincount(np.asarray(skeleton.parents)[1:], minlength=skeleton.n_joints) > 0
    searched = [
        (int(j), *chain_hypotheses(skeleton, int(j)))
        for level in (skeleton.levels if discrete else ())
        for j in level
        if has_child[j] and (skeleton.parents[j] >= 0 or root_turns)
    ]
    # shapes held constant (beam rows, n_hyp hypotheses; padding scored +inf) so that every joint and
    # every candidate placement runs one compiled expand / refine / score
    n_hyp = max([h.shape[0] for _, h, _, _ in searched] or [1])

    def padded(q):
        return jax.device_put(np.vstack([q, np.tile([1.0, 0.0, 0.0, 0.0], (n_hyp - q.shape[0], 1))]).astype(dt))

    bone_weights = np.asarray(src_coarse[1])  # read back once, not once per joint
    moving = {j: moving_diracs(skeleton, bone_weights, j, moving_tol) for j, *_ in searched}
    few = [m.size for m in moving.values() if 0 < m.size <= src_coarse[0].size // 2]
    size = -(-max(few, default=0) // 32) * 32  # one size for all: one compiled program

    def part(j):
        """The Diracs joint j moves, padded to ``size``, or None where they are over half of all
        (the full sum then costs as much).
        """
        idx = moving[j]
        if not 0 < idx.size <= size:
            return None
        return jax.device_put((np.resize(idx, size).astype(np.int32), (np.arange(size) < idx.size).astype(dt)))

    searched = [(j, h.shape[0], padded(h), padded(hc), c, part(j)) for j, h, hc, c in searched]
    # limb exchanges go before the first joint of the limbs' level (their parent posed, they not yet)
    depth = skeleton.depth
    limbs = exchangeable_limbs(skeleton) if discrete else []
    plan = []
    for step in searched:
        plan += [limb for limb in limbs if depth[limb[0][0]] == depth[step[0]] and not any(limb is q for q in plan)]
        plan.append(step)

    def beam_search(sigma, exchange, y_coarse):
        """The best ``beam`` poses down the tree (rows past the distinct count repeat the best)."""
        beams = _picked(rest_stack, np.zeros(beam, int))
        n_real, n_scored = 1, 0
        for step in plan:
            if len(step) == 2:  # a limb exchange: each beam pose with and without it
                if exchange:
                    beams, n_real, n_new = _exchange_step(skeleton, beams, n_real, step, sigma, score_coarse, y_coarse)
                    n_scored += n_new
                continue
            j, n_h, hyp, hyp_child, c, moved = step
            args = (beams.rotations, beams.translation, hyp, hyp_child, j, c, sigma, y_coarse, n_real, n_h)
            cand, s = expand(*args) if moved is None else expand_part(*args, *moved)
            s = np.array(s, np.float64)
            n_scored += n_real * n_h
            keep = np.argsort(s, kind="stable")[: min(beam, n_real * n_h)]
            keep = np.concatenate([keep, np.repeat(keep[:1], beam - keep.size)])  # pad with the best
            n_real = min(beam, n_real * n_h)
            beams = _picked(cand, keep)
        return beams, n_real, n_scored

    def pool(found):
        """All searches' beams and the rest pose in one stack, and which rows are real."""
        pooled = _stacked(*[b for b, _, _ in found], rest_stack)
        return pooled, np.concatenate([np.arange(beam) < n for _, n, _ in found] + [[True]])

    pose_joints = jax.jit(jax.vmap(lambda p: joint_positions(forward_kinematics(skeleton, p))))

    def unit_swing(pose: Pose) -> Pose:
        """The score cannot see the twist of one-child joints (the field moves by the swing alone):
        dropped, and the rotations made unit as the kinematics does (a twist of 180° leaves a zero
        swing, the identity).
        """
        pose = swing_only(skeleton, pose)
        return Pose(quat_normalize(pose.rotations), pose.translation)

    # beams that differ only by such twists are one pose: the same score and, canonical, the same joints
    canonical = jax.jit(jax.vmap(unit_swing))

    n_refined = min(refined, len(searches) * beam)
    results = []
    for target_vertices in target_candidates:
        y_coarse = surface_diracs(target_vertices, target_faces, n_search, seed + 3)
        y_fine = surface_diracs(target_vertices, target_faces, n_refine, seed + 5)
        found = [beam_search(float(sigma), bool(exchange), y_coarse) for sigma, exchange in searches]
        n_scored = 1 + sum(f[2] for f in found)
        pooled, valid = pool(found)
        pooled = _host(canonical(pooled))
        # the searches often agree: refine at most ``refined`` distinct poses, best scored first
        first = np.array(score_fine(pooled, valid, float(sigmas_refine[0]), y_fine), np.float64)
        picked = best_distinct(first[:-1], np.asarray(pose_joints(pooled))[:-1], n_refined, distinct)
        rows = np.array(picked + [pooled.rotations.shape[0] - 1] * (n_refined + 1 - len(picked)))
        real = np.arange(rows.size) < len(picked)
        real[-1] = True  # the rest pose, refined too; the copies before it fill the fixed shape
        only = np.zeros(valid.size, bool)
        scored = np.concatenate([real, only[rows.size :]])
        candidates = _picked(pooled, rows)
        active = real
        for level, sigma in enumerate(sigmas_refine):
            if level:  # finer scales: the best few that are still distinct
                shaped = _completed(candidates, pooled)
                s = np.array(score_fine(shaped, scored, float(sigma), y_fine), np.float64)[: rows.size]
                joints = np.asarray(pose_joints(shaped))[: rows.size]
                active = np.isin(np.arange(rows.size), best_distinct(s, joints, refined_fine, distinct))
            candidates = refine_all(candidates, active, float(sigma), y_fine)
        padded = _completed(candidates, pooled)
        final = np.array(score_fine(padded, scored, float(sigmas_refine[-1]), y_fine), np.float64)
        rests = _picked(rest_stack, np.zeros(valid.size, int))
        only[0] = True
        rest_score = float(np.asarray(score_fine(rests, only, float(sigmas_refine[-1]), y_fine))[0])
        candidates = padded
        best = int(np.argmin(final))
        if final[best] >= rest_score:
            results.append(PoseSearchResult(rest, rest_score, rest_score, n_scored))
            continue
        pose = jax.device_put(_picked(canonical(_picked(candidates, slice(best, best + 1))), 0))
        results.append(PoseSearchResult(pose, float(final[best]), rest_score, n_scored))
    return results
