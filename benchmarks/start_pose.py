"""What does a right start pose give? The default match of a hand pair from a pose fitted to the target skeleton.

For one pair folder of ``bash benchmarks/hands.sh DIR --pairs-only`` (``DIR/pairs/<name>/pair_000`` with
``source.ply``, ``target.ply``, ``source_skeleton.tgf``, ``target_skeleton.tgf`` and ``gt.npz``): prepares and
places the pair as :class:`ncflow.matcher.steps.Matcher` does (pose search included), fits a pose to the
target skeleton's joints (Adam on the joint positions as the field poses them — the twist of one-child joints
removed — from the search's pose), trains from that pose ("truth") — and, with ``--search``, from the
search's pose as well — on the same programs and keys, saves each result under OUT/<name>/<start>/ and
scores it with ``ncflow evaluate``. Prints, per start, the largest joint error of each finger (normalised
units; a finger more than 0.3 off is wrong) at the start and after training, the data term of each
training phase and the geodesic AUC. ``--set`` takes the configuration overrides of ``ncflow match``
(e.g. ``weights.tissue=0``, ``flow.pose_lr_scale=0``). About 3–4 min a start on 2 cores.

    python benchmarks/start_pose.py PAIRS_DIR NAME OUT [--search] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from fingers import finger_joint_errors  # noqa: E402


def fingers_off(setup, pose, truth: np.ndarray, skeleton) -> dict:
    """Largest joint error of each finger (and the palm) of ``pose`` against the target joints ``truth``."""
    from ncflow.flow.skinning import swing_only
    from ncflow.skeleton.kinematics import forward_kinematics, joint_positions

    joints = np.asarray(
        joint_positions(forward_kinematics(setup.skeleton_normalized, swing_only(setup.skeleton_normalized, pose)))
    )
    err = finger_joint_errors(np.linalg.norm(joints - truth, axis=1), skeleton.parents, skeleton.names)
    return {label: round(e, 3) for label, e in err.items() if e is not None}


def fit_to_joints(skeleton, pose, truth: np.ndarray, steps: int = 800, lr: float = 0.01):
    """A pose whose joints match ``truth`` (J, 3) as the skeleton-driven field poses them (the twist of one-child
    joints removed, :func:`ncflow.flow.skinning.swing_only`): Adam from ``pose`` on the squared distances.
    """
    import jax
    import jax.numpy as jnp
    import optax

    from ncflow.flow.skinning import swing_only
    from ncflow.skeleton.kinematics import Pose, forward_kinematics, joint_positions

    target = jnp.asarray(truth)
    opt = optax.adam(lr)

    def loss(p):
        return jnp.sum((joint_positions(forward_kinematics(skeleton, swing_only(skeleton, p))) - target) ** 2)

    @jax.jit
    def step(p, state):
        value, grad = jax.value_and_grad(loss)(p)
        updates, state = opt.update(grad, state, p)
        return optax.apply_updates(p, updates), state, value

    p = jax.tree.map(jnp.asarray, pose)
    state = opt.init(p)
    for _ in range(steps):
        p, state, _ = step(p, state)
    return Pose(p.rotations / jnp.linalg.norm(p.rotations, axis=1, keepdims=True), p.translation)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("pairs", type=Path)
    parser.add_argument("name")
    parser.add_argument("out", type=Path)
    parser.add_argument("--search", action="store_true", help="also train from the search's pose")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()

    from ncflow.config import preset, validate_config
    from ncflow.config.files import apply_overrides
    from ncflow.matcher.steps import Matcher
    from ncflow.skeleton import load_skeleton

    p = args.pairs / args.name / "pair_000"
    cfg = validate_config(apply_overrides(dataclasses.replace(preset("fast"), setup_cache=False), args.set))
    matcher = Matcher(p / "source.ply", p / "target.ply", p / "source_skeleton.tgf", cfg, quiet=True)
    skeleton = load_skeleton(p / "source_skeleton.tgf")
    setup, placed = matcher.setup, matcher.placed
    truth = placed.placement.apply(setup.normalization.apply(load_skeleton(p / "target_skeleton.tgf").positions))
    starts = {"truth": fit_to_joints(setup.skeleton_normalized, placed.initial_pose, truth)}
    if args.search:
        starts["search"] = placed.initial_pose
    for label, pose in starts.items():
        matcher.placed = dataclasses.replace(placed, initial_pose=pose)
        result = matcher.run()
        folder = args.out / args.name / label
        result.save(folder)
        command = [
            "ncflow",
            "evaluate",
            str(folder),
            "--source",
            str(p / "source.ply"),
            "--target",
            str(p / "target.ply"),
        ]
        subprocess.run([*command, "--gt", str(p / "gt.npz"), "--no-plots"], check=True, capture_output=True)
        evaluation = json.loads((folder / "evaluation.json").read_text())
        row = {
            "start": fingers_off(setup, pose, truth, skeleton),
            "end": fingers_off(setup, result.state.pose, truth, skeleton),
            "data": [round(ph["data"], 4) for ph in result.metrics["phases"]],
            "tissue": [round(ph["tissue"], 3) for ph in result.metrics["phases"]],
            "geodesic_auc": evaluation["headline"]["geodesic_auc"],
        }
        print(f"{args.name} {label}: {json.dumps(row)}", flush=True)


if __name__ == "__main__":
    main()
