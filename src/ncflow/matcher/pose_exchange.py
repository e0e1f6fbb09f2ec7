"""The one-to-one finger assignment of the pose search: neighbouring chains exchanged at the fine scale.

At the coarse scale of the beam search two fingers side by side blur into one, and the search can leave
them exchanged — the index lying on the target's middle finger and the middle on its index, or the tips
of two fingers crossed over — while every other finger is right. Each source chain claims one target
finger, so a wrong assignment is a permutation of neighbours. After the refinement, this step tries every
pair of exchangeable chains of a joint with three or more of them
(:func:`~ncflow.matcher.pose_hypotheses.exchangeable_limbs`: fingers, toes) exchanged whole and from each
of their later joints on (:func:`exchange_variants`), each chain taking the other's bone directions or
reaching for the other's joints (:func:`~ncflow.matcher.pose_hypotheses.exchanged`); scores them at the
fine scale, refines the best few together with the found pose (one batched program) and keeps the lowest
refined score. A wrong assignment that only looked better at the coarse scale loses here.
"""

from __future__ import annotations

import jax
import numpy as np
from jaxtyping import Float

from ncflow.matcher.pose_hypotheses import exchange_moves, exchangeable_limbs, exchanged, world_frames
from ncflow.skeleton import Skeleton
from ncflow.skeleton.kinematics import Pose

MIN_GROUP = 3
"""Limbs are exchanged here only where at least this many alike hang from one joint: fingers, toes — not
a body's pair of legs or arms, whose exchanges the beam search tries (measured on hands only)."""

MOVED = 0.1
"""An exchange wins only when its refined pose is another pose: a joint of it at least this far (normalised
units, a hand about 4 long) from where the found pose has it; an exchange the refinement takes back to the
found pose is no other assignment."""


def exchange_variants(
    skeleton: Skeleton, rotations: Float[np.ndarray, "J 4"], min_move: float = 0.25, min_group: int = MIN_GROUP
) -> tuple[Float[np.ndarray, "K J 4"], list[tuple[int, int, int, bool]]]:
    """(K, J, 4) local rotations: ``rotations`` (J, 4) with each pair of exchangeable limbs exchanged from
    their first joint, and from each later joint that moves a bone, on, each bone taking the other's
    direction or reaching for the other's joint (:func:`~ncflow.matcher.pose_hypotheses.exchanged`,
    ``reach``); and per variant (limb a's first joint, limb b's, the depth into the limbs the exchange
    starts at, whether it reaches). Only limbs of a joint with at least
    ``min_group`` exchangeable limbs; a variant whose joints move by less than ``min_move`` × the limbs'
    mean length (two straight fingers side by side) is left out.
    """
    rot = np.asarray(rotations, np.float64)
    parents = np.asarray(skeleton.parents)
    base = world_frames(skeleton, rot)[1]
    limbs = exchangeable_limbs(skeleton)
    group: dict[int, set] = {}
    for a, b in limbs:
        group.setdefault(int(parents[a[0]]), set()).update((int(a[0]), int(b[0])))
    out, labels = [], []
    for a, b in limbs:
        if len(group[int(parents[a[0]])]) < min_group:
            continue
        for k in range(a.size):
            if not np.any(parents == a[k]):
                break
            if k and np.count_nonzero(parents == a[k]) != 1:
                break  # a branching limb is exchanged whole only
            for reach in (False, True):
                swapped = exchanged(skeleton, rot, a[k:], b[k:], reach)
                if exchange_moves(skeleton, base, swapped, a, b, min_move):
                    out.append(swapped)
                    labels.append((int(a[0]), int(b[0]), k, reach))
    return np.asarray(out).reshape(-1, *rot.shape), labels


def exchange_step(scorer, pose: Pose, n_rows: int, y_fine, sigma: float, moved: float = MOVED) -> tuple[Pose, bool]:
    """The pose of :func:`exchange_variants` that explains the target best at ``sigma`` after refinement:
    every variant of ``pose`` (host arrays, one pose) scored by ``scorer``
    (:class:`~ncflow.matcher.pose_scorer.PoseScorer`) against the Diracs ``y_fine``, the best ``n_rows`` − 1
    refined together with ``pose`` (one batch of ``n_rows``, the shape of the refinement's programs), and
    the lowest refined score kept when it is lower than that of ``pose`` refined again and one of its
    joints is at least ``moved`` from where ``pose`` has it. Returns (pose, whether an exchange won);
    ``pose`` itself, untouched, when none did.
    """
    rot = np.asarray(pose.rotations, np.float64)
    variants, _ = exchange_variants(scorer.skeleton, rot)
    if not variants.shape[0]:
        return pose, False
    dtype = np.asarray(pose.rotations).dtype
    translation = np.asarray(pose.translation)

    def stack(rows):
        rows = np.concatenate([rows, np.repeat(rows[:1], n_rows - rows.shape[0], 0)])
        return Pose(rows.astype(dtype), np.repeat(translation[None], n_rows, 0))

    scores = []
    for start in range(0, variants.shape[0], n_rows):
        part = variants[start : start + n_rows]
        active = np.arange(n_rows) < part.shape[0]
        scores.append(np.asarray(scorer.score_fine(stack(part), active, sigma, y_fine), np.float64)[: part.shape[0]])
    best = variants[np.argsort(np.concatenate(scores), kind="stable")[: n_rows - 1]]
    rows = np.concatenate([rot[None], best])
    active = np.arange(n_rows) < rows.shape[0]
    refined = scorer.refine_all(stack(rows), active, sigma, y_fine)
    final = np.array(scorer.score_fine(refined, active, sigma, y_fine), np.float64)
    reference = final[0]
    joints = np.asarray(scorer.pose_joints(refined), np.float64)
    before = np.asarray(scorer.pose_joints(stack(rot[None])), np.float64)[0]
    other = np.linalg.norm(joints - before, axis=-1).max(-1) >= moved
    final[~other] = np.inf
    win = int(np.argmin(final))
    if not final[win] < reference:
        return pose, False
    return jax.tree.map(lambda x: np.asarray(x)[win], refined), True
