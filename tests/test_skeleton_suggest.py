"""``ncflow skeleton suggest`` (ncflow.skeleton.suggest): on generated characters with known skeletons,
a joint near every true limb tip, every joint inside, a connected acyclic tree of 10–40 joints; a sphere
and a torus get a small skeleton inside; placement-free and deterministic; the command's file and errors."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from ncflow.cli import main
from ncflow.geometry.winding import winding_numbers
from ncflow.io.meshes import load_mesh, save_mesh
from ncflow.skeleton import load_skeleton
from ncflow.skeleton.suggest import prune_branches, suggest_skeleton
from ncflow.synthetic.characters import make_character

TIP_BOUND = 0.05
"""A true limb tip's nearest suggested leaf joint is within this share of the bounding-box diagonal."""


def _leaves(parents: np.ndarray) -> np.ndarray:
    return np.setdiff1d(np.arange(parents.shape[0]), parents[1:])


def _is_tree(parents: np.ndarray) -> bool:
    """One root first, every parent before its child: connected and acyclic."""
    return parents[0] == -1 and bool(np.all((parents[1:] >= 0) & (parents[1:] < np.arange(1, parents.shape[0]))))


KNOWN_MISS = pytest.mark.xfail(
    strict=True, reason="the index finger's branch is lost to the middle finger's (docs/skeleton-suggest.md, Limits)"
)


@pytest.mark.parametrize(
    "kind, seed",
    [
        ("humanoid", 0),
        ("humanoid", 1),
        ("hand", 0),
        ("hand", 1),
        pytest.param("hand", 2, marks=KNOWN_MISS),
        ("quadruped", 0),
    ],
)
def test_generated_characters(kind, seed):
    ch = make_character(kind, seed)
    v, f = ch.mesh.vertices, ch.mesh.faces
    diag = np.linalg.norm(np.ptp(v, axis=0))
    found = suggest_skeleton(v, f)
    sk = found.skeleton
    assert _is_tree(np.asarray(sk.parents)) and 10 <= sk.n_joints <= 40
    assert np.all(np.abs(winding_numbers(sk.positions, v[f])) > 0.5)  # every joint inside
    leaves = sk.positions[_leaves(np.asarray(sk.parents))]
    true_parents = np.asarray(ch.skeleton.parents)
    for tip in _leaves(true_parents):
        nearest = np.linalg.norm(leaves - ch.skeleton.positions[tip], axis=1).min()
        assert nearest < TIP_BOUND * diag, (ch.skeleton.names[tip], nearest / diag)


def test_placement_free_and_deterministic():
    """Rotated, moved and scaled mesh: the same joints, rotated, moved and scaled (the AGD is intrinsic)."""
    ch = make_character("humanoid", 0)
    v, f = ch.mesh.vertices, ch.mesh.faces
    first = suggest_skeleton(v, f).skeleton
    assert np.array_equal(suggest_skeleton(v, f).skeleton.positions, first.positions)
    r = Rotation.from_rotvec([0.4, -1.1, 0.7]).as_matrix()
    moved = suggest_skeleton(2.5 * v @ r.T + [3.0, -1.0, 0.5], f).skeleton
    np.testing.assert_array_equal(moved.parents, first.parents)
    diag = np.linalg.norm(np.ptp(v, axis=0))
    np.testing.assert_allclose((moved.positions - [3.0, -1.0, 0.5]) / 2.5, first.positions @ r.T, atol=1e-6 * diag)


@pytest.mark.parametrize("shape", ["sphere", "torus"])
def test_shapes_without_limbs(shape):
    mesh = trimesh.creation.icosphere(3) if shape == "sphere" else trimesh.creation.torus(1.0, 0.3)
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    sk = suggest_skeleton(v, f).skeleton
    assert _is_tree(np.asarray(sk.parents)) and 2 <= sk.n_joints <= 8
    assert np.all(np.abs(winding_numbers(sk.positions, v[f])) > 0.5)


