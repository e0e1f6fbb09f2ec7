"""Does the data term tell the true pose from the one the pose search found? (issue 16, "pull at a distance")

For every named pair folder of the hard development set (``bash benchmarks/hard_pairs.sh DIR --pairs-only``),
prepares the problem as the matcher does (placement + pose search, default preset), fits a "true" pose
to the target skeleton the generator wrote (joint positions, Adam), refines it by the search's own
Varifold descent (σ = 0.3, then 0.15) and prints, for the pose found, the true pose and the refined true
pose, the normalised Varifold distance at σ = 0.3 / 0.15 / 0.08 and the Sinkhorn divergence
(ott-jax, uniform area weights, ε = 0.01 and 0.001 on positions, and with normals × 0.2 appended).
A score that ranks the refined true pose below the found one could choose between hypotheses; one
that does not cannot. Needs ``pip install ott-jax`` (not an ncflow dependency).

Usage: python benchmarks/pose_scores.py DIR NAME [NAME ...]
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax


def main() -> None:
    from ott.tools.sinkhorn_divergence import sinkdiv

    from ncflow.config import preset, validate_config
    from ncflow.flow.bone_weights import skinning_weights
    from ncflow.matcher.place import place
    from ncflow.matcher.placement import surface_diracs
    from ncflow.matcher.pose_scorer import skinned
    from ncflow.matcher.prepare import prepare, skinning_width
    from ncflow.measures.varifold import varifold_inner
    from ncflow.skeleton import load_skeleton
    from ncflow.skeleton.kinematics import Pose, forward_kinematics, joint_positions

    if len(sys.argv) < 3:
        sys.exit(__doc__)
    root = Path(sys.argv[1]) / "pairs"
    cfg = preset("fast")
    cfg = validate_config(dataclasses.replace(cfg, sampling=dataclasses.replace(cfg.sampling, tissue_samples=0)))
    opt = optax.adam(0.01)

    def descend(loss, pose, steps):
        def body(carry, _):
            q, st = carry
            u, st = opt.update(jax.grad(loss)(q), st, q)
            q = optax.apply_updates(q, u)
            return (Pose(q.rotations / jnp.linalg.norm(q.rotations, axis=-1, keepdims=True), q.translation), st), None

        return jax.lax.scan(body, (pose, opt.init(pose)), None, length=steps)[0][0]

    def one(name):
        p = root / name / "pair_000"
        prob = prepare(p / "source.ply", p / "target.ply", p / "source_skeleton.tgf", cfg)
        placed = place(prob, cfg)
        sk = prob.skeleton_normalized
        truth = placed.placement.apply(prob.normalization.apply(load_skeleton(p / "target_skeleton.tgf").positions))
        truth = jnp.asarray(truth, jnp.float32)

        def joint_loss(pose):
            return jnp.sum((joint_positions(forward_kinematics(sk, pose)) - truth) ** 2)

        x = surface_diracs(prob.working.vertices, prob.working.faces, 1200, 4)
        pos, bones = jnp.asarray(sk.positions, jnp.float32), np.asarray(sk.bones)
        w = skinning_weights(x.centers, pos[bones[:, 0]], pos[bones[:, 1]], skinning_width(cfg, sk))
        y = surface_diracs(placed.placement.apply(prob.target_vertices), np.asarray(prob.target_faces), 1200, 5)

        def varifold(pose, s):
            xs = skinned(sk, w.astype(jnp.float32), x, pose)
            yy = varifold_inner(y, y, s, 0.5)
            return (varifold_inner(xs, xs, s, 0.5) - 2 * varifold_inner(xs, y, s, 0.5) + yy) / yy

        found = placed.pose_search.pose
        true = jax.jit(lambda q: descend(joint_loss, q, 3000))(found)
        refined = jax.jit(
            lambda q: descend(lambda r: varifold(r, 0.15), descend(lambda r: varifold(r, 0.3), q, 100), 100)
        )(true)
        for label, pose in (("found", found), ("true", true), ("true, refined", refined)):
            rms = float(jnp.sqrt(joint_loss(pose) / sk.n_joints))
            row = [f"{name} {label}: joint rms {rms:.3f}"]
            row += [f"V{s} {float(varifold(pose, s)):.4f}" for s in (0.3, 0.15, 0.08)]
            xs = skinned(sk, w.astype(jnp.float32), x, pose)
            a, b = xs.weights / xs.weights.sum(), y.weights / y.weights.sum()
            for eps in (1e-2, 1e-3):
                for nw in (0.0, 0.2):
                    xa = jnp.concatenate([xs.centers, nw * xs.normals], 1)
                    ya = jnp.concatenate([y.centers, nw * y.normals], 1)
                    row.append(f"S(eps {eps}, n {nw}) {float(sinkdiv(xa, ya, a=a, b=b, epsilon=eps)[0]):.5f}")
            print(" | ".join(row), flush=True)

    for name in sys.argv[2:]:
        one(name)


if __name__ == "__main__":
    main()
