"""``ncflow batch`` on Dask: the task engine with cheap fake tasks (retries, dead workers, resume, summary,
Ctrl-C), hostile csv files and scheduler addresses, and real tiny matches on a local cluster (a worker
killed, the rerun, ``--jobs 1`` against ``--jobs 2``) and on a real ``dask scheduler`` + two ``dask worker``.

Worker processes import ``ncflow`` afresh: the fake task functions of this module travel by value
(cloudpickle), and the real matches share one persistent compilation cache folder (``jit_cache``), so
only the first pair of the session compiles.
"""

import dataclasses
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import cloudpickle
import numpy as np
import pytest

import ncflow.runs.batch as batch
from ncflow.cli import main
from ncflow.config import preset
from ncflow.errors import InputError
from ncflow.evaluate import ground_truth_from_vertex_map
from ncflow.geometry.mesh import Mesh
from ncflow.io.result import read_result
from ncflow.runs.cluster import open_client, worker_environment
from ncflow.runs.engine import TEST_KILL_ENV, Task, run_tasks
from ncflow.skeleton import Skeleton
from ncflow.synthetic.pairs import Pair, write_pairs
from ncflow.synthetic.shapes import bend, capsule

cloudpickle.register_pickle_by_value(sys.modules[__name__])

CONTRACT = (
    "deformed_source.ply",
    "p2p_src_to_tgt.txt",
    "p2p_tgt_to_src.txt",
    "map_tgt_to_src.npz",
    "frames/frame_0000.ply",
    "frames/frame_0001.ply",
    "animation.glb",
    "skeleton_target.tgf",
    "skeleton_frames.json",
    "target.ply",
)


def tiny_args(jit_dir):
    """The cheapest real match: 2 steps, 2 frames, one data term, tiny nets, no placement, pose search,
    skinning field or MDMM (soft constraints)."""
    sets = {
        "flow.width": 8,
        "flow.depth": 1,
        "flow.gso_width": 4,
        "flow.gso_depth": 1,
        "flow.n_times": 3,
        "flow.skinning": "false",
        "sampling.bone_samples": 5,
        "sampling.tissue_samples": 16,
        "sampling.surface_edges": 0,
        "weights.surface": 0,
        "compress": "none",
        "placement": "none",
        "pose_search": "false",
        "jit_cache": str(jit_dir),
    }
    args = ["--steps", "2", "--frames", "2", "--metric", "varifold", "--constraints", "soft"]
    for k, v in sets.items():
        args += ["--set", f"{k}={v}"]
    return args


def capsule_pairs(folder, angles):
    """Capsule pairs (one source, targets bent by ``angles`` degrees), written with a pairs csv."""
    vs, fs = capsule(radius=0.4, length=3.0, n_around=8, n_along=8)
    source = Mesh(vs, fs, "capsule")
    skel = Skeleton.from_arrays(np.array([[0, 0, -1.6], [0, 0, 0.0], [0, 0, 1.6]]), np.array([-1, 0, 1]))
    gt = ground_truth_from_vertex_map(np.arange(len(vs)), source, len(vs))
    pairs = [Pair(f"bend_{a}", source, Mesh(bend(vs, float(a)), fs, f"bend_{a}"), skel, gt, "capsule") for a in angles]
    return write_pairs(pairs, folder)


def subset_csv(csv_path, names, name="subset.csv"):
    lines = Path(csv_path).read_text().splitlines()
    keep = [lines[0]] + [ln for ln in lines[1:] if ln.split(",")[0] in names]
    out = Path(csv_path).with_name(name)
    out.write_text("\n".join(keep) + "\n")
    return out


def summary(out):
    data = json.loads((Path(out) / "batch.json").read_text())
    return data, {p["name"]: p for p in data["pairs"]}


# ----------------------------------------------------------------------------------------------
# The engine with fake tasks (no JAX)


def fake_task(arg):
    """A task of the engine tests: ``arg = (kind, marker_dir)``."""
    kind, marker_dir = arg
    if kind == "die":
        os.kill(os.getpid(), signal.SIGKILL)
    if kind == "raise":
        raise RuntimeError("always broken\nsecond line")
    if kind == "bad":
        raise InputError("bad input", "x.ply")
    if kind == "flaky":
        marker = Path(marker_dir) / "flaky-tried"
        if not marker.exists():
            marker.write_text("1")
            raise RuntimeError("first attempt fails")
    time.sleep(0.3)
    return {"kind": kind, "pid": os.getpid()}


