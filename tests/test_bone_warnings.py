"""Bones that end beyond their tolerance ε are named, with their violation and its likely cause
(ncflow.matcher.result.bones_beyond_tolerance), and the multiplier schedule's ceiling is the sum of its
steps."""

import jax.numpy as jnp
import numpy as np
import pytest

import ncflow
from ncflow.config import apply_overrides, preset, scale_steps
from ncflow.geometry.mesh import Mesh
from ncflow.matcher.result import bones_beyond_tolerance
from ncflow.optim.mdmm import ascend_multipliers, multiplier_ceiling, multiplier_rate
from ncflow.skeleton import Skeleton
from ncflow.synthetic.shapes import capsule
from tiny import TINY


@pytest.mark.parametrize(("lr", "n"), [(1.0, 400), (0.5, 37), (2.0, 1)])
def test_the_ceiling_is_what_an_always_violated_multiplier_reaches(lr, n):
    lam = jnp.zeros(1, jnp.float64)
    for d in range(n):
        lam = ascend_multipliers(lam, jnp.ones(1, jnp.float64), 0.0, multiplier_rate(lr, d / n))
    brute = sum(2.0 * lr * d / n for d in range(n))
    assert multiplier_ceiling(lr, n) == pytest.approx(brute, rel=1e-12)
    assert float(lam[0]) == pytest.approx(brute, rel=1e-5)


def _row(name, g_ep, g_tr, lam_ep, lam_tr=0.0):
    return {
        "bone": name,
        "g_endpoint": g_ep,
        "g_trajectory": g_tr,
        "multiplier_endpoint": lam_ep,
        "multiplier_trajectory": lam_tr,
    }


def test_bones_beyond_tolerance_are_named_largest_first_with_their_cause():
    eps = 1e-3
    rows = [
        _row("a -> b", 0.5e-3, 0.9e-3, 10.0),
        _row("b -> c", 1.5e-3, 0.2e-3, 399.0),
        _row("c -> d", 0.1e-3, 4.0e-3, 50.0, 399.0),
        _row("d -> e", 1.0e-3, 1.0e-3, 0.0),  # at ε: held
    ]
    beyond, warning = bones_beyond_tolerance(rows, eps, 399.0)
    assert [b["bone"] for b in beyond] == ["c -> d", "b -> c"]
    assert [round(b["violation_ratio"], 6) for b in beyond] == [4.0, 1.5]
    assert all(b["multiplier_at_ceiling"] for b in beyond)
    assert warning.startswith("2 of 4 bones end beyond their tolerance ε: c -> d (4 ε), b -> c (1.5 ε); 2 of them")
    assert "skeleton may not reach" in warning
    # below the ceiling: held in training, beyond ε on the final samples
    beyond, warning = bones_beyond_tolerance([_row("a -> b", 1.2e-3, 0.0, 20.0)], eps, 399.0)
    assert beyond[0]["multiplier_at_ceiling"] is False and "final fresh samples" in warning
    assert bones_beyond_tolerance(rows[:1] + rows[3:], eps, 399.0) == ([], None)


def test_bones_a_stretched_target_pulls_beyond_tolerance_are_named_in_a_warning():
    """The target's upper half is 60 % longer along the bone, which no pose of the skeleton reaches; in a
    short run (30 steps) both bones end beyond ε (the upper one most) and the match names them, as
    ``metrics.json`` lists them, largest violation first.
    """
    vs, fs = capsule(radius=0.4, length=3.0, n_around=9, n_along=12)
    vt = vs.copy()
    vt[:, 2] = np.where(vt[:, 2] > 0, 1.6 * vt[:, 2], vt[:, 2])
    skel = Skeleton.from_arrays(np.array([[0, 0, -1.6], [0, 0, 0.0], [0, 0, 1.6]]), np.array([-1, 0, 1]))
    tiny = [*TINY, "compress=200", "placement=none", "pose_search=false"]
    cfg = scale_steps(apply_overrides(preset("fast"), tiny), 30)
    result = ncflow.match(Mesh(vs, fs, "source"), Mesh(vt, fs, "stretched"), skel, cfg, quiet=True)
    c, eps = result.metrics["constraints"], cfg.constraints.eps
    ratios = {b["bone"]: max(b["g_endpoint"], b["g_trajectory"]) / eps for b in c["bones"]}
    assert sorted(ratios, key=ratios.get, reverse=True) == ["joint 1 -> joint 2", "joint 0 -> joint 1"]
    assert min(ratios.values()) > 1.1  # well beyond ε: the comparison below can fail
    assert [b["bone"] for b in c["beyond_tolerance"]] == ["joint 1 -> joint 2", "joint 0 -> joint 1"]
    expected = [ratios["joint 1 -> joint 2"], ratios["joint 0 -> joint 1"]]
    assert [b["violation_ratio"] for b in c["beyond_tolerance"]] == expected
    warning = [w for w in result.metrics["warnings"] if "beyond their tolerance" in w]
    assert len(warning) == 1
    top = ratios["joint 1 -> joint 2"]
    assert warning[0].startswith(f"2 of 2 bones end beyond their tolerance ε: joint 1 -> joint 2 ({top:.2g} ε), ")
