"""``ncflow transfer``: carry source attributes to the target."""

from __future__ import annotations

import argparse

KINDS = ("auto", "values", "labels", "weights", "uv", "colors", "landmarks")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "transfer",
        help="carry source attributes (values, labels, skin weights, UVs, colours, landmarks) to the target",
        description=(
            "Read the correspondence of RESULT (map_tgt_to_src.npz: for every target vertex a source face and "
            "barycentric coordinates) and carry ATTRIBUTES of the source to the target. ATTRIBUTES is a .npy or "
            ".txt array with one row per source vertex (integers: labels, by the barycentric-weighted majority of "
            "the mapped face's corners; floats: values, interpolated; --kind weights: skin weights, renormalised "
            "and inpainted where the map is unreliable), an .obj of the source with face-varying UVs (seams kept; "
            "written as the target .obj with UVs), a .ply of the source with vertex colours or other properties "
            "(written as the target .ply with them) or a .json of landmarks (source vertex ids or points; written "
            "as target points, faces, barycentrics and nearest vertices). See docs/transfer.md."
        ),
    )
    p.add_argument("result_dir", metavar="RESULT", help="folder written by ncflow match")
    p.add_argument("attributes", metavar="ATTRIBUTES", help="source attributes: .npy, .txt, .obj, .ply or .json")
    p.add_argument(
        "--out",
        required=True,
        metavar="OUT",
        help="output file: .npy/.txt for arrays, .obj for UVs, .ply for PLY properties, .json for landmarks",
    )
    p.add_argument(
        "--kind",
        choices=KINDS,
        default="auto",
        help="what ATTRIBUTES holds (default auto: from the file; integer arrays are labels, float arrays "
        "values; skin weights must be asked for with --kind weights)",
    )
    p.add_argument(
        "--label-rule",
        choices=("majority", "nearest"),
        default="majority",
        help="labels: barycentric-weighted majority of the face's corners (default) or the corner of largest weight",
    )
    p.add_argument("--target", metavar="MESH", help="the target mesh, only for a result without target.ply")
    p.add_argument(
        "--max-distance",
        type=float,
        metavar="D",
        help="skin weights: target vertices farther than D from the flowed source are inpainted",
    )
    p.add_argument(
        "--max-normal-angle",
        type=float,
        metavar="DEG",
        help="skin weights: target vertices whose normal differs by more than DEG degrees are inpainted",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing OUT")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ncflow.cli.options import MiB, check_number, output_file
    from ncflow.retarget.attributes import summary_line, transfer

    check_number(args.max_distance, "--max-distance", positive=True)
    check_number(args.max_normal_angle, "--max-normal-angle", lo=0.0, hi=180.0)
    output_file(args.out, need_bytes=MiB, option="--out")
    summary = transfer(
        args.result_dir,
        args.attributes,
        args.out,
        kind=args.kind,
        target=args.target,
        label_rule=args.label_rule,
        max_distance=args.max_distance,
        max_normal_angle=args.max_normal_angle,
        overwrite=args.overwrite,
    )
    print(summary_line(summary))
    return 0
