"""Stacks of poses on the host: the fixed-shape batches the pose search's compiled programs take
(:mod:`ncflow.matcher.pose_search`, :mod:`ncflow.matcher.pose_exchange`), picked and stacked in NumPy.
"""

from __future__ import annotations

import jax
import numpy as np

from ncflow.skeleton.kinematics import Pose


def host(pose: Pose) -> Pose:
    """The pose in NumPy: the bookkeeping between the compiled programs (picking, stacking poses) runs
    on the host. With jax.numpy each operation and shape is one more program to compile, and on a cold
    run each waits seconds behind the training step compiling in its thread (:mod:`ncflow.jit.ahead`).
    """
    return jax.tree.map(np.asarray, pose)


def picked(pose: Pose, rows) -> Pose:
    """The rows ``rows`` (an index, indices or a slice) of a stack of poses."""
    return jax.tree.map(lambda a: np.asarray(a)[rows], pose)


def stacked(*poses: Pose) -> Pose:
    """Stacks of poses, one after the other."""
    return jax.tree.map(lambda *a: np.concatenate([np.asarray(x) for x in a]), *poses)


def completed(first: Pose, pooled: Pose) -> Pose:
    """``first``, then the rows of ``pooled`` past its length: one scorer serves both stacks."""
    n = first.rotations.shape[0]
    return stacked(first, picked(pooled, slice(n, None)))
