"""The result does not depend on where and how the target is placed (issue 16: placement).

A small generated pair is matched twice — as generated, and with the target turned by 135° about a
random axis and moved — with the same configuration; the geodesic AUC of the two correspondences
must agree within 0.02, every output must stay in the user's coordinates (the deformed source lies
on the target as given), and metrics.json records the placement found.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ncflow.config import apply_overrides, preset, scale_steps
from ncflow.evaluate import auc, closest_points_on_surface, geodesic_errors
from ncflow.geometry.mesh import Mesh
from ncflow.matcher.steps import match
from ncflow.synthetic.pairs import make_pair


def _config():
    cfg = apply_overrides(
        preset("fast"),
        [
            "flow.width=32",
            "flow.depth=2",
            "flow.gso_width=8",
            "flow.gso_depth=1",
            "sampling.bone_samples=8",
            "sampling.tissue_samples=0",
            "weights.tissue=0",
            "sampling.surface_edges=128",
            "compress=500",
            "frames=3",
            "pose_search=false",  # this test is about the placement; the pose search has its own
        ],
    )
    return scale_steps(cfg, 30)


@pytest.fixture(scope="module")
def pair():
    return make_pair("humanoid", seed=4, resolution=36, target_resolution=32)


def _geodesic_auc(p, result):
    gt = p.ground_truth
    e = geodesic_errors(p.source, result.maps["map_face"], result.maps["map_bary"], gt.face, gt.bary)
    return auc(e, 0.20)


def test_turned_and_moved_target_gives_the_same_correspondence(pair):
    cfg = _config()
    plain = match(pair.source, pair.target, pair.skeleton, cfg, quiet=True)
    r = Rotation.from_rotvec(np.radians(135.0) * np.array([0.6, -0.3, 0.74]) / np.linalg.norm([0.6, -0.3, 0.74]))
    moved_v = pair.target.vertices @ r.as_matrix().T + np.array([0.8, 0.5, -1.2])
    moved = match(pair.source, Mesh(moved_v, pair.target.faces, "moved"), pair.skeleton, cfg, quiet=True)
    a, b = _geodesic_auc(pair, plain), _geodesic_auc(pair, moved)
    assert a > 0.6  # a real match, not two equally failed ones
    assert abs(a - b) <= 0.02, (a, b)
    # outputs in the user's coordinates: the deformed source lies on the moved target, and the
    # last frame is the deformed source
    dist, _, _ = closest_points_on_surface(moved.deformed_source, moved_v, pair.target.faces)
    scale = np.linalg.norm(np.ptp(moved_v, axis=0))
    assert np.median(dist) < 0.02 * scale
    np.testing.assert_allclose(moved.frames[-1], moved.deformed_source, atol=1e-9)
    np.testing.assert_allclose(moved.frames[0], pair.source.vertices, atol=1e-9)
    placement = moved.metrics["placement"]
    assert placement["moved"] and 100.0 < placement["angle_degrees"] < 170.0  # 135° ± the pair's own turn
