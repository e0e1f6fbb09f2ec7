"""Procedural characters: deterministic, clean closed meshes, skeletons inside, smooth weights,
posing by forward kinematics and skinning that agrees with ncflow's dual-quaternion FK."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ncflow.errors import InputError
from ncflow.geometry.mesh import validate_mesh
from ncflow.geometry.remesh import check_closed_surface, euler_characteristic
from ncflow.geometry.winding import signed_volume
from ncflow.geometry.winding import winding_numbers as geometry_winding_numbers
from ncflow.skeleton import Pose, check_inside, forward_kinematics, joint_positions
from ncflow.synthetic.bodies import DEFAULT_RESOLUTION, KINDS, character_sdf
from ncflow.synthetic.characters import (
    make_character,
    pose_character,
    pose_from_rotvecs,
    pose_world_transforms,
    random_pose,
)

N_BONES = {"humanoid": 21, "hand": 20, "quadruped": 24}
LIMBS = {  # bones (named by their end joint) of limb segments that have a middle of their own
    "humanoid": ["elbow_l", "wrist_r", "knee_r", "ankle_l", "head_end"],
    "hand": ["index2", "middle3", "little2", "ring3", "thumb3"],
    "quadruped": ["elbow_l", "knee_r", "hock_l", "tail3", "nose"],
}


@pytest.fixture(scope="module")
def characters():
    return {kind: make_character(kind, 0) for kind in KINDS}


def winding_numbers(points, vertices, faces):
    tri = vertices[faces][None] - points[:, None, None, :]
    a, b, c = tri[:, :, 0], tri[:, :, 1], tri[:, :, 2]
    la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
    num = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
    den = la * lb * lc + np.einsum("pfi,pfi->pf", a, b) * lc + np.einsum("pfi,pfi->pf", b, c) * la
    den += np.einsum("pfi,pfi->pf", c, a) * lb
    return np.arctan2(num, den).sum(axis=1) / (2 * np.pi)


def min_angles(v, f):
    t = v[f]
    out = []
    for k in range(3):
        e1, e2 = t[:, (k + 1) % 3] - t[:, k], t[:, (k + 2) % 3] - t[:, k]
        cos = np.einsum("ij,ij->i", e1, e2) / (np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1))
        out.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    return np.min(out, axis=0)


def bone_angle_at(joints, parents, j):
    """Angles (degrees) between the bone into joint j and each bone out of it."""
    d_in = joints[j] - joints[parents[j]]
    out = []
    for c in np.flatnonzero(parents == j):
        d_out = joints[c] - joints[j]
        cos = d_in @ d_out / (np.linalg.norm(d_in) * np.linalg.norm(d_out))
        out.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    return np.array(out)


# ----------------------------------------------------------------------------------------------
# construction


def test_deterministic_per_seed(characters):
    a = characters["quadruped"]
    b = make_character("quadruped", 0)
    for x, y in [
        (a.vertices, b.vertices),
        (a.faces, b.faces),
        (a.weights, b.weights),
        (a.skeleton.positions, b.skeleton.positions),
    ]:
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()
    c = make_character("quadruped", 1)
    assert c.vertices.shape != a.vertices.shape or not np.array_equal(c.vertices, a.vertices)
    assert not np.allclose(c.skeleton.positions, a.skeleton.positions)
    # proportions differ: some bone length changes by more than 1 %
    ratio = c.skeleton.bone_lengths / a.skeleton.bone_lengths
    assert np.max(np.abs(ratio - 1)) > 0.01


@pytest.mark.parametrize("kind", KINDS)
def test_closed_clean_mesh(characters, kind):
    ch = characters[kind]
    v, f = ch.vertices, ch.faces
    assert v.dtype == np.float64 and f.dtype == np.int64
    validate_mesh(v, f, name=kind)  # raises on bad input
    assert check_closed_surface(v, f) is None
    m = trimesh.Trimesh(v, f, process=False)
    assert m.is_watertight and m.is_winding_consistent
    assert m.volume > 0  # outward normals
    assert m.body_count == 1
    assert m.euler_number == 2  # a sphere: no fused limbs
    assert 1000 <= v.shape[0] <= 3000
    assert ch.resolution == DEFAULT_RESOLUTION[kind]
    # triangle quality: no slivers
    ang = min_angles(v, f)
    assert ang.min() > 10.0
    assert np.mean(ang > 25.0) > 0.99
    # vertices lie on the implicit surface
    assert np.max(np.abs(character_sdf(ch.spec, v))) < 1e-9 * ch.spec.size


@pytest.mark.parametrize("kind", KINDS)
def test_skeleton_inside(characters, kind):
    ch = characters[kind]
    sk = ch.skeleton
    assert sk.n_bones == N_BONES[kind] >= 10
    assert np.array_equal(sk.file_index, np.arange(sk.n_joints))  # already topologically ordered
    assert sk.names is not None and len(set(sk.names)) == sk.n_joints
    w = winding_numbers(sk.positions, ch.vertices, ch.faces)
    np.testing.assert_allclose(w, 1.0, atol=1e-6)  # every joint strictly inside
    assert check_inside(sk, ch.vertices, ch.faces) == []
    assert np.all(character_sdf(ch.spec, sk.positions) < 0)


def test_winding_numbers_signed_volume_and_euler_characteristic(characters):
    ch = characters["hand"]
    v, f = ch.vertices, ch.faces
    rng = np.random.default_rng(0)
    lo, hi = v.min(axis=0), v.max(axis=0)
    points = np.concatenate([ch.skeleton.positions, rng.uniform(lo - 0.02, hi + 0.02, size=(60, 3))])
    reference = winding_numbers(points, v, f)  # the brute-force formula above, all at once
    chunked = [geometry_winding_numbers(points, v[f], chunk=chunk) for chunk in (1, 50_000, 200_000)]
    for w in chunked:  # chunking does not change a bit; the formula's terms are summed in another order
        np.testing.assert_array_equal(w, chunked[0])
        np.testing.assert_allclose(w, reference, rtol=0.0, atol=1e-12)
    inside = character_sdf(ch.spec, points) < -1e-3 * ch.spec.size
    outside = character_sdf(ch.spec, points) > 1e-3 * ch.spec.size
    np.testing.assert_allclose(reference[inside], 1.0, atol=1e-6)
    np.testing.assert_allclose(reference[outside], 0.0, atol=1e-6)
    m = trimesh.Trimesh(v, f, process=False)
    assert signed_volume(v, f) == pytest.approx(m.volume, rel=1e-12)
    assert signed_volume(v, f[:, ::-1]) == pytest.approx(-m.volume, rel=1e-12)
    # V - E + F counted by hand: a sphere; a disk once a fan of faces is cut out
    edges = np.unique(np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    assert euler_characteristic(v, f) == v.shape[0] - edges.shape[0] + f.shape[0] == 2
    assert euler_characteristic(v, f[np.all(f != 0, axis=1)]) == 1


def test_skeleton_structure(characters):
    hand = characters["hand"].skeleton
    # MANO-like: wrist, 5 fingers × 3 joints, 5 tips; every finger is a chain of 4 bones
    assert hand.names[0] == "wrist"
    for f in ("index", "middle", "little", "ring", "thumb"):
        chain = [hand.names.index(f"{f}{k}") for k in (1, 2, 3)] + [hand.names.index(f"{f}_tip")]
        assert hand.parents[chain[0]] == 0
        assert all(hand.parents[chain[k + 1]] == chain[k] for k in range(3))
    human = characters["humanoid"].skeleton
    for name in ("head_end", "hand_l", "hand_r", "toe_l", "toe_r"):
        assert not np.any(human.parents == human.names.index(name))  # extremity bones end in leaves
    quad = characters["quadruped"].skeleton
    for name in ("nose", "tail3", "fpaw_l", "fpaw_r", "hpaw_l", "hpaw_r"):
        assert not np.any(quad.parents == quad.names.index(name))


@pytest.mark.parametrize("kind", KINDS)
def test_skinning_weights(characters, kind):
    ch = characters[kind]
    w = ch.weights
    assert w.shape == (ch.vertices.shape[0], ch.skeleton.n_bones)
    assert np.all(w >= 0)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
    # smooth: weights change little across an edge
    e = np.concatenate([ch.faces[:, [0, 1]], ch.faces[:, [1, 2]], ch.faces[:, [2, 0]]])
    jump = np.max(np.abs(w[e[:, 0]] - w[e[:, 1]]), axis=1)
    assert jump.max() < 0.55 and jump.mean() < 0.1
    # local: every limb segment dominates a region of the surface, and that region is near the bone
    for name in LIMBS[kind]:
        b = ch.skeleton.names.index(name) - 1
        assert w[:, b].max() > 0.75, name
        mine = w[:, b] > 0.5
        seg_a, seg_b = ch.skeleton.positions[ch.skeleton.parents[b + 1]], ch.skeleton.positions[b + 1]
        t = np.clip((ch.vertices[mine] - seg_a) @ (seg_b - seg_a) / np.sum((seg_b - seg_a) ** 2), 0, 1)
        dist = np.linalg.norm(ch.vertices[mine] - (seg_a + t[:, None] * (seg_b - seg_a)), axis=1)
        assert dist.max() < 0.1 * ch.spec.size, name
    if kind == "humanoid":  # long limbs: their middles are rigidly attached
        for name in LIMBS[kind]:
            assert np.sum(w[:, ch.skeleton.names.index(name) - 1] == 1.0) >= 10, name


# ----------------------------------------------------------------------------------------------
# posing


@pytest.mark.parametrize("kind", KINDS)
def test_fk_matches_dual_quaternion_fk(characters, kind):
    import jax.numpy as jnp

    ch = characters[kind]
    pose, _ = random_pose(ch, 5)
    t = pose_world_transforms(ch.skeleton.positions, ch.skeleton.parents, pose)[:, :3, 3]
    world = forward_kinematics(ch.skeleton, Pose(jnp.asarray(pose.rotations), jnp.asarray(pose.translation)))
    np.testing.assert_allclose(t, np.asarray(joint_positions(world)), atol=1e-12)
    posed = pose_character(ch, pose)
    np.testing.assert_allclose(posed.joints, t, atol=0)
    # bone lengths are kept
    parents = ch.skeleton.parents
    np.testing.assert_allclose(
        np.linalg.norm(posed.joints[1:] - posed.joints[parents[1:]], axis=1), ch.skeleton.bone_lengths, rtol=1e-12
    )


@pytest.mark.parametrize("skinning", ["dqs", "lbs"])
def test_rest_and_rigid_motion(characters, skinning):
    ch = characters["hand"]
    rest = pose_character(ch, np.zeros((ch.skeleton.n_joints, 3)), skinning=skinning)
    np.testing.assert_allclose(rest.vertices, ch.vertices, atol=1e-14)
    # a root rotation + translation moves everything rigidly about the root joint
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    angle = np.radians(70.0)
    p0 = ch.skeleton.positions[0]
    s = np.array([0.1, -0.2, 0.3])
    posed = pose_character(ch, {"wrist": axis * angle, "translation": s}, skinning=skinning)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rot = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    np.testing.assert_allclose(posed.vertices, (ch.vertices - p0) @ rot.T + p0 + s, atol=1e-12)


@pytest.mark.parametrize("skinning", ["dqs", "lbs"])
def test_single_joint_rotation(characters, skinning):
    """Rotating the right elbow by 90° moves the forearm rigidly about the elbow, and nothing else."""
    ch = characters["humanoid"]
    names = ch.skeleton.names
    j = names.index("elbow_r")
    axis = ch.spec.flex_axes[j]
    posed = pose_character(ch, {"elbow_r": axis * np.pi / 2}, skinning=skinning)
    pe = ch.skeleton.positions[j]
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rot = np.eye(3) + k + k @ k  # 90°
    # frames moved by the elbow: the elbow's own frame and everything below it
    below = {j}
    for c in range(len(names)):
        if ch.skeleton.parents[c] in below:
            below.add(c)
    frame_of_bone = ch.skeleton.parents[1:]
    w_moving = ch.weights[:, np.isin(frame_of_bone, sorted(below))].sum(axis=1)
    rigid = w_moving > 1 - 1e-12
    still = w_moving < 1e-12
    assert rigid.sum() > 50 and still.sum() > 1000
    np.testing.assert_allclose(posed.vertices[rigid], (ch.vertices[rigid] - pe) @ rot.T + pe, atol=1e-12)
    np.testing.assert_allclose(posed.vertices[still], ch.vertices[still], atol=1e-12)
    # the wrist turned by 90° about the elbow
    wr = names.index("wrist_r")
    np.testing.assert_allclose(posed.joints[wr], (ch.skeleton.positions[wr] - pe) @ rot.T + pe, atol=1e-12)
    assert bone_angle_at(posed.joints, ch.skeleton.parents, j)[0] == pytest.approx(90.0, abs=1e-9)


@pytest.mark.parametrize("kind", KINDS)
def test_random_pose_has_large_rotation(characters, kind):
    ch = characters[kind]
    for seed in range(3):
        pose, info = random_pose(ch, seed)
        pose2, info2 = random_pose(ch, seed)
        assert np.array_equal(pose.rotations, pose2.rotations) and info == info2
        assert 60.0 <= info["large_angle_deg"] <= 100.0
        j = ch.skeleton.names.index(info["large_joint"])
        posed = pose_character(ch, pose)
        change = bone_angle_at(posed.joints, ch.skeleton.parents, j) - bone_angle_at(
            ch.skeleton.positions, ch.skeleton.parents, j
        )
        assert np.max(np.abs(change)) >= 60.0 - 1e-9
        # plus a global motion: the root turned and moved
        assert abs(pose.rotations[0, 0]) < 1.0 - 1e-6
        assert np.linalg.norm(pose.translation) > 0


def test_pose_inputs(characters):
    ch = characters["hand"]
    n = ch.skeleton.n_joints
    rv = np.zeros((n, 3))
    rv[ch.skeleton.names.index("index2")] = [0.3, 0.0, 0.0]
    a = pose_character(ch, rv)
    b = pose_character(ch, {"index2": [0.3, 0.0, 0.0]})
    c = pose_character(ch, pose_from_rotvecs(rv))
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.vertices, c.vertices)
    r = pose_character(ch, seed=4)
    assert r.info["large_joint"] is not None
    with pytest.raises(InputError, match="no joint named"):
        pose_character(ch, {"elbow_x": [0, 0, 1.0]})
    with pytest.raises(InputError, match="shape"):
        pose_character(ch, np.zeros((3, 3)))
    with pytest.raises(InputError, match="skinning"):
        pose_character(ch, rv, skinning="magic")


def test_bad_arguments():
    with pytest.raises(InputError, match="unknown character kind"):
        make_character("octopus", 0)
    with pytest.raises(InputError, match="resolution"):
        make_character("hand", 0, resolution=2)
    with pytest.raises(InputError, match="higher resolution"):
        make_character("hand", 0, resolution=12)


def test_check_closed_surface_finds_defects():
    s = trimesh.creation.icosphere(subdivisions=2)
    v, f = np.asarray(s.vertices), np.asarray(s.faces, dtype=np.int64)
    assert check_closed_surface(v, f) is None
    assert "boundary" in check_closed_surface(v, f[1:])
    flipped = f.copy()
    flipped[0] = flipped[0, ::-1]
    assert "directed edge" in check_closed_surface(v, flipped)
    two = np.concatenate([f, f + len(v)])
    assert "2 connected components" in check_closed_surface(np.concatenate([v, v + 3.0]), two)
    # glue two far-apart vertices: still one closed component, but a pinched (non-manifold) vertex
    far = int(np.argmax(np.linalg.norm(v - v[0], axis=1)))
    glued = np.where(f == far, 0, f)
    glued = np.where(glued > far, glued - 1, glued)
    assert "non-manifold" in check_closed_surface(np.delete(v, far, axis=0), glued)
