"""``ncflow make-shape``: write a procedural test surface."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    from ncflow.synthetic.shapes import SHAPES

    p = sub.add_parser(
        "make-shape",
        help="write a procedural test surface (sphere, capsule, tube, box, rounded-box)",
        description="Write a procedural test surface, optionally bent at its middle, as OBJ/PLY/OFF/STL/GLB.",
    )
    p.add_argument("kind", choices=sorted(SHAPES))
    p.add_argument("out", help="output mesh file (format from the suffix)")
    p.add_argument("--resolution", type=int, default=24, help="points around (default 24)")
    p.add_argument("--bend", type=float, default=0.0, metavar="DEG", help="bend the upper half by DEG degrees")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ncflow.errors import InputError
    from ncflow.io.meshes import MESH_SUFFIXES, save_mesh
    from ncflow.synthetic.shapes import make_shape

    if not args.out.lower().endswith(MESH_SUFFIXES):
        raise InputError(f"output must end with one of {', '.join(MESH_SUFFIXES)}", args.out)
    from ncflow.cli.options import check_int, check_number, output_file

    check_int(args.resolution, "--resolution", 3, 4096)
    check_number(args.bend, "--bend", -360.0, 360.0)
    out = output_file(args.out, option="output")  # not under a file, writable, before any work
    v, f = make_shape(args.kind, args.resolution, args.bend)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_mesh(out, v, f)
    print(f"wrote {args.out}: {len(v)} vertices, {len(f)} faces")
    return 0
