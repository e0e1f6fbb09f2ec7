"""Quaternions and unit dual quaternions in JAX (paper §4.3, Eqs. 18–19; Appendices B–C).

Conventions
-----------
* A quaternion is an array (..., 4) ordered (w, x, y, z); products are Hamilton products.
  A unit quaternion q rotates a vector v as q (0, v) q*; :func:`quat_to_matrix` gives the
  matching 3×3 matrix acting on column vectors.
* A dual quaternion (DQ) is an array (..., 8) = [real (4), dual (4)]. The rigid motion
  x ↦ R x + t (rotate, then translate) is the unit DQ (r, ½ (0, t) ⊗ r) (paper Eq. 18/28).
  Products compose like matrices: ``dq_mul(A, B)`` applies B first, then A (M_A M_B).
* Unit DQs ±Q are the same motion. Only the interpolation functions choose between them:
  :func:`sclerp`, :func:`slerp` and :func:`seplerp` flip the end point B when the dot product
  of the two real parts is negative, so that the relative motion A* B has w ≥ 0, i.e. a
  rotation angle θ ≤ π (the shortest screw / great-circle path). Exactly at θ = π both paths
  are equally short and the choice jumps; nothing else is discontinuous.
* Logarithm / power. A unit DQ is exp(ω + ε u) with ω = (θ/2) l and u = (θ/2) m + (d/2) l
  (screw angle θ, pitch / translation along the axis d, unit axis l, moment m = p × l for a point
  p on the axis; paper Eqs. 31–33). Q^t = exp(t log Q). The functions of θ that appear
  (cos, sin(φ)/φ, (φ cos φ − sin φ)/φ³ with φ = θ/2) are evaluated by Taylor series near φ = 0
  behind a double ``where``, so values AND gradients are finite and accurate at the identity
  and at pure translations (θ → 0). The logarithm is singular only at real part w = −1
  (θ = 2π), which the shortest-path interpolants never reach.

All functions are pure, jit/vmap/grad-friendly, and follow the dtype of their inputs.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ncflow.geometry.rigid import HAMILTON_SIGNS

# ----------------------------------------------------------------------------------------------
# helpers


def _float(x: ArrayLike) -> Array:
    x = jnp.asarray(x)
    return x if jnp.issubdtype(x.dtype, jnp.floating) else x.astype(jnp.result_type(float))


def _is64(x: Array) -> bool:
    return x.dtype == jnp.float64


def _tiny(x: Array) -> float:
    return 1e-150 if _is64(x) else 1e-30


def _safe_norm(v: Array) -> tuple[Array, Array]:
    """(‖v‖, ok) over the last axis; ‖v‖ = 0 with a zero (not NaN) gradient where v ≈ 0."""
    sq = jnp.sum(v * v, axis=-1)
    ok = sq > _tiny(v)
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, sq, 1.0)), 0.0), ok


def _horner(x: Array, coeffs: np.ndarray) -> Array:
    """Σ_k coeffs[:, k] x^k for every row of ``coeffs`` (S, K) at once: (..., S). One multiply-add per
    term for all S series (the kinematic chain's programs evaluate these many times).
    """
    x = x[..., None]
    out = jnp.broadcast_to(jnp.asarray(coeffs[:, -1], x.dtype), x.shape[:-1] + coeffs.shape[:1])
    for k in range(coeffs.shape[1] - 2, -1, -1):
        out = out * x + jnp.asarray(coeffs[:, k], x.dtype)
    return out


def _fact(n: int) -> float:
    out = 1.0
    for k in range(2, n + 1):
        out *= k
    return out


# Series in φ² (8 terms; truncation < 1e-15 relative for φ ≤ 1): cos φ, sin φ / φ, (φ cos φ − sin φ)/φ³
_SERIES = np.array(
    [
        [(-1) ** k / _fact(2 * k) for k in range(8)],
        [(-1) ** k / _fact(2 * k + 1) for k in range(8)],
        [(-1) ** (k + 1) * (2 * k + 2) / _fact(2 * k + 3) for k in range(8)],
    ]
)


def _trig(phi2: Array) -> tuple[Array, Array, Array]:
    """Cos φ, sin φ / φ and (φ cos φ − sin φ)/φ³ as smooth functions of φ² ≥ 0."""
    thr = 0.1 if _is64(phi2) else 1.0  # below: Taylor; above: closed form (cancellation-free enough)
    small = phi2 < thr * thr
    big2 = jnp.where(small, 1.0, phi2)  # the closed forms never see φ ≈ 0, not even unselected
    phi = jnp.sqrt(big2)
    s, c = jnp.sin(phi), jnp.cos(phi)
    series = _horner(phi2, _SERIES)
    cos_ = jnp.where(small, series[..., 0], c)
    sinc = jnp.where(small, series[..., 1], s / phi)
    c3 = jnp.where(small, series[..., 2], (phi * c - s) / (phi * big2))
    return cos_, sinc, c3


def _vec(v: Array) -> Array:
    """Pure quaternion (0, v) from (..., 3)."""
    return jnp.concatenate([jnp.zeros_like(v[..., :1]), v], axis=-1)


# ----------------------------------------------------------------------------------------------
# quaternions


def quat_mul(a: Float[ArrayLike, "... 4"], b: Float[ArrayLike, "... 4"]) -> Float[Array, "... 4"]:
    """Hamilton product a ⊗ b of quaternions (w, x, y, z); broadcasts over leading axes.

    Written as the contraction Σ_jk a_j b_k C_jki with the constant sign table C
    (:data:`~ncflow.geometry.rigid.HAMILTON_SIGNS`, shared with the NumPy product; elementwise, exact:
    each output sums its four products and twelve exact zeros) rather than as sixteen sliced products:
    the kinematic chain, its Jacobian and its gradient call it hundreds of times per compiled
    program, and the sliced form made up 60 % of the training step's operations (compile time).
    """
    a, b = _float(a), _float(b)
    dtype = jnp.result_type(a, b)
    outer = a[..., :, None, None] * b[..., None, :, None]  # (..., 4, 4, 1)
    return jnp.sum(outer * jnp.asarray(HAMILTON_SIGNS, dtype), axis=(-3, -2))


def quat_conj(q: Float[ArrayLike, "... 4"]) -> Float[Array, "... 4"]:
    """Conjugate (w, −x, −y, −z); the inverse of a unit quaternion."""
    q = _float(q)
    return q * jnp.asarray([1.0, -1.0, -1.0, -1.0], q.dtype)


def quat_normalize(q: Float[ArrayLike, "... 4"]) -> Float[Array, "... 4"]:
    """Q / ‖q‖; the zero quaternion maps to the identity (1, 0, 0, 0). NaN-free gradients."""
    q = _float(q)
    n, ok = _safe_norm(q)
    ident = jnp.zeros_like(q).at[..., 0].set(1.0)
    return jnp.where(ok[..., None], q / jnp.where(ok, n, 1.0)[..., None], ident)


def quat_rotate(q: Float[ArrayLike, "... 4"], v: Float[ArrayLike, "... 3"]) -> Float[Array, "... 3"]:
    """Rotate vectors v by unit quaternions q: the vector part of q (0, v) q*."""
    q, v = _float(q), _float(v)
    w, u = q[..., :1], q[..., 1:]
    uv = jnp.cross(u, v)
    return v + 2.0 * (w * uv + jnp.cross(u, uv))


def quat_to_matrix(q: Float[ArrayLike, "... 4"]) -> Float[Array, "... 3 3"]:
    """3×3 rotation matrix R of a unit quaternion, R v = q (0,v) q*."""
    q = _float(q)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


def quat_from_matrix(m: Float[ArrayLike, "... 3 3"]) -> Float[Array, "... 4"]:
    """Unit quaternion of a rotation matrix (Shepperd's method: the best-conditioned of four
    formulas), with w ≥ 0.
    """
    m = _float(m)
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    t = jnp.stack(
        [1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], axis=-1
    )  # 4w², 4x², 4y², 4z²
    cands = jnp.stack(
        [
            jnp.stack([t[..., 0], m21 - m12, m02 - m20, m10 - m01], -1),
            jnp.stack([m21 - m12, t[..., 1], m01 + m10, m02 + m20], -1),
            jnp.stack([m02 - m20, m01 + m10, t[..., 2], m12 + m21], -1),
            jnp.stack([m10 - m01, m02 + m20, m12 + m21, t[..., 3]], -1),
        ],
        axis=-2,
    )
    k = jnp.argmax(t, axis=-1)
    best = jnp.take_along_axis(cands, k[..., None, None], axis=-2)[..., 0, :]
    tk = jnp.take_along_axis(t, k[..., None], axis=-1)
    q = best / (2.0 * jnp.sqrt(tk))
    return jnp.where(q[..., :1] < 0, -q, q)


def quat_exp(v: Float[ArrayLike, "... 3"]) -> Float[Array, "... 4"]:
    """Exp of the pure quaternion (0, v): (cos‖v‖, sin‖v‖ v/‖v‖); the rotation by angle 2‖v‖."""
    v = _float(v)
    cos_, sinc, _ = _trig(jnp.sum(v * v, axis=-1))
    return jnp.concatenate([cos_[..., None], sinc[..., None] * v], axis=-1)


def _log_factor(q: Array) -> tuple[Array, Array]:
    """G = φ/‖v‖ with φ = atan2(‖v‖, w), so that log q = g v; returns (g, ‖v‖²)."""
    w, v = q[..., 0], q[..., 1:]
    s2 = jnp.sum(v * v, axis=-1)
    thr = 1e-4 if _is64(q) else 2e-2  # ≈ eps^(1/4): two series terms are exact to eps
    small = (s2 < thr * thr) & (w > 0)
    w_s = jnp.where(small, w, 1.0)
    x2 = s2 / (w_s * w_s)
    g_small = (1.0 - x2 / 3.0 + x2 * x2 / 5.0) / w_s  # atan(x)/x / w, x = ‖v‖/w
    s_big = jnp.sqrt(jnp.maximum(jnp.where(small, 1.0, s2), _tiny(q)))
    g_big = jnp.arctan2(s_big, w) / s_big
    return jnp.where(small, g_small, g_big), s2


def quat_log(q: Float[ArrayLike, "... 4"]) -> Float[Array, "... 3"]:
    """Logarithm of a unit quaternion as the 3-vector v with q = exp(0, v), ‖v‖ = θ/2 ∈ [0, π]."""
    q = _float(q)
    g, _ = _log_factor(q)
    return g[..., None] * q[..., 1:]


def quat_pow(q: Float[ArrayLike, "... 4"], t: Float[ArrayLike, ...]) -> Float[Array, "... 4"]:
    """q^t = exp(t log q) for unit q (no hemisphere flip: q and −q give different paths)."""
    q, t = _float(q), _float(t)
    return quat_exp(t[..., None] * quat_log(q))


def quat_from_axis_angle(axis: Float[ArrayLike, "... 3"], angle: Float[ArrayLike, ...]) -> Float[Array, "... 4"]:
    """(cos θ/2, sin θ/2 · axis) for a unit axis."""
    axis, angle = _float(axis), _float(angle)
    half = 0.5 * angle[..., None]
    return jnp.concatenate([jnp.cos(half), jnp.sin(half) * axis], axis=-1)


def quat_from_rotvec(rotvec: Float[ArrayLike, "... 3"]) -> Float[Array, "... 4"]:
    """Unit quaternion of a rotation vector (axis × angle); smooth at the zero vector."""
    return quat_exp(0.5 * _float(rotvec))


def _shortest(a_real: Array, b: Array) -> Array:
    """B or −b, whichever has a non-negative real-part dot product with a_real."""
    dot = jnp.sum(a_real * b[..., :4], axis=-1, keepdims=True)
    return jnp.where(dot < 0, -b, b)


def slerp(
    t: Float[ArrayLike, ...], q0: Float[ArrayLike, "... 4"], q1: Float[ArrayLike, "... 4"]
) -> Float[Array, "... 4"]:
    """Spherical linear interpolation q0 (q0* q1)^t (paper Eq. 30) along the shorter arc
    (q1 is replaced by −q1 when q0·q1 < 0).
    """
    q0, q1, t = _float(q0), _float(q1), _float(t)
    q1 = _shortest(q0, q1)
    return quat_mul(q0, quat_pow(quat_mul(quat_conj(q0), q1), t))


# ----------------------------------------------------------------------------------------------
# dual quaternions


def dq_identity(shape: tuple[int, ...] = (), dtype=None) -> Float[Array, "... 8"]:
    """Identity DQ (1,0,0,0, 0,0,0,0) of batch shape ``shape``."""
    return jnp.zeros((*shape, 8), dtype=dtype or jnp.result_type(float)).at[..., 0].set(1.0)


def dq_from_rt(r: Float[ArrayLike, "... 4"], t: Float[ArrayLike, "... 3"]) -> Float[Array, "... 8"]:
    """Unit DQ of x ↦ R(r) x + t: real r, dual ½ (0, t) ⊗ r (paper Eq. 18)."""
    r, t = _float(r), _float(t)
    dual = 0.5 * quat_mul(_vec(t), r)
    return jnp.concatenate([jnp.broadcast_to(r, dual.shape), dual], axis=-1)


def dq_rotation(q: Float[ArrayLike, "... 8"]) -> Float[Array, "... 4"]:
    """The real part (rotation quaternion)."""
    return _float(q)[..., :4]


def dq_translation(q: Float[ArrayLike, "... 8"]) -> Float[Array, "... 3"]:
    """Translation t = 2 (dual ⊗ real*)_vec of a unit DQ (the image of the origin)."""
    q = _float(q)
    return 2.0 * quat_mul(q[..., 4:], quat_conj(q[..., :4]))[..., 1:]


def dq_from_matrix(m: Float[ArrayLike, "... 4 4"]) -> Float[Array, "... 8"]:
    """Unit DQ of a 4×4 rigid matrix [[R, t], [0, 1]] (real part with w ≥ 0)."""
    m = _float(m)
    return dq_from_rt(quat_from_matrix(m[..., :3, :3]), m[..., :3, 3])


def dq_to_matrix(q: Float[ArrayLike, "... 8"]) -> Float[Array, "... 4 4"]:
    """4×4 rigid matrix [[R, t], [0, 1]] of a unit DQ."""
    q = _float(q)
    rot = quat_to_matrix(q[..., :4])
    t = dq_translation(q)
    top = jnp.concatenate([rot, t[..., None]], axis=-1)
    bottom = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 0.0, 1.0], q.dtype), (*q.shape[:-1], 1, 4))
    return jnp.concatenate([top, bottom], axis=-2)


def dq_mul(a: Float[ArrayLike, "... 8"], b: Float[ArrayLike, "... 8"]) -> Float[Array, "... 8"]:
    """DQ product (r_a r_b, r_a d_b + d_a r_b): the motion "b, then a" (matrix M_a M_b)."""
    a, b = _float(a), _float(b)
    ra, da, rb, db = a[..., :4], a[..., 4:], b[..., :4], b[..., 4:]
    return jnp.concatenate([quat_mul(ra, rb), quat_mul(ra, db) + quat_mul(da, rb)], axis=-1)


def dq_conj(q: Float[ArrayLike, "... 8"]) -> Float[Array, "... 8"]:
    """Quaternion conjugate Q* = (r*, d*); the inverse of a unit DQ."""
    q = _float(q)
    return jnp.concatenate([quat_conj(q[..., :4]), quat_conj(q[..., 4:])], axis=-1)


def dq_dual_conj(q: Float[ArrayLike, "... 8"]) -> Float[Array, "... 8"]:
    """Dual-number conjugate (r, −d)."""
    q = _float(q)
    return jnp.concatenate([q[..., :4], -q[..., 4:]], axis=-1)


def dq_inverse(q: Float[ArrayLike, "... 8"]) -> Float[Array, "... 8"]:
    """Inverse of a unit DQ (= :func:`dq_conj`)."""
    return dq_conj(q)


def dq_normalize(q: Float[ArrayLike, "... 8"]) -> Float[Array, "... 8"]:
    """Nearest unit DQ: divide by ‖r‖ and remove the component of d along r (so r·d = 0).
    A zero real part maps to the identity. NaN-free gradients.
    """
    q = _float(q)
    r, d = q[..., :4], q[..., 4:]
    n, ok = _safe_norm(r)
    inv = jnp.where(ok, 1.0 / jnp.where(ok, n, 1.0), 0.0)[..., None]
    r, d = r * inv, d * inv
    d = d - jnp.sum(r * d, axis=-1, keepdims=True) * r
    return jnp.where(ok[..., None], jnp.concatenate([r, d], axis=-1), dq_identity(q.shape[:-1], q.dtype))


def dq_transform_point(q: Float[ArrayLike, "... 8"], p: Float[ArrayLike, "... 3"]) -> Float[Array, "... 3"]:
    """Apply the rigid motion of a unit DQ to points: R p + t (paper Eq. 35)."""
    q = _float(q)
    return quat_rotate(q[..., :4], p) + dq_translation(q)


def dq_exp(omega: Float[ArrayLike, "... 3"], u: Float[ArrayLike, "... 3"]) -> Float[Array, "... 8"]:
    """Exp of the pure dual quaternion (0, ω) + ε (0, u) (paper Eq. 33 with ω + εu = (θ̂/2) v̂).

    With φ = ‖ω‖: real (cos φ, sinc φ · ω); dual (−(ω·u) sinc φ, sinc φ · u + c(φ) (ω·u) ω),
    c(φ) = (φ cos φ − sin φ)/φ³ — all smooth in ω, including ω = 0 (pure translation by 2u).
    """
    omega, u = _float(omega), _float(u)
    omega, u = jnp.broadcast_arrays(omega, u)
    cos_, sinc, c3 = _trig(jnp.sum(omega * omega, axis=-1))
    wu = jnp.sum(omega * u, axis=-1)
    real = jnp.concatenate([cos_[..., None], sinc[..., None] * omega], axis=-1)
    dual = jnp.concatenate([(-wu * sinc)[..., None], sinc[..., None] * u + (c3 * wu)[..., None] * omega], axis=-1)
    return jnp.concatenate([real, dual], axis=-1)


def dq_log(q: Float[ArrayLike, "... 8"]) -> tuple[Float[Array, "... 3"], Float[Array, "... 3"]]:
    """Logarithm (ω, u) of a unit DQ, the inverse of :func:`dq_exp` with ‖ω‖ = θ/2 ∈ [0, π].

    ω = (θ/2) l, u = (θ/2) m + (d/2) l in screw terms. Smooth at the identity and at pure
    translations; singular only where the real part is −1 (θ = 2π).
    """
    q = _float(q)
    g, s2 = _log_factor(q[..., :4])  # g = 1/sinc φ
    omega = g[..., None] * q[..., 1:4]
    _, _, c3 = _trig(s2 * g * g)
    wu = -q[..., 4] * g
    u = g[..., None] * (q[..., 5:] - (c3 * wu)[..., None] * omega)
    return omega, u


def dq_pow(q: Float[ArrayLike, "... 8"], t: Float[ArrayLike, ...]) -> Float[Array, "... 8"]:
    """Q^t = exp(t log Q) for a unit DQ: the screw motion of Q with angle and pitch scaled by t."""
    t = _float(t)[..., None]
    omega, u = dq_log(q)
    return dq_exp(t * omega, t * u)


def dq_to_screw(
    q: Float[ArrayLike, "... 8"],
) -> tuple[Float[Array, ...], Float[Array, ...], Float[Array, "... 3"], Float[Array, "... 3"]]:
    """Screw parameters (θ, d, l, m) of a unit DQ (paper Eq. 32).

    θ ∈ [0, 2π]: rotation angle about the axis; d: translation along the axis; l: unit axis
    direction; m: moment of the axis (p × l for any point p on it; m ⊥ l). For a pure
    translation θ = 0, l = t/‖t‖, d = ‖t‖, m = 0; for the identity everything is 0 (l = 0).
    Values and gradients are finite everywhere except at real part −1.
    """
    omega, u = dq_log(q)
    half, rot = _safe_norm(omega)
    l_rot = omega / jnp.where(rot, half, 1.0)[..., None]
    d_rot = 2.0 * jnp.sum(u * l_rot, axis=-1)
    m_rot = (u - 0.5 * d_rot[..., None] * l_rot) / jnp.where(rot, half, 1.0)[..., None]
    un, trans = _safe_norm(u)
    l_tr = jnp.where(trans[..., None], u / jnp.where(trans, un, 1.0)[..., None], 0.0)
    rot3 = rot[..., None]
    theta = 2.0 * half
    d = jnp.where(rot, d_rot, 2.0 * un)
    l = jnp.where(rot3, l_rot, l_tr)
    m = jnp.where(rot3, m_rot, 0.0)
    return theta, d, l, m


def dq_from_screw(
    theta: Float[ArrayLike, ...],
    d: Float[ArrayLike, ...],
    l: Float[ArrayLike, "... 3"],
    m: Float[ArrayLike, "... 3"],
) -> Float[Array, "... 8"]:
    """Unit DQ of a screw motion (paper Eq. 31): real (cos θ/2, sin θ/2 l),
    dual (−d/2 sin θ/2, sin θ/2 m + d/2 cos θ/2 l).
    """
    theta, d, l, m = _float(theta), _float(d), _float(l), _float(m)
    s, c = jnp.sin(0.5 * theta)[..., None], jnp.cos(0.5 * theta)[..., None]
    hd = 0.5 * d[..., None]
    real = jnp.concatenate([c, s * l], axis=-1)
    dual = jnp.concatenate([-hd * s, s * m + hd * c * l], axis=-1)
    real, dual = jnp.broadcast_arrays(real, dual)
    return jnp.concatenate([real, dual], axis=-1)


def sclerp(
    t: Float[ArrayLike, ...], a: Float[ArrayLike, "... 8"], b: Float[ArrayLike, "... 8"]
) -> Float[Array, "... 8"]:
    """Screw linear interpolation ScLERP(t; A, B) = A (A* B)^t (paper Eq. 19/34, read with A*B).

    B is replaced by −B when the real parts have a negative dot product, so the relative screw
    turns by θ ≤ π. Constant screw velocity in t; exact end points; smooth in A, B and t
    (including A = B and pure translations).
    """
    a, b, t = _float(a), _float(b), _float(t)
    b = _shortest(a[..., :4], b)
    return dq_mul(a, dq_pow(dq_mul(dq_conj(a), b), t))


def lerp(
    t: Float[ArrayLike, ...], x0: Float[ArrayLike, "... k"], x1: Float[ArrayLike, "... k"]
) -> Float[Array, "... k"]:
    """(1 − t) x0 + t x1 (paper Eq. 29)."""
    t = _float(t)[..., None]
    return (1.0 - t) * _float(x0) + t * _float(x1)


def seplerp(
    t: Float[ArrayLike, ...], a: Float[ArrayLike, "... 8"], b: Float[ArrayLike, "... 8"]
) -> Float[Array, "... 8"]:
    """The "Sep(LERP)" baseline (paper App. C): SLERP of the rotations, LERP of the translations,
    recombined into a DQ. Same end points as :func:`sclerp`, different path in between.
    """
    a, b = _float(a), _float(b)
    return dq_from_rt(slerp(t, a[..., :4], b[..., :4]), lerp(t, dq_translation(a), dq_translation(b)))
