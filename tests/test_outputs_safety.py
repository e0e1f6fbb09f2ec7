"""Where and how ncflow writes its outputs: output paths checked before any work, symbolic links,
foreign files, failing disks, folder modes, make-pairs sets, benchmark manifests and crashed workers.

The matcher is replaced by a stub that returns a tiny result at once (the point is the writing,
not the matching); results are written by the real :func:`ncflow.io.result.write_result`.
"""

from __future__ import annotations

import json
import os
import stat
import tempfile
from pathlib import Path

import numpy as np
import pytest

import ncflow.io.atomic as atomic
import ncflow.io.result as export
import ncflow.matcher.steps as matcher_module
import ncflow.runs.benchmark as bench
import ncflow.synthetic.pairs as pairs_module
from ncflow.cli import main
from ncflow.config import preset
from ncflow.evaluate import ground_truth_from_vertex_map
from ncflow.geometry.mesh import Mesh
from ncflow.io.fallback import save_result
from ncflow.io.result import CONTRACT_FILES, ResultFolder, read_result
from ncflow.skeleton import Skeleton
from ncflow.synthetic.pairs import Pair, write_pairs
from ncflow.synthetic.shapes import bend, capsule

# ----------------------------------------------------------------------------------------------
# a tiny result and a stub matcher


def _capsule():
    v, f = capsule(radius=0.4, length=2.0, n_around=6, n_along=5)
    return np.asarray(v, np.float64), np.asarray(f, np.int64)


class FakeResult:
    """What the CLI uses of a MatchResult: the arrays, ``metrics`` and ``save``."""

    def __init__(self, shift: float = 0.0, k: int = 3):
        v, f = _capsule()
        self.source = Mesh(v, f, "source")
        n = v.shape[0]
        self.frame_times = np.linspace(0.0, 1.0, k)
        self.frames = np.stack([v + shift + t for t in self.frame_times])
        self.deformed_source = self.frames[-1]
        self.maps = {
            "map_face": np.zeros(n, np.int64),
            "map_bary": np.tile([1.0, 0.0, 0.0], (n, 1)),
            "p2p_tgt_to_src": np.arange(n),
            "p2p_src_to_tgt": np.arange(n),
        }
        self.metrics = {
            "constraints": {"max_violation_ratio": 0.5, "all_satisfied": True},
            "timings": {"train": 0.0, "per_step": 0.0, "total": 0.0},
        }

    def to_folder(self) -> ResultFolder:
        return ResultFolder(
            deformed_source=self.deformed_source,
            source_faces=self.source.faces,
            maps=self.maps,
            frames=self.frames,
            frame_times=self.frame_times,
            metrics=self.metrics,
        )

    def save(self, out_dir, overwrite=False, *, shown=None):  # as MatchResult.save: the library's fallback
        return save_result(self.to_folder(), out_dir, overwrite=overwrite, shown=shown)


@pytest.fixture
def stub_matcher(monkeypatch):
    """Replace the matcher: records its calls and returns a FakeResult (``calls["shift"]`` sets its values)."""
    calls = {"n": 0, "shift": 1.0}

    class FakeMatcher:
        def __init__(self, *args, **kwargs):
            calls["n"] += 1

        def run(self):
            return FakeResult(calls["shift"])

    monkeypatch.setattr(matcher_module, "Matcher", FakeMatcher)
    return calls


def _tiny_pair(name: str = "tiny", angle: float = 40.0) -> Pair:
    v, f = _capsule()
    source = Mesh(v, f, name)
    skel = Skeleton.from_arrays(np.array([[0, 0, -1.0], [0, 0, 0.0], [0, 0, 1.0]]), np.array([-1, 0, 1]))
    gt = ground_truth_from_vertex_map(np.arange(len(v)), source, len(v))
    return Pair(name, source, Mesh(bend(v, angle), f, f"{name}_t"), skel, gt, "capsule")


@pytest.fixture
def stub_pairs(monkeypatch):
    """``make_pair`` returns tiny capsule pairs at once; ``calls["fail_at"]`` makes the k-th call raise."""
    calls = {"n": 0, "fail_at": None, "angle": 40.0}

    def fake_make_pair(kind, seed=0, **kwargs):
        calls["n"] += 1
        if calls["fail_at"] is not None and calls["n"] == calls["fail_at"]:
            raise OSError(28, "No space left on device (injected)")
        return _tiny_pair(f"{kind}_{int(seed):03d}", calls["angle"] + seed)

    monkeypatch.setattr(pairs_module, "make_pair", fake_make_pair)
    return calls


