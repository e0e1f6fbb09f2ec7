"""A broad, seeded hand benchmark (issue 44 item 1): MANO pairs chosen by pose class, and procedural hands.

Every captured pose of the MANO model (the rows of ``hands_coeffs``) is posed with the package's own MANO
code (:func:`ncflow.synthetic.mano.mano_forward`) and measured:

* reach: the mean distance of the index, middle, ring and little fingertips (vertices 320, 443, 555, 672)
  to the palm centre (the centroid of the vertices skinned mostly to the wrist, as in
  :func:`ncflow.synthetic.mano.mano_fist_pose`);
* pinch gap: the distance of the thumb tip (vertex 744) to the nearer of the index and middle fingertips.

A pose is fist-like when its reach is in the lowest decile over all poses, flat-like in the highest
decile, a pinch when its gap is in the lowest 3 %. From these classes and ``numpy.random.default_rng(seed)``
the script draws 41 MANO pairs — 20 random row pairs, 5 flat → fist (the first one the named poses
``flat`` → ``fist``), 5 fist → flat (the first ``fist`` → ``flat``), 5 with a pinch target, 2 fist → fist,
2 pinch → fist, 2 pinch → flat — and turns and moves the target of half of them (chosen at random) by
``--target-rotation 0,180 --target-translation 0.1,0.5`` (a uniform angle up to 180° about a random
axis, drawn by make-pairs from the pair's own seed). Every MANO target is re-triangulated. Then 12
procedural hands (``--kind hand``, one pair per folder): ``--large-joints`` 2, 3, 4 in turn (4 is
the most the procedural hand accepts: its four finger middle joints), every third one
``--articulation curl``, half of them (at random) turned and moved like the MANO targets.

Each pair is built by ``ncflow make-pairs --overwrite ... OUT/pairs/<name>`` (run in this process), then
``merge_pairs.py`` writes ``OUT/pairs/all.csv`` (each row named after its folder). ``OUT/pairs/selection.json``
records the seed, the classification (thresholds and class sizes), and for every pair its kind, rows,
motion ranges, seed and the make-pairs command line. The same model and seed give the same pairs; a
folder holding another selection is refused (use a new OUT).

    python benchmarks/hand_pairs.py MODEL OUT [--seed 0] [--dry-run] [--only NAME[,NAME...]]

(--dry-run: write selection.json and print the commands, build nothing; --only: build only these pairs.)
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

#: fingertip order of the MANO tip vertices (``ncflow.synthetic.mano.MANO_TIP_VERTICES``)
TIP_NAMES = ("index", "middle", "little", "ring", "thumb")

FIST_QUANTILE = 0.10
FLAT_QUANTILE = 0.90
PINCH_QUANTILE = 0.03

#: MANO pair kinds (source class → target class) and how many of each are drawn
MANO_COUNTS = {
    "random": 20,
    "flatfist": 5,
    "fistflat": 5,
    "pinch": 5,
    "fistfist": 2,
    "pinchfist": 2,
    "pinchflat": 2,
}
#: source and target class of each kind ("any": every row; "notpinch": every row that is not a pinch)
KIND_CLASSES = {
    "random": ("any", "any"),
    "flatfist": ("flat", "fist"),
    "fistflat": ("fist", "flat"),
    "pinch": ("notpinch", "pinch"),
    "fistfist": ("fist", "fist"),
    "pinchfist": ("pinch", "fist"),
    "pinchflat": ("pinch", "flat"),
}
#: kinds whose first pair is the named poses instead of rows
NAMED_FIRST = {"flatfist": ("flat", "fist"), "fistflat": ("fist", "flat")}

ROTATION_DEG = (0.0, 180.0)
TRANSLATION = (0.1, 0.5)
N_PROCEDURAL = 12
LARGE_JOINTS = (2, 3, 4)


def pose_features(model, poses, tip_vertices=None) -> tuple[np.ndarray, np.ndarray]:
    """Fingertips and palm centre of the MANO model in each pose (no global rotation, template shape).

    Args:
        model: a :class:`ncflow.io.mano.ManoModel`.
        poses: N poses as :func:`ncflow.synthetic.mano.mano_finger_pose` reads them (row numbers of
            ``hands_coeffs`` or the names ``flat`` / ``fist``).
        tip_vertices: the five fingertip vertices, index, middle, little, ring, thumb (default MANO's).

    Returns:
        (tips (N, 5, 3) in the order of :data:`TIP_NAMES`, palm centres (N, 3): the centroid of the
        vertices whose largest skinning weight is the wrist's).
    """
    from ncflow.synthetic.mano import MANO_TIP_VERTICES, mano_finger_pose, mano_forward

    tip_vertices = list(MANO_TIP_VERTICES if tip_vertices is None else tip_vertices)
    on_wrist = np.argmax(model.weights, axis=1) == 0
    poses = list(poses)
    tips, palm = np.zeros((len(poses), 5, 3)), np.zeros((len(poses), 3))
    for k, pose in enumerate(poses):
        verts, _ = mano_forward(model, mano_finger_pose(model, pose))
        tips[k], palm[k] = verts[tip_vertices], verts[on_wrist].mean(axis=0)
    return tips, palm


def classify_poses(
    tips: np.ndarray,
    palm: np.ndarray,
    fist_quantile: float = FIST_QUANTILE,
    flat_quantile: float = FLAT_QUANTILE,
    pinch_quantile: float = PINCH_QUANTILE,
) -> dict:
    """Fist-like, flat-like and pinch poses among N poses, by quantiles of two distances.

    Args:
        tips: (N, 5, 3) fingertips, index, middle, little, ring, thumb (:data:`TIP_NAMES`).
        palm: (N, 3) palm centres.
        fist_quantile: a pose is fist-like when its reach is at most this quantile of all reaches.
        flat_quantile: flat-like when its reach is at least this quantile.
        pinch_quantile: a pinch when its pinch gap is at most this quantile of all gaps.

    Returns:
        ``reach`` (N,): mean distance of the four finger tips (not the thumb) to the palm centre;
        ``pinch_gap`` (N,): distance of the thumb tip to the nearer of the index and middle tips;
        ``fist``, ``flat``, ``pinch`` (N,) bool; ``thresholds``: the reach and gap limits (model units)
        and the quantiles they come from.
    """
    tips, palm = np.asarray(tips, dtype=np.float64), np.asarray(palm, dtype=np.float64)
    reach = np.linalg.norm(tips[:, :4] - palm[:, None], axis=2).mean(axis=1)
    gap = np.minimum(np.linalg.norm(tips[:, 4] - tips[:, 0], axis=1), np.linalg.norm(tips[:, 4] - tips[:, 1], axis=1))
    fist_reach, flat_reach = np.quantile(reach, fist_quantile), np.quantile(reach, flat_quantile)
    pinch_gap = np.quantile(gap, pinch_quantile)
    return {
        "reach": reach,
        "pinch_gap": gap,
        "fist": reach <= fist_reach,
        "flat": reach >= flat_reach,
        "pinch": gap <= pinch_gap,
        "thresholds": {
            "fist_quantile": float(fist_quantile),
            "fist_reach_max": float(fist_reach),
            "flat_quantile": float(flat_quantile),
            "flat_reach_min": float(flat_reach),
            "pinch_quantile": float(pinch_quantile),
            "pinch_gap_max": float(pinch_gap),
        },
    }


def _motion(turned: bool) -> dict:
    """The make-pairs motion ranges of a pair: :data:`ROTATION_DEG` and :data:`TRANSLATION` when turned, else None."""
    if not turned:
        return {"target_rotation": None, "target_translation": None}
    return {"target_rotation": list(ROTATION_DEG), "target_translation": list(TRANSLATION)}


def select_mano_pairs(classes: dict, seed: int = 0, counts: dict | None = None) -> list[dict]:
    """Draw the MANO pairs from pose classes with ``numpy.random.default_rng(seed)``.

    Args:
        classes: ``fist``, ``flat``, ``pinch``: (N,) bool masks over the N rows (:func:`classify_poses`).
        seed: the seed; the same classes and seed give the same list.
        counts: pairs per kind (default :data:`MANO_COUNTS`; kinds of :data:`KIND_CLASSES`).

    Returns:
        one dict per pair: ``name`` (``mano_<kind>_<source>_<target>``), ``kind``, ``source`` and ``target``
        (a row number or a pose name), ``seed`` (the make-pairs seed: 1000 × seed + position), and the
        motion ranges ``target_rotation`` / ``target_translation`` (None for the half left unturned).
        No (source, target) pair occurs twice and no pair has the same row on both sides.
    """
    counts = MANO_COUNTS if counts is None else counts
    rng = np.random.default_rng(seed)
    n_rows = int(np.asarray(classes["fist"]).size)
    pinch = np.asarray(classes["pinch"], dtype=bool)
    rows = {
        "any": np.arange(n_rows),
        "notpinch": np.flatnonzero(~pinch),
        "fist": np.flatnonzero(classes["fist"]),
        "flat": np.flatnonzero(classes["flat"]),
        "pinch": np.flatnonzero(pinch),
    }
    seen, drawn = set(), []
    for kind, count in counts.items():
        src_class, tgt_class = KIND_CLASSES[kind]
        for k in range(count):
            if k == 0 and kind in NAMED_FIRST:
                a, b = NAMED_FIRST[kind]
            else:
                for _ in range(1000):
                    a, b = int(rng.choice(rows[src_class])), int(rng.choice(rows[tgt_class]))
                    if a != b and (a, b) not in seen:
                        break
                else:
                    raise ValueError(f"cannot draw {count} distinct {kind} pairs from the classes")
            seen.add((a, b))
            drawn.append({"name": f"mano_{kind}_{a}_{b}", "kind": kind, "source": a, "target": b})
    turned = set(rng.permutation(len(drawn))[: len(drawn) // 2].tolist())
    for k, pair in enumerate(drawn):
        pair.update(seed=1000 * seed + k, **_motion(k in turned))
    return drawn


def select_procedural_hands(seed: int = 0, n: int = N_PROCEDURAL) -> list[dict]:
    """The procedural hand pairs: one per folder, varied large joints, some curled, half turned.

    Args:
        seed: the seed of ``numpy.random.default_rng`` (which hands are turned) and of the hands'
            make-pairs seeds (1000 × seed + 500 + k).
        n: number of hands.

    Returns:
        one dict per hand: ``name`` (``hand_lj<L>[_curl]_s<S>``), ``kind`` ``"hand"``, ``seed`` S,
        ``large_joints`` L (cycling through :data:`LARGE_JOINTS`), ``articulation`` (``"curl"`` for every
        third hand, else None) and the motion ranges (None when not turned).
    """
    rng = np.random.default_rng([seed, 1])
    turned = set(rng.permutation(n)[: n // 2].tolist())
    hands = []
    for k in range(n):
        s, lj = 1000 * seed + 500 + k, LARGE_JOINTS[k % len(LARGE_JOINTS)]
        curl = "curl" if k % 3 == 2 else None
        name = f"hand_lj{lj}{'_curl' if curl else ''}_s{s}"
        hands.append({"name": name, "kind": "hand", "seed": s, "large_joints": lj, "articulation": curl})
        hands[-1].update(_motion(k in turned))
    return hands


def make_pairs_argv(pair: dict, model_path: str, pairs_dir: Path) -> list[str]:
    """The ``ncflow make-pairs`` arguments (without the program name) that build one selected pair."""
    if pair["kind"] == "hand":
        argv = ["make-pairs", "--overwrite", "--kind", "hand", "--n", "1", "--seed", str(pair["seed"])]
        argv += ["--large-joints", str(pair["large_joints"])]
        argv += ["--articulation", pair["articulation"]] if pair["articulation"] else []
    else:
        argv = ["make-pairs", "--overwrite", "--mano", str(model_path), "--poses", f"{pair['source']},{pair['target']}"]
        argv += ["--retriangulate", "--seed", str(pair["seed"])]
    if pair["target_rotation"]:
        argv += ["--target-rotation", ",".join(f"{x:g}" for x in pair["target_rotation"])]
        argv += ["--target-translation", ",".join(f"{x:g}" for x in pair["target_translation"])]
    return argv + [str(pairs_dir / pair["name"])]


def selection(model_path: str, seed: int = 0) -> dict:
    """Classify the model's captured poses and draw every pair: the content of ``selection.json``.

    Returns:
        ``seed``, ``model``, ``n_poses``, ``classification`` (thresholds; class sizes; the reach of
        the named ``flat`` and ``fist`` poses), ``motion`` (the ranges turned targets get) and
        ``pairs`` (MANO pairs then procedural hands, see :func:`select_mano_pairs` and
        :func:`select_procedural_hands`; each MANO pair with its rows' reach and pinch gap).
    """
    from ncflow.io.mano import load_mano

    model = load_mano(model_path)
    if model.hands_coeffs is None:
        sys.exit(f"{model_path} has no hands_coeffs (captured poses) to choose pairs from")
    n = int(model.hands_coeffs.shape[0])
    classes = classify_poses(*pose_features(model, range(n)))
    named_tips, named_palm = pose_features(model, ["flat", "fist"])
    named_reach = np.linalg.norm(named_tips[:, :4] - named_palm[:, None], axis=2).mean(axis=1)
    mano = select_mano_pairs(classes, seed)
    for pair in mano:
        for side in ("source", "target"):
            if isinstance(pair[side], int):
                pair[f"{side}_reach"] = float(classes["reach"][pair[side]])
                pair[f"{side}_pinch_gap"] = float(classes["pinch_gap"][pair[side]])
    fist, flat, pinch = classes["fist"], classes["flat"], classes["pinch"]
    return {
        "seed": int(seed),
        "model": str(model_path),
        "n_poses": n,
        "classification": {
            **classes["thresholds"],
            "counts": {
                "fist": int(fist.sum()),
                "flat": int(flat.sum()),
                "pinch": int(pinch.sum()),
                "pinch_and_fist": int((pinch & fist).sum()),
                "pinch_and_flat": int((pinch & flat).sum()),
            },
            "reach_range": [float(classes["reach"].min()), float(classes["reach"].max())],
            "pinch_gap_range": [float(classes["pinch_gap"].min()), float(classes["pinch_gap"].max())],
            "named_reach": {"flat": float(named_reach[0]), "fist": float(named_reach[1])},
        },
        "motion": {"target_rotation_deg": list(ROTATION_DEG), "target_translation": list(TRANSLATION)},
        "pairs": mano + select_procedural_hands(seed),
    }


def _check_folder(pairs_dir: Path, chosen: dict) -> None:
    """Refuse a pairs folder that holds another selection or pair folders outside this one."""
    old = pairs_dir / "selection.json"
    names = [p["name"] for p in chosen["pairs"]]
    if old.is_file():
        before = json.loads(old.read_text())
        if before.get("seed") != chosen["seed"] or [p["name"] for p in before.get("pairs", [])] != names:
            sys.exit(f"{pairs_dir} holds the pairs of another selection (seed {before.get('seed')}): use a new folder")
    stray = sorted(p.parent.name for p in pairs_dir.glob("*/pairs.csv") if p.parent.name not in set(names))
    if stray:
        sys.exit(f"{pairs_dir} holds pair folders of no selection ({', '.join(stray)}): use a new folder")


def build(model_path: str, out: str | os.PathLike, seed: int = 0, only=None, dry_run: bool = False) -> dict:
    """Select the pairs, build them with ``ncflow make-pairs`` and merge them into ``OUT/pairs/all.csv``.

    Args:
        model_path: the MANO model file.
        out: the output folder; the pairs go to ``OUT/pairs/<name>/``.
        seed: the selection seed.
        only: names of the pairs to build (default: all).
        dry_run: write ``selection.json`` and print the commands only.

    Returns:
        the selection (:func:`selection`), each pair with its ``command``.
    """
    from merge_pairs import merge
    from ncflow.cli import main as ncflow_main

    pairs_dir = Path(out) / "pairs"
    chosen = selection(model_path, seed)
    for pair in chosen["pairs"]:
        pair["command"] = shlex.join(["ncflow"] + make_pairs_argv(pair, model_path, pairs_dir))
    unknown = set(only or ()) - {p["name"] for p in chosen["pairs"]}
    if unknown:
        sys.exit(f"no such pairs in the selection of seed {seed}: {', '.join(sorted(unknown))}")
    pairs_dir.mkdir(parents=True, exist_ok=True)
    _check_folder(pairs_dir, chosen)
    (pairs_dir / "selection.json").write_text(json.dumps(chosen, indent=1) + "\n")
    c = chosen["classification"]
    print(
        f"{chosen['n_poses']} poses: {c['counts']['fist']} fist-like (reach <= {c['fist_reach_max']:.4f}), "
        f"{c['counts']['flat']} flat-like (reach >= {c['flat_reach_min']:.4f}), {c['counts']['pinch']} pinch "
        f"(gap <= {c['pinch_gap_max']:.4f}); {len(chosen['pairs'])} pairs"
    )
    for pair in chosen["pairs"]:
        if only and pair["name"] not in only:
            continue
        print(pair["command"], flush=True)
        if not dry_run and ncflow_main(make_pairs_argv(pair, model_path, pairs_dir)) != 0:
            sys.exit(f"ncflow make-pairs failed for {pair['name']}")
    if not dry_run:
        print(f"{pairs_dir / 'all.csv'}: {merge(pairs_dir)} pairs")
    return chosen


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", metavar="MODEL", help="MANO model (mano_right.npz)")
    ap.add_argument("out", metavar="OUT", help="output folder (pairs in OUT/pairs)")
    ap.add_argument("--seed", type=int, default=0, help="selection seed (default 0)")
    ap.add_argument("--dry-run", action="store_true", help="write selection.json and print the commands only")
    ap.add_argument("--only", help="comma-separated pair names to build (default: all)")
    args = ap.parse_args()
    if args.seed < 0:
        ap.error("--seed must be at least 0")
    build(args.model, args.out, args.seed, args.only.split(",") if args.only else None, args.dry_run)


if __name__ == "__main__":
    main()
