"""Articulated initialisation: search the skeleton pose that best explains the target (beyond the paper,
which starts every run at the rest pose).

The optimisation follows the local gradient of a kernel data term whose pull vanishes for parts
further apart than σ; a finger that must straighten by 90° or a leg that must swing forward is left
where the first stage cannot see it. Before the flow trains, this module searches (not only
descends) for the pose of the source skeleton whose skinned source best matches the target:

* the score of a pose is the normalised Varifold distance from the source's Diracs, moved by the
  skeleton-driven field's bone weights, to the target's (:mod:`ncflow.matcher.pose_scorer`, which holds
  the compiled programs);
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
  :func:`~ncflow.matcher.pose_hypotheses.exchangeable_limbs`) are also tried exchanged, each taking
  the other's bone directions (:func:`~ncflow.matcher.pose_hypotheses.exchanged`), before their own
  joints are searched: the legs of a walking animal swap between two poses, and bending one leg
  while the other is still in its place scores worse than leaving it;
* three such searches run — at σ = 0.3 without and with the exchanges, and at σ = 0.15, where
  fingers or legs side by side no longer blur into one — and their distinct survivors are refined
  by gradient descent on the same score: all of them at the coarse σ, then only the best few that
  are still distinct (scored at the finer σ; several survivors often end in one pose) at the finer
  σ — poses compared without the twists the field drops, which would make one pose look like
  several; the best one initialises the field's pose (and the per-step pose fit); the rest pose is kept
  when nothing explains the target better;
* against a single view, the score a search returns (placements are compared by it) leaves out what the
  view hides (:func:`seen_scores`): a view of a person's back is told from one of their front by it.
* with ``exchange_fingers`` (off by default), the refined pose's neighbouring fingers are tried exchanged at
  the fine σ, the one-to-one assignment of fingers (:mod:`ncflow.matcher.pose_exchange`).

:func:`search_poses` runs a :func:`search_plan` with :func:`beam_search` per search and refines the pooled
beams (:func:`refine_pooled`).

Off by default (docs/tuning.md): ``chain_sigma`` adds :func:`search_chains`, each finger or limb re-posed
from a grid of planar curls with the others held at a finer σ. ``skin_aware`` gives the source's samples bone
weights that leave out the bones in front of their skin; the matcher turns it on where the training's
weights do the same (``flow.skinning_weights`` "surface": a source whose limbs touch).

The ``paper`` preset (no skeleton-driven field) does not use it: there the pose only enters the
constraints, which are refitted at every step.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import numpy as np
from jaxtyping import Float, Int

from ncflow.matcher.pose_exchange import exchange_step
from ncflow.matcher.pose_hypotheses import (
    chain_grid,
    chain_hypotheses,
    exchange_moves,
    exchangeable_limbs,
    exchanged,
    limb_chains,
    world_frames,
)
from ncflow.matcher.pose_scorer import DTYPE, PoseScorer
from ncflow.matcher.pose_stacks import completed, host, picked, stacked
from ncflow.skeleton import Skeleton
from ncflow.skeleton.kinematics import Pose


@dataclasses.dataclass(frozen=True)
class PoseSearchResult:
    """The pose found and how much it explains.

    Attributes:
        pose: the best pose (rotations (J, 4) (w, x, y, z), translation (3,)), float32.
        score: its normalised data term d(X(pose), Y) / ⟨Y, Y⟩ at the finest σ (lower is better; against a
            single view, what the view hides left out: :func:`seen_scores`).
        rest_score: the same for the rest pose.
        hypotheses: number of poses scored.
    """

    pose: Pose
    score: float
    rest_score: float
    hypotheses: int

    def pose_stack(self) -> Pose:
        """The pose as a stack of one."""
        return jax.tree.map(lambda a: np.asarray(a)[None], self.pose)

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
    chosen: list[int] = []
    for i in np.argsort(scores, kind="stable"):
        if np.isfinite(scores[i]) and len(chosen) < count:
            if all(np.abs(joints[i] - joints[k]).max() > distinct for k in chosen):
                chosen.append(int(i))
    return chosen


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


def _padded_diracs(indices: np.ndarray, size: int):
    """Dirac indices repeated to ``size`` and their mask (1 on the real ones), on the device: one shape,
    one compiled program, for every joint or chain.
    """
    return jax.device_put((np.resize(indices, size).astype(np.int32), (np.arange(size) < indices.size).astype(DTYPE)))


def _padded_size(counts) -> int:
    """The largest count rounded up to a multiple of 32 (0 when none)."""
    return -(-max(counts, default=0) // 32) * 32


def _exchange_step(skeleton, beams: Pose, n_real: int, limbs, sigma, score, y, min_move: float = 0.25):
    """Each real beam pose and its copy with ``limbs`` exchanged
    (:func:`~ncflow.matcher.pose_hypotheses.exchanged`), scored; the best ``beam`` kept. A copy whose
    joints move by less than ``min_move`` × the limbs' length (two straight fingers side by side) is
    not a different hypothesis and is not kept. Returns the new beam, its number of distinct poses
    and the number of poses scored.
    """
    beam = beams.rotations.shape[0]
    a, b = limbs
    rot = np.asarray(beams.rotations, np.float64)
    swapped, distinct = rot.copy(), np.zeros(beam, bool)
    for i in range(n_real):
        swapped[i] = exchanged(skeleton, rot[i], a, b)
        distinct[i] = exchange_moves(skeleton, world_frames(skeleton, rot[i])[1], swapped[i], a, b, min_move)
    if not distinct.any():
        return beams, n_real, 0
    beams = host(beams)
    cand = stacked(beams, Pose(swapped.astype(beams.rotations.dtype), beams.translation))
    s = np.array(score(cand, np.concatenate([np.arange(beam) < n_real, distinct]), sigma, y), np.float64)
    n_new = n_real + int(distinct.sum())
    keep = np.argsort(s, kind="stable")[: min(beam, n_new)]
    keep = np.concatenate([keep, np.repeat(keep[:1], beam - keep.size)])
    return picked(cand, keep), min(beam, n_new), int(distinct.sum())


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
    chain_sigma: float | None = None,
    skin_aware: bool = False,
    chain_sweeps: int = 2,
    chain_near: float = 0.1,
    exchange_fingers: bool = False,
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
            the placement's, :func:`~ncflow.matcher.placement.placement_candidates`; the refinement
            still turns the root a little).
        chain_sigma: kernel scale of the chain search (:func:`search_chains`) that re-poses each finger
            or limb with the others held (0.1 was measured); None (the default): none. Not adopted: it
            fixes procedural hands' fingers in the search, but see docs/tuning.md.
        skin_aware: the source samples' bone weights leave out the bones in front of their skin
            (:func:`~ncflow.flow.bone_weights.surface_skinning_weights`), as the training's do with
            ``flow.skinning_weights`` "surface" (:func:`ncflow.matcher.place.place` passes it then).
        chain_sweeps: passes of the chain search over the chains.
        chain_near: the chain search runs on the placements whose score is within this share of the best.
        exchange_fingers: try the refined pose's fingers exchanged at the last ``sigmas_refine``
            (:func:`~ncflow.matcher.pose_exchange.exchange_step`).
    """
    scorer = PoseScorer(
        skeleton,
        source_vertices,
        source_faces,
        skinning_width,
        n_search=n_search,
        n_refine=n_refine,
        refine_steps=refine_steps,
        seed=seed,
        skin_aware=skin_aware,
    )
    plan = search_plan(skeleton, scorer, discrete, root_turns, moving_tol)
    n_refined = min(refined, len(searches) * beam)
    results, targets = [], []
    for target_vertices in target_candidates:
        y_coarse, y_fine = scorer.target_diracs(target_vertices, target_faces)
        found = [
            beam_search(scorer, plan, float(sigma), bool(exchange), y_coarse, beam) for sigma, exchange in searches
        ]
        pooled = host(scorer.canonical(stacked(*[b for b, _, _ in found], scorer.rest_stack)))
        valid = np.concatenate([np.arange(beam) < n for _, n, _ in found] + [[True]])
        refining = (sigmas_refine, n_refined, refined_fine, distinct)
        results.append(refine_pooled(scorer, pooled, valid, y_fine, *refining, 1 + sum(f[2] for f in found)))
        if discrete and exchange_fingers:
            results[-1] = _exchange(scorer, results[-1], pooled, valid, y_fine, float(sigmas_refine[-1]))
        targets.append((y_fine, pooled, valid))
    chains = limb_chains(skeleton) if discrete and chain_sigma else []
    if chains:
        best = min(r.score for r in results)
        for i, (y_fine, pooled, valid) in enumerate(targets):
            if results[i].score <= best + chain_near * abs(best):
                stack = (pooled, valid, n_refined + 1, float(sigmas_refine[-1]))
                chain = (chain_sigma, chain_sweeps, moving_tol)
                results[i] = search_chains(scorer, chains, results[i], y_fine, *chain, *stack)
    return results


