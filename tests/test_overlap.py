"""Self-overlap of a surface (ncflow.geometry.overlap) and the matcher's choice of bone weights."""

import dataclasses

import numpy as np
import pytest
import trimesh

from ncflow.config import apply_overrides, preset
from ncflow.geometry.overlap import DEFAULT_OFFSET, self_overlap
from ncflow.matcher.prepare import AUTO_CONTACT, AUTO_OVERLAP, skinning_weight_mode
from ncflow.skeleton import Skeleton


def _box(lo, hi, subdivisions=3):
    """A closed, outward-wound box [lo, hi] as a finely subdivided triangle mesh."""
    m = trimesh.creation.box(bounds=np.array([lo, hi], float))
    for _ in range(subdivisions):
        m = m.subdivide()
    return np.asarray(m.vertices), np.asarray(m.faces)


def _union(*meshes):
    vs, fs, n = [], [], 0
    for v, f in meshes:
        vs.append(v)
        fs.append(f + n)
        n += v.shape[0]
    return np.concatenate(vs), np.concatenate(fs)


def _inside(p, lo, hi):
    return np.all((p > np.asarray(lo)) & (p < np.asarray(hi)), axis=1)


def _oracle(v, f, boxes):
    """The overlapped share by point-in-box tests: a face is overlapped when its inward-moved centre is
    inside a box other than its own (each box's faces are consecutive)."""
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    diag = np.linalg.norm(v.max(0) - v.min(0))
    q = tri.mean(1) - DEFAULT_OFFSET * diag * cross / (2 * area[:, None])
    per_box = f.shape[0] // len(boxes)
    owner = np.arange(f.shape[0]) // per_box
    hit = np.zeros(f.shape[0], bool)
    for i, (lo, hi) in enumerate(boxes):
        hit |= (owner != i) & _inside(q, lo, hi)
    return area[hit].sum() / area.sum()


def test_a_closed_surface_without_self_intersection_has_none():
    v, f = _box([0, 0, 0], [1, 2, 0.5])
    assert self_overlap(v, f, max_vertices=10_000) == 0.0
    sphere = trimesh.creation.icosphere(subdivisions=4)  # 2562 vertices: decimated first
    assert self_overlap(sphere.vertices, sphere.faces) == 0.0


def test_interpenetrating_boxes_against_point_in_box_tests():
    boxes = [([0, 0, 0], [1, 1, 1]), ([0.6, 0.3, 0.2], [1.6, 1.1, 0.9])]
    v, f = _union(*(_box(lo, hi) for lo, hi in boxes))
    expected = _oracle(v, f, boxes)
    assert 0.05 < expected < 0.5  # the case is not trivial
    got = self_overlap(v, f, max_vertices=10_000)
    assert got == pytest.approx(expected, abs=1e-12)
    # the winding is either way round: the same share
    assert self_overlap(v, f[:, ::-1], max_vertices=10_000) == pytest.approx(expected, abs=1e-12)
    # two boxes apart: nothing overlaps
    apart = _union(_box([0, 0, 0], [1, 1, 1]), _box([2, 0, 0], [3, 1, 1]))
    assert self_overlap(*apart, max_vertices=10_000) == 0.0


def test_decimation_keeps_a_large_overlap():
    boxes = [([0, 0, 0], [1, 1, 1]), ([0.5, 0.2, 0.2], [1.5, 0.8, 0.8])]
    v, f = _union(*(_box(lo, hi, subdivisions=4) for lo, hi in boxes))  # 2 × 1538 vertices
    full = self_overlap(v, f, max_vertices=10_000)
    assert self_overlap(v, f) == pytest.approx(full, abs=0.05)  # decimated to 1000 vertices