def test_engine_retries_once_and_survives_dead_workers(tmp_path):
    kinds = ["ok1", "die", "ok2", "raise", "bad", "flaky", "ok3", "ok4"]
    seen = []
    with open_client(2) as (client, info):
        assert info["kind"] == "local" and info["workers"] == 2 and info["threads_per_worker"] == 1
        env = client.run(lambda: (os.environ.get("MALLOC_TRIM_THRESHOLD_"), os.environ.get("PJRT_NPROC")))
        # Dask's nanny would set MALLOC_TRIM_THRESHOLD_, which makes XLA:CPU's allocations 4x slower
        assert sorted(env.values()) == [(None, "1"), (None, "1")]
        out = run_tasks(
            client,
            [Task(k, fake_task, (k, str(tmp_path))) for k in kinds],
            on_done=lambda o: seen.append(o.key),
            progress=False,
        )
    got = {o.key: o for o in out}
    assert [o.key for o in out] == kinds and sorted(seen) == sorted(kinds)
    for k in ("ok1", "ok2", "ok3", "ok4"):  # no task is taken down with the worker that "die" kills
        assert (got[k].status, got[k].attempts, got[k].error) == ("ok", 1, None)
        assert got[k].value["pid"] != os.getpid() and got[k].worker.endswith(str(got[k].value["pid"]))
    assert (got["die"].status, got["die"].attempts) == ("failed", 2) and "crashed" in got["die"].error
    assert (got["raise"].status, got["raise"].attempts) == ("failed", 2)
    assert got["raise"].error == "RuntimeError: always broken"  # one line
    assert (got["bad"].status, got["bad"].attempts) == ("failed", 1)  # bad input is not retried
    assert got["bad"].error.startswith("InputError: x.ply: bad input")
    assert (got["flaky"].status, got["flaky"].attempts, got["flaky"].value["kind"]) == ("ok", 2, "flaky")


