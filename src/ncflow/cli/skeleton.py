"""``ncflow skeleton``: inspect and convert skeleton files (TGF, JSON, glTF/GLB)."""

from __future__ import annotations

import argparse


def _animation(value: str) -> str | int:
    return int(value) if value.lstrip("-").isdigit() else value


def _add_gltf_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--time", type=float, metavar="T", help="glTF/GLB: pose at animation time T (seconds); default rest pose"
    )
    p.add_argument("--animation", type=_animation, metavar="A", help="glTF/GLB: animation name or index")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "skeleton",
        help="inspect or convert a skeleton file",
        description="Inspect or convert skeletons (TGF, JSON, glTF/GLB input; TGF or JSON output).",
    )
    ssub = p.add_subparsers(dest="skeleton_command", metavar="ACTION", required=True)

    info = ssub.add_parser(
        "info",
        help="joints, bones, lengths and placement checks",
        description="Print the joints and bones of a skeleton, their lengths and the root; with "
        "--mesh, also warn about joints outside (closed mesh) or far from (open mesh) the surface.",
    )
    info.add_argument("skeleton", help="skeleton file (.tgf, .json, .glb, .gltf)")
    info.add_argument("--mesh", help="mesh the skeleton belongs to (OBJ/PLY/OFF/STL/GLB)")
    _add_gltf_options(info)
    info.add_argument("--json", action="store_true", help="print one JSON object")
    info.set_defaults(func=run_info)

    conv = ssub.add_parser(
        "convert",
        help="convert between skeleton formats",
        description="Read a skeleton (TGF/JSON/glTF/GLB) and write it as TGF (1-based) or JSON, "
        "joints in topological order (parents first).",
    )
    conv.add_argument("input", help="skeleton file (.tgf, .json, .glb, .gltf)")
    conv.add_argument("output", help="output file (.tgf or .json)")
    _add_gltf_options(conv)
    conv.set_defaults(func=run_convert)

    sug = ssub.add_parser(
        "suggest",
        help="suggest a skeleton for a mesh that has none",
        description="Suggest a skeleton for MESH: a tree of joints inside the mesh, bones along its limbs, the "
        "root at the body's centre and a joint near every limb tip, from the Reeb graph of the mesh's average "
        "geodesic distance (docs/skeleton-suggest.md). Deterministic; seconds on a CPU. Written as TGF or JSON "
        "in the mesh's own units and placement.",
    )
    sug.add_argument("mesh", help="mesh file (OBJ/PLY/OFF/STL/GLB)")
    sug.add_argument("--out", required=True, metavar="SKELETON", help="output skeleton (.tgf or .json)")
    sug.add_argument(
        "--other-pose",
        action="append",
        default=[],
        metavar="MESH",
        help="the same body in another pose (any triangulation; repeatable): joints go where its limbs bend, "
        "as ncflow match does with its target",
    )
    sug.add_argument(
        "--bases",
        choices=("auto", "ring", "inside"),
        default="auto",
        help="where a limb's first joint goes: where the limb leaves the body (ring); for limbs in pairs (arms, "
        "legs, fingers) a limb's radius further in, at a shoulder, hip or knuckle (inside); or inside for "
        "fingers and toes only (limbs in groups of four or more alike from one node), ring elsewhere (auto, the "
        "default, as ncflow match without --skeleton unless --set skeleton_bases=ring, =inside or =choose)",
    )
    sug.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    sug.set_defaults(func=run_suggest)


def _load(args: argparse.Namespace, path: str):
    from ncflow.io.skeletons import load_skeleton

    return load_skeleton(path, time=args.time, animation=args.animation)