def test_pruning_keeps_the_tip_and_drops_the_spur():
    """A chain 0-1-2-3-4 split at 3 into a tip 4 (0.1 long) and a spur 5 (0.05 long); a second branch at
    1 (node 6, 0.3 long) keeps node 1 a branch node. Pruned at 0.12: the spur goes first, then 3 is no
    branch and the tip stays."""
    c = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [3.1, 0, 0], [3, 0.05, 0], [1, 0.3, 0]], float)
    adj = [{1}, {0, 2, 6}, {1, 3}, {2, 4, 5}, {3}, {3}, {1}]
    pruned = prune_branches(adj, c, 0.12)
    assert pruned[5] == set() and pruned[4] == {3} and pruned[6] == {1}


def test_cli(tmp_path, capsys):
    ch = make_character("quadruped", 0)
    mesh = tmp_path / "animal.ply"
    save_mesh(mesh, ch.mesh.vertices, ch.mesh.faces)
    out = tmp_path / "sk" / "animal.tgf"
    assert main(["skeleton", "suggest", str(mesh), "--out", str(out)]) == 0
    assert "joints" in capsys.readouterr().out
    sk = load_skeleton(out)
    np.testing.assert_allclose(
        sk.positions, suggest_skeleton(ch.mesh.vertices, ch.mesh.faces).skeleton.positions, atol=1e-5
    )
    before = out.read_bytes()
    assert main(["skeleton", "suggest", str(mesh), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--overwrite" in err and err.count("\n") == 1 and out.read_bytes() == before
    assert main(["skeleton", "suggest", str(mesh), "--out", str(tmp_path / "x.bvh")]) == 2
    assert ".tgf or .json" in capsys.readouterr().err
    tiny = tmp_path / "tiny.ply"
    save_mesh(
        tiny,
        np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]),
        np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]),
    )
    assert main(["skeleton", "suggest", str(tiny), "--out", str(tmp_path / "t.tgf")]) == 2
    err = capsys.readouterr().err
    assert "tiny.ply" in err and "too few" in err and not (tmp_path / "t.tgf").exists()


def test_match_without_a_skeleton(tmp_path, capsys):
    """``ncflow match`` without ``--skeleton`` suggests one from the source: named in a warning and in
    metrics.json, written as skeleton_source.tgf (the suggestion's joints), read back by read_result."""
    from ncflow.geometry.mesh import repaired_mesh
    from ncflow.io.result import read_result
    from ncflow.synthetic.shapes import capsule
    from tiny import TINY

    vs, fs = capsule(radius=0.4, length=3.0, n_around=12, n_along=16)
    bend = Rotation.from_rotvec([0.6, 0.0, 0.0]).as_matrix()
    vt = np.where(vs[:, 2:3] > 0, vs @ bend.T, vs)
    src, tgt = tmp_path / "a.ply", tmp_path / "b.ply"
    save_mesh(src, vs, fs)
    save_mesh(tgt, vt, fs)
    out = tmp_path / "result"
    sets = [a for s in [*TINY, "compress=200", "placement=none", "pose_search=false"] for a in ("--set", s)]
    assert main(["match", str(src), str(tgt), "--out", str(out), "--steps", "12", "--quiet", *sets]) == 0
    source = repaired_mesh(load_mesh(src))[0]  # the match's intake step, default repair settings
    expected = suggest_skeleton(source.vertices, source.faces).skeleton
    written = load_skeleton(out / "skeleton_source.tgf")
    np.testing.assert_allclose(written.positions, expected.positions, atol=1e-5)
    np.testing.assert_array_equal(written.parents, expected.parents)
    res = read_result(out)
    assert res.skeleton_source is not None and res.skeleton_source.n_joints == expected.n_joints
    assert res.skeleton_target.n_joints == expected.n_joints
    info = res.metrics["skeleton_suggested"]
    assert info["n_joints"] == expected.n_joints and info["file"] == "skeleton_source.tgf"
    assert any(w.startswith("no skeleton given: one was suggested") for w in res.metrics["warnings"])