def _exchange(scorer: PoseScorer, found: PoseSearchResult, pooled: Pose, valid, y_fine, sigma) -> PoseSearchResult:
    """``found`` or, where an exchange of its fingers explains the target better at ``sigma``, that pose."""
    pose, won = exchange_step(scorer, host(found.pose), valid.size, y_fine, sigma)
    if not won:
        return found
    stack = host(scorer.canonical(picked(pose, None)))
    score, rest_score = seen_scores(scorer, stack, pooled, valid.size, y_fine, sigma)
    return PoseSearchResult(jax.device_put(picked(stack, 0)), score, rest_score, found.hypotheses)


def search_chains(
    scorer: PoseScorer,
    chains: list[np.ndarray],
    found: PoseSearchResult,
    y_fine,
    sigma: float,
    sweeps: int,
    moving_tol: float,
    pooled: Pose,
    valid,
    n_rows: int,
    sigma_score: float,
) -> PoseSearchResult:
    """Re-pose each chain (:func:`~ncflow.matcher.pose_hypotheses.limb_chains`: a finger, a limb) of the pose
    ``found`` with the others held, ``sweeps`` times: every pose of its grid
    (:func:`~ncflow.matcher.pose_hypotheses.chain_grid`) and its current one scored at the finer ``sigma``,
    where neighbouring fingers no longer blur into one, the best kept; then the whole pose refined by
    gradient descent at ``sigma``. The pose is kept when it explains the target better than ``found`` at
    ``sigma``; its score is then given at ``sigma_score`` (the placements' common scale). ``pooled``,
    ``valid`` and ``n_rows``: the stacks of :func:`refine_pooled`, whose shapes (one compiled program each)
    are reused.
    """
    skeleton = scorer.skeleton
    grids = [chain_grid(skeleton, c) for c in chains]
    n_hyp, n_len = max(g.shape[0] for g in grids) + 1, max(c.size for c in chains)
    weights = np.asarray(scorer.fine[1])
    moving = [moving_diracs(skeleton, weights, int(c[0]), moving_tol) for c in chains]
    size = _padded_size(m.size for m in moving)
    moved = [_padded_diracs(m, size) for m in moving]
    start = host(found.pose)
    rot, translation = np.array(start.rotations, np.float32), start.translation
    for _ in range(sweeps):
        for c, grid, (idx, mask) in zip(chains, grids, moved):
            hyp = np.concatenate([rot[c][None], grid.astype(np.float32)])
            n_real = hyp.shape[0]
            hyp = np.concatenate([hyp, np.repeat(hyp[:1], n_hyp - n_real, 0)])
            hyp = np.concatenate([hyp, np.repeat(hyp[:, -1:], n_len - c.size, 1)], 1)
            joints = np.concatenate([c, np.repeat(c[-1:], n_len - c.size)]).astype(np.int32)
            active = np.arange(n_hyp) < n_real
            s = scorer.expand_chain(Pose(rot, translation), joints, hyp, active, sigma, y_fine, idx, mask)
            rot[c] = hyp[int(np.argmin(np.asarray(s))), : c.size]
    rows = picked(pooled, np.full(n_rows, valid.size - 1))
    rows = stacked(Pose(rot[None], np.asarray(translation)[None]), picked(rows, slice(1, None)))
    active = np.arange(n_rows) == 0
    rows = host(scorer.refine_all(rows, active, sigma, y_fine))
    both = completed(stacked(picked(rows, slice(0, 1)), host(found.pose_stack())), pooled)
    scored = np.arange(valid.size) < 2
    at_sigma = np.array(scorer.score_fine(both, scored, sigma, y_fine), np.float64)
    if not at_sigma[0] < at_sigma[1]:
        return found
    final = float(np.asarray(scorer.score_compared(both, scored, sigma_score, y_fine))[0])
    pose = jax.device_put(picked(scorer.canonical(picked(both, slice(0, 1))), 0))
    return PoseSearchResult(pose, final, found.rest_score, found.hypotheses + sweeps * sum(g.shape[0] for g in grids))


