"""The one-to-one finger assignment (ncflow.matcher.pose_exchange): neighbouring fingers exchanged at the
fine scale, against poses built by hand and a target posed by the search's own skinning."""

import functools

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ncflow.flow.bone_weights import skinning_weights
from ncflow.geometry.normalize import fit_normalization
from ncflow.matcher.pose_exchange import exchange_step, exchange_variants
from ncflow.matcher.pose_hypotheses import limb_chains
from ncflow.matcher.pose_scorer import PoseScorer, skinned
from ncflow.measures.varifold import Varifold
from ncflow.skeleton import Skeleton
from ncflow.skeleton.kinematics import Pose, forward_kinematics, joint_positions


def _palm(n_fingers: int, spacing: float = 0.3):
    """A root with ``n_fingers`` straight three-bone chains along +y, side by side along x."""
    joints, parents = [[0.0, 0.0, 0.0]], [-1]
    for f in range(n_fingers):
        x = (f - (n_fingers - 1) / 2) * spacing
        base = len(joints)
        for k in range(4):
            joints.append([x, 1.0 + 0.4 * k, 0.0])
            parents.append(0 if k == 0 else base + k - 1)
    return Skeleton.from_arrays(np.asarray(joints), np.asarray(parents))


def _curled(skel: Skeleton, fingers, degrees: float = 60.0) -> np.ndarray:
    """Local rotations (J, 4): every joint of the named chains bent by ``degrees`` about x (a curl)."""
    rot = np.tile([1.0, 0.0, 0.0, 0.0], (skel.n_joints, 1))
    chains = limb_chains(skel)
    for f in fingers:
        rot[chains[f]] = Rotation.from_rotvec([np.radians(degrees), 0.0, 0.0]).as_quat(scalar_first=True)
    return rot


def _with_tip(skel: Skeleton, chain: np.ndarray) -> np.ndarray:
    """The chain's joints and the leaf its last bone ends at."""
    return np.append(chain, np.flatnonzero(np.asarray(skel.parents) == chain[-1])[0])


def _joints(skel, rot):
    pose = Pose(jnp.asarray(rot, jnp.float32), jnp.zeros(3, jnp.float32))
    return np.asarray(joint_positions(forward_kinematics(skel, pose)), np.float64)


def test_exchange_variants_give_each_finger_its_neighbours_bone_directions():
    """Four fingers, the first curled: the whole exchange of fingers 0 and 1 curls finger 1 exactly as finger 0
    was (the same bone directions, from forward kinematics) and straightens finger 0; exchanges of the
    directions of two straight fingers are left out (nothing moves), and a body's two alike limbs get none."""
    skel = _palm(4)
    rot = _curled(skel, [0])
    variants, labels = exchange_variants(skel, rot)
    chains = limb_chains(skel)
    assert labels and all(chains[0][0] in (a, b) for a, b, _, reach in labels if not reach)
    k = labels.index((int(chains[0][0]), int(chains[1][0]), 0, False))
    before, after = _joints(skel, rot), _joints(skel, variants[k])

    def directions(pos, chain):
        pts = pos[_with_tip(skel, chain)]
        d = np.diff(pts, axis=0)
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    np.testing.assert_allclose(directions(after, chains[1]), directions(before, chains[0]), atol=1e-6)
    np.testing.assert_allclose(directions(after, chains[0]), directions(before, chains[1]), atol=1e-6)
    np.testing.assert_allclose(after[chains[2]], before[chains[2]], atol=1e-9)
    reach = _joints(skel, variants[labels.index((int(chains[0][0]), int(chains[1][0]), 0, True))])
    aim = before[chains[1][1]] - before[chains[0][0]]  # finger 0's first bone reaches for finger 1's second joint
    np.testing.assert_allclose(directions(reach, chains[0])[0], aim / np.linalg.norm(aim), atol=1e-6)
    legs = _palm(2)
    assert exchange_variants(legs, _curled(legs, [0]))[0].shape[0] == 0
    assert exchange_variants(legs, _curled(legs, [0]), min_group=2)[0].shape[0] > 0


