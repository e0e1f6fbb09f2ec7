"""``ncflow demo``: generate an articulated character in two poses and match them, end to end."""

from __future__ import annotations

import argparse

from ncflow.cli.options import MiB, add_config_arguments, check_seed, config_from_args, output_dir


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="match a built-in procedural character pair (no downloads) and report its accuracy",
        description=(
            "Generates a watertight articulated character (skeleton of >= 10 bones) in two poses with a large "
            "joint rotation, the target re-triangulated and with exact ground truth, runs the matcher with the "
            "default preset, writes the full output contract (plus the inputs and ground truth, and view.html: the "
            "offline viewer page of ncflow view with the geodesic-error map) into --out, and prints the "
            "correspondence accuracy and the run time."
        ),
    )
    p.add_argument("--out", default="ncflow-demo", help="output directory (default ./ncflow-demo)")
    p.add_argument(
        "--kind", choices=["humanoid", "hand", "quadruped"], default="humanoid", help="character (default humanoid)"
    )
    p.add_argument("--pair-seed", type=int, default=0, help="seed of the generated character and poses (default 0)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing demo output")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    add_config_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json
    import time

    from ncflow.evaluate import auc, geodesic_errors
    from ncflow.io.atomic import atomic_write_text, move_into_place, remove_tree, staging_dir
    from ncflow.matcher.steps import Matcher
    from ncflow.synthetic.pairs import PAIR_FILES, make_pair, write_pair
    from ncflow.view.page import write_view

    check_seed(args.pair_seed, "--pair-seed")
    cfg = config_from_args(args)
    out = output_dir(args.out, overwrite=args.overwrite, result=True, need_bytes=64 * MiB)
    _check_demo_extras(out)
    t0 = time.perf_counter()
    pair = make_pair(args.kind, seed=args.pair_seed)
    if not args.quiet:
        print(
            f"demo pair: {args.kind} (seed {args.pair_seed}), source {pair.source.n_vertices} vertices, "
            f"target {pair.target.n_vertices} vertices (re-triangulated), {pair.skeleton.n_bones} bones"
        )
    result = Matcher(pair.source, pair.target, pair.skeleton, cfg, quiet=args.quiet).run()
    gt = pair.ground_truth
    err = geodesic_errors(
        pair.source,
        result.maps["map_face"][gt.target_index],
        result.maps["map_bary"][gt.target_index],
        gt.face,
        gt.bary,
    )
    summary = {
        "kind": args.kind,
        "pair_seed": args.pair_seed,
        "n_source": pair.source.n_vertices,
        "n_target": pair.target.n_vertices,
        "n_bones": pair.skeleton.n_bones,
        "geodesic_error_mean": float(err.mean()),
        "geodesic_auc_0.20": auc(err, 0.2),
        "max_bone_violation_ratio": result.metrics["constraints"]["max_violation_ratio"],
        "seconds": time.perf_counter() - t0,
    }
    result.metrics["demo"] = summary
    result.save(out, overwrite=args.overwrite, shown=args.out)
    # the inputs: staged beside, then swapped in (only the files write_pair writes are replaced)
    inputs = out / "inputs"
    staged = staging_dir(inputs)
    try:
        write_pair(pair, staged, "ply")
        move_into_place(staged, inputs, lambda name: name in PAIR_FILES)
    except BaseException:
        remove_tree(staged)
        raise
    atomic_write_text(out / "demo_summary.json", json.dumps(summary, indent=2))
    page = write_view(out, out / "view.html", gt=inputs / "gt.npz", title=f"ncflow demo ({args.kind})")
    print(f"wrote {args.out} (inputs and ground truth in {inputs}); open {page} in a browser to see it")
    print(
        f"correspondence: mean geodesic error / sqrt(area) = {summary['geodesic_error_mean']:.4f}, "
        f"AUC(0.20) = {summary['geodesic_auc_0.20']:.3f}; largest bone violation g/eps = "
        f"{summary['max_bone_violation_ratio']:.2f}; run time {summary['seconds']:.1f} s"
    )
    return 0


def _check_demo_extras(out) -> None:
    """``inputs/``, ``demo_summary.json`` and ``view.html`` of an earlier demo may be replaced; anything else there
    is refused.
    """
    from ncflow.errors import InputError
    from ncflow.synthetic.pairs import PAIR_FILES
    from ncflow.view.page import check_view_output

    inputs, summary, page = out / "inputs", out / "demo_summary.json", out / "view.html"
    if page.exists() or page.is_symlink():
        try:
            check_view_output(page)  # a page of ncflow view, else refused
        except InputError:
            raise InputError("was not written by ncflow demo; move it away first", page) from None
    if summary.is_symlink() or (summary.exists() and not summary.is_file()):
        raise InputError("is not a file ncflow wrote; remove it first", summary)
    if inputs.is_symlink() or (inputs.exists() and not inputs.is_dir()):
        raise InputError("is not a folder ncflow wrote; remove it first", inputs)
    if inputs.is_dir():
        for entry in inputs.iterdir():
            if entry.is_symlink() or not entry.is_file() or entry.name not in PAIR_FILES:
                raise InputError("was not written by ncflow demo; move it away first", entry)
