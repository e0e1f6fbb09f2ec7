"""The sequence development set of ``ncflow track``: build sequences with exact ground truth, track them, score
every frame.

    python benchmarks/track_sequences.py OUT [--only NAME ...] [--frames N] [--warm-steps S] [--seed K] [--vs-match]
        [--set KEY=VALUE ...]

Sequences (every frame re-triangulated on its own grid, exact ground truth per frame):

* ``cesiumman_walk`` — CesiumMan's walk clip (``../shared/data/gltf``), N times over its 2 s;
* ``fox_run`` — the Fox's Run clip, N times over its 1.16 s;
* ``humanoid_move``, ``quadruped_move``, ``hand_move`` — a generated character through three key poses
  (large flexions), turning 90° and travelling half its diagonal (:func:`ncflow.synthetic.sequences.make_sequence`);
* ``mano_move`` — the MANO hand (``../shared/data/mano``) through three captured poses drawn from the seed,
  ``mano_fist`` — flat → fist → a captured pose (:func:`ncflow.synthetic.sequences.mano_sequence`), turning 60°;
* ``humanoid_scan``, ``mano_scan`` — ``humanoid_move`` and ``mano_move`` as a fixed camera sees them
  (:func:`ncflow.synthetic.scans.scanned_sequence`: single-view meshes with holes, ground truth on the
  part seen); ``humanoid_cloud`` — the same views as point clouds (``.xyz``, no faces).

Per sequence (``OUT/report.json`` and a table on stdout): per-frame geodesic AUC (τmax 0.20; mean, worst
frame), drift (mean AUC of the last quarter minus the first quarter's), jitter (the registered source's
mean vertex acceleration |x_{k+1} − 2 x_k + x_{k−1}| and the ground truth's, × the bounding-box diagonal),
the largest bone violation, frames that fell back, the time of the first frame (a full match) and of the
whole sequence, and the speed-up N × first / total (≥ 6: the warm start pays). With ``--vs-match``, also
issue 46's own measure: the sequence's last frame matched in full by ``ncflow match`` (a new process, as a user
runs it, the same preset; its time includes the command's start, about 3 s of imports), and the speed-up
N × that match's wall time / the track's wall time.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from ncflow.config import apply_overrides, preset
from ncflow.evaluate.metrics import auc, geodesic_errors
from ncflow.io.files import read_npz_arrays
from ncflow.io.mano import load_mano
from ncflow.io.meshes import load_mesh
from ncflow.synthetic.scans import scanned_sequence
from ncflow.synthetic.sequences import gltf_sequence, make_sequence, mano_sequence, write_sequence
from ncflow.track import track_sequence

GLTF = Path(__file__).resolve().parents[2] / "shared" / "data" / "gltf"
MANO = Path(__file__).resolve().parents[2] / "shared" / "data" / "mano" / "mano_right.npz"
NAMES = [
    "cesiumman_walk",
    "fox_run",
    "humanoid_move",
    "quadruped_move",
    "hand_move",
    "mano_move",
    "mano_fist",
    "humanoid_scan",
    "mano_scan",
    "humanoid_cloud",
]


def build(name: str, n: int, seed: int):
    if name.endswith(("_scan", "_cloud")):
        base = build(name.split("_")[0] + "_move", n, seed)
        return dataclasses.replace(scanned_sequence(base, seed), name=name.replace("_", "_seq_") + f"_{seed:03d}")
    if name.startswith("mano_"):
        model = load_mano(MANO)
        if name == "mano_fist":
            poses = ["flat", "fist", int(np.random.default_rng(seed).integers(model.hands_coeffs.shape[0]))]
        else:
            poses = [int(p) for p in np.random.default_rng(seed).choice(model.hands_coeffs.shape[0], 3, replace=False)]
        return mano_sequence(model, poses, n, seed=seed, name=f"{name.replace('_', '_seq_')}_{seed:03d}")
    if name == "cesiumman_walk":
        return gltf_sequence(GLTF / "CesiumMan.glb", np.linspace(0.0, 2.0, n), seed=seed, name=name)
    if name == "fox_run":
        return gltf_sequence(GLTF / "Fox.glb", np.linspace(0.0, 1.15, n), "Run", seed=seed, name=name)
    kind = name.split("_")[0]
    return make_sequence(kind, seed, n)


def jitter(frames: np.ndarray) -> float:
    acc = frames[2:] - 2 * frames[1:-1] + frames[:-2]
    return float(np.mean(np.linalg.norm(acc, axis=-1)))


def score(name: str, data: Path, run: Path) -> dict:
    record = json.loads((data / "sequence.json").read_text())
    metrics = json.loads((run / "metrics.json").read_text())
    source = load_mesh(data / record["source"])
    diag = float(np.linalg.norm(np.ptp(source.vertices, axis=0)))
    aucs, registered, truth = [], [], np.load(data / "source_frames.npy")
    for fr in record["frames"]:
        stem = fr["stem"]
        if not (run / "maps" / f"{stem}.npz").is_file():
            aucs.append(float("nan"))
            continue
        pred = read_npz_arrays(run / "maps" / f"{stem}.npz", ("face", "bary"))
        gt = read_npz_arrays(data / fr["gt"], ("face", "bary"), ("target_index",))
        seen = gt.get("target_index", np.arange(gt["face"].shape[0]))  # a scan: the points with a truth
        e = geodesic_errors(source, pred["face"][seen], pred["bary"][seen], gt["face"], gt["bary"])
        aucs.append(auc(e, 0.20))
        registered.append(load_mesh(run / "registered" / f"{stem}.ply").vertices)
    a = np.asarray(aucs)
    q = max(1, len(a) // 4)
    first = metrics["timings"]["first_frame"]
    total = sum(f.get("seconds") or 0.0 for f in metrics["frames"]) + metrics["timings"].get("outputs", 0.0)
    return {
        "name": name,
        "n_frames": len(a),
        "auc_mean": float(np.nanmean(a)),
        "auc_worst": float(np.nanmin(a)),
        "auc_per_frame": a.tolist(),
        "drift": float(np.nanmean(a[-q:]) - np.nanmean(a[:q])),
        "jitter": jitter(np.stack(registered)) / diag if len(registered) > 2 else None,
        "jitter_truth": jitter(truth) / diag,
        "max_violation_ratio": metrics["max_violation_ratio"],
        "n_fell_back": metrics["n_fell_back"],
        "n_failed": metrics["n_failed"],
        "first_frame_seconds": first,
        "total_seconds": total,
        "speedup": len(a) * first / total if first else None,
        "max_key_error": metrics["animation"]["max_key_error"],
    }


def match_wall(data: Path, files: dict, out: Path, settings: list[str]) -> float:
    """Wall seconds of ``ncflow match`` of the sequence's last frame, run as a new process (with the track's
    ``--set`` settings)."""
    cmd = [
        sys.executable,
        "-m",
        "ncflow",
        "match",
        str(data / files["source"]),
        str(data / files["frames"][-1]["mesh"]),
    ]
    cmd += ["--skeleton", str(data / files["skeleton"]), "--out", str(out), "--overwrite", "--quiet"]
    cmd += [arg for kv in settings for arg in ("--set", kv)]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True)
    return time.perf_counter() - t0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out")
    p.add_argument("--only", nargs="+", choices=NAMES, default=NAMES)
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--warm-steps", type=int, default=None)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--vs-match", action="store_true", help="also time a full `ncflow match` of the last frame")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a setting, as `ncflow match --set`")
    args = p.parse_args(argv)
    config = apply_overrides(preset("fast"), args.set)
    out = Path(args.out)
    rows = []
    for name in args.only:
        data, run = out / "data" / name, out / "runs" / name
        if not (data / "sequence.json").is_file():
            write_sequence(build(name, args.frames, args.seed), data, frame_format="xyz" if "cloud" in name else None)
        files = json.loads((data / "sequence.json").read_text())
        t0 = time.perf_counter()
        options = {} if args.warm_steps is None else {"warm_steps": args.warm_steps}
        track_sequence(
            data / files["source"],
            [data / f["mesh"] for f in files["frames"]],
            data / files["skeleton"],
            run,
            config,
            quiet=True,
            **options,
        )
        track_wall = time.perf_counter() - t0
        row = score(name, data, run)
        row["wall_seconds"] = time.perf_counter() - t0
        row["track_wall_seconds"] = track_wall
        if args.vs_match:
            row["match_wall_seconds"] = match_wall(data, files, out / "match" / name, args.set)
            row["speedup_vs_match"] = row["n_frames"] * row["match_wall_seconds"] / track_wall
        rows.append(row)
        print(
            f"{name:16s} N={row['n_frames']:3d} AUC mean {row['auc_mean']:.3f} worst {row['auc_worst']:.3f} "
            f"drift {row['drift']:+.3f} jitter {row['jitter'] or 0:.4f} (truth {row['jitter_truth']:.4f}) "
            f"g/eps {row['max_violation_ratio']:.2f} fell back {row['n_fell_back']} "
            f"first {row['first_frame_seconds']:.0f} s total {row['total_seconds']:.0f} s "
            f"speed-up {row['speedup']:.1f}"
            + (
                f"; full match of the last frame {row['match_wall_seconds']:.0f} s, track {track_wall:.0f} s: "
                f"speed-up {row['speedup_vs_match']:.1f}"
                if args.vs_match
                else ""
            ),
            flush=True,
        )
        (out / "report.json").write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