@functools.cache
def _hand_problem():
    """The procedural hand (seed 3), normalised, and a target posed by the search's own skinning: index and
    ring curled by 80° at every joint, middle and little stretched. Returns (scorer, truth rotations,
    target Diracs for the refinement, chains)."""
    from ncflow.synthetic.pairs import make_pair

    pair = make_pair("hand", 3)
    norm = fit_normalization(pair.source.vertices, pair.source.faces)
    skel = pair.skeleton.with_positions(norm.apply(pair.skeleton.positions))
    v, f = norm.apply(pair.source.vertices), pair.source.faces
    width = 0.05 * float(np.median(skel.bone_lengths))
    chains = limb_chains(skel)
    pos = np.asarray(skel.positions)
    across = pos[chains[2][0]] - pos[chains[0][0]]  # index knuckle → little knuckle
    rot = np.tile([1.0, 0.0, 0.0, 0.0], (skel.n_joints, 1))
    for c in (chains[0], chains[3]):  # index and ring (MANO's joint order: index, middle, little, ring, thumb)
        along = pos[_with_tip(skel, c)[-1]] - pos[c[0]]
        axis = np.cross(across, along)
        axis /= np.linalg.norm(axis)
        rot[c] = Rotation.from_rotvec(np.radians(80.0) * axis).as_quat(scalar_first=True)
    truth = Pose(jnp.asarray(rot, jnp.float32), jnp.zeros(3, jnp.float32))
    bones = np.asarray(skel.bones)
    w = skinning_weights(jnp.asarray(v), jnp.asarray(pos[bones[:, 0]]), jnp.asarray(pos[bones[:, 1]]), width)
    ones = jnp.ones(v.shape[0])
    tv = np.asarray(skinned(skel, w, Varifold(jnp.asarray(v), jnp.asarray(v), ones), truth).centers)
    scorer = PoseScorer(skel, v, f, width, n_search=300, n_refine=800, refine_steps=100, seed=0)
    _, y_fine = scorer.target_diracs(tv, f)
    return scorer, rot, y_fine, chains


def _finger_errors(skel, rot, truth_rot, chains):
    got, want = _joints(skel, rot), _joints(skel, truth_rot)
    err = np.linalg.norm(got - want, axis=1)
    return [float(err[_with_tip(skel, c)].max()) for c in chains]


@pytest.mark.parametrize("depth, reach", [(0, False), (1, False), (0, True)])
def test_exchange_step_puts_back_two_neighbouring_fingers_that_were_exchanged(depth, reach):
    """The target's index curled and middle stretched; the start has them exchanged (whole, or from their
    second joint on; taking each other's directions, or crossed over, each reaching for the other's
    joints; over 0.5 normalised units off on both fingers, the hand about 4 long, the others exact). The
    exchange step returns every finger within 0.1 of the truth, and leaves the true pose as it is."""
    scorer, truth_rot, y, chains = _hand_problem()
    skel = scorer.skeleton
    variants, labels = exchange_variants(skel, truth_rot)
    start = variants[labels.index((int(chains[0][0]), int(chains[1][0]), depth, reach))]
    before = _finger_errors(skel, start, truth_rot, chains)
    assert min(before[0], before[1]) > 0.5 and max(before[2:]) < 1e-6
    n_rows = 13

    def pose(r):
        return Pose(np.asarray(r, np.float32), np.zeros(3, np.float32))

    found, won = exchange_step(scorer, pose(start), n_rows, y, 0.15)
    assert won
    after = _finger_errors(skel, np.asarray(found.rotations), truth_rot, chains)
    assert max(after) < 0.1, after
    kept, won = exchange_step(scorer, pose(truth_rot), n_rows, y, 0.15)
    assert not won and np.array_equal(np.asarray(kept.rotations), np.asarray(truth_rot, np.float32))