def test_auto_weights_take_the_start_when_only_the_target_passes_through_itself():
    apart = _union(_box([0, 0, 0], [1, 1, 1], 2), _box([1.2, 0, 0], [2.2, 1, 1], 2))
    through = _union(_box([0, 0, 0], [1, 1, 1], 2), _box([0.7, 0, 0], [1.7, 1, 1], 2))
    cfg = preset("fast")
    assert cfg.flow.skinning_weights == "auto"
    got = skinning_weight_mode(cfg, *apart, *through)
    assert got["mode"] == "start" and got["source_overlap"] == 0.0
    assert got["target_overlap"] > AUTO_OVERLAP
    # the source passing through itself as much: a flow keeps that, so the weights stay current
    assert skinning_weight_mode(cfg, *through, *through)["mode"] == "current"
    assert skinning_weight_mode(cfg, *apart, *apart)["mode"] == "current"
    # a fixed setting is used as it is, without measuring
    fixed = skinning_weight_mode(apply_overrides(cfg, ["flow.skinning_weights=current"]), *apart, *through)
    assert fixed == {
        "setting": "current",
        "mode": "current",
        "source_contact": None,
        "source_overlap": None,
        "target_overlap": None,
    }
    paper = dataclasses.replace(cfg, flow=dataclasses.replace(cfg.flow, skinning=False))
    assert skinning_weight_mode(paper, *apart, *through)["mode"] == "current"
    with pytest.raises(Exception, match="skinning_weights"):
        apply_overrides(cfg, ["flow.skinning_weights=local"])


def test_a_strided_subset_of_the_faces_stands_for_them_all():
    # the bound on the work of a mesh with far more faces than vertices (max_pairs): a strided
    # tenth of the faces is tested instead of all of them
    boxes = [([0, 0, 0], [1, 1, 1]), ([0.6, 0.3, 0.2], [1.6, 1.1, 0.9])]
    v, f = _union(*(_box(lo, hi) for lo, hi in boxes))
    full = self_overlap(v, f, max_vertices=10_000)
    part = self_overlap(v, f, max_vertices=10_000, max_pairs=(f.shape[0] + 12) * f.shape[0] // 10)
    assert part != full  # the subset path ran
    assert part == pytest.approx(full, abs=0.05)


def _palm_and_finger(lift):
    """A palm (box) with its bone 0.3 under its top, and a finger (box) lying ``lift`` above the palm's
    top with its bone along its middle; the finger hangs off the palm's far end by two bones, so that its
    bone is three joints from the palm's (a curled finger's tip and its palm bone)."""
    palm = _box([0, 0, 0], [2, 1, 0.6], 2)
    finger = _box([0.5, 0.3, 0.6 + lift], [1.5, 0.7, 0.8 + lift], 2)
    z = 0.7 + lift
    joints = [[0, 0.5, 0.3], [2, 0.5, 0.3], [2, 0.5, z], [1.6, 0.5, z], [0.5, 0.5, z]]
    skel = Skeleton.from_arrays(joints, [-1, 0, 1, 2, 3])
    return (*_union(palm, finger), skel)


def test_auto_weights_see_the_skin_when_the_source_limbs_touch():
    """A finger resting on the palm: the palm's top skin lies nearer the finger's bone than its own, in
    front of it: the skin-aware weights of the start ("surface"), whatever the target; lifted clear of the
    palm, the rule of the overlaps as before."""
    cfg = preset("fast")
    v, f, skel = _palm_and_finger(0.02)
    apart_v, apart_f, apart_skel = _palm_and_finger(1.0)
    got = skinning_weight_mode(cfg, v, f, apart_v, apart_f, skel)
    assert got["mode"] == "surface" and got["source_contact"] > AUTO_CONTACT
    assert got["source_overlap"] is None  # decided before the overlaps are measured
    clear = skinning_weight_mode(cfg, apart_v, apart_f, v, f, apart_skel)
    assert clear["mode"] == "current" and clear["source_contact"] < 0.005
    # the share is the palm's top under and beside the finger: about its area over the whole, not less
    palm_top, total = 2.0 * 1.0, 2 * (2 * 1 + 2 * 0.6 + 1 * 0.6) + 2 * (1 * 0.4 + 1 * 0.2 + 0.4 * 0.2)
    assert 0.4 * 1.0 / total < got["source_contact"] < palm_top / total
    # the same bone over the palm two joints from the palm's (a neighbour in the limb, not another limb)
    near = Skeleton.from_arrays(np.delete(skel.positions, 3, axis=0), [-1, 0, 1, 2])
    assert near.bone_hops[2, 0] == 2
    assert skinning_weight_mode(cfg, v, f, apart_v, apart_f, near)["source_contact"] == 0.0
    fixed = skinning_weight_mode(apply_overrides(cfg, ["flow.skinning_weights=start"]), v, f, apart_v, apart_f, skel)
    assert fixed["mode"] == "start" and fixed["source_contact"] is None
