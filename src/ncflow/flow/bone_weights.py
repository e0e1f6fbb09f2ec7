"""Bone weights of the skeleton-driven flow and its rigid cores: which bone's rigid motion a point follows.

* :func:`skinning_weights`: w_b(x) = softmax_b(−d_b(x)/τ), d_b the distance of x to bone b's segment;
* :func:`surface_skinning_weights`: the same for surface points, leaving out bones that lie in front of the
  skin (and the islands of :func:`ncflow.flow.islands.surface_skin`); :func:`skin_contact` measures where the
  two differ;
* the rigid cores (:func:`core_gate`, :func:`core_memberships`, :func:`core_weights`): inside the cylinder
  around each bone where its samples lie, the Flow-Net is faded out and the weights are the bone's alone.

Every function here reads the point–bone distances from two (N, 3) × (3, B) matrix products
(:func:`_projection_terms`) and the part of each segment it needs (:func:`_part_distance`), so the
weights and the cores of the same points share them. Used by :class:`ncflow.flow.SkinnedField` (see its
module, :mod:`ncflow.flow.skinning`), the pose search's scorer and the exported skin weights.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from ncflow.skeleton.samples import DEFAULT_AXIAL_RANGE

_HIGHEST = jax.lax.Precision.HIGHEST  # full float32 products on GPUs too (not TF32): see measures/kernels.py


def _mm(a: Array, b: Array) -> Array:
    return jnp.matmul(a, b, precision=_HIGHEST)


def _projection_terms(x: Float[Array, "N 3"], a: Float[Array, "B 3"], b: Float[Array, "B 3"]):
    """(x − a)·(b − a), |b − a|² and |x − a|², (N, B), (B,), (N, B): what the distance of x to any part of the
    segments a–b is read from (:func:`_part_distance`). (N, B) arrays only: the point-bone products come from
    two matrix products.
    """
    ab = b - a
    ab2 = jnp.maximum(jnp.sum(ab * ab, -1), 1e-12)
    ap_ab = _mm(x, ab.T) - jnp.sum(a * ab, -1)
    ap2 = jnp.sum(x * x, -1)[:, None] - 2.0 * _mm(x, a.T) + jnp.sum(a * a, -1)
    return ap_ab, ab2, ap2


def _part_distance(terms, lo=0.0, hi=1.0):
    """(u, d), both (N, B): where along each segment's part [lo, hi] (z / L, scalars or (B,)) its nearest point to
    x lies (0 at a, 1 at b) and how far it is, from :func:`_projection_terms` — the nearest point of a part of a
    line segment is the whole line's nearest point clipped to the part.
    """
    ap_ab, ab2, ap2 = terms
    u = jnp.clip(ap_ab / ab2, lo, hi)
    d2 = ap2 - 2.0 * u * ap_ab + u * u * ab2
    return u, jnp.sqrt(jnp.maximum(d2, 0.0) + 1e-12)


def _segment_projection(x: Float[Array, "N 3"], a: Float[Array, "B 3"], b: Float[Array, "B 3"]):
    """(u, d), both (N, B): where along each segment a–b its nearest point to x lies (0 at a, 1 at b) and
    how far it is.
    """
    return _part_distance(_projection_terms(x, a, b))


def skinning_weights(
    x: Float[Array, "N 3"], heads: Float[Array, "B 3"], tails: Float[Array, "B 3"], width: float | Float[Array, ""]
) -> Float[Array, "N B"]:
    """w_b(x) = softmax_b(−d_b(x)/width), d_b the distance of x to the segment heads[b]–tails[b]."""
    return _plain(_projection_terms(x, heads, tails), width)


def _plain(terms, width) -> Float[Array, "N B"]:
    """:func:`skinning_weights` from :func:`_projection_terms` of x."""
    return jax.nn.softmax(-_part_distance(terms)[1] / width, axis=-1)


def surface_skinning_weights(
    x: Float[Array, "N 3"],
    normals: Float[Array, "N C"],
    heads: Float[Array, "B 3"],
    tails: Float[Array, "B 3"],
    width: float | Float[Array, ""],
) -> Float[Array, "N B"]:
    """Bone weights of surface points that see which bones lie under their skin: as
    :func:`skinning_weights`, but a bone whose nearest point lies in front of the surface at x (on the
    outer side of its normal: in a fist, the fingertip resting on the palm's skin, nearer that skin than
    the palm's own bone) is left out, so the skin moves with the part it covers. ``normals`` (N, 3), or
    (N, 3 + B) as :func:`ncflow.flow.islands.surface_skin` gives them: a column at 1 leaves that bone out
    too (an island: a fingertip sunk into the palm, whose bone lies behind the palm's skin). Where every
    bone is left out (a normal turned the wrong way), all are kept alike: the plain weights.
    """
    n = normals[:, :3]
    u, d = _segment_projection(x, heads, tails)
    # (nearest point − x)·n = a·n + u (b − a)·n − x·n, in (N, B) products as the distance is
    front = _mm(n, heads.T) + u * _mm(n, (tails - heads).T) - jnp.sum(x * n, -1)[:, None] > 0.0
    if normals.shape[1] > 3:
        front = front | (normals[:, 3:] > 0.5)
    return jax.nn.softmax(-(d + jnp.where(front, FRONT_PENALTY * width, 0.0)) / width, axis=-1)


FRONT_PENALTY = 1e3
"""Added to a bone's distance (× the width) where it lies in front of the skin (:func:`surface_skinning_weights`)."""


def skin_contact(
    x: Float[ArrayLike, "N 3"],
    normals: Float[ArrayLike, "N 3"],
    weights: Float[ArrayLike, " N"],
    heads: Float[ArrayLike, "B 3"],
    tails: Float[ArrayLike, "B 3"],
    counted: Bool[ArrayLike, "B B"] | None = None,
) -> float:
    """The share (by ``weights``, e.g. vertex areas) of surface points whose nearest bone lies in front
    of their skin: where :func:`surface_skinning_weights` gives a point to another bone than
    :func:`skinning_weights` does — counted only where ``counted[nearest, given]`` (default: all), e.g.
    bones of different limbs, so that a bone running just under the skin of its own limb is no contact.
    """
    args = [jnp.asarray(a, jnp.float32) for a in (x, normals, heads, tails)]
    plain = np.asarray(jnp.argmax(skinning_weights(args[0], args[2], args[3], 1.0), -1))
    skin = np.asarray(jnp.argmax(surface_skinning_weights(*args, 1.0), -1))
    moved = plain != skin if counted is None else (plain != skin) & np.asarray(counted)[plain, skin]
    w = np.asarray(weights, np.float64)
    return float(w @ moved / max(w.sum(), 1e-300))


def core_gate(
    x: Float[Array, "N 3"],
    heads: Float[Array, "B 3"],
    tails: Float[Array, "B 3"],
    radius: Float[ArrayLike, " B"],
    outer: Float[ArrayLike, " B"],
    axial_range: tuple[float, float] | Float[ArrayLike, "B 2"] = DEFAULT_AXIAL_RANGE,
) -> Float[Array, " N"]:
    """The residual's gate γ(x) ∈ [0, 1]: 0 inside every bone's core, the cylinder of radius ``radius[b]``
    around the part ``axial_range`` (z / L, for all bones or (B, 2) one per bone) of its segment where the
    bone samples lie (:func:`ncflow.skeleton.sample_bones`), rising as a smoothstep to 1 at ``outer[b]``
    (> ``radius[b]``); a bone of radius 0 has no core.

    γ = min_b h(clip((d_b(x) − r_b)/(o_b − r_b), 0, 1)), d_b the distance to bone b's core segment,
    h(u) = 3u² − 2u³ (C¹: the field stays Lipschitz).
    """
    core = _core_table(heads.shape[0], radius, outer, axial_range, x.dtype)
    return _gate(_projection_terms(x, heads, tails), core)


def core_memberships(
    x: Float[Array, "N 3"],
    heads: Float[Array, "B 3"],
    tails: Float[Array, "B 3"],
    radius: Float[ArrayLike, " B"],
    outer: Float[ArrayLike, " B"],
    axial_range: tuple[float, float] | Float[ArrayLike, "B 2"] = DEFAULT_AXIAL_RANGE,
) -> Float[Array, "N B"]:
    """m_b(x) = 1 − h(clip((d_b(x) − r_b)/(o_b − r_b), 0, 1)) per bone (:func:`core_gate`'s terms): 1 inside
    bone b's core, 0 beyond its outer radius (and for a bone of radius 0); γ = 1 − max_b m_b.
    """
    core = _core_table(heads.shape[0], radius, outer, axial_range, x.dtype)
    return 1.0 - _smoothstep(_core_scaled(_projection_terms(x, heads, tails), core))


def _core_table(n_bones, radius, outer, axial_range, dtype) -> Float[Array, "B 4"]:
    rng = jnp.broadcast_to(jnp.asarray(axial_range, dtype), (n_bones, 2))
    r = jnp.broadcast_to(jnp.asarray(radius, dtype), (n_bones,))
    o = jnp.broadcast_to(jnp.asarray(outer, dtype), (n_bones,))
    return jnp.column_stack([r, o, rng])


def _core_scaled(terms, core: Float[Array, "B 4"]) -> Float[Array, "N B"]:
    """s_b = (d_b − r_b)/(o_b − r_b), d_b the distance to bone b's core segment (from :func:`_projection_terms`
    of the posed bones), 1 for a bone without a core: m_b = 1 − h(clip(s_b, 0, 1)).
    """
    r, o = core[:, 0], core[:, 1]
    _, d = _part_distance(terms, core[:, 2], core[:, 3])
    return jnp.where(r > 0, (d - r) / jnp.where(r > 0, o - r, 1.0), 1.0)


def _smoothstep(s):
    u = jnp.clip(s, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def _gate(terms, core: Float[Array, "B 4"]) -> Float[Array, " N"]:
    """γ = 1 − max_b m_b = h(clip(min_b s_b, 0, 1)) (h and the clip rise with s): the smoothstep taken on the
    nearest core's s alone, an (N,) array, not on every bone's.
    """
    return _smoothstep(jnp.min(_core_scaled(terms, core), axis=-1))


def core_weights(
    weights: Float[Array, "N B"], x: Float[Array, "N 3"], heads: Float[Array, "B 3"], tails: Float[Array, "B 3"], core
) -> Float[Array, "N B"]:
    """Bone weights taken over by the rigid cores: w' = (1 − C) w + C softmax_b(m_b / κ), with m the
    :func:`core_memberships` of x, C = max_b m_b and κ = :data:`CORE_SHARPNESS`, so that a point inside
    bone b's core (m_b = 1) has the weight of b alone — its bone's rigid motion, not a blend with the
    neighbouring bone's near a bent joint, whose core ramp may reach it (m < 1: a share e^{−(1 − m)/κ}) —
    and the weights stay continuous (a tie between two cores splits evenly); ``core`` (B, 4) as
    :class:`SkinnedField` holds it, None: w unchanged.
    """
    if core is None:
        return weights
    return _cored(weights, _projection_terms(x, heads, tails), core)


def _cored(weights, terms, core):
    """:func:`core_weights` from :func:`_projection_terms` of x."""
    m = (1.0 - _smoothstep(_core_scaled(terms, core))).astype(weights.dtype)
    c = jnp.max(m, axis=-1, keepdims=True)
    return (1.0 - c) * weights + c * jax.nn.softmax(m / CORE_SHARPNESS, axis=-1)


CORE_SHARPNESS = 0.02
"""κ of :func:`core_weights`: a neighbouring core's ramp at 0.7 of its height leaves it a weight of e^{−15}."""

CORE_CLEAR = 0.7
"""The membership m below which a neighbouring core leaves a point to its own core's bone (a share e^{−15}
at :data:`CORE_SHARPNESS`): :func:`core_clearance`."""


def core_clearance(ramp: float) -> float:
    """How far from a bone's core part, in core radii c, its membership m falls to :data:`CORE_CLEAR`: the
    capsule other bones' samples must stay out of to keep their own bone's motion alone. With the ramp
    to (1 + ``ramp``) c (:func:`ncflow.matcher.objective.bone_cores`), m = 1 − h(s), s = (d − c)/(ramp c),
    so d = c (1 + ramp · h⁻¹(1 − CORE_CLEAR)), h⁻¹(y) = ½ − sin(arcsin(1 − 2y)/3) (the smoothstep's inverse).
    """
    s = 0.5 - np.sin(np.arcsin(1.0 - 2.0 * (1.0 - CORE_CLEAR)) / 3.0)
    return float(1.0 + ramp * s)
