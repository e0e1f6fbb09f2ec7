"""``ncflow batch`` on a local Dask cluster: 8 tiny pairs with ``--jobs 1`` and ``--jobs 2``.

Builds 8 capsule pairs (two sources, four bends each; exact ground truth not needed), fills a private
compilation cache with one warm-up pair (its time is reported as the cold start), then runs the same
batch with ``--jobs 1`` and ``--jobs 2`` into fresh folders, each as its own ``ncflow batch`` process,
and reports the wall time, the CPU time of the process and all its workers (``getrusage`` of the
children), the CPU use (CPU seconds per wall second, i.e. busy cores), the mean time per pair on its
worker, and whether the two runs wrote byte-identical results (every contract file but metrics.json).

With ``--threads2`` it also runs ``--jobs 1 --threads 2`` (one worker with two JAX threads).

Usage: python benchmarks/batch.py [--work DIR] [--steps 30] [--json FILE] [--threads2]
(run it with ``nice -n 10`` on a shared machine; the load average before each run is printed).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CONTRACT = (
    "deformed_source.ply",
    "p2p_src_to_tgt.txt",
    "p2p_tgt_to_src.txt",
    "map_tgt_to_src.npz",
    "animation.glb",
    "skeleton_target.tgf",
    "skeleton_frames.json",
    "target.ply",
)


def make_pairs(folder: Path) -> Path:
    from ncflow.evaluate import ground_truth_from_vertex_map
    from ncflow.geometry.mesh import Mesh
    from ncflow.skeleton import Skeleton
    from ncflow.synthetic.pairs import Pair, write_pairs
    from ncflow.synthetic.shapes import bend, capsule

    pairs = []
    for radius in (0.4, 0.5):
        vs, fs = capsule(radius=radius, length=3.0, n_around=12, n_along=16)
        source = Mesh(vs, fs, f"capsule_{radius}")
        skel = Skeleton.from_arrays(np.array([[0, 0, -1.6], [0, 0, 0.0], [0, 0, 1.6]]), np.array([-1, 0, 1]))
        gt = ground_truth_from_vertex_map(np.arange(len(vs)), source, len(vs))
        for a in (30, 50, 70, 90):
            target = Mesh(bend(vs, float(a)), fs, f"bend_{a}")
            pairs.append(Pair(f"r{radius}_bend_{a}", source, target, skel, gt, "capsule"))
    return write_pairs(pairs, folder)


def config_args(steps: int, jit: Path) -> list[str]:
    sets = {
        "flow.width": 32,
        "flow.depth": 2,
        "sampling.bone_samples": 16,
        "sampling.tissue_samples": 128,
        "sampling.surface_edges": 128,
        "compress": "none",
        "jit_cache": str(jit),
    }
    args = ["--steps", str(steps), "--frames", "5", "--metric", "varifold"]
    for k, v in sets.items():
        args += ["--set", f"{k}={v}"]
    return args


def run_batch(csv: Path, out: Path, jobs: int, args: list[str], threads: int = 1) -> dict:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "ncflow", "batch", str(csv), "--out", str(out), "--jobs", str(jobs)]
    cmd += ["--threads", str(threads), *args]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"ncflow batch --jobs {jobs} failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    summary = json.loads((out / "batch.json").read_text())
    seconds = [p["seconds"] for p in summary["pairs"] if p["status"] == "ok"]
    return {
        "jobs": jobs,
        "load_before": round(load, 2),
        "wall_s": round(wall, 1),
        "cpu_s": round(cpu, 1),
        "cpu_use": round(cpu / wall, 2),
        "pairs_ok": summary["counts"]["ok"],
        "mean_pair_s": round(float(np.mean(seconds)), 1) if seconds else None,
        "jax_threads": summary["cluster"]["jax_threads"],
    }


def identical(a: Path, b: Path) -> bool:
    for pair in sorted(p.name for p in a.iterdir() if p.is_dir() and p.name != "tissue"):
        files = list(CONTRACT) + sorted(f"frames/{f.name}" for f in (a / pair / "frames").iterdir())
        if any((a / pair / f).read_bytes() != (b / pair / f).read_bytes() for f in files):
            return False
    return True


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", help="working folder (default: a temporary one)")
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--json", help="also write the numbers here")
    ap.add_argument("--threads2", action="store_true", help="also run --jobs 1 --threads 2")
    a = ap.parse_args()
    work = Path(a.work or tempfile.mkdtemp(prefix="ncflow-batch-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("NCFLOW_CACHE_DIR", str(work / "cache"))
    csv = make_pairs(work / "pairs")
    args = config_args(a.steps, work / "jit")
    one = csv.with_name("warmup.csv")
    lines = csv.read_text().splitlines()
    one.write_text("\n".join(lines[:2]) + "\n")
    warm = run_batch(one, work / "warmup", 1, args)
    print(f"cold start (1 pair, empty compilation cache): {warm['wall_s']} s wall")
    rows = [run_batch(csv, work / f"jobs{j}", j, args) for j in (1, 2)]
    same = identical(work / "jobs1", work / "jobs2")
    if a.threads2:  # one worker with two JAX threads: what the second core adds inside one match
        rows.append(run_batch(csv, work / "jobs1_threads2", 1, args, threads=2))
    print(f"8 pairs, {a.steps} steps each, {os.cpu_count()} cores; results byte-identical: {same}")
    print("| --jobs | JAX threads/worker | load before | wall s | CPU s | CPU use (cores) | mean s/pair | speed-up |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        speed = rows[0]["wall_s"] / r["wall_s"]
        print(
            f"| {r['jobs']} | {r['jax_threads']} | {r['load_before']} | {r['wall_s']} | {r['cpu_s']} | "
            f"{r['cpu_use']} | {r['mean_pair_s']} | {speed:.2f}× |"
        )
    if a.json:
        Path(a.json).write_text(json.dumps({"cold": warm, "runs": rows, "identical": same}, indent=1) + "\n")


if __name__ == "__main__":
    main()