def run_info(args: argparse.Namespace) -> int:
    import json

    import numpy as np

    from ncflow.cli.options import check_number

    check_number(args.time, "--time")

    skel = _load(args, args.skeleton)
    warnings: list[str] = []
    if args.mesh:
        from ncflow.geometry.mesh import repaired_mesh
        from ncflow.io.meshes import load_mesh
        from ncflow.skeleton.checks import check_inside

        mesh = repaired_mesh(load_mesh(args.mesh))[0]
        warnings = check_inside(skel, mesh.vertices, mesh.faces)
    lengths = skel.bone_lengths
    bones = [
        {"parent": skel.label(int(a)), "child": skel.label(int(c)), "length": float(lengths[b])}
        for b, (a, c) in enumerate(skel.bones)
    ]
    lo, hi = skel.positions.min(0), skel.positions.max(0)
    if args.json:
        out = {
            "file": args.skeleton,
            "n_joints": skel.n_joints,
            "n_bones": skel.n_bones,
            "root": skel.label(0),
            "depth": int(skel.depth.max()),
            "total_length": float(lengths.sum()),
            "bbox_min": lo.tolist(),
            "bbox_max": hi.tolist(),
            "bones": bones,
            "warnings": warnings,
        }
        print(json.dumps(out))
        return 0
    print(f"skeleton: {args.skeleton}")
    print(f"  joints: {skel.n_joints}   bones: {skel.n_bones}   root: {skel.label(0)}   depth: {int(skel.depth.max())}")
    print(
        f"  bone length: total {lengths.sum():.6g}, min {lengths.min():.6g}, "
        f"median {np.median(lengths):.6g}, max {lengths.max():.6g}"
    )
    print(f"  bounding box: [{', '.join(f'{x:.4g}' for x in lo)}] to [{', '.join(f'{x:.4g}' for x in hi)}]")
    print("  bones (parent -> child: length):")
    for b in bones:
        print(f"    {b['parent']} -> {b['child']}: {b['length']:.6g}")
    if args.mesh:
        if warnings:
            print(f"  {len(warnings)} warning(s) against {args.mesh}:")
            for w in warnings:
                print(f"    warning: {w}")
        else:
            print(f"  all joints inside / near {args.mesh}")
    return 0


def run_convert(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ncflow.cli.options import check_number, output_file
    from ncflow.errors import InputError
    from ncflow.io.skeletons import save_skeleton

    if Path(args.output).suffix.lower() not in (".tgf", ".json"):
        raise InputError("can only write skeletons as .tgf or .json", args.output)
    check_number(args.time, "--time")
    out = output_file(args.output, option="output")
    skel = _load(args, args.input)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_skeleton(out, skel)
    print(f"wrote {args.output}: {skel.n_joints} joints, {skel.n_bones} bones")
    return 0


def run_suggest(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from ncflow.cli.options import output_file
    from ncflow.errors import InputError
    from ncflow.geometry.mesh import repaired_mesh
    from ncflow.io.atomic import atomic_path
    from ncflow.io.meshes import load_mesh
    from ncflow.io.skeletons import save_skeleton
    from ncflow.skeleton.checks import check_inside
    from ncflow.skeleton.suggest import suggest_skeleton

    out = Path(args.out)
    if out.suffix.lower() not in (".tgf", ".json"):
        raise InputError("can only write skeletons as .tgf or .json", args.out)
    if (out.exists() or out.is_symlink()) and not args.overwrite:
        raise InputError("exists (pass --overwrite to replace it)", args.out)
    real = output_file(args.out, option="--out")
    start = time.perf_counter()
    mesh = repaired_mesh(load_mesh(args.mesh))[0]
    others = []
    for path in args.other_pose:
        other = repaired_mesh(load_mesh(path))[0]
        if other.faces.shape[0] < 20:
            raise InputError(f"has {other.faces.shape[0]} faces: too few to show a pose", path)
        others.append((other.vertices, other.faces))
    try:
        found = suggest_skeleton(
            mesh.vertices, mesh.faces, name=Path(args.mesh).stem, other_poses=others, bases=args.bases
        )
    except InputError as err:
        raise InputError(str(err), args.mesh) from None
    skel = found.skeleton
    real.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(real) as tmp:
        save_skeleton(tmp, skel)
    print(
        f"wrote {args.out}: {skel.n_joints} joints, {skel.n_bones} bones, {found.n_leaves} limb tips"
        + (f", {found.bends_seen} cut where the other poses bend" if others else "")
        + f" ({time.perf_counter() - start:.1f} s)"
    )
    for warning in check_inside(skel, mesh.vertices, mesh.faces):
        print(f"warning: {warning}")
    return 0
