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
* the surviving poses are refined by gradient descent on the same score (coarse, then finer σ) and the
  best one initialises the field's pose (and the per-step pose fit); the rest pose is kept when
  nothing explains the target better.

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
from scipy.spatial.transform import Rotation

from ncflow.flow.skinning import skinning_weights, swing_only
from ncflow.match.placement import surface_diracs
from ncflow.measures.varifold import Varifold, varifold_inner
from ncflow.skeleton import Skeleton
from ncflow.skeleton.dualquat import dq_rotation, dq_translation, quat_mul, quat_to_matrix
from ncflow.skeleton.kinematics import Pose, bone_motions, rest_pose


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


def _bend_axes(skeleton: Skeleton, joint: int):
    children = np.flatnonzero(np.asarray(skeleton.parents) == joint)
    pos = np.asarray(skeleton.positions)
    d = pos[children].mean(0) - pos[joint]
    if np.linalg.norm(d) < 1e-6 * max(np.linalg.norm(pos[children[0]] - pos[joint]), 1e-12):
        d = pos[children[0]] - pos[joint]  # children on opposite sides (a pelvis): the first child's bone
    a = d / max(np.linalg.norm(d), 1e-12)
    u = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    return a, u, np.cross(a, u)


_BENDS = (45, -45, 90, -90, 135, -135, 180)


def joint_hypotheses(skeleton: Skeleton, joint: int) -> Float[np.ndarray, "H 4"]:
    """Local rotations (w, x, y, z) tried at ``joint``: the identity first, then bends of ±45°, ±90°,
    ±135° and 180° about the two axes across the mean direction of its child bones and twists of
    ±90° and 180° about it.
    """
    a, u, v = _bend_axes(skeleton, joint)
    rotvecs = [np.zeros(3)]
    for axis in (u, v):
        for deg in _BENDS:
            rotvecs.append(np.radians(deg) * axis)
    for deg in (90, -90, 180):
        rotvecs.append(np.radians(deg) * a)
    return Rotation.from_rotvec(np.asarray(rotvecs)).as_quat(scalar_first=True)


def chain_hypotheses(skeleton: Skeleton, joint: int) -> tuple[Float[np.ndarray, "H 4"], Float[np.ndarray, "H 4"], int]:
    """Pairs of local rotations for ``joint`` and the next joint down its chain, and that joint.

    A bend that only pays off together with the next one — a hip flexed by 90° with the knee bent
    back (a crouch), a finger's first joint curled with the second (a fist) — scores worse alone
    than no bend and falls out of the beam. So when ``joint`` has one child that itself moves a bone,
    each bend of ±45°, ±90° and ±135° of ``joint`` is also tried with the child bent by the same
    angle, about the same axis, in the opposite (a Z) and in the same sense (a C). Returns
    (H, 4) rotations of ``joint`` (:func:`joint_hypotheses` first), (H, 4) of the child (identity
    where it does not move) and the child's index (``joint`` itself when there is no such child).
    """
    parents = np.asarray(skeleton.parents)
    single = joint_hypotheses(skeleton, joint)
    children = np.flatnonzero(parents == joint)
    ident = np.tile([1.0, 0.0, 0.0, 0.0], (single.shape[0], 1))
    if children.size != 1 or not np.any(parents == children[0]):
        return single, ident, joint
    _, u, v = _bend_axes(skeleton, joint)
    first, second = [], []
    for axis in (u, v):
        for deg in _BENDS[:-1]:
            for sense in (-1, 1):
                first.append(np.radians(deg) * axis)
                second.append(sense * np.radians(deg) * axis)
    q1 = Rotation.from_rotvec(np.asarray(first)).as_quat(scalar_first=True)
    q2 = Rotation.from_rotvec(np.asarray(second)).as_quat(scalar_first=True)
    return np.concatenate([single, q1]), np.concatenate([ident, q2]), int(children[0])