def search_plan(skeleton: Skeleton, scorer: PoseScorer, discrete: bool, root_turns: bool, moving_tol: float) -> list:
    """The steps of a beam search down the tree, every shape fixed so that one compiled program serves
    them all: per searched joint (j, its number of hypotheses, its and its child's padded rotations, the
    child, the Diracs it moves or None), and before the first joint of a level the limbs of that level
    that are tried exchanged (pairs of joint lists).
    """
    has_child = np.bincount(np.asarray(skeleton.parents)[1:], minlength=skeleton.n_joints) > 0
    searched = [
        (int(j), *chain_hypotheses(skeleton, int(j)))
        for level in (skeleton.levels if discrete else ())
        for j in level
        if has_child[j] and (skeleton.parents[j] >= 0 or root_turns)
    ]
    n_hyp = max([h.shape[0] for _, h, _, _ in searched] or [1])

    def padded(q):
        return jax.device_put(np.vstack([q, np.tile([1.0, 0.0, 0.0, 0.0], (n_hyp - q.shape[0], 1))]).astype(DTYPE))

    bone_weights = np.asarray(scorer.coarse[1])  # read back once, not once per joint
    moving = {j: moving_diracs(skeleton, bone_weights, j, moving_tol) for j, *_ in searched}
    few = [m.size for m in moving.values() if 0 < m.size <= scorer.coarse[0].size // 2]
    size = _padded_size(few)  # one size for all: one compiled program

    def part(j):
        """The Diracs joint j moves, padded to ``size``, or None where they are over half of all (the full
        sum then costs as much).
        """
        idx = moving[j]
        if not 0 < idx.size <= size:
            return None
        return _padded_diracs(idx, size)

    searched = [(j, h.shape[0], padded(h), padded(hc), c, part(j)) for j, h, hc, c in searched]
    depth = skeleton.depth
    limbs = exchangeable_limbs(skeleton) if discrete else []
    plan = []
    for step in searched:
        plan += [limb for limb in limbs if depth[limb[0][0]] == depth[step[0]] and not any(limb is q for q in plan)]
        plan.append(step)
    return plan


def beam_search(scorer: PoseScorer, plan: list, sigma: float, exchange: bool, y_coarse, beam: int):
    """The best ``beam`` poses down the tree at ``sigma`` (rows past the distinct count repeat the best),
    limb exchanges tried when ``exchange``: (beam poses, their distinct count, poses scored).
    """
    beams = picked(scorer.rest_stack, np.zeros(beam, int))
    n_real, n_scored = 1, 0
    for step in plan:
        if len(step) == 2:  # a limb exchange: each beam pose with and without it
            if exchange:
                beams, n_real, n_new = _exchange_step(
                    scorer.skeleton, beams, n_real, step, sigma, scorer.score_coarse, y_coarse
                )
                n_scored += n_new
            continue
        j, n_h, hyp, hyp_child, c, moved = step
        args = (beams.rotations, beams.translation, hyp, hyp_child, j, c, sigma, y_coarse, n_real, n_h)
        cand, s = scorer.expand(*args) if moved is None else scorer.expand_part(*args, *moved)
        s = np.array(s, np.float64)
        n_scored += n_real * n_h
        keep = np.argsort(s, kind="stable")[: min(beam, n_real * n_h)]
        keep = np.concatenate([keep, np.repeat(keep[:1], beam - keep.size)])  # pad with the best
        n_real = min(beam, n_real * n_h)
        beams = picked(cand, keep)
    return beams, n_real, n_scored


def refine_pooled(
    scorer: PoseScorer,
    pooled: Pose,
    valid,
    y_fine,
    sigmas_refine,
    n_refined: int,
    refined_fine: int,
    distinct: float,
    n_scored: int,
) -> PoseSearchResult:
    """Refine the pooled beams (the rest pose last; ``valid``: their real rows) by gradient descent: at most
    ``n_refined`` distinct poses, best scored first, at the first σ, then the best ``refined_fine`` still
    distinct at each finer σ. The best refined pose, or the rest pose when nothing explains the target
    better (``n_scored``: the poses the beam searches scored).
    """
    first = np.array(scorer.score_fine(pooled, valid, float(sigmas_refine[0]), y_fine), np.float64)
    chosen = best_distinct(first[:-1], np.asarray(scorer.pose_joints(pooled))[:-1], n_refined, distinct)
    rows = np.array(chosen + [pooled.rotations.shape[0] - 1] * (n_refined + 1 - len(chosen)))
    real = np.arange(rows.size) < len(chosen)
    real[-1] = True  # the rest pose, refined too; the copies before it fill the fixed shape
    only = np.zeros(valid.size, bool)
    scored = np.concatenate([real, only[rows.size :]])
    candidates = picked(pooled, rows)
    active = real
    for level, sigma in enumerate(sigmas_refine):
        if level:  # finer scales: the best few that are still distinct
            shaped = completed(candidates, pooled)
            s = np.array(scorer.score_fine(shaped, scored, float(sigma), y_fine), np.float64)[: rows.size]
            joints = np.asarray(scorer.pose_joints(shaped))[: rows.size]
            active = np.isin(np.arange(rows.size), best_distinct(s, joints, refined_fine, distinct))
        candidates = scorer.refine_all(candidates, active, float(sigma), y_fine)
    padded = completed(candidates, pooled)
    final = np.array(scorer.score_fine(padded, scored, float(sigmas_refine[-1]), y_fine), np.float64)
    rests = picked(scorer.rest_stack, np.zeros(valid.size, int))
    only[0] = True
    rest_score = float(np.asarray(scorer.score_fine(rests, only, float(sigmas_refine[-1]), y_fine))[0])
    best = int(np.argmin(final))
    seen = seen_scores(scorer, picked(padded, slice(best, best + 1)), pooled, valid.size, y_fine, sigmas_refine[-1])
    if final[best] >= rest_score:
        return PoseSearchResult(scorer.rest, seen[1], seen[1], n_scored)
    pose = jax.device_put(picked(scorer.canonical(picked(padded, slice(best, best + 1))), 0))
    return PoseSearchResult(pose, seen[0], seen[1], n_scored)


def seen_scores(scorer: PoseScorer, pose: Pose, pooled: Pose, n_rows: int, y_fine, sigma) -> tuple[float, float]:
    """``PoseScorer.score_compared`` at ``sigma`` of ``pose`` (a stack of one) and the rest pose, ``pooled``'s shape."""
    rows = completed(stacked(pose, scorer.rest_stack), pooled)
    s = scorer.score_compared(rows, np.arange(n_rows) < 2, sigma, y_fine)
    return float(s[0]), float(s[1])