def _inputs(tmp_path: Path) -> list[str]:
    d = tmp_path / "in"
    d.mkdir(exist_ok=True)
    for name in ("s.ply", "t.ply", "k.tgf"):
        (d / name).write_text("stub\n")
    return [str(d / "s.ply"), str(d / "t.ply"), "--skeleton", str(d / "k.tgf")]


def _snapshot(folder: Path) -> dict:
    """Every entry under ``folder`` (hidden ones too), files with their bytes, links with their targets."""
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = str(p.relative_to(folder))
        if p.is_symlink():
            out[rel] = ("link", os.readlink(p))
        elif p.is_file():
            out[rel] = p.read_bytes()
        else:
            out[rel] = "dir"
    return out


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


# ----------------------------------------------------------------------------------------------
# 1. --out checked before any work


def _commands(tmp_path: Path, out: str) -> dict[str, list[str]]:
    csv = tmp_path / "in" / "pairs.csv"
    csv.write_text("name,source,target,skeleton,gt\np,s.ply,t.ply,k.tgf,identity\n")
    return {
        "match": ["match", *_inputs(tmp_path), "--out", out, "--quiet"],
        "demo": ["demo", "--out", out, "--quiet"],
        "make-pairs": ["make-pairs", out],
        "benchmark": ["benchmark", str(csv), "--out", out],
        "pose": ["pose", str(tmp_path / "in" / "rig.glb"), "--out", f"{out}/posed.ply"],
        "make-shape": ["make-shape", "sphere", f"{out}/shape.ply"],
        "evaluate": ["evaluate", out, "--source", "s.ply", "--target", "t.ply", "--gt", "identity"],
    }


@pytest.mark.parametrize("command", ["match", "demo", "make-pairs", "benchmark", "pose", "make-shape", "evaluate"])
@pytest.mark.parametrize("where", ["file", "under_file", "cwd", "ancestor", "no_space", "read_only"])
def test_out_is_checked_before_any_work(tmp_path, monkeypatch, capsys, stub_matcher, stub_pairs, command, where):
    _inputs(tmp_path)
    work = tmp_path / "work" / "deep"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    blocker = tmp_path / "blocker.txt"
    blocker.write_text("a user's file\n")
    if where == "file":
        out = str(blocker)
    elif where == "under_file":
        out = str(blocker / "sub")
    elif where == "cwd":
        out = "."
    elif where == "ancestor":
        out = str(tmp_path / "work")
    elif where == "no_space":
        out = str(tmp_path / "new")

        class Usage:
            total, used, free = 10**12, 10**12, 1000

        monkeypatch.setattr(atomic.shutil, "disk_usage", lambda p: Usage())
    else:
        if os.geteuid() == 0:
            pytest.skip("root writes anywhere")
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o555)
        out = str(ro / "new")
    if command in ("pose", "make-shape", "evaluate") and where in ("cwd", "ancestor"):
        pytest.skip("a file output inside the current folder is fine; evaluate adds files to an existing result")
    if command == "evaluate" and where == "no_space":
        out = str(tmp_path / "in")  # an existing folder (a result folder)
    import ncflow.evaluate.score as score

    monkeypatch.setattr(score, "evaluate_result", lambda *a, **k: pytest.fail("the evaluation started"))
    args = _commands(tmp_path, out)[command]
    if command in ("pose", "make-shape") and where == "file":
        args[-1] = str(tmp_path)  # a file output that is an existing folder
    monkeypatch.setattr(bench, "run_task", lambda t: pytest.fail("a run started"))
    before = _snapshot(tmp_path)
    try:
        rc = main(args)
    finally:
        if where == "read_only":
            (tmp_path / "ro").chmod(0o755)
    assert rc == 2
    err = _one_line(capsys)
    assert err.startswith(f"ncflow {command}: error:"), err
    assert stub_matcher["n"] == 0 and stub_pairs["n"] == 0  # nothing computed
    assert _snapshot(tmp_path) == before  # nothing written


# ----------------------------------------------------------------------------------------------
# 2. a symlinked --out and the user's files with --overwrite


