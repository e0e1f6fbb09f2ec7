"""Self-overlap of a surface (ncflow.geometry.overlap) and the matcher's choice of bone weights."""

import dataclasses

import numpy as np
import pytest
import trimesh

from ncflow.config import apply_overrides, preset
from ncflow.geometry.overlap import DEFAULT_OFFSET, self_overlap
from ncflow.matcher.prepare import AUTO_OVERLAP, skinning_weight_mode


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
    assert fixed == {"setting": "current", "mode": "current", "source_overlap": None, "target_overlap": None}
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
