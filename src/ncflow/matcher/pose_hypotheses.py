"""The hypotheses of the articulated pose search (:mod:`ncflow.matcher.pose_search`): the local rotations
each joint tries (bends across its bone, twists about it, and bends chained with the next joint's)
and the limbs that are tried exchanged (same-shaped subtrees of one joint, each taking the other's
bone directions). NumPy and SciPy rotations on the host; nothing here is compiled.
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Float
from scipy.spatial.transform import Rotation

from ncflow.skeleton import Skeleton


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


def exchangeable_limbs(skeleton: Skeleton, length_ratio: float = 1.5) -> list[tuple[np.ndarray, np.ndarray]]:
    """Pairs of limbs the search tries exchanging: subtrees hanging from the same joint with the same
    shape (a chain of as many joints, or the same branching) whose bone lengths sum to within
    ``length_ratio`` of each other — left and right legs, arms, fingers. Each pair is two arrays
    of joint indices in matching depth-first order, the limb's first joint first.
    """
    parents = np.asarray(skeleton.parents)
    children = [np.flatnonzero(parents == j).tolist() for j in range(skeleton.n_joints)]
    lengths = np.concatenate([[0.0], skeleton.bone_lengths])

    def shape(j):
        return tuple(shape(c) for c in children[j])

    def order(j):
        return [j] + [k for c in children[j] for k in order(c)]

    pairs = []
    for kids in children:
        for i, a in enumerate(kids):
            for b in kids[i + 1 :]:
                if not children[a] or shape(a) != shape(b):
                    continue
                la, lb = order(a), order(b)
                sa, sb = lengths[la[1:]].sum(), lengths[lb[1:]].sum()
                if max(sa, sb) <= length_ratio * max(min(sa, sb), 1e-12):
                    pairs.append((np.asarray(la), np.asarray(lb)))
    return pairs


def world_frames(skeleton: Skeleton, rotations: np.ndarray) -> tuple[Rotation, np.ndarray]:
    """World rotations and joint positions (root at its rest place) of local rotations (J, 4), in
    float64 on the host: :func:`~ncflow.skeleton.kinematics.forward_kinematics` (G_j = G_parent L_j)
    for the few poses of an exchange step, without a device round trip per pose.
    """
    parents, off = np.asarray(skeleton.parents), np.asarray(skeleton.offsets)
    local = Rotation.from_quat(rotations, scalar_first=True)
    world, pos = [None] * skeleton.n_joints, np.zeros((skeleton.n_joints, 3))
    for j in np.concatenate(skeleton.levels):
        p = parents[j]
        world[j] = local[j] if p < 0 else world[p] * local[j]
        pos[j] = off[j] if p < 0 else pos[p] + world[p].apply(off[j])
    return Rotation.concatenate(world), pos


def exchange_moves(
    skeleton: Skeleton,
    base: Float[np.ndarray, "J 3"],
    swapped: Float[np.ndarray, "J 4"],
    a: np.ndarray,
    b: np.ndarray,
    min_move: float,
) -> bool:
    """Whether the exchange ``swapped`` (local rotations, :func:`exchanged`) of limbs ``a`` and ``b`` moves a
    joint at least ``min_move`` × the limbs' mean length from ``base`` (the joints before it,
    :func:`world_frames`): two straight fingers side by side exchanged are the same pose.
    """
    length = skeleton.bone_lengths[np.concatenate([a[1:], b[1:]]) - 1].sum() / 2.0
    return bool(np.linalg.norm(world_frames(skeleton, swapped)[1] - base, axis=1).max() >= min_move * length)


def exchanged(
    skeleton: Skeleton, rotations: Float[np.ndarray, "J 4"], a: np.ndarray, b: np.ndarray, reach: bool = False
) -> Float[np.ndarray, "J 4"]:
    """Local rotations (J, 4) with limbs ``a`` and ``b`` (:func:`exchangeable_limbs`) exchanged: every
    joint of one limb turns its bone (towards the mean of its children) to the world direction of the
    matching bone of the other, by the smallest rotation from rest; the rest of the pose is kept. With
    ``reach``, each bone turns instead towards the other limb's matching joint *position* from where the
    limb's own joint now lies (two fingers crossed over each other, each lying where the other should:
    taking the other's directions would move each a finger's width too far).
    """
    world, pos = world_frames(skeleton, rotations)
    parents, off = np.asarray(skeleton.parents), np.asarray(skeleton.offsets)
    new_world = {j: world[j] for j in range(skeleton.n_joints)}
    out = np.array(rotations, np.float64)
    for mine, other in ((a, b), (b, a)):
        to_other = dict(zip(mine.tolist(), other.tolist()))
        now = {int(mine[0]): pos[mine[0]]}
        for j in mine.tolist():
            kids = np.flatnonzero(parents == j)
            if kids.size == 0:
                continue
            k = to_other[j]
            aim = pos[[to_other[c] for c in kids.tolist()]].mean(0) - (now[j] if reach else pos[k])
            rest = off[kids].mean(0)
            if np.linalg.norm(aim) < 1e-9 or np.linalg.norm(rest) < 1e-9:
                continue
            turn = Rotation.align_vectors(aim[None], rest[None])[0]
            new_world[j] = turn
            out[j] = (new_world[parents[j]].inv() * turn).as_quat(scalar_first=True)
            for c in kids.tolist():
                now[c] = now[j] + turn.apply(off[c])
    return out


def limb_chains(skeleton: Skeleton, min_joints: int = 2) -> list[np.ndarray]:
    """The chains the finger-level search re-poses one at a time (fingers off a palm, limbs off a pelvis):
    from each child of a joint with several children, the joints down a single line of descent that
    move a bone (each has exactly one child), when there are at least ``min_joints`` of them and the
    line ends in a leaf. Each chain is an array of joint indices, its first joint first.
    """
    parents = np.asarray(skeleton.parents)
    children = [np.flatnonzero(parents == j) for j in range(skeleton.n_joints)]
    chains = []
    for kids in children:
        if kids.size < 2:
            continue
        for k in kids.tolist():
            chain = []
            while children[k].size == 1:
                chain.append(k)
                k = int(children[k][0])
            if children[k].size == 0 and len(chain) >= min_joints:
                chains.append(np.asarray(chain))
    return chains


#: bend angles (degrees) of a chain's first joint and of its second (the rest follow the second in turn)
CHAIN_BENDS = (-90, -60, -30, 0, 30, 60, 90)
#: shares of the second joint's bend taken by each further joint
CHAIN_FOLLOW = (0.5, 1.0)
#: spreads (degrees) of the first joint about the axis across the bend
CHAIN_SPREADS = (-30, 0, 30)
#: bend planes tried (degrees about the chain's direction)
CHAIN_PLANES = (0, 45, 90, 135)


def chain_grid(skeleton: Skeleton, chain: np.ndarray) -> Float[np.ndarray, "H L 4"]:
    """Local rotations (w, x, y, z) of the joints of ``chain`` (:func:`limb_chains`), each row a whole
    pose of the chain from rest: every joint bent about one axis across the chain's rest direction (a
    finger curls in a plane), the plane one of :data:`CHAIN_PLANES`; the first joint by each of
    :data:`CHAIN_BENDS` and spread by :data:`CHAIN_SPREADS` about the other axis (one swing, no twist),
    the second by each of :data:`CHAIN_BENDS`, every further one by a share (:data:`CHAIN_FOLLOW`) of the
    second's.
    """
    pos = np.asarray(skeleton.positions, np.float64)
    parents = np.asarray(skeleton.parents)
    tip = int(np.flatnonzero(parents == chain[-1])[0])
    a = pos[tip] - pos[chain[0]]
    a /= max(np.linalg.norm(a), 1e-12)
    u = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(a, u)
    rows = []
    for plane in np.radians(CHAIN_PLANES):
        axis, across = np.cos(plane) * u + np.sin(plane) * v, -np.sin(plane) * u + np.cos(plane) * v
        for first in np.radians(CHAIN_BENDS):
            for spread in np.radians(CHAIN_SPREADS):
                q0 = Rotation.from_rotvec(first * axis + spread * across).as_quat(scalar_first=True)
                for second in np.radians(CHAIN_BENDS):
                    q1 = Rotation.from_rotvec(second * axis).as_quat(scalar_first=True)
                    for follow in CHAIN_FOLLOW if len(chain) > 2 else (1.0,):
                        later = Rotation.from_rotvec(second * follow * axis).as_quat(scalar_first=True)
                        rows.append([q0, q1] + [later] * (len(chain) - 2))
    return np.asarray(rows)