def test_symlinked_out_with_overwrite_never_moves_user_files(tmp_path, monkeypatch, capsys, stub_matcher):
    monkeypatch.chdir(tmp_path)
    args = _inputs(tmp_path)
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("my notes\n")
    (mine / "data").mkdir()
    (mine / "data" / "scan.ply").write_text("my scan\n")
    link = tmp_path / "link"
    link.symlink_to(mine, target_is_directory=True)
    assert main(["match", *args, "--out", str(link), "--quiet"]) == 2  # occupied, no --overwrite
    assert "not empty" in _one_line(capsys)
    # first result, then a second one over it, both through the link
    for shift in (1.0, 2.0):
        stub_matcher["shift"] = shift
        assert main(["match", *args, "--out", str(link), "--overwrite", "--quiet"]) == 0
        assert link.is_symlink() and os.readlink(link) == str(mine)  # the link itself untouched
        assert (mine / "notes.txt").read_text() == "my notes\n"
        assert (mine / "data" / "scan.ply").read_text() == "my scan\n"
        res = read_result(mine)
        np.testing.assert_allclose(res.frames[0], FakeResult(shift).frames[0], atol=1e-5)
        no_skeleton = set(CONTRACT_FILES) - {
            "skeleton_target.tgf",
            "skeleton_frames.json",
            "skeleton_source.tgf",
            "target.ply",
            "source_seen.txt",
        }
        assert sorted(p.name for p in mine.iterdir()) == sorted([*no_skeleton, "notes.txt", "data"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in", "link", "mine"]  # nothing moved out
    # a file of the user's inside a contract folder: refused before any work, nothing touched
    (mine / "frames" / "my_render.png").write_bytes(b"png")
    before = _snapshot(tmp_path)
    n = stub_matcher["n"]
    assert main(["match", *args, "--out", str(link), "--overwrite", "--quiet"]) == 2
    assert "my_render.png" in _one_line(capsys)
    assert stub_matcher["n"] == n and _snapshot(tmp_path) == before


# ----------------------------------------------------------------------------------------------
# 3. a failing disk during the final write


def _fail_once(real, exc=None):
    state = {"done": False}

    def wrapper(*args, **kwargs):
        if not state["done"]:
            state["done"] = True
            raise exc or OSError(28, "No space left on device")
        return real(*args, **kwargs)

    return wrapper


STEPS = [
    "save_mesh",
    "_write_indices",
    "savez",
    "write_frames",
    "write_animation_glb",
    "atomic_write_text",
    "first_rename",
    "rename_mid_swap",
]


@pytest.mark.parametrize("step", STEPS)
@pytest.mark.parametrize("earlier", [True, False])
def test_failing_disk_leaves_nothing_partial_and_keeps_the_result(
    tmp_path, monkeypatch, capsys, stub_matcher, step, earlier
):
    monkeypatch.chdir(tmp_path)
    args = _inputs(tmp_path)
    systmp = tmp_path / "systmp"
    systmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(systmp))
    out = tmp_path / "res"
    if earlier:
        FakeResult(0.0).save(out)
        (out / "notes.txt").write_text("mine\n")
    before = _snapshot(tmp_path / "in"), (_snapshot(out) if earlier else None)
    if step == "savez":
        monkeypatch.setattr(export.np, "savez", _fail_once(np.savez))
    elif step in ("first_rename", "rename_mid_swap"):
        real = os.rename
        count = {"n": 0}
        fail_at = 1 if step == "first_rename" else 4

        def flaky(src, dst):
            count["n"] += 1
            if count["n"] == fail_at:
                raise OSError(5, "Input/output error")
            return real(src, dst)

        monkeypatch.setattr(atomic.os, "rename", flaky)
        if not earlier and step == "rename_mid_swap":
            pytest.skip("a new folder is moved into place by one rename")
    else:
        monkeypatch.setattr(export, step, _fail_once(getattr(export, step)))
    stub_matcher["shift"] = 5.0
    rc = main(["match", *args, "--out", str(out), "--quiet"] + (["--overwrite"] if earlier else []))
    monkeypatch.undo()
    assert rc != 0
    err = _one_line(capsys)
    assert "cannot write the result" in err and "Traceback" not in err
    # nothing partial: the earlier result (and the user's file) intact, or no folder at all
    if earlier:
        assert _snapshot(out) == before[1]
    else:
        assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["in", "systmp"] + (["res"] if earlier else []))
    # the trained result was kept: a complete copy under the system's temporary folder, named in the message
    (copy_base,) = list(systmp.iterdir())
    copy = copy_base / "result"
    assert str(copy) in err
    np.testing.assert_allclose(read_result(copy).frames, FakeResult(5.0).frames, atol=1e-5)


