"""The placement and the pose search of a pair kept in the cache folder (issue 17: fixed costs)."""

import dataclasses

import numpy as np
import pytest

import ncflow.matcher.place as prep
from ncflow.config import apply_overrides, preset
from ncflow.skeleton import Skeleton
from ncflow.synthetic.shapes import bend, capsule


@pytest.fixture(scope="module")
def pair():
    vs, fs = capsule(radius=0.4, length=3.0, n_around=8, n_along=10)
    skel = Skeleton.from_arrays(np.array([[0, 0, -1.6], [0, 0, 0.0], [0, 0, 1.6]]), np.array([-1, 0, 1]))
    turn = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # the target turned by 90° across its axis
    return vs / 3.0, fs, bend(vs, 60.0) @ turn.T / 3.0 + 0.1, fs, skel.with_positions(skel.positions / 3.0)


def _run(pair, cfg, monkeypatch, calls):
    """``place_and_pose_cached``, counting the searches it runs."""
    real = getattr(prep.place_and_pose, "real", prep.place_and_pose)

    def counted(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    counted.real = real
    monkeypatch.setattr(prep, "place_and_pose", counted)
    return prep.place_and_pose_cached(*pair, cfg)


def _same(a, b):
    (pa, sa, ta, *_), (pb, sb, tb, *_) = a, b
    assert pa == dataclasses.replace(pb, rotation=pa.rotation, translation=pa.translation)  # scores, moved
    np.testing.assert_array_equal(pa.rotation, pb.rotation)
    np.testing.assert_array_equal(pa.translation, pb.translation)
    np.testing.assert_array_equal(np.asarray(sa.pose.rotations), np.asarray(sb.pose.rotations))
    np.testing.assert_array_equal(np.asarray(sa.pose.translation), np.asarray(sb.pose.translation))
    assert (sa.score, sa.rest_score, sa.hypotheses) == (sb.score, sb.rest_score, sb.hypotheses)
    assert ta == tb


def test_a_second_run_reads_the_placement_and_pose_back_bit_for_bit(pair, tmp_path, monkeypatch):
    monkeypatch.setenv("NCFLOW_CACHE_DIR", str(tmp_path))
    cfg = preset("fast")
    calls = []
    first, info = _run(pair, cfg, monkeypatch, calls)
    assert calls == [1] and not info["hit"] and info["file"].startswith(str(tmp_path / "setup"))
    assert first[0].moved and first[1] is not None and len(first[2]) >= 2  # turned: placed, posed, candidates tried
    again, info2 = _run(pair, cfg, monkeypatch, calls)
    assert calls == [1] and info2 == {"hit": True, "file": info["file"]}
    _same(first, again)
    assert again[4] == 0.0  # no search this time
    # the settings it depends on make another entry; the training's do not
    _run(pair, apply_overrides(cfg, ["seed=1"]), monkeypatch, calls)
    assert calls == [1, 1]
    _, info3 = _run(pair, apply_overrides(cfg, ["flow.width=8", "frames=3"]), monkeypatch, calls)
    assert calls == [1, 1] and info3["hit"]
    # the chain search is one of them; "auto" without skin-aware weights searches no chains: the same entry
    _, info4 = _run(pair, apply_overrides(cfg, ["pose_chains=auto"]), monkeypatch, calls)
    assert calls == [1, 1] and info4["hit"]
    _run(pair, apply_overrides(cfg, ["pose_chains=on"]), monkeypatch, calls)
    assert calls == [1, 1, 1]


def test_the_chain_search_runs_where_pose_chains_asks():
    cfg = preset("fast")
    assert cfg.pose_chains == "off"
    for value, plain, skin_aware in (("off", None, None), ("auto", None, prep.CHAIN_SIGMA), ("on", 0.1, 0.1)):
        chosen = apply_overrides(cfg, [f"pose_chains={value}"])
        assert prep.chain_sigma(chosen, False) == plain and prep.chain_sigma(chosen, True) == skin_aware
    assert prep.chain_sigma(apply_overrides(cfg, ["pose_chains=on", "pose_search=false"]), True) is None


def test_a_broken_entry_is_computed_again_and_the_cache_can_be_off(pair, tmp_path, monkeypatch):
    monkeypatch.setenv("NCFLOW_CACHE_DIR", str(tmp_path))
    cfg = preset("fast")
    calls = []
    first, info = _run(pair, cfg, monkeypatch, calls)
    with open(info["file"], "wb") as f:
        f.write(b"PK\x03\x04 not an archive")
    again, info2 = _run(pair, cfg, monkeypatch, calls)
    assert calls == [1, 1] and not info2["hit"] and info2["file"] == info["file"]
    _same(first, again)
    _, info3 = _run(pair, cfg, monkeypatch, calls)
    assert calls == [1, 1] and info3["hit"]  # the entry was written again
    # an entry that reads but holds a non-finite pose is computed again too
    entry = dict(np.load(info["file"]))
    entry["pose_rotations"] = np.full_like(entry["pose_rotations"], np.nan)
    np.savez(info["file"], **entry)
    again, _ = _run(pair, cfg, monkeypatch, calls)
    assert calls == [1, 1, 1]
    _same(first, again)
    off, info4 = _run(pair, apply_overrides(cfg, ["setup_cache=false"]), monkeypatch, calls)
    assert calls == [1, 1, 1, 1] and info4 == {"hit": False, "file": None}
    _same(first, off)
    # nothing to keep without a placement or a pose search
    _, info5 = _run(pair, apply_overrides(cfg, ["placement=none", "pose_search=false"]), monkeypatch, calls)
    assert info5 == {"hit": False, "file": None} and sorted(p.name for p in (tmp_path / "setup").glob("*.npz")) == [
        info["file"].rsplit("/", 1)[1]
    ]
