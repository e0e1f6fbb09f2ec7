"""How far from rigid does the integrator leave a bone that turns far? (issue 49)

A straight chain of four bones (lengths 1, 1, 1, 0.7; normalised units, about a finger of a hand 4
long scaled up 2–3×) curled by the same angle at each of its three inner joints, so that its last bone
turns three times that angle; the skeleton-driven field (:class:`ncflow.flow.SkinnedField`, rigid cores
of radius 0.1 × the bone's length, "current" weights, no Flow-Net) moves each bone's samples from rest
to that pose on the grid of T times. Printed per bone: g^EP / ε (ε = 3e-4, the default tolerance;
:func:`ncflow.losses.bone_constraints` against the bones' own rigid motion), for

* ``heun``: the paper's recursion on the field's velocities (the field called as a plain function of
  (x, t): how ncflow integrated the skeleton-driven field before session 34), and
* ``closed form``: :func:`ncflow.flow.integrate` as it is, which steps the bones' motions exactly.

    python benchmarks/bone_steps.py [--angles 30 60 90] [--times 10 20]
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from ncflow.flow import SkinnedField, integrate, make_flow_field, time_grid
from ncflow.losses import bone_constraints
from ncflow.skeleton import Skeleton, rigid_reference, sample_bones
from ncflow.skeleton.dualquat import quat_from_rotvec
from ncflow.skeleton.kinematics import Pose

EPS = 3e-4


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--angles", type=float, nargs="+", default=[30.0, 60.0, 90.0], help="degrees per joint")
    ap.add_argument("--times", type=int, nargs="+", default=[10, 20], help="grid sizes T")
    args = ap.parse_args()
    jax.config.update("jax_enable_x64", True)
    pos = np.array([[0, 0, 0], [0, 0, 1.0], [0, 0, 2.0], [0, 0, 3.0], [0, 0, 3.7]])
    skel = Skeleton.from_arrays(pos, np.array([-1, 0, 1, 2, 3]))
    samples = sample_bones(skel, jax.random.key(0), 50, radius=0.1, dtype=jnp.float64)
    pts = samples.flat()
    bare = make_flow_field(jax.random.key(0), width=8, depth=1, alpha=0.0, dtype=jnp.float64)
    print("| degrees per joint | T | scheme | g^EP / ε per bone (root → tip) |")
    print("|---|---|---|---|")
    for deg in args.angles:
        turns = [[0, 0, 0]] + [[np.radians(deg), 0, 0]] * 3 + [[0, 0, 0]]
        pose = Pose(jnp.stack([quat_from_rotvec(jnp.asarray(v, jnp.float64)) for v in turns]), jnp.zeros(3))
        field = SkinnedField(bare, skel, pose, 0.05, dtype=jnp.float64, core=0.1 * skel.bone_lengths)
        for n_times in args.times:
            ref = rigid_reference(skel, field.swing_pose(), samples.points, time_grid(n_times, jnp.float64))
            for name, f in (("heun", lambda x, t, f=field: f(x, t)), ("closed form", field)):
                xs, _ = jax.jit(lambda p, f=f, n=n_times: integrate(f, p, n))(pts)
                g_ep, _ = bone_constraints(xs.reshape(ref.shape), ref)
                shown = " ".join(f"{v:.3g}" for v in np.asarray(g_ep) / EPS)
                print(f"| {deg:g} | {n_times} | {name} | {shown} |")


if __name__ == "__main__":
    main()