def test_cli_reports_os_errors_in_one_line(tmp_path, monkeypatch, capsys):
    """Any OSError escaping a command (here from the mesh writer) is one line, exit status 1."""
    import ncflow.io.meshes as meshes

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(meshes, "save_mesh", broken)
    assert main(["make-shape", "sphere", str(tmp_path / "s.ply"), "--resolution", "6"]) == 1
    assert "No space left on device" in _one_line(capsys)
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------------------------
# 4. folder modes


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_output_folders_honour_the_umask(tmp_path, umask, stub_pairs):
    old = os.umask(umask)
    try:
        out = FakeResult().save(tmp_path / "res")
        write_pairs([_tiny_pair()], tmp_path / "pairs")
    finally:
        os.umask(old)
    want = 0o777 & ~umask
    for folder in (out, out / "frames", tmp_path / "pairs", tmp_path / "pairs" / "pair_000"):
        assert stat.S_IMODE(folder.stat().st_mode) == want, folder


# ----------------------------------------------------------------------------------------------
# 5. make-pairs: no silent overwrite, the whole set atomically


def test_make_pairs_refuses_occupied_folder_and_writes_the_set_atomically(tmp_path, capsys, stub_pairs):
    out = tmp_path / "pairs"
    assert main(["make-pairs", str(out), "--n", "3"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["pair_000", "pair_001", "pair_002", "pairs.csv"]
    (out / "README.txt").write_text("my notes\n")
    first = _snapshot(out)
    n = stub_pairs["n"]
    # an existing non-empty folder: refused without --overwrite, before any pair is built
    assert main(["make-pairs", str(out), "--n", "2"]) == 2
    assert "not empty" in _one_line(capsys) and stub_pairs["n"] == n
    # interrupted part-way (the second pair fails): the old set is intact, nothing new beside it
    stub_pairs.update(fail_at=stub_pairs["n"] + 2, angle=70.0)
    assert main(["make-pairs", str(out), "--n", "2", "--overwrite"]) == 1
    _one_line(capsys)
    assert _snapshot(out) == first
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pairs"]
    # a full re-run with --overwrite: the new set replaces the old one as a whole, the user's file kept
    stub_pairs["fail_at"] = None
    assert main(["make-pairs", str(out), "--n", "2", "--overwrite"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["README.txt", "pair_000", "pair_001", "pairs.csv"]
    assert (out / "README.txt").read_text() == "my notes\n"
    rows = (out / "pairs.csv").read_text().splitlines()
    assert len(rows) == 3
    assert (out / "pair_000" / "target.ply").read_bytes() != first["pair_000/target.ply"]
    # a folder the user put under a pair name is not ncflow's: refused, not deleted
    (out / "pair_007").mkdir()
    (out / "pair_007" / "thesis.tex").write_text("x")
    assert main(["make-pairs", str(out), "--n", "1", "--overwrite"]) == 2
    assert "thesis.tex" in _one_line(capsys)
    assert (out / "pair_007" / "thesis.tex").read_text() == "x"


# ----------------------------------------------------------------------------------------------
# 7. benchmark: manifests and crashed workers


def _fake_match(task):
    FakeResult().save(task.run_dir, overwrite=True)


def _fake_evaluate(task):
    record = {
        "headline": {"geodesic_auc": 0.5, "chamfer_auc": 0.5, "conformal_auc": 0.5, "max_bone_violation_ratio": 0.1},
        "timings": {"match": 1.0, "evaluate": 0.5},
        "curves": {},
    }
    Path(task.run_dir, "evaluation.json").write_text(json.dumps(record))
    return record


def test_benchmark_resumes_only_runs_whose_manifest_matches(tmp_path, monkeypatch, capsys):
    csv_path = write_pairs([_tiny_pair("a"), _tiny_pair("b", 70.0)], tmp_path / "pairs")
    monkeypatch.setattr(bench, "_match", _fake_match)
    monkeypatch.setattr(bench, "_evaluate", _fake_evaluate)
    out = tmp_path / "bench"
    args = ["benchmark", str(csv_path), "--out", str(out), "--no-plots", "--steps", "5", "--jobs", "0"]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "ncflow/a: matched" in printed and "ncflow/b: matched" in printed
    manifest = json.loads((out / "runs" / "ncflow" / "a" / bench.MANIFEST_FILE).read_text())
    m = manifest["match"]
    assert len(m["source_sha256"]) == 64 and m["ncflow_version"] and m["config"]["seed"] == 0
    assert manifest["evaluation"]["gt_format"] == "npz" and manifest["evaluation"]["geodesic_method"] == "auto"
    assert len(manifest["evaluation"]["gt"]) == 1
    # the same command: both skipped
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "ncflow/a: skipped" in printed and "ncflow/b: skipped" in printed
    # pair a's target changed on disk: only it is matched again; another geodesic method: re-evaluated
    target = tmp_path / "pairs" / "pair_000" / "target.ply"
    target.write_bytes(target.read_bytes() + b"\n")
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "ncflow/a: matched" in printed and "ncflow/b: skipped" in printed
    assert main([*args, "--geodesic-method", "dijkstra"]) == 0
    printed = capsys.readouterr().out
    assert "ncflow/a: evaluated" in printed and "ncflow/b: evaluated" in printed
    # a run made before manifests existed is not trusted
    (out / "runs" / "ncflow" / "b" / bench.MANIFEST_FILE).unlink()
    assert main(args) == 0
    assert "ncflow/b: matched" in capsys.readouterr().out


def crashing_worker(task):
    """A benchmark worker whose process dies on the pair named ``crash`` (module level: spawn pickles it)."""
    if task.pair.name == "crash":
        os._exit(9)
    return {"method": task.method, "pair": task.pair.name, "status": "matched", "seconds": 0.0, "error": None}


def test_crashed_worker_is_a_failed_run_and_the_report_is_written(tmp_path, monkeypatch, capsys):
    spec = bench.PairSpec("ok", "s", "t", "k", "identity", None, "d")
    tasks = [
        bench.RunTask("ncflow", dataclasses_replace(spec, name=name), preset("fast"), str(tmp_path / name), False)
        for name in ("ok", "crash", "ok2")
    ]
    lines = []
    outcomes = bench._execute(tasks, 2, lines.append, lambda o: f"{o['pair']}: {o['status']}", worker=crashing_worker)
    got = {o["pair"]: o for o in outcomes}
    assert got["ok"]["status"] == "matched" and got["ok2"]["status"] == "matched"
    assert got["crash"]["status"] == "failed" and "crashed" in got["crash"]["error"]
    assert len(lines) == 3
    # the report is written even when a run failed and drawing the curve plots fails
    csv_path = write_pairs([_tiny_pair("a"), _tiny_pair("b", 70.0)], tmp_path / "pairs")
    monkeypatch.setattr(bench, "_match", _fake_match)

    def evaluate_or_fail(task):
        if task.pair.name == "b":
            raise RuntimeError("worker failed")
        return _fake_evaluate(task)

    monkeypatch.setattr(bench, "_evaluate", evaluate_or_fail)
    real_report = bench.write_benchmark_report

    def report(*args, plots=True, **kwargs):
        if plots:
            raise RuntimeError("no display")
        return real_report(*args, plots=plots, **kwargs)

    monkeypatch.setattr(bench, "write_benchmark_report", report)
    out = tmp_path / "bench"
    assert main(["benchmark", str(csv_path), "--out", str(out), "--steps", "5", "--jobs", "0"]) == 1
    rows = {r["pair"]: r for r in json.loads((out / "report.json").read_text())["runs"]}
    assert rows["a"]["status"] == "ok" and rows["b"]["status"] == "failed" and "worker failed" in rows["b"]["error"]
    assert (out / "report.md").is_file()


def dataclasses_replace(obj, **changes):
    import dataclasses

    return dataclasses.replace(obj, **changes)


def test_demo_refuses_a_foreign_view_page_before_any_work(tmp_path, capsys, stub_matcher):
    out = tmp_path / "demo"
    out.mkdir()
    (out / "view.html").write_text("my page\n")
    before = _snapshot(tmp_path)
    assert main(["demo", "--out", str(out), "--overwrite", "--quiet"]) == 2
    line = _one_line(capsys)
    assert "view.html" in line and "not written by ncflow demo" in line
    assert stub_matcher["n"] == 0 and _snapshot(tmp_path) == before
