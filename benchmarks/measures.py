"""Normal Cycle loss cost vs mesh resolution, raw and with the target compressed (paper Table 2 analogue).

For each target size N (edges) and each setting it times one value+gradient of the NC matching
loss L(X) = <X,X> - 2<X,Y> (the constant <Y,Y> is precomputed once, as in training) with respect
to the source vertices, jit-compiled, float32, median of several runs, and the peak resident
memory of a fresh process running just that case. Settings:

* ``raw``            source = a mesh of N edges, target = N edges, no compression;
* ``tgt->M``         source N edges, target compressed to M representatives;
* ``src7k raw``      source fixed at the working resolution (~7k edges), target N edges raw;
* ``src7k tgt->M``   source ~7k edges, target compressed to M (the training configuration:
                     cost must not depend on the target's resolution).

The compression itself (once per length scale) is timed separately.

Usage: python benchmarks/measures.py [--sizes 2k,7k,25k,100k] [--repeats 3] [--sigma 0.1]
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

SIZES = {"2k": 22, "7k": 40, "25k": 76, "100k": 152}  # capsule resolution giving ~that many edges
WORKING = 40


def _target(target_res: int):
    from ncflow.geometry.topology import mesh_topology
    from ncflow.synthetic.shapes import bend, capsule

    vt, ft = capsule(n_around=target_res + 1, n_along=target_res, diagonal="left")
    return bend(vt, 30.0), mesh_topology(ft)


def _compress(target_res: int, m: int, sigma: float, path: str) -> dict:
    """Compress the target in its own process (its dense m×m solve must not count as loss memory)."""
    import jax.numpy as jnp
    import numpy as np

    from ncflow.measures import compress_normal_cycle, normal_cycle

    vt, tt = _target(target_res)
    t0 = time.perf_counter()
    y, rep = compress_normal_cycle(normal_cycle(jnp.asarray(vt, jnp.float32), tt), m, sigma, seed=0)
    secs = time.perf_counter() - t0
    np.savez(path, centers=np.asarray(y.centers), weights=np.asarray(y.weights))
    return {
        "compress_seconds": secs,
        "relative_error": rep.relative_error,
        "compress_peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }


def _case(target_res: int, source_res: int, m: int, sigma: float, repeats: int, path: str | None) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from ncflow.geometry.topology import mesh_topology
    from ncflow.measures import NormalCycle, normal_cycle, normal_cycle_inner
    from ncflow.synthetic.shapes import capsule

    vs, fs = capsule(n_around=source_res, n_along=source_res)
    vt, tt = _target(target_res)
    ts = mesh_topology(fs)
    if path:
        data = np.load(path)
        y = NormalCycle(jnp.asarray(data["centers"]), jnp.asarray(data["weights"]))
    else:
        y = normal_cycle(jnp.asarray(vt, jnp.float32), tt)

    def loss(v):
        x = normal_cycle(v, ts)
        return normal_cycle_inner(x, x, sigma) - 2.0 * normal_cycle_inner(x, y, sigma)

    f = jax.jit(jax.value_and_grad(loss))
    v0 = jnp.asarray(vs, jnp.float32)
    t0 = time.perf_counter()
    jax.block_until_ready(f(v0))
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(f(v0 + 1e-3))
        times.append(time.perf_counter() - t0)
    return {
        "source_points": int(ts.n_edges),
        "target_points": int(tt.n_edges),
        "target_used": int(y.size),
        "seconds": float(np.median(times)),
        "compile_seconds": compile_s,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="2k,7k,25k,100k")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--sigma", type=float, default=0.1)
    ap.add_argument("--_case", help=argparse.SUPPRESS)
    ap.add_argument("--_compress", help=argparse.SUPPRESS)
    ap.add_argument("--_path", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args._compress:
        t, m = (int(x) for x in args._compress.split(","))
        print(json.dumps(_compress(t, m, args.sigma, args._path)))
        return
    if args._case:
        t, s, m = (int(x) for x in args._case.split(","))
        print(json.dumps(_case(t, s, m, args.sigma, args.repeats, args._path)))
        return
    settings = [
        ("raw", None, 0),
        ("tgt->5k", None, 5000),
        ("tgt->10k", None, 10000),
        ("src7k raw", WORKING, 0),
        ("src7k tgt->5k", WORKING, 5000),
        ("src7k tgt->10k", WORKING, 10000),
    ]
    sizes = args.sizes.split(",")
    rows = []
    tmp = tempfile.mkdtemp()

    def run(flag: str, spec: str, path: str | None) -> dict:
        cmd = [sys.executable, __file__, flag, spec, "--sigma", str(args.sigma), "--repeats", str(args.repeats)]
        out = subprocess.run(cmd + (["--_path", path] if path else []), capture_output=True, text=True)
        if out.returncode != 0:
            return {"error": (out.stderr.strip().splitlines() or ["failed"])[-1][:80]}
        return json.loads(out.stdout.strip().splitlines()[-1])

    compressed = {}
    for size in sizes:
        for m in {m for _, _, m in settings if m}:
            path = os.path.join(tmp, f"{size}_{m}.npz")
            compressed[size, m] = (path, run("--_compress", f"{SIZES[size]},{m}", path))
            print("compress", size, m, compressed[size, m][1], file=sys.stderr, flush=True)
    for label, src, m in settings:
        row = {"setting": label}
        for size in sizes:
            res = SIZES[size]
            path = compressed[size, m][0] if m else None
            row[size] = run("--_case", f"{res},{src or res},{m}", path)
            if m:
                row[size].update(compressed[size, m][1])
            print(label, size, row[size], file=sys.stderr, flush=True)
        rows.append(row)
    print(f"\nNC loss value+grad, float32, sigma={args.sigma}; time [s] / peak RSS [MB] (per fresh process)\n")
    head = (
        "| setting | " + " | ".join(f"{s} (target {rows[0][s].get('target_points', '?')} edges)" for s in sizes) + " |"
    )
    print(head)
    print("|" + "---|" * (len(sizes) + 1))
    for row in rows:
        cells = []
        for s in sizes:
            r = row[s]
            cells.append(r["error"] if "error" in r else f"{r['seconds']:.3f} s / {r['peak_rss_mb']:.0f} MB")
        print(f"| {row['setting']} | " + " | ".join(cells) + " |")
    print("\ntarget compression (once per length scale): time [s] / peak RSS [MB] / relative error")
    for m in sorted({m for _, _, m in settings if m}):
        cells = []
        for s in sizes:
            r = compressed[s, m][1]
            cells.append(
                r.get("error")
                or f"{s}: {r['compress_seconds']:.1f} s / {r['compress_peak_rss_mb']:.0f} MB "
                f"/ {r['relative_error']:.1e}"
            )
        print(f"  m={m}: " + ", ".join(cells))


if __name__ == "__main__":
    main()