def _skinned(skeleton, weights, x: Varifold, pose: Pose) -> Varifold:
    m = bone_motions(skeleton, swing_only(skeleton, pose), jnp.asarray(1.0, pose.rotations.dtype))
    r, c = quat_to_matrix(dq_rotation(m)), dq_translation(m)  # (B, 3, 3), (B, 3)
    centers = jnp.einsum("nb,bij,nj->ni", weights, r, x.centers) + weights @ c
    normals = jnp.einsum("nb,bij,nj->ni", weights, r, x.normals)
    normals = normals / jnp.maximum(jnp.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)
    return Varifold(centers, normals, x.weights)


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
    sigma_search: float = 0.3,
    sigmas_refine: tuple[float, ...] = (0.3, 0.15),
    beam: int = 4,
    refine_steps: int = 100,
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
        sigma_search: kernel scale of the discrete search.
        sigmas_refine: kernel scales of the gradient refinement, in turn.
        beam: number of complete poses kept between joints.
        refine_steps: gradient steps per refinement scale.
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
    pos = jnp.asarray(skeleton.positions, dt)

    def source_diracs(n, offset):
        x = surface_diracs(source_vertices, source_faces, n, seed + offset)
        w = skinning_weights(x.centers, pos[bones[:, 0]], pos[bones[:, 1]], skinning_width).astype(dt)
        return x, w

    src_coarse, src_fine = source_diracs(n_search, 2), source_diracs(n_refine, 4)

    def distance(pose: Pose, sigma, src, y):
        x, w = src
        xs = _skinned(skeleton, w, x, pose)
        yy = varifold_inner(y, y, sigma, 0.5)
        return (varifold_inner(xs, xs, sigma, 0.5) - 2.0 * varifold_inner(xs, y, sigma, 0.5) + yy) / yy

    rest = rest_pose(skeleton, dt)
    # lax.map, not vmap: a batch of blocked kernel sums runs ~6× faster one after the other on CPU
    score_fine = jax.jit(lambda poses, s, y: jax.lax.map(lambda p: distance(p, s, src_fine, y), poses))

    @jax.jit
    def expand(rotations, translations, hyp, hyp_child, j, c, y):
        """Every beam pose × every local rotation pair of joint j and its child c, and their scores."""
        nb, nh = rotations.shape[0], hyp.shape[0]
        rot = jnp.repeat(rotations, nh, axis=0)
        rot = rot.at[:, j].set(quat_mul(rot[:, j], jnp.tile(hyp, (nb, 1))))
        rot = rot.at[:, c].set(quat_mul(rot[:, c], jnp.tile(hyp_child, (nb, 1))))
        cand = Pose(rot, jnp.repeat(translations, nh, axis=0))
        return cand, jax.lax.map(lambda p: distance(p, sigma_search, src_coarse, y), cand)

    opt = optax.adam(0.01)

    def refine(pose: Pose, sigma, y):
        state = opt.init(pose)

        def body(carry, _):
            p, st = carry
            g = jax.grad(lambda q: distance(q, sigma, src_fine, y))(p)
            u, st = opt.update(g, st, p)
            p = optax.apply_updates(p, u)
            return (Pose(p.rotations / jnp.linalg.norm(p.rotations, axis=-1, keepdims=True), p.translation), st), None

        return jax.lax.scan(body, (pose, state), None, length=refine_steps)[0][0]

    refine_all = jax.jit(lambda poses, s, y: jax.lax.map(lambda p: refine(p, s, y), poses))
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
        return jnp.asarray(np.vstack([q, np.tile([1.0, 0.0, 0.0, 0.0], (n_hyp - q.shape[0], 1))]), dt)

    searched = [(j, h.shape[0], padded(h), padded(hc), c) for j, h, hc, c in searched]
    results = []
    for target_vertices in target_candidates:
        y_coarse = surface_diracs(target_vertices, target_faces, n_search, seed + 3)
        y_fine = surface_diracs(target_vertices, target_faces, n_refine, seed + 5)
        beams = Pose(jnp.repeat(rest.rotations[None], beam, 0), jnp.repeat(rest.translation[None], beam, 0))
        n_real, n_scored = 1, 1
        for j, n_h, hyp, hyp_child, c in searched:
            cand, s = expand(beams.rotations, beams.translation, hyp, hyp_child, j, c, y_coarse)
            s = np.array(s, np.float64).reshape(beam, n_hyp)
            s[n_real:], s[:, n_h:] = np.inf, np.inf
            s = s.ravel()
            n_scored += n_real * n_h
            keep = np.argsort(s, kind="stable")[: min(beam, n_real * n_h)]
            keep = np.concatenate([keep, np.repeat(keep[:1], beam - keep.size)])  # pad with the best
            n_real = min(beam, n_real * n_h)
            beams = Pose(cand.rotations[keep], cand.translation[keep])
        candidates = Pose(
            jnp.concatenate([beams.rotations, rest.rotations[None]]),
            jnp.concatenate([beams.translation, rest.translation[None]]),
        )
        for sigma in sigmas_refine:
            candidates = refine_all(candidates, float(sigma), y_fine)
        final = np.array(score_fine(candidates, float(sigmas_refine[-1]), y_fine), np.float64)
        final[n_real:beam] = np.inf  # copies
        rests = Pose(jnp.repeat(rest.rotations[None], beam + 1, 0), jnp.repeat(rest.translation[None], beam + 1, 0))
        rest_score = float(np.asarray(score_fine(rests, float(sigmas_refine[-1]), y_fine))[0])
        best = int(np.argmin(final))
        if final[best] >= rest_score:
            results.append(PoseSearchResult(rest, rest_score, rest_score, n_scored))
            continue
        # the score cannot see the twist of one-child joints (the field moves by the swing alone): drop it
        pose = swing_only(skeleton, Pose(candidates.rotations[best], candidates.translation[best]))
        rot = pose.rotations / jnp.linalg.norm(pose.rotations, axis=-1, keepdims=True)
        results.append(PoseSearchResult(Pose(rot, pose.translation), float(final[best]), rest_score, n_scored))
    return results
