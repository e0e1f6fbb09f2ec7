"""Reproducible soft tissue (issue 18): versioned and locked cache, its hash, reuse of an exact tissue,
one tetrahedralisation per source in a benchmark."""

import threading
import time

import numpy as np
import pytest

import ncflow.tissue as tissue_mod
from ncflow.config import TissueConfig
from ncflow.errors import InputError
from ncflow.synthetic.shapes import capsule


def _fake_soft_tissue(calls, delay=0.0):
    def run(vertices, faces, **kwargs):
        calls.append(1)
        time.sleep(delay)
        rng = np.random.default_rng(len(calls))  # a different tissue on every call, like fTetWild
        c = rng.uniform(-0.2, 0.2, size=(50, 3))
        return tissue_mod.Tissue(np.zeros((0, 3)), np.zeros((0, 4), np.int64), c, np.ones(50), 10)

    return run


@pytest.fixture
def surface():
    return capsule(radius=0.4, length=3.0, n_around=10, n_along=12)


def test_cache_entry_has_hash_and_path_and_is_reused(monkeypatch, tmp_path, surface):
    monkeypatch.setenv("NCFLOW_CACHE_DIR", str(tmp_path))
    calls = []
    monkeypatch.setattr(tissue_mod, "soft_tissue", _fake_soft_tissue(calls))
    v, f = surface
    c1, info1 = tissue_mod.tissue_centroids(v, f, TissueConfig())
    c2, info2 = tissue_mod.tissue_centroids(v, f, TissueConfig())
    assert len(calls) == 1 and not info1["cached"] and info2["cached"]
    np.testing.assert_array_equal(c1, c2)
    assert info1["sha256"] == info2["sha256"] == tissue_mod.centroids_digest(c1)
    assert info1["cache_file"] == info2["cache_file"] and info1["cache_file"].startswith(str(tmp_path))
    # the key includes the tool versions: another pytetwild means another entry
    monkeypatch.setattr(tissue_mod, "_tool_versions", lambda: "ncflow=0,pytetwild=other")
    _, info3 = tissue_mod.tissue_centroids(v, f, TissueConfig())
    assert len(calls) == 2 and info3["cache_file"] != info1["cache_file"]


def test_concurrent_runs_tetrahedralise_once(monkeypatch, tmp_path, surface):
    monkeypatch.setenv("NCFLOW_CACHE_DIR", str(tmp_path))
    calls = []
    monkeypatch.setattr(tissue_mod, "soft_tissue", _fake_soft_tissue(calls, delay=0.3))
    v, f = surface
    out = []
    threads = [
        threading.Thread(target=lambda: out.append(tissue_mod.tissue_centroids(v, f, TissueConfig())[0]))
        for _ in range(3)
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(calls) == 1
    for c in out[1:]:
        np.testing.assert_array_equal(c, out[0])


def test_tissue_file_is_checked(tmp_path, surface):
    v, _ = surface
    good = tmp_path / "good.npz"
    np.savez(good, centroids=np.zeros((5, 3)))
    np.testing.assert_array_equal(tissue_mod.load_tissue_file(good, v), np.zeros((5, 3)))
    cases = {
        "shape.npz": np.zeros((5, 2)),
        "nan.npz": np.full((5, 3), np.nan),
        "far.npz": np.full((5, 3), 50.0),
    }
    for name, arr in cases.items():
        np.savez(tmp_path / name, centroids=arr)
        with pytest.raises(InputError, match=name):
            tissue_mod.load_tissue_file(tmp_path / name, v)
    (tmp_path / "junk.npz").write_bytes(b"PK\x03\x04 not an archive")
    with pytest.raises(InputError, match="junk.npz"):
        tissue_mod.load_tissue_file(tmp_path / "junk.npz", v)
    np.savez(tmp_path / "other.npz", points=np.zeros((5, 3)))
    with pytest.raises(InputError, match="centroids"):
        tissue_mod.load_tissue_file(tmp_path / "other.npz", v)


def test_prepare_uses_the_given_tissue_exactly(tmp_path, surface):
    import dataclasses

    from ncflow.config import preset
    from ncflow.geometry.mesh import Mesh
    from ncflow.matcher.prepare import prepare
    from ncflow.skeleton import Skeleton

    v, f = surface
    c = np.random.default_rng(0).uniform(-0.3, 0.3, size=(40, 3))
    path = tmp_path / "t.npz"
    np.savez(path, centroids=c)
    cfg = preset("fast")
    cfg = dataclasses.replace(
        cfg, placement="none", pose_search=False, tissue=dataclasses.replace(cfg.tissue, file=str(path))
    )
    skel = Skeleton.from_arrays(np.array([[0, 0, -1.6], [0, 0, 0.0], [0, 0, 1.6]]), np.array([-1, 0, 1]))
    prob = prepare(Mesh(v, f, "s"), Mesh(v, f, "t"), skel, cfg)
    np.testing.assert_array_equal(prob.centroids, c)
    assert prob.tissue_info["sha256"] == tissue_mod.centroids_digest(c)


def test_benchmark_tetrahedralises_each_source_once_for_all_methods(monkeypatch, tmp_path, surface):
    from ncflow.config import preset
    from ncflow.io.meshes import save_mesh
    from ncflow.runs.benchmark import PairSpec, RunTask, share_tissues

    monkeypatch.setenv("NCFLOW_CACHE_DIR", str(tmp_path / "cache"))
    calls = []
    monkeypatch.setattr(tissue_mod, "soft_tissue", _fake_soft_tissue(calls))
    v, f = surface
    save_mesh(tmp_path / "a.ply", v, f)
    save_mesh(tmp_path / "b.ply", v * 1.1, f)

    def pair(name):
        return PairSpec(name, str(tmp_path / name), "t.ply", "s.tgf", "identity", None, "d")

    cfg = preset("fast")
    tasks = [
        RunTask(m, pair(s), cfg, str(tmp_path / "runs" / m / s))
        for s in ("a.ply", "b.ply")
        for m in ("ncflow", "var-dq", "nc-dq")
    ]
    shared = share_tissues(tasks, tmp_path / "bench", log=lambda text: None)
    assert len(calls) == 2  # one per distinct source
    files = [t.config.tissue.file for t in shared]
    assert len(set(files[:3])) == 1 and len(set(files[3:])) == 1 and files[0] != files[3]
    c = np.load(files[0])["centroids"]
    np.testing.assert_array_equal(c, tissue_mod.load_tissue_file(files[0], c))
