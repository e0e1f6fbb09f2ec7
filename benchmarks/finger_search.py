"""The pose search alone on the hand benchmark, per finger: which fingers does it leave wrong?

For every pair folder of ``bash benchmarks/hands.sh DIR --pairs-only`` (each ``DIR/pairs/<name>/pair_000``
holds ``source.ply``, ``target.ply``, ``source_skeleton.tgf`` and ``target_skeleton.tgf``), runs the
placement and the pose search of the default preset (:func:`ncflow.matcher.prepare.prepare`,
:func:`ncflow.matcher.place.place`; tissue off: it does not enter the search) and measures each finger's
largest joint error against the target skeleton (normalised units, the hand about 4 long; fingers as
:func:`fingers.finger_groups` groups them). A finger more than ``--wrong`` (0.3) off is wrong: on the
hand benchmark a wrong finger is 0.45–2.1 off (on its neighbour, folded back, curled where the target's
is straight), a right one under 0.27. About 35–80 s a pair on 2 cores. Results are kept in OUT.json
(a pair already there is skipped, so an interrupted run goes on).

    python benchmarks/finger_search.py run PAIRS_DIR OUT.json [NAME ...]
    python benchmarks/finger_search.py compare BEFORE.json AFTER.json [--wrong 0.3]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from fingers import PALM, finger_joint_errors  # noqa: E402

WRONG = 0.3


def run(root: Path, out: Path, names: list[str]) -> None:
    from ncflow.config import preset, validate_config
    from ncflow.matcher.place import place
    from ncflow.matcher.prepare import prepare
    from ncflow.skeleton import load_skeleton
    from ncflow.skeleton.kinematics import forward_kinematics, joint_positions

    names = names or sorted(p.name for p in root.iterdir() if (p / "pair_000").is_dir())
    cfg = preset("fast")
    cfg = validate_config(dataclasses.replace(cfg, sampling=dataclasses.replace(cfg.sampling, tissue_samples=0)))
    results = json.loads(out.read_text()) if out.exists() else {}
    for name in names:
        if name in results:
            continue
        p = root / name / "pair_000"
        t0 = time.perf_counter()
        setup = prepare(p / "source.ply", p / "target.ply", p / "source_skeleton.tgf", cfg)
        placed = place(setup, cfg)
        skeleton = load_skeleton(p / "source_skeleton.tgf")
        target = load_skeleton(p / "target_skeleton.tgf").positions
        truth = placed.placement.apply(setup.normalization.apply(target))
        pose = placed.pose_search.pose
        found = np.asarray(joint_positions(forward_kinematics(setup.skeleton_normalized, pose)))
        err = np.linalg.norm(found - truth, axis=1)
        fingers = finger_joint_errors(err, skeleton.parents, skeleton.names)
        results[name] = {
            "mean": float(err.mean()),
            "max": float(err.max()),
            "fingers": fingers,
            "score": placed.pose_search.score,
            "rotations": np.asarray(pose.rotations, float).round(6).tolist(),
            "translation": np.asarray(pose.translation, float).round(6).tolist(),
            "truth": truth.round(6).tolist(),
            "seconds": time.perf_counter() - t0,
        }
        shown = {k: round(v, 3) for k, v in fingers.items() if v is not None}
        print(f"{name} {err.mean():.3f} {err.max():.3f} {shown} {results[name]['seconds']:.0f}s", flush=True)
        out.write_text(json.dumps(results, indent=1))


def wrong_fingers(pair: dict, wrong: float) -> list[str]:
    """The fingers (not the palm) more than ``wrong`` off, by name."""
    return sorted(k for k, v in pair["fingers"].items() if k != PALM and v is not None and v > wrong)


def compare(before: dict, after: dict, wrong: float) -> None:
    names = [n for n in before if n in after]
    print("| pair | joint error mean | largest | wrong fingers | s |\n|---|---|---|---|---|")
    for n in names:
        a, b = before[n], after[n]
        wa, wb = wrong_fingers(a, wrong), wrong_fingers(b, wrong)
        print(
            f"| {n} | {a['mean']:.3f} → {b['mean']:.3f} | {a['max']:.3f} → {b['max']:.3f} | "
            f"{', '.join(wa) or '–'} → {', '.join(wb) or '–'} | {a['seconds']:.0f} → {b['seconds']:.0f} |"
        )
    for label, runs in (("before", before), ("after", after)):
        w = [wrong_fingers(runs[n], wrong) for n in names]
        means = np.array([runs[n]["mean"] for n in names])
        print(
            f"{label}: {len(names)} pairs, {sum(map(len, w))} fingers wrong (> {wrong}) in {sum(map(bool, w))} pairs; "
            f"mean joint error {means.mean():.4f}, worst pair {means.max():.3f}; "
            f"median {np.median([runs[n]['seconds'] for n in names]):.0f} s"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run")
    r.add_argument("pairs", type=Path)
    r.add_argument("out", type=Path)
    r.add_argument("names", nargs="*")
    c = sub.add_parser("compare")
    c.add_argument("before", type=Path)
    c.add_argument("after", type=Path)
    c.add_argument("--wrong", type=float, default=WRONG)
    args = parser.parse_args()
    if args.command == "run":
        run(args.pairs, args.out, args.names)
    else:
        compare(json.loads(args.before.read_text()), json.loads(args.after.read_text()), args.wrong)


if __name__ == "__main__":
    main()
