"""``ncflow make-pairs``: write source/target pairs with exact ground truth and a ``pairs.csv``."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "make-pairs",
        help="write source/target pairs with exact ground truth (procedural characters, MANO, glTF)",
        description=(
            "Write matching problems with exact ground truth into OUT_DIR: per pair a folder pair_XXX "
            "with source and target meshes, the source skeleton (source_skeleton.tgf; the target pose's "
            "joints in target_skeleton.tgf) and gt.npz (for every target vertex the source face 'face' "
            "and barycentric coordinates 'bary'), plus OUT_DIR/pairs.csv (columns name, source, target, "
            "skeleton, gt, gt_format, dataset; paths relative to the csv). Sources: procedural "
            "characters (--kind, --n, --seed; rest pose to a random pose with one large joint rotation "
            "and a global motion; --large-joints and --articulation for larger articulations), a "
            "user-supplied MANO model (--mano MODEL --poses i,j,...: rows of hands_coeffs or the names "
            "flat and fist, taken two at a time) or a skinned glTF/GLB animation (--gltf FILE --times "
            "a,b,...: seconds, two at a time). --target-rotation and --target-translation turn and move "
            "every target by a random rigid motion drawn from the pair's seed (the ground truth is "
            "unchanged; the motion is written to target_motion.json and listed in pairs.csv)."
        ),
    )
    p.add_argument("out_dir", metavar="OUT_DIR", help="output folder (created; written as a whole when complete)")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the pairs (pair_XXX/, pairs.csv) of an existing non-empty OUT_DIR; other files are kept",
    )
    p.add_argument(
        "--kind",
        choices=("humanoid", "hand", "quadruped"),
        default="humanoid",
        help="procedural character kind (default humanoid)",
    )
    p.add_argument("--n", type=int, default=1, metavar="N", help="number of procedural pairs (default 1)")
    p.add_argument(
        "--seed",
        type=int,
        default=0,
        metavar="S",
        help="first seed; pair k uses seed S+k (procedural: proportions and poses; MANO and glTF: "
        "retriangulation grid offset and target motion) (default 0)",
    )
    p.add_argument(
        "--resolution",
        type=float,
        metavar="R",
        help="source marching-cubes cells along the largest extent (procedural; default per kind)",
    )
    p.add_argument(
        "--target-resolution",
        type=float,
        metavar="R",
        help="resolution of the retriangulated target (procedural default 0.8 x the source's; "
        "MANO default 36, glTF 48)",
    )
    p.add_argument(
        "--retriangulate",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="give the target its own triangulation (default: yes for procedural characters, "
        "no for MANO and glTF, whose identity ground truth is then vertex to vertex)",
    )
    p.add_argument(
        "--posed-source",
        action="store_true",
        help="procedural: pose the source too (small random rotations) instead of the rest pose",
    )
    p.add_argument(
        "--large-joints",
        type=int,
        default=1,
        metavar="N",
        help="procedural: N joints of the target pose get a large flexion (--large-angle), drawn without "
        "replacement from the kind's hinge joints (humanoid: elbows, knees; hand: finger middle joints; "
        "quadruped: neck, tail, elbows, knees) (default 1)",
    )
    p.add_argument(
        "--large-angle",
        metavar="LO,HI",
        help="procedural: range in degrees of the large flexions (default 60,100)",
    )
    p.add_argument(
        "--articulation",
        choices=("cross", "stride", "crouch", "curl", "gallop"),
        help="procedural: a whole-body articulation of the target pose on top of the random one: "
        "humanoid cross (arms crossed), stride (long stride, arms swinging), crouch (hips and knees "
        "bent); hand curl (every finger curled); quadruped gallop (legs swung forward / back)",
    )
    p.add_argument(
        "--target-rotation",
        metavar="DEG[,HI]",
        help="turn every target by DEG degrees (or uniformly LO..HI) about a random axis through its "
        "centroid (at most 180; default: no rotation)",
    )
    p.add_argument(
        "--target-translation",
        metavar="FRAC[,HI]",
        help="then move it by FRAC (or uniformly LO..HI) x the source's bounding-box diagonal in a random "
        "direction (default: no translation)",
    )
    p.add_argument(
        "--defects",
        metavar="NAME[,NAME...]",
        help="give every target these defects, in order, keeping the ground truth of its own vertices: soup "
        "(unshared vertices), degenerate (1.6%% zero-area faces), duplicates (2%% faces twice), stray (1%% "
        "vertices in no face), fins (triangles on 1%% of the edges: edges of 3 and 4 faces), fragment / "
        "fragment-flipped (a floor patch of 3%% of the area, wound up / down), pinch (a tetrahedron touching "
        "the surface at one vertex)",
    )
    p.add_argument("--format", choices=("ply", "obj"), default="ply", help="mesh format (default ply)")
    p.add_argument("--mano", metavar="MODEL", help="MANO model file (.npz or .pkl), supplied by the user")
    p.add_argument(
        "--poses",
        metavar="I,J[,K,L...]",
        help="MANO: hands_coeffs rows or the names flat (the template) and fist, paired two at a time",
    )
    p.add_argument("--gltf", metavar="FILE", help="skinned .glb / .gltf file")
    p.add_argument("--times", metavar="A,B[,C,D...]", help="glTF: animation times (seconds), paired two at a time")
    p.add_argument("--animation", metavar="NAME_OR_INDEX", help="glTF: clip name or index (default: the first)")
    p.set_defaults(func=run)


def _pairs_of(text: str | None, option: str, cast, what: str = "numbers") -> list[tuple]:
    from ncflow.errors import InputError

    if not text:
        raise InputError(f"{option} is required")
    try:
        values = [cast(x) for x in text.replace(" ", "").split(",") if x != ""]
    except ValueError:
        raise InputError(f"{option} must be a comma-separated list of {what} (got {text!r})") from None
    if len(values) < 2 or len(values) % 2:
        raise InputError(f"{option} needs an even number of values (taken two at a time), got {len(values)}")
    return [(values[k], values[k + 1]) for k in range(0, len(values), 2)]


def _float(text: str) -> float:
    import math

    value = float(text)
    if not math.isfinite(value):
        raise ValueError(text)
    return value


def _mano_pose(text: str) -> int | str:
    from ncflow.synthetic.mano import MANO_NAMED_POSES

    return text if text in MANO_NAMED_POSES else int(text)


def _range(text: str | None, option: str):
    """None, one number, or a (lo, hi) pair from 'X' or 'LO,HI'."""
    from ncflow.errors import InputError

    if text is None:
        return None
    try:
        values = [_float(x) for x in text.replace(" ", "").split(",") if x != ""]
    except ValueError:
        raise InputError(f"{option} must be a number or LO,HI (got {text!r})") from None
    if len(values) not in (1, 2):
        raise InputError(f"{option} must be a number or LO,HI (got {text!r})")
    return values[0] if len(values) == 1 else (values[0], values[1])


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from ncflow.cli.options import MiB, check_int, check_number, check_seed, output_dir
    from ncflow.errors import InputError
    from ncflow.synthetic.gltf import gltf_pair
    from ncflow.synthetic.mano import mano_pair
    from ncflow.synthetic.motion import target_motion
    from ncflow.synthetic.pairs import check_pairs_dir, make_pair, write_pairs

    if args.mano and args.gltf:
        raise InputError("use either --mano or --gltf, not both")
    check_int(args.n, "--n", 1, 100_000)
    check_seed(args.seed, "--seed", count=args.n if not (args.mano or args.gltf) else 1)
    check_int(args.large_joints, "--large-joints", 0, 1000)
    check_number(args.resolution, "--resolution", hi=1000.0)
    check_number(args.target_resolution, "--target-resolution", hi=1000.0)
    if args.target_resolution is not None and not args.target_resolution >= 8:
        raise InputError(f"--target-resolution must be at least 8 (got {args.target_resolution:g})")
    if (args.mano or args.gltf) and (args.large_joints != 1 or args.large_angle or args.articulation):
        raise InputError("--large-joints, --large-angle and --articulation are for procedural characters only")
    motion = {
        "target_rotation": _range(args.target_rotation, "--target-rotation"),
        "target_translation": _range(args.target_translation, "--target-translation"),
    }
    # check the values and the output folder before any pair is built
    target_motion(0, motion["target_rotation"], motion["target_translation"], np.zeros(3), 1.0)
    n_pairs = args.n if not (args.mano or args.gltf) else 1
    out = output_dir(args.out_dir, overwrite=args.overwrite, need_bytes=4 * MiB * n_pairs, option="OUT_DIR")
    check_pairs_dir(out, args.overwrite)
    if args.mano:
        from ncflow.io.mano import load_mano

        model = load_mano(args.mano)
        retri = bool(args.retriangulate)
        pairs = (
            mano_pair(
                model, i, j, retriangulate=retri, target_resolution=args.target_resolution, seed=args.seed + k, **motion
            )
            for k, (i, j) in enumerate(_pairs_of(args.poses, "--poses", _mano_pose, "row numbers, flat or fist"))
        )
    elif args.gltf:
        retri = bool(args.retriangulate)
        times = _pairs_of(args.times, "--times", _float)
        pairs = (
            gltf_pair(
                args.gltf,
                a,
                b,
                args.animation,
                retriangulate=retri,
                target_resolution=args.target_resolution,
                seed=args.seed + k,
                **motion,
            )
            for k, (a, b) in enumerate(times)
        )
    else:
        if args.n < 1:
            raise InputError(f"--n must be at least 1 (got {args.n})")
        if args.resolution is not None and not args.resolution >= 8:
            raise InputError(f"--resolution must be at least 8 (got {args.resolution:g})")
        retri = True if args.retriangulate is None else args.retriangulate
        extra = {"large_joints": args.large_joints, "articulation": args.articulation}
        if args.large_angle is not None:
            angle = _range(args.large_angle, "--large-angle")
            if not isinstance(angle, tuple):
                raise InputError(f"--large-angle must be LO,HI (got {args.large_angle!r})")
            extra["large_angle"] = angle
        pairs = (
            make_pair(
                args.kind,
                args.seed + k,
                retriangulate=retri,
                resolution=args.resolution,
                target_resolution=args.target_resolution,
                source_pose="random" if args.posed_source else "rest",
                **extra,
                **motion,
            )
            for k in range(args.n)
        )
    if args.defects:
        from ncflow.synthetic.defects import add_defects, parse_defects

        defects = parse_defects(args.defects)
        pairs = (add_defects(pair, defects, seed=args.seed + k) for k, pair in enumerate(pairs))
    csv_path = write_pairs(pairs, out, fmt=args.format, verbose=True, overwrite=args.overwrite)
    print(f"wrote {csv_path}")
    return 0
