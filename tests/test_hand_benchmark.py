"""The hand benchmark scripts: pose classes and pair selection (benchmarks/hand_pairs.py), per-finger errors
(benchmarks/fingers.py), on inputs built here (a hand-made MANO-format model, the procedural hand).
"""

import csv
import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

from ncflow.io.mano import ManoModel
from ncflow.synthetic.bodies import character_spec

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(f"benchmarks_{name}", BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


hand_pairs = _load("hand_pairs")
fingers = _load("fingers")


# ----------------------------------------------------------------------------------------------
# pose classes


def _tips_at(reach: float, rng) -> np.ndarray:
    """Four fingertips at distance `reach` from the origin in random directions (mean distance = reach)."""
    d = rng.normal(size=(4, 3))
    return reach * d / np.linalg.norm(d, axis=1, keepdims=True)


def test_classify_poses_on_hand_made_fingertips():
    rng = np.random.default_rng(0)
    n = 40
    reach = 0.02 + 0.003 * np.arange(n)
    reach[0] = 0.0  # every fingertip on the palm centre
    palm = rng.normal(size=(n, 3))
    tips = np.zeros((n, 5, 3))
    for k in range(n):
        tips[k, :4] = palm[k] + _tips_at(reach[k], rng)
        tips[k, 4] = palm[k] + [0.0, 0.0, 1.0 + 0.001 * k]  # thumb far from every fingertip
    tips[10, 4] = tips[10, 0]  # thumb on the index tip
    tips[20, 4] = tips[20, 1] + [0.002, 0.0, 0.0]  # thumb 2 mm from the middle tip
    c = hand_pairs.classify_poses(tips, palm, fist_quantile=0.1, flat_quantile=0.9, pinch_quantile=0.04)
    np.testing.assert_allclose(c["reach"], reach, atol=1e-12)
    # quantile 0.1 of 40 sorted reaches lies between the 4th and 5th: poses 0-3 are fist-like
    assert np.flatnonzero(c["fist"]).tolist() == [0, 1, 2, 3]
    assert np.flatnonzero(c["flat"]).tolist() == [36, 37, 38, 39]
    assert c["pinch_gap"][10] == 0.0 and c["pinch_gap"][20] == pytest.approx(0.002)
    assert np.flatnonzero(c["pinch"]).tolist() == [10, 20]
    t = c["thresholds"]
    assert 0.02 + 0.003 * 3 <= t["fist_reach_max"] < 0.02 + 0.003 * 4
    assert 0.02 + 0.003 * 35 < t["flat_reach_min"] <= 0.02 + 0.003 * 36
    assert 0.002 <= t["pinch_gap_max"] < np.sort(c["pinch_gap"])[2]


MANO_PARENTS = [-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14]


def _fake_model() -> ManoModel:
    """A MANO-format model of 23 vertices: 0-15 the joints, 16-20 the tips (index, middle, little, ring, thumb),
    21-22 two more wrist vertices; fingers along +z, one-hot skinning, no pose blend shapes, PCA basis = identity.
    Rows of hands_coeffs: 0 flat; 1 the index MCP flexed 90 degrees about +x.
    """
    joints = np.zeros((16, 3))
    for finger, x in enumerate([0.02, 0.0, -0.04, -0.02]):
        for k in range(3):
            joints[1 + 3 * finger + k] = [x, 0.0, 0.08 + 0.03 * k]
    for k in range(3):
        joints[13 + k] = [0.03 + 0.02 * k, -0.01, 0.02 + 0.02 * k]
    tips = joints[[3, 6, 9, 12, 15]] + [0.0, 0.0, 0.02]
    v = np.concatenate([joints, tips, [[0.0, 0.01, 0.03], [0.0, -0.01, 0.06]]])
    weights = np.zeros((23, 16))
    weights[np.arange(16), np.arange(16)] = 1.0
    weights[16 + np.arange(5), [3, 6, 9, 12, 15]] = 1.0
    weights[21:, 0] = 1.0
    coeffs = np.zeros((2, 45))
    coeffs[1, 0] = math.pi / 2
    return ManoModel(
        v_template=v,
        faces=np.stack([np.arange(21), np.arange(1, 22), np.arange(2, 23)], axis=1),
        weights=weights,
        J_regressor=np.eye(16, 23),
        parents=np.array(MANO_PARENTS),
        posedirs=np.zeros((23, 3, 135)),
        hands_components=np.eye(45),
        hands_mean=np.zeros(45),
        hands_coeffs=coeffs,
    )


def test_pose_features_pose_the_model():
    model = _fake_model()
    tips, palm = hand_pairs.pose_features(model, [0, 1, "flat"], tip_vertices=[16, 17, 18, 19, 20])
    v = model.v_template
    np.testing.assert_allclose(tips[0], v[16:21], atol=1e-15)
    np.testing.assert_allclose(tips[2], v[16:21], atol=1e-15)
    # palm centre: vertices 0, 21, 22 (skinned to the wrist)
    np.testing.assert_allclose(palm, np.tile(v[[0, 21, 22]].mean(0), (3, 1)), atol=1e-15)
    # row 1: the index tip (0.02, 0, 0.16) turned 90 degrees about x around the MCP (0.02, 0, 0.08): (0.02, -0.08, 0.08)
    np.testing.assert_allclose(tips[1, 0], [0.02, -0.08, 0.08], atol=1e-12)
    np.testing.assert_allclose(tips[1, 1:], v[17:21], atol=1e-15)
    c = hand_pairs.classify_poses(tips[:2], palm[:2], fist_quantile=0.5, flat_quantile=0.5, pinch_quantile=0.0)
    assert c["fist"].tolist() == [False, True] and c["flat"].tolist() == [True, False]


# ----------------------------------------------------------------------------------------------
# pair selection


def _classes(n: int = 300) -> dict:
    k = np.arange(n)
    return {"fist": k % 10 == 0, "flat": k % 10 == 1, "pinch": k % 25 == 2}


def test_select_mano_pairs_follows_the_classes_and_the_seed():
    classes = _classes()
    pairs = hand_pairs.select_mano_pairs(classes, seed=3)
    assert len(pairs) == sum(hand_pairs.MANO_COUNTS.values()) >= 40
    kinds = [p["kind"] for p in pairs]
    assert {k: kinds.count(k) for k in set(kinds)} == hand_pairs.MANO_COUNTS
    rows = {"fist": set(np.flatnonzero(classes["fist"])), "flat": set(np.flatnonzero(classes["flat"]))}
    rows["pinch"] = set(np.flatnonzero(classes["pinch"]))
    for p in pairs:
        src, tgt = hand_pairs.KIND_CLASSES[p["kind"]]
        if isinstance(p["source"], str):
            assert (p["source"], p["target"]) == hand_pairs.NAMED_FIRST[p["kind"]]
            continue
        assert p["source"] != p["target"] and p["name"] == f"mano_{p['kind']}_{p['source']}_{p['target']}"
        assert src not in rows or p["source"] in rows[src]
        assert tgt not in rows or p["target"] in rows[tgt]
        if src == "notpinch":
            assert p["source"] not in rows["pinch"]
    assert [p["source"] for p in pairs if p["kind"] == "flatfist"][0] == "flat"
    assert [p["source"] for p in pairs if p["kind"] == "fistflat"][0] == "fist"
    assert len({(p["source"], p["target"]) for p in pairs}) == len(pairs)
    assert len({p["seed"] for p in pairs}) == len(pairs)
    turned = [p for p in pairs if p["target_rotation"] is not None]
    assert len(turned) == len(pairs) // 2
    assert all(p["target_rotation"] == [0.0, 180.0] and p["target_translation"] == [0.1, 0.5] for p in turned)
    assert hand_pairs.select_mano_pairs(classes, seed=3) == pairs
    assert hand_pairs.select_mano_pairs(classes, seed=4) != pairs


def test_procedural_hands_and_command_lines():
    hands = hand_pairs.select_procedural_hands(seed=0)
    assert len(hands) >= 10 and len({h["name"] for h in hands}) == len(hands)
    assert {h["large_joints"] for h in hands} == {2, 3, 4}
    assert 0 < sum(h["articulation"] == "curl" for h in hands) < len(hands)
    assert sum(h["target_rotation"] is not None for h in hands) == len(hands) // 2
    assert hand_pairs.select_procedural_hands(seed=0) == hands
    hand = {"name": "hand_x", "kind": "hand", "seed": 7, "large_joints": 3, "articulation": "curl"}
    hand.update(target_rotation=[0.0, 180.0], target_translation=[0.1, 0.5])
    assert hand_pairs.make_pairs_argv(hand, "m.npz", Path("out")) == [
        "make-pairs",
        "--overwrite",
        "--kind",
        "hand",
        "--n",
        "1",
        "--seed",
        "7",
        "--large-joints",
        "3",
        "--articulation",
        "curl",
        "--target-rotation",
        "0,180",
        "--target-translation",
        "0.1,0.5",
        str(Path("out") / "hand_x"),
    ]
    mano = {"name": "mano_flatfist_flat_fist", "kind": "flatfist", "source": "flat", "target": "fist", "seed": 20}
    mano.update(target_rotation=None, target_translation=None)
    assert hand_pairs.make_pairs_argv(mano, "m.npz", Path("out")) == [
        "make-pairs",
        "--overwrite",
        "--mano",
        "m.npz",
        "--poses",
        "flat,fist",
        "--retriangulate",
        "--seed",
        "20",
        str(Path("out") / "mano_flatfist_flat_fist"),
    ]


# ----------------------------------------------------------------------------------------------
# per-finger grouping


def _reference_group(names, parent: int, child: int) -> str:
    """The finger of bone (parent, child) of the procedural hand, from its joint names."""
    if names[parent] == "wrist":
        return "palm"
    return names[child].split("_")[0].rstrip("0123456789")


def _segment_distance(p, a, b) -> float:
    ab = b - a
    t = min(1.0, max(0.0, float(np.dot(p - a, ab) / np.dot(ab, ab))))
    return float(np.linalg.norm(p - (a + t * ab)))


def test_finger_groups_of_the_procedural_hand():
    spec = character_spec("hand", 3)
    parents, names = np.asarray(spec.parents), spec.names
    for given in (names, None):  # the joint names, or none (a TGF file): MANO's joint order
        labels, group = fingers.finger_groups(parents, given)
        assert labels == ["index", "middle", "little", "ring", "thumb", "palm"]
        expected = [_reference_group(names, int(parents[j]), j) for j in range(1, len(parents))]
        assert [labels[g] for g in group] == expected
    assert fingers.column_order(labels) == ["thumb", "index", "middle", "ring", "little", "palm"]


def test_finger_groups_of_an_unknown_tree():
    # 0 -> 1 (forearm), palm joint 1 with chains 2-3, 4-5-6 and the single bone 1-7
    parents = [-1, 0, 1, 2, 1, 4, 5, 1]
    labels, group = fingers.finger_groups(parents)
    assert labels == ["finger1", "finger2", "finger3", "palm"]
    assert [labels[g] for g in group] == ["palm", "palm", "finger1", "palm", "finger2", "finger2", "finger3"]
    names = ["arm", "hand", "Pinky_01", "x", "Thumb_01", "y", "z", "stub"]
    assert fingers.finger_groups(parents, names)[0] == ["pinky", "thumb", "stub", "palm"]


def test_vertex_groups_follow_the_nearest_bone():
    spec = character_spec("hand", 3)
    parents, names, pos = np.asarray(spec.parents), spec.names, spec.positions
    labels, bone_group = fingers.finger_groups(parents, names)
    j = {n: k for k, n in enumerate(names)}
    offset = np.array([0.0, 0.001, 0.0])
    points = np.stack(
        [
            0.5 * (pos[j["thumb2"]] + pos[j["thumb3"]]) + offset,
            0.5 * (pos[j["index2"]] + pos[j["index3"]]) + offset,
            0.5 * (pos[j["little3"]] + pos[j["little_tip"]]) + offset,
            0.5 * (pos[j["wrist"]] + pos[j["middle1"]]) + offset,
        ]
    )
    got = fingers.vertex_groups(points, pos, parents, bone_group)
    assert [labels[g] for g in got] == ["thumb", "index", "little", "palm"]
    rng = np.random.default_rng(1)
    lo, hi = pos.min(0) - 0.01, pos.max(0) + 0.01
    cloud = rng.uniform(lo, hi, size=(300, 3))
    got = fingers.vertex_groups(cloud, pos, parents, bone_group)
    bones = [(int(parents[c]), c) for c in range(1, len(parents))]
    for p, g in zip(cloud, got):
        b = min(range(len(bones)), key=lambda k: _segment_distance(p, pos[bones[k][0]], pos[bones[k][1]]))
        assert labels[g] == _reference_group(names, *bones[b])


# ----------------------------------------------------------------------------------------------
# per-finger numbers


def test_group_errors_and_summary():
    errors = np.array([0.1, 0.3, np.nan, 0.05, np.inf, 0.0])
    groups = np.array([0, 0, 0, 1, 1, 1])
    out = fingers.group_errors(errors, groups, ["thumb", "palm", "index"], tau=0.2)
    assert out["thumb"] == {"n": 2, "mean": pytest.approx(0.2), "share_beyond": 0.5}
    assert out["palm"]["n"] == 3 and out["palm"]["mean"] == np.inf
    assert out["palm"]["share_beyond"] == pytest.approx(1 / 3)
    assert out["index"]["n"] == 0 and math.isnan(out["index"]["mean"])

    def result(name, auc, means):
        groups = {g: {"n": 1, "mean": m, "share_beyond": float(m > 0.2)} for g, m in means.items()}
        return {"name": name, "auc": auc, "groups": groups, "worst": max(means, key=means.get)}

    pairs = [
        result("a", 0.9, {"thumb": 0.01, "index": 0.02, "palm": 0.005}),
        result("b", 0.5, {"thumb": 0.3, "index": 0.25, "palm": 0.01}),
        result("c", 0.8, {"thumb": 0.05, "index": 0.01, "palm": 0.02}),
    ]
    s = fingers.summarize(pairs, tau=0.2)
    assert s["mean_auc"] == pytest.approx(2.2 / 3)
    assert s["p10_auc"] == pytest.approx(0.5 + 0.2 * 0.3)  # numpy's linear percentile of 0.5, 0.8, 0.9
    assert s["worst_pair"] == "b"
    assert s["worst_finger_count"] == {"thumb": 2, "index": 1, "palm": 0}
    assert s["mean_above_tau_count"] == {"thumb": 1, "index": 1, "palm": 0}
    text = fingers.markdown(pairs, s)
    assert "| b | 0.500 | 0.300 | 0.250 | 0.010 | thumb |" in text
    assert "| worst finger of (pairs) | 2 | 1 | 0 |" in text


def test_pair_fingers_on_a_procedural_hand(tmp_path):
    """A run that maps every thumb vertex to a neighbouring vertex and every other vertex to its true point:
    the thumb's mean error is the mean edge length over √area, every other finger's is 0.
    """
    from ncflow.io.ground_truth import load_ground_truth
    from ncflow.io.meshes import load_mesh
    from ncflow.skeleton import load_skeleton
    from ncflow.synthetic.pairs import make_pair, write_pairs

    write_pairs([make_pair("hand", 2, retriangulate=False, resolution=30)], tmp_path / "pairs")
    root = tmp_path / "pairs"
    row = next(csv.DictReader(open(root / "pairs.csv", newline="")))
    source, target = load_mesh(root / row["source"]), load_mesh(root / row["target"])
    gt = load_ground_truth(root / row["gt"], source, target, "npz")
    corner = np.argmax(gt.bary, axis=1)
    vertex = source.faces[gt.face, corner]
    # independent grouping: nearest bone by brute force, finger from the procedural hand's joint names
    spec = character_spec("hand", 2)
    names, parents = spec.names, np.asarray(spec.parents)
    skel = load_skeleton(root / row["skeleton"])
    assert np.array_equal(skel.parents, parents)
    bones = [(int(parents[c]), c) for c in range(1, len(parents))]
    pos = skel.positions
    finger = []
    for p in source.vertices[vertex]:
        b = min(range(len(bones)), key=lambda k: _segment_distance(p, pos[bones[k][0]], pos[bones[k][1]]))
        finger.append(_reference_group(names, *bones[b]))
    finger = np.array(finger)
    on_thumb = finger == "thumb"
    assert 10 < on_thumb.sum() < 0.5 * finger.size
    face = np.zeros(target.n_vertices, dtype=np.int64)
    bary = np.zeros((target.n_vertices, 3))
    face[gt.target_index], bary[gt.target_index] = gt.face, gt.bary
    other = (corner + 1) % 3
    moved = gt.target_index[on_thumb]
    bary[moved] = np.eye(3)[other[on_thumb]]
    run = tmp_path / "run"
    run.mkdir()
    np.savez(run / "map_tgt_to_src.npz", face=face, bary=bary)
    headline = {"geodesic_auc": 0.75, "geodesic_mean": 0.5}
    (run / "evaluation.json").write_text(
        json.dumps({"headline": headline, "summary": {"geodesic_solver": {"method": "exact"}}})
    )
    result = fingers.pair_fingers(row, root, run)
    v, f = source.vertices, source.faces
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum()
    edge = np.linalg.norm(v[vertex[on_thumb]] - v[source.faces[gt.face[on_thumb], other[on_thumb]]], axis=1)
    g = result["groups"]
    assert g["thumb"]["n"] == on_thumb.sum()
    assert g["thumb"]["mean"] == pytest.approx(edge.mean() / math.sqrt(area), rel=1e-6)
    assert g["thumb"]["share_beyond"] == 0.0
    for name in ("index", "middle", "ring", "little", "palm"):
        assert g[name]["n"] == int(np.sum(finger == name)) > 0
        assert g[name]["mean"] == pytest.approx(0.0, abs=1e-9)
    assert result["worst"] == "thumb" and result["auc"] == 0.75
    assert result["mean_recomputed"] == pytest.approx(edge.sum() / math.sqrt(area) / finger.size, rel=1e-6)


def test_finger_search_counts_the_fingers_beyond_the_bound_never_the_palm():
    """benchmarks/finger_search.py: a finger is wrong when its largest joint error exceeds the bound; the
    palm, a finger without joints (None) and one exactly at the bound are not."""
    finger_search = _load("finger_search")
    pair = {"fingers": {"index": 0.31, "middle": 0.3, "little": None, "thumb": 1.2, "palm": 2.0}}
    assert finger_search.wrong_fingers(pair, 0.3) == ["index", "thumb"]
    assert finger_search.wrong_fingers(pair, 1.5) == []


def test_finger_joint_errors_takes_each_fingers_largest_joint_error():
    """benchmarks/fingers.py: on MANO's tree with fingertips, each finger's value is the largest error of the
    joints its bones end at (by hand: index joints 1, 2, 3 and its tip 16); the wrist's own error counts for
    no group; a group without bones is None."""
    fingers = _load("fingers")
    parents = np.array(fingers.MANO_PARENTS + (3, 6, 9, 12, 15))  # the five tips after MANO's 16 joints
    errors = np.zeros(parents.size)
    errors[0] = 9.0  # the wrist: no bone ends there
    errors[[1, 2, 3, 16]] = [0.1, 0.4, 0.2, 0.3]  # index
    errors[[13, 14, 15, 20]] = [0.05, 0.02, 0.5, 0.01]  # thumb
    out = fingers.finger_joint_errors(errors, parents)
    assert out["index"] == 0.4 and out["thumb"] == 0.5
    assert out["middle"] == out["little"] == out["ring"] == 0.0
    assert out["palm"] == 0.1  # the metacarpal bones (wrist -> 1, 4, 7, 10, 13) end at the chains' first joints
    two = fingers.finger_joint_errors(np.array([5.0, 0.7, 0.2]), [-1, 0, 0])  # two one-bone fingers, no palm bone
    assert two == {"finger1": 0.7, "finger2": 0.2, "palm": None}
