"""What the integrator's rematerialised steps save (issue 49's time bound): forward and backward of
:func:`ncflow.flow.integrate` with ``checkpoint`` on (each step recomputed in the backward pass, the default)
and off (every step's activations kept), for

* ``bare``: the paper's Flow-Net alone (the ``paper`` preset's field; width and depth as given),
* ``skinned``: the ``fast`` preset's skeleton-driven field without rigid cores, and
* ``cored``: the same with rigid cores (radius 0.2 × the bone's length), the ``fast`` preset's default,

in "current" and "start" bone weights, on N random points around a chain of B bones (T = 10 grid times;
float32; the loss a sum over every grid state). Printed: median and minimum wall milliseconds of the
compiled value-and-gradient over ``--repeats`` calls (the variants called in turn, so that a drift of
the machine's speed falls on all alike), and the largest relative difference of the gradient between the
two settings. Run it pinned to one core for the numbers of benchmarks/RESULTS.md (session 54)::

    XLA_FLAGS="--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1" \\
        taskset -c 0 python benchmarks/remat.py [--points 3900] [--bones 21] [--width 64] [--depth 3]
"""

from __future__ import annotations

import argparse
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ncflow.flow import SkinnedField, integrate, make_flow_field
from ncflow.skeleton import Skeleton
from ncflow.skeleton.dualquat import quat_from_rotvec
from ncflow.skeleton.kinematics import Pose


def _fields(n_bones: int, width: int, depth: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    parents = np.array([-1, 0, *range(1, n_bones)])
    positions = np.cumsum(rng.normal(size=(n_bones + 1, 3)) * 0.1, axis=0)
    skeleton = Skeleton.from_arrays(positions, parents)
    net = make_flow_field(jax.random.key(seed), width=width, depth=depth, dtype=jnp.float32)
    turns = rng.normal(size=(n_bones + 1, 3)) * 0.3
    pose = Pose(jnp.stack([quat_from_rotvec(jnp.asarray(v, jnp.float32)) for v in turns]), jnp.zeros(3, jnp.float32))
    cores = 0.2 * np.asarray(skeleton.bone_lengths)
    fields = {"bare": net}
    for mode in ("current", "start"):
        fields[f"skinned {mode}"] = SkinnedField(net, skeleton, pose, 0.05, dtype=jnp.float32, weight_mode=mode)
        fields[f"cored {mode}"] = SkinnedField(
            net, skeleton, pose, 0.05, dtype=jnp.float32, weight_mode=mode, core=cores
        )
    return fields, positions.mean(0), rng


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=3900)
    ap.add_argument("--bones", type=int, default=21)
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--depth", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=12)
    args = ap.parse_args()
    fields, centre, rng = _fields(args.bones, args.width, args.depth)
    x0 = jnp.asarray(rng.normal(size=(args.points, 3)) * 0.3 + centre, jnp.float32)

    def loss(field, checkpoint):
        xs, _ = integrate(field, x0, 10, checkpoint=checkpoint)
        return jnp.sum(xs[-1] ** 2) + 1e-3 * jnp.sum(xs**2)

    runs = {}
    for name, field in fields.items():
        for checkpoint in (False, True):
            fn = eqx.filter_jit(eqx.filter_value_and_grad(lambda f, c=checkpoint: loss(f, c)))
            runs[name, checkpoint] = (fn, field, jax.block_until_ready(fn(field)))
    seconds = {k: [] for k in runs}
    for _ in range(args.repeats):
        for k, (fn, field, _) in runs.items():
            t0 = time.perf_counter()
            jax.block_until_ready(fn(field))
            seconds[k].append(time.perf_counter() - t0)
    print(f"N = {args.points}, B = {args.bones}, width {args.width}, depth {args.depth}, T = 10")
    print("| field | kept (ms, median / min) | rematerialised (ms) | ratio | largest gradient difference |")
    print("|---|---|---|---|---|")
    for name in fields:
        kept, remat = (np.asarray(seconds[name, c]) * 1e3 for c in (False, True))
        g = [jax.tree.leaves(eqx.filter(runs[name, c][2][1], eqx.is_inexact_array)) for c in (False, True)]
        diff = max(float(jnp.max(jnp.abs(a - b)) / (jnp.max(jnp.abs(a)) + 1e-30)) for a, b in zip(*g, strict=True))
        print(
            f"| {name} | {np.median(kept):.0f} / {kept.min():.0f} | {np.median(remat):.0f} / {remat.min():.0f} "
            f"| {np.median(remat) / np.median(kept):.2f} | {diff:.1e} |"
        )


if __name__ == "__main__":
    main()