def fake_match(job):
    """Stands in for :func:`ncflow.runs.batch.match_pair`: writes metrics.json and the manifest,
    fails on the pairs the marker files name."""
    name = job.pair.name
    if (Path(job.run_dir).parent / f"raise-{name}").exists():
        raise RuntimeError(f"{name} is broken")
    time.sleep(0.2)
    run_dir = Path(job.run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    record = {"tissue_file": job.config.tissue.file, "seed": job.config.seed, "pid": os.getpid()}
    (run_dir / "metrics.json").write_text(json.dumps(record))
    batch.write_manifest(run_dir, job.manifest)
    return {"steps": 0}


def test_batch_summary_resume_and_interrupt(tmp_path, monkeypatch):
    csv_path = capsule_pairs(tmp_path / "pairs", (20, 40, 60, 80))
    out = tmp_path / "out"
    out.mkdir()
    monkeypatch.setattr(batch, "match_pair", fake_match)
    monkeypatch.setenv(TEST_KILL_ENV, "bend_40")
    (out / "raise-bend_60").write_text("")
    cfg = preset("fast")
    lines = []

    res = batch.run_batch(csv_path, out, cfg, jobs=2, progress=False, log=lines.append)
    data, rows = summary(out)
    assert res.summary == data and res.n_failed == 2
    assert {n: (r["status"], r["attempts"]) for n, r in rows.items()} == {
        "bend_20": ("ok", 1),
        "bend_40": ("failed", 2),
        "bend_60": ("failed", 2),
        "bend_80": ("ok", 1),
    }
    assert "crashed" in rows["bend_40"]["error"] and rows["bend_60"]["error"] == "RuntimeError: bend_60 is broken"
    assert data["counts"] == {"ok": 2, "skipped": 0, "failed": 2, "interrupted": 0} and not data["interrupted"]
    assert data["cluster"]["kind"] == "local" and data["cluster"]["workers"] == 2
    assert data["config"]["seed"] == 0 and "jit_cache" not in data["config"]
    # every pair of the one source reads one shared tissue file, computed once
    tissues = list((out / "tissue").iterdir())
    assert len(tissues) == 1 and sum("tissue of source.ply" in ln for ln in lines) == 1
    for name in ("bend_20", "bend_80"):
        assert json.loads((out / name / "metrics.json").read_text())["tissue_file"] == str(tissues[0])
        manifest = batch.read_manifest(out / name)
        pair_dir = Path(rows[name]["source"]).parent
        assert manifest["match"]["source_sha256"] == batch.file_sha256(pair_dir / "source.ply")
        assert manifest["match"]["config"]["tissue"]["file"] == f"sha256:{batch.file_sha256(tissues[0])}"

    # the same command: only the two failed pairs run (and now succeed)
    monkeypatch.delenv(TEST_KILL_ENV)
    (out / "raise-bend_60").unlink()
    before = {n: (out / n / "metrics.json").stat().st_mtime_ns for n in ("bend_20", "bend_80")}
    batch.run_batch(csv_path, out, cfg, jobs=2, progress=False, log=lines.append)
    data, rows = summary(out)
    assert {n: r["status"] for n, r in rows.items()} == {
        "bend_20": "skipped",
        "bend_40": "ok",
        "bend_60": "ok",
        "bend_80": "skipped",
    }
    assert {n: (out / n / "metrics.json").stat().st_mtime_ns for n in before} == before

    # an input changed on disk: only its pair runs again
    target = Path(rows["bend_80"]["target"])
    target.write_bytes(target.read_bytes() + b"\n")
    batch.run_batch(csv_path, out, cfg, jobs=1, progress=False, log=lines.append)
    _, rows = summary(out)
    assert [n for n, r in rows.items() if r["status"] == "ok"] == ["bend_80"]

    # Ctrl-C after the first pair of a new seed: batch.json is written, the rest marked interrupted
    def interrupt(line):
        if line.startswith("[1/"):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        batch.run_batch(csv_path, out, dataclasses.replace(cfg, seed=7), jobs=1, progress=False, log=interrupt)
    data, rows = summary(out)
    assert data["interrupted"] and data["seed"] == 7
    assert data["counts"]["ok"] == 1 and data["counts"]["interrupted"] == 3


# ----------------------------------------------------------------------------------------------
# Bad input: one line, exit 2, before any work


@pytest.mark.parametrize(
    "rows, message",
    [
        ("name,source,target\nx,s.tgf,s.tgf\n", "missing column(s) skeleton"),
        ("name,source,target,skeleton\nx,s.tgf,s.tgf,s.tgf\nx,s.tgf,s.tgf,s.tgf\n", "duplicate pair name 'x'"),
        ("name,source,target,skeleton\nAb,s.tgf,s.tgf,s.tgf\naB,s.tgf,s.tgf,s.tgf\n", "ignoring case"),
        ("name,source,target,skeleton\n../up,s.tgf,s.tgf,s.tgf\n", "line 2: pair name '../up'"),
        ("name,source,target,skeleton\na/b,s.tgf,s.tgf,s.tgf\n", "line 2: pair name 'a/b'"),
        ("name,source,target,skeleton\nx,nope.ply,s.tgf,s.tgf\n", "line 2: source file not found"),
        ("name,source,target,skeleton\nx,s.tgf,,s.tgf\n", "line 2: empty 'target'"),
        ("name,source,target,skeleton,name\nx,s.tgf,s.tgf,s.tgf,y\n", "column(s) name appear more than once"),
        ("name,source,target,skeleton\n", "no pairs listed"),
    ],
)
def test_bad_csv_is_one_line_before_any_work(tmp_path, capsys, monkeypatch, rows, message):
    (tmp_path / "s.tgf").write_text("0 0 0\n0 0 1\n#\n1 2\n")
    csv_path = tmp_path / "pairs.csv"
    csv_path.write_text(rows)
    monkeypatch.setattr(batch, "open_client", lambda *a, **k: pytest.fail("a cluster started"))
    out = tmp_path / "out"
    assert main(["batch", str(csv_path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and "pairs.csv" in err, err
    assert err.startswith("ncflow batch: error:") and not out.exists()


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_scheduler_address_problems_are_one_line_and_quick(tmp_path, capsys):
    csv_path = tmp_path / "pairs.csv"
    (tmp_path / "s.tgf").write_text("0 0 0\n0 0 1\n#\n1 2\n")
    csv_path.write_text("name,source,target,skeleton\nx,s.tgf,s.tgf,s.tgf\n")
    out = tmp_path / "out"
    port = _free_port()  # nothing listens there
    t0 = time.perf_counter()
    assert main(["batch", str(csv_path), "--out", str(out), "--scheduler", f"tcp://127.0.0.1:{port}"]) == 2
    assert time.perf_counter() - t0 < 20
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no Dask scheduler answers" in err and str(port) in err, err
    for args, message in [
        (["--scheduler", "nowhere"], "not a Dask scheduler address"),
        (["--scheduler", "tcp://127.0.0.1:70000"], "port 70000 out of range"),
        (["--scheduler", "tcp://127.0.0.1:1", "--jobs", "2"], "--jobs and --threads size the local cluster"),
        (["--jobs", "-1"], "--jobs must be at least 0"),
        (["--threads", "0"], "--threads must be at least 1"),
    ]:
        assert main(["batch", str(csv_path), "--out", str(out), *args]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and message in err, err
    assert not out.exists()


# ----------------------------------------------------------------------------------------------
# Real tiny matches


@pytest.fixture(scope="module")
def real_batch(tmp_path_factory):
    """Tiny real matches: ``bend_30`` alone with ``--jobs 1`` (it fills the compilation cache), then
    ``bend_30``, ``bend_50`` and ``bend_80`` on a 2-worker local cluster, the worker that runs ``bend_50``
    killed (twice)."""
    base = tmp_path_factory.mktemp("real")
    csv_path = capsule_pairs(base / "pairs", (30, 50, 80))
    jit = base / "jit"
    one = subset_csv(csv_path, {"bend_30"})
    rc1 = main(["batch", str(one), "--out", str(base / "jobs1"), "--jobs", "1", *tiny_args(jit)])
    old = os.environ.get(TEST_KILL_ENV)
    os.environ[TEST_KILL_ENV] = "bend_50"
    try:
        rc2 = main(["batch", str(csv_path), "--out", str(base / "jobs2"), "--jobs", "2", *tiny_args(jit)])
    finally:
        os.environ.pop(TEST_KILL_ENV)
        if old is not None:
            os.environ[TEST_KILL_ENV] = old
    return {"csv": csv_path, "jit": jit, "base": base, "out": base / "jobs2", "rc": (rc1, rc2)}


def _same_results(a, b):
    for name in CONTRACT:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    ma, mb = (json.loads((d / "metrics.json").read_text()) for d in (a, b))
    for m in (ma, mb):
        m.pop("timings")
        m["config"]["tissue"]["file"] = m["tissue"]["file"] = None  # the tissue's path (its content is equal)
    assert ma == mb


def test_killed_worker_is_one_failure_and_the_rerun_retries_only_it(real_batch, monkeypatch, capsys):
    out = real_batch["out"]
    assert real_batch["rc"] == (0, 1)
    data, rows = summary(out)
    assert data["counts"] == {"ok": 2, "skipped": 0, "failed": 1, "interrupted": 0}
    assert (rows["bend_50"]["status"], rows["bend_50"]["attempts"]) == ("failed", 2)
    assert "crashed" in rows["bend_50"]["error"] and not (out / "bend_50").exists()
    for name in ("bend_30", "bend_80"):
        r = read_result(out / name)
        assert (rows[name]["status"], rows[name]["attempts"], rows[name]["steps"]) == ("ok", 1, 2)
        assert r.frames.shape[0] == 2 and np.all(np.isfinite(r.deformed_source))
        assert batch.read_manifest(out / name)["match"]["target_sha256"] == batch.file_sha256(rows[name]["target"])
    # the same command (the worker still dies on bend_50): only bend_50 is tried again, twice
    before = {n: (out / n / "deformed_source.ply").stat().st_mtime_ns for n in ("bend_30", "bend_80")}
    monkeypatch.setenv(TEST_KILL_ENV, "bend_50")
    capsys.readouterr()
    assert main(["batch", str(real_batch["csv"]), "--out", str(out), "--jobs", "2", *tiny_args(real_batch["jit"])]) == 1
    data, rows = summary(out)
    assert {n: (r["status"], r["attempts"]) for n, r in rows.items()} == {
        "bend_30": ("skipped", 0),
        "bend_50": ("failed", 2),
        "bend_80": ("skipped", 0),
    }
    assert {n: (out / n / "deformed_source.ply").stat().st_mtime_ns for n in before} == before
    captured = capsys.readouterr()
    assert "0 matched, 2 already done, 1 failed" in captured.out and "run the same command again" in captured.err


def test_jobs_1_and_jobs_2_give_byte_identical_results(real_batch):
    one, two = real_batch["base"] / "jobs1", real_batch["out"]
    assert summary(one)[0]["cluster"]["workers"] == 1 and summary(two)[0]["cluster"]["workers"] == 2
    assert summary(one)[0]["cluster"]["jax_threads"] == summary(two)[0]["cluster"]["jax_threads"] == 1
    _same_results(one / "bend_30", two / "bend_30")


@pytest.fixture()
def dask_cluster(tmp_path):
    """A real ``dask scheduler`` (random port) and two ``dask worker`` processes; always torn down."""
    scheduler_file = tmp_path / "scheduler.json"
    env = dict(os.environ)
    env.update(DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES="0", DASK_DISTRIBUTED__SCHEDULER__WORKER_SATURATION="1.0")
    env.pop(TEST_KILL_ENV, None)
    log = open(tmp_path / "dask.log", "w")  # noqa: SIM115 -- closed in the finally
    dask = [sys.executable, "-m", "dask"]
    procs = []
    try:
        procs.append(
            subprocess.Popen(
                [*dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard"]
                + ["--scheduler-file", str(scheduler_file)],
                env=env,
                stdout=log,
                stderr=subprocess.STDOUT,
            )
        )
        deadline = time.monotonic() + 60
        while not scheduler_file.is_file() and time.monotonic() < deadline:
            assert procs[0].poll() is None, "the scheduler stopped"
            time.sleep(0.2)
        address = json.loads(scheduler_file.read_text())["address"]
        worker_env = {**env, **worker_environment(1)}
        for i in range(2):
            procs.append(
                subprocess.Popen(
                    [*dask, "worker", address, "--nthreads", "1", "--no-dashboard", "--name", f"w{i}"],
                    env=worker_env,
                    stdout=log,
                    stderr=subprocess.STDOUT,
                )
            )
        from distributed import Client

        with Client(address, timeout=30) as c:
            c.wait_for_workers(2, timeout=90)
            env = c.run(lambda: (os.environ.get("MALLOC_TRIM_THRESHOLD_"), os.environ.get("PJRT_NPROC")))
            assert sorted(env.values()) == [(None, "1"), (None, "1")]  # worker_environment reaches the workers
        yield address
    finally:
        for p in reversed(procs):  # workers killed outright, the scheduler asked to stop
            p.kill() if p is not procs[0] else p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=10)
        log.close()


def test_batch_on_a_running_dask_scheduler(real_batch, dask_cluster, capsys):
    assert dask_cluster.startswith("tcp://127.0.0.1:")
    one = subset_csv(real_batch["csv"], {"bend_80"}, "one80.csv")
    out = real_batch["base"] / "remote"
    rc = main(["batch", str(one), "--out", str(out), "--scheduler", dask_cluster, *tiny_args(real_batch["jit"])])
    assert rc == 0, capsys.readouterr()
    data, rows = summary(out)
    assert data["cluster"]["kind"] == "scheduler" and data["cluster"]["workers"] == 2
    assert data["cluster"]["address"] == dask_cluster
    assert (rows["bend_80"]["status"], rows["bend_80"]["attempts"]) == ("ok", 1)
    # the worker was one of the cluster's, and its result is the local cluster's, byte for byte
    assert rows["bend_80"]["worker"].split(":")[-1] != str(os.getpid())
    _same_results(real_batch["out"] / "bend_80", out / "bend_80")
