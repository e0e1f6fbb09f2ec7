"""``ncflow distance``: the Varifold or Normal Cycle distance between two meshes."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "distance",
        help="Varifold / Normal Cycle distance between two meshes",
        description=(
            "Print d(A, B) = <A,A> + <B,B> - 2<A,B> for the oriented Varifold or the Normal Cycle "
            "metric with a Gaussian kernel of width SIGMA, in the coordinates of the files "
            "(unless --normalize)."
        ),
    )
    p.add_argument("a", help="first mesh (OBJ/PLY/OFF/STL/GLB)")
    p.add_argument("b", help="second mesh")
    p.add_argument("--metric", choices=["varifold", "normal-cycles"], default="normal-cycles")
    p.add_argument("--sigma", type=float, required=True, help="spatial kernel width σ")
    p.add_argument(
        "--sigma-normal", type=float, default=0.5, help="normal kernel width σ_n (varifold only; default 0.5)"
    )
    p.add_argument("--compress", type=int, metavar="M", help="compress B to M representatives (Nyström) first")
    p.add_argument("--seed", type=int, default=0, help="seed of the compression's sampling (default 0)")
    p.add_argument(
        "--normalize",
        action="store_true",
        help="first map both meshes by A's normalisation (centroid to origin, volume 4π/3)",
    )
    p.add_argument("--float32", action="store_true", help="compute in float32 (default float64)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json
    import time

    import jax

    from ncflow.cli.options import check_int, check_number, check_seed
    from ncflow.errors import InputError

    if not args.sigma > 0:
        raise InputError(f"--sigma must be positive (got {args.sigma})")
    if not args.sigma_normal > 0:
        raise InputError(f"--sigma-normal must be positive (got {args.sigma_normal})")
    check_number(args.sigma, "--sigma", positive=True)
    check_number(args.sigma_normal, "--sigma-normal", positive=True)
    check_int(args.compress, "--compress", 1, 10**9)
    check_seed(args.seed)
    if not args.float32:
        jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    from ncflow.geometry.mesh import repaired_mesh
    from ncflow.geometry.normalize import fit_normalization
    from ncflow.geometry.topology import mesh_topology
    from ncflow.io.meshes import load_mesh
    from ncflow.measures.registry import get_metric

    t0 = time.perf_counter()
    a, b = (repaired_mesh(load_mesh(path))[0] for path in (args.a, args.b))
    va, vb = a.vertices, b.vertices
    if args.normalize:
        norm = fit_normalization(a.vertices, a.faces)
        va, vb = norm.apply(va), norm.apply(vb)
    dtype = jnp.float32 if args.float32 else jnp.float64
    va, vb = jnp.asarray(va, dtype), jnp.asarray(vb, dtype)
    report = None
    metric = get_metric(args.metric)
    x = metric.represent(va, mesh_topology(a.faces, a.n_vertices, name=a.name))
    y = metric.represent(vb, mesh_topology(b.faces, b.n_vertices, name=b.name))
    if args.compress:
        y, report = metric.compress(y, args.compress, args.sigma, args.sigma_normal, args.seed)
    d = metric.distance(x, y, args.sigma, args.sigma_normal)
    d = float(d)
    seconds = time.perf_counter() - t0
    if args.json:
        out = {
            "distance": d,
            "metric": args.metric,
            "sigma": args.sigma,
            "sigma_normal": args.sigma_normal if args.metric == "varifold" else None,
            "n_source": int(x.size),
            "n_target": int(y.size if report is None else report.n),
            "normalized": bool(args.normalize),
            "dtype": "float32" if args.float32 else "float64",
            "seconds": seconds,
        }
        if report is not None:
            out["compression"] = report.to_dict()
        print(json.dumps(out))
    else:
        print(f"{args.metric} distance (sigma={args.sigma:g}): {d:.9g}")
        print(f"  points: {x.size} vs {y.size if report is None else report.n}   time: {seconds:.2f} s")
        if report is not None:
            print(f"  target compressed to {report.m} points, relative error {report.relative_error:.3g}")
    return 0
