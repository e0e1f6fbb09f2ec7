"""``ncflow pose``: pose a skinned glTF/GLB character at an animation time and write the mesh."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "pose",
        help="pose a skinned glTF/GLB character at an animation time (source/target pairs with ground truth)",
        description=(
            "Pose the skinned mesh of a glTF 2.0 / GLB file by linear blend skinning at TIME seconds of "
            "an animation clip (file timeline, clamped to the clip; the first clip by default) and write "
            "it with seam duplicates welded. Every pose of one file has the same vertex order, so two "
            "poses are a source/target pair with exact vertex-to-vertex ground truth. Without --time the "
            "bind pose is written."
        ),
    )
    p.add_argument("file", help="skinned .glb / .gltf file")
    p.add_argument("--time", metavar="T", help="seconds into the clip (default: the bind pose)")
    p.add_argument("--animation", metavar="NAME_OR_INDEX", help="clip name or 0-based index (default: the first clip)")
    p.add_argument("--out", metavar="MESH", help="output mesh (.ply, .obj, .off, .stl, .glb)")
    p.add_argument("--skeleton-out", metavar="SKEL", help="also write the posed skeleton (.tgf or .json)")
    p.add_argument("--skin", type=int, metavar="N", help="which skin of the file (default: the first)")
    p.add_argument("--no-weld", action="store_true", help="keep the file's seam duplicates")
    p.add_argument("--list", action="store_true", help="list the animation clips with their durations and exit")
    p.set_defaults(func=run)


def _parse_time(text: str | None) -> float | None:
    import math

    from ncflow.errors import InputError

    if text is None:
        return None
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"--time must be a number of seconds (got {text!r})") from None
    if not math.isfinite(value):
        raise InputError(f"--time must be finite (got {text!r})")
    return value


def _write_all(writers: list[tuple]) -> None:
    """Write every output to a temporary sibling first, then move all into place (no partial outputs)."""
    import os
    from pathlib import Path

    from ncflow.io.atomic import temporary_sibling

    done: list[tuple[Path, Path]] = []
    try:
        for path, write in writers:
            path = Path(path)
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = temporary_sibling(path)
            done.append((tmp, path))
            write(tmp)
        for tmp, path in done:
            os.replace(tmp, path)
    finally:
        for tmp, _ in done:
            if tmp.exists():
                tmp.unlink()


def run(args: argparse.Namespace) -> int:
    from ncflow.errors import InputError
    from ncflow.io.gltf.document import GLTF_SUFFIXES
    from ncflow.io.gltf.skins import gltf_skeleton, load_gltf_skin
    from ncflow.io.meshes import MESH_SUFFIXES, save_mesh

    if not args.file.lower().endswith(GLTF_SUFFIXES):
        raise InputError("expected a .glb or .gltf file", args.file)
    if args.list:
        from ncflow.io.gltf.animation import gltf_animations

        clips = gltf_animations(args.file)
        if not clips:
            print(f"{args.file}: no animations")
        for c in clips:
            print(
                f"{c.index}\t{c.name or '(unnamed)'}\t{c.duration:.4g} s\t"
                f"[{c.start:.4g}, {c.end:.4g}]\t{c.n_channels} channels"
            )
        return 0
    if not args.out:
        raise InputError("--out is required (or use --list)")
    if not args.out.lower().endswith(MESH_SUFFIXES):
        raise InputError(f"output must end with one of {', '.join(MESH_SUFFIXES)}", args.out)
    if args.skeleton_out and not args.skeleton_out.lower().endswith((".tgf", ".json")):
        raise InputError("skeleton output must end with .tgf or .json", args.skeleton_out)
    time = _parse_time(args.time)
    from ncflow.cli.options import MiB, check_int, output_file

    check_int(args.skin, "--skin", 0, 10**6)
    # the outputs checked (symbolic links resolved) before the file is read
    out = output_file(args.out, need_bytes=8 * MiB, option="--out")
    skeleton_out = output_file(args.skeleton_out, option="--skeleton-out") if args.skeleton_out else None
    if skeleton_out is not None and skeleton_out == out:
        raise InputError("--skeleton-out is the same file as --out", args.skeleton_out)

    rig = load_gltf_skin(args.file, args.skin)
    posed = rig.pose(time, args.animation, weld=not args.no_weld)

    writers = [(out, lambda p: save_mesh(p, posed.vertices, posed.faces))]
    dropped: list[str] = []
    if args.skeleton_out:
        from ncflow.skeleton import save_skeleton

        # joints stacked on their parent (zero-length bones) are merged, chosen in the bind pose
        # so that every pose of the file gives the same joints
        skeleton, keep = gltf_skeleton(rig, time, args.animation, name=args.file)
        dropped = [n for j, n in enumerate(posed.names) if j not in set(keep.tolist())]
        writers.append((skeleton_out, lambda p: save_skeleton(p, skeleton)))
    _write_all(writers)

    what = "bind pose" if posed.time is None else f"clip {posed.animation or '(unnamed)'!r} at t={posed.time:g} s"
    print(f"wrote {args.out}: {len(posed.vertices)} vertices, {len(posed.faces)} faces ({what})")
    if args.skeleton_out:
        note = f" (merged {len(dropped)} joints onto their parents: {', '.join(dropped)})" if dropped else ""
        print(f"wrote {args.skeleton_out}: {len(posed.names) - len(dropped)} joints{note}")
    return 0
