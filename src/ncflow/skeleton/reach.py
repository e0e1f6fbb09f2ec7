"""Whether the skeleton reached the target: the stretch of each bone's skin along the bone.

With the skeleton-driven field's rigid cores (``flow.rigid_core``) every bone follows its rigid motion
whatever the target. Where no pose of the skeleton reaches the target — a limb longer or shorter than
the bone, a limb the target misses — the Flow-Net stretches or squeezes the skin along the rigid bone
instead. :func:`skin_stretch` measures that on the matched source: per bone, the scale along the bone
that best maps its skin at rest to its skin matched, after the skin's best rigid motion.
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Float
from scipy.spatial.transform import Rotation

from ncflow.geometry.skeleton import Skeleton
from ncflow.skeleton.checks import skin_vertices

MIN_SKIN_VERTICES = 12
MIN_SKIN_SPREAD = 0.1  # the skin's standard deviation along the bone, as a fraction of its length


def skin_stretch(
    rest: Float[np.ndarray, "V 3"], moved: Float[np.ndarray, "V 3"], skeleton: Skeleton
) -> Float[np.ndarray, " B"]:
    """(B,) per bone, the stretch s of its skin along the bone: with the skin vertices' (:func:`skin_vertices`)
    rest positions p_i and moved positions q_i, both centred, R their best rotation (Kabsch,
    :meth:`scipy.spatial.transform.Rotation.align_vectors`) and e the bone's rest direction,

        s = Σ_i ⟨q_i, R e⟩ ⟨p_i, e⟩ / Σ_i ⟨p_i, e⟩²,

    the least-squares scale of the skin's coordinates along the bone: 1 when the skin kept its length
    (however it bent or turned), 1.5 when it is half as long again, invariant to a rigid motion and a
    uniform scaling of both shapes. NaN where it cannot be told: a bone with fewer than
    :data:`MIN_SKIN_VERTICES` skin vertices or a skin spread along the bone by less than
    :data:`MIN_SKIN_SPREAD` of its length.
    """
    rest = np.asarray(rest, np.float64)
    moved = np.asarray(moved, np.float64)
    owner = skin_vertices(rest, skeleton)
    p = np.asarray(skeleton.positions, np.float64)
    bones = np.asarray(skeleton.bones)
    out = np.full(skeleton.n_bones, np.nan)
    for k in range(skeleton.n_bones):
        sel = owner == k
        axis = p[bones[k, 1]] - p[bones[k, 0]]
        length = np.linalg.norm(axis)
        if np.count_nonzero(sel) < MIN_SKIN_VERTICES:
            continue
        p0 = rest[sel] - rest[sel].mean(0)
        q0 = moved[sel] - moved[sel].mean(0)
        z = p0 @ (axis / length)
        if np.std(z) < MIN_SKIN_SPREAD * length:
            continue
        rot, _ = Rotation.align_vectors(q0, p0)
        out[k] = float(np.dot(q0 @ rot.apply(axis / length), z) / np.dot(z, z))
    return out
