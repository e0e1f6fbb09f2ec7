"""``ncflow rig``: the target of a match result as a skinned glTF character (GLB)."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "rig",
        help="write the target of a result as a skinned glTF character (GLB) with the interpolation as a clip",
        description=(
            "Read RESULT (a folder written by ncflow match with a skeleton) and write the target as a rigged "
            "character: the fitted target skeleton as joints (its pose is the bind pose), the target mesh as the "
            "skinned mesh, skin weights carried from the source through map_tgt_to_src (from the source's glTF "
            "skin with --source-skin, else the skeleton's bone weights on the source), inpainted where the map is "
            "unreliable (Abdrashitov et al. 2023) and cut to 4 influences per vertex, and the interpolation as "
            "an animation clip of joint rotations (first key: the source pose; last: the target). Opens and "
            "re-poses in Blender and three.js; see docs/rig.md."
        ),
    )
    p.add_argument("result_dir", metavar="RESULT", help="folder written by ncflow match")
    p.add_argument("--out", required=True, metavar="GLB", help="output .glb")
    p.add_argument(
        "--source-skin",
        metavar="SRC.glb",
        help="the source as a skinned .glb/.gltf (the file given to ncflow match): carry its skin weights; "
        "its joints are matched to the skeleton's by name",
    )
    p.add_argument("--target", metavar="MESH", help="the target mesh, for a result without target.ply")
    p.add_argument("--no-animation", action="store_true", help="write the rig without the clip")
    p.add_argument(
        "--bvh",
        metavar="FILE.bvh",
        help="also write the clip's skeleton motion as a Biovision Hierarchy file (the same joints, bind pose and "
        "key rotations as the GLB; opens in Blender, MotionBuilder, three.js)",
    )
    p.add_argument(
        "--max-distance",
        type=float,
        default=0.05,
        metavar="FRACTION",
        help="carried weights are reliable within this distance of the flowed source, as a fraction of the "
        "target's bounding-box diagonal (default 0.05)",
    )
    p.add_argument(
        "--max-angle",
        type=float,
        default=30.0,
        metavar="DEG",
        help="... and where the target's and the flowed source's normals differ by at most this angle (default 30)",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ncflow.cli.options import MiB, check_number, output_file
    from ncflow.errors import InputError

    out = Path(args.out)
    if out.suffix.lower() != ".glb":
        raise InputError("the output must end with .glb (a binary glTF)", args.out)
    if (out.exists() or out.is_symlink()) and not args.overwrite:
        raise InputError("exists (pass --overwrite to replace it)", args.out)
    output_file(args.out, need_bytes=8 * MiB, option="--out")
    if args.bvh is not None:
        output_file(args.bvh, need_bytes=MiB, option="--bvh")
    check_number(args.max_distance, "--max-distance", lo=0.0)
    check_number(args.max_angle, "--max-angle", lo=0.0, hi=180.0)

    from ncflow.retarget.rig import rig_result

    report = rig_result(
        args.result_dir,
        args.out,
        source_skin=args.source_skin,
        target=args.target,
        animation=not args.no_animation,
        overwrite=args.overwrite,
        max_distance=args.max_distance,
        max_normal_angle=args.max_angle,
        bvh=args.bvh,
    )
    share = 100.0 * report.n_unreliable / max(report.n_vertices, 1)
    source = "the source's glTF skin" if report.weights_from == "gltf skin" else "the skeleton (bone weights)"
    clip = f", clip of {report.n_keys} keys" if report.n_keys else ", no clip"
    print(
        f"wrote {args.out}: {report.n_vertices} vertices, {report.n_faces} faces, {report.n_joints} joints{clip}; "
        f"weights from {source}, {report.n_unreliable} vertices ({share:.1f} %) inpainted; "
        f"bind pose within {report.bind_error:.2g} of the target ({report.seconds:.1f} s)"
    )
    if args.bvh is not None:
        print(f"wrote {args.bvh}: the skeleton motion, {report.n_keys} frames")
    return 0
