"""Rigid-motion maths in NumPy float64: rotations, TRS matrices, forward kinematics and skinning.

One copy of each, shared by the glTF reader, the procedural characters and MANO; the JAX versions
that training differentiates are in :mod:`ncflow.skeleton` (:mod:`ncflow.skeleton.dualquat`).

Rotations go through :class:`scipy.spatial.transform.Rotation` (and :class:`~scipy.spatial.transform.Slerp`).
**Quaternion order is never implicit**: every function that takes or returns a quaternion has a
required keyword ``scalar_first`` — ``True`` for ``(w, x, y, z)`` (the order of
:class:`ncflow.skeleton.Pose` and of :mod:`ncflow.skeleton.dualquat`), ``False`` for ``(x, y, z, w)``
(glTF's and scipy's order). Quaternions are normalised on input; returned unit quaternions have
``w ≥ 0`` where the sign is free (:func:`matrix_to_quat`).

Transforms are 4×4 homogeneous matrices (…, 4, 4) acting on column vectors. One forward kinematics
(:func:`forward_kinematics`: world = world(parent) · local over a parent array), one linear blend
skinning (:func:`linear_blend_skinning`, dense per-vertex weights; glTF's sparse ``(joints, weights)``
go through the front end :func:`sparse_linear_blend_skinning`) and dual-quaternion skinning
(:func:`dual_quaternion_skinning`, Kavan et al. 2008). Kept by hand because scipy has no
equivalent: the quaternion product of *non-unit* quaternions (:func:`quat_multiply`; dual-quaternion
parts are not rotations, and scipy's ``Rotation`` composes unit quaternions only), the
dual-quaternion blend, and the tree composition of forward kinematics (a loop of 4×4 products over
a parent array; ``Rotation`` composes sequences, not trees, and has no scale for glTF's TRS).
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Float, Int
from scipy.spatial.transform import Rotation, Slerp

_TO_XYZW = [1, 2, 3, 0]  # (w, x, y, z) -> (x, y, z, w)
_TO_WXYZ = [3, 0, 1, 2]  # (x, y, z, w) -> (w, x, y, z)


def _hamilton_signs() -> np.ndarray:
    table = np.zeros((4, 4, 4))
    for j, k, i, sign in (
        (0, 0, 0, 1), (1, 1, 0, -1), (2, 2, 0, -1), (3, 3, 0, -1),
        (0, 1, 1, 1), (1, 0, 1, 1), (2, 3, 1, 1), (3, 2, 1, -1),
        (0, 2, 2, 1), (1, 3, 2, -1), (2, 0, 2, 1), (3, 1, 2, 1),
        (0, 3, 3, 1), (1, 2, 3, 1), (2, 1, 3, -1), (3, 0, 3, 1),
    ):  # fmt: skip
        table[j, k, i] = sign
    return table


HAMILTON_SIGNS = _hamilton_signs()
"""C (4, 4, 4) with (a ⊗ b)_i = Σ_jk a_j b_k C_jki for quaternions (w, x, y, z): the Hamilton product's
signs, shared by :func:`quat_multiply` (NumPy) and :func:`ncflow.skeleton.dualquat.quat_mul` (JAX)."""


def _as_rotation(q, scalar_first: bool) -> Rotation:
    """The scipy rotations of quaternions (..., 4), flattened to (n, 4) (scipy ≥ 1.10 takes no more dimensions)."""
    q = np.asarray(q, dtype=np.float64)
    return Rotation.from_quat((q[..., _TO_XYZW] if scalar_first else q).reshape(-1, 4))


def _out_quat(q_xyzw: np.ndarray, shape: tuple, scalar_first: bool) -> np.ndarray:
    return (q_xyzw[..., _TO_WXYZ] if scalar_first else q_xyzw).reshape(shape + (4,))


# ----------------------------------------------------------------------------------------------
# Rotations


def quat_to_matrix(q: Float[np.ndarray, "... 4"], *, scalar_first: bool) -> Float[np.ndarray, "... 3 3"]:
    """Rotation matrices of quaternions (normalised first; a zero quaternion raises ValueError).

    Args:
        q: (..., 4) quaternions, ``(w, x, y, z)`` if ``scalar_first`` else ``(x, y, z, w)`` (glTF).
        scalar_first: the quaternion order (required, see the module docstring).

    Returns:
        (..., 3, 3) rotation matrices.
    """
    q = np.asarray(q, dtype=np.float64)
    return _as_rotation(q, scalar_first).as_matrix().reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat(r: Float[np.ndarray, "... 3 3"], *, scalar_first: bool) -> Float[np.ndarray, "... 4"]:
    """Unit quaternions of rotation matrices, with ``w ≥ 0``.

    scipy's ``from_matrix``: a matrix that is not exactly orthonormal gives the quaternion of the
    nearest rotation.

    Args:
        r: (..., 3, 3) rotation matrices.
        scalar_first: return ``(w, x, y, z)`` if True, else ``(x, y, z, w)`` (glTF).

    Returns:
        (..., 4) unit quaternions.
    """
    r = np.asarray(r, dtype=np.float64)
    q = Rotation.from_matrix(r.reshape(-1, 3, 3)).as_quat()
    q = np.where(q[:, 3:] < 0.0, -q, q)
    return _out_quat(q, r.shape[:-2], scalar_first)


def rotvec_to_quat(rotvec: Float[np.ndarray, "... 3"], *, scalar_first: bool) -> Float[np.ndarray, "... 4"]:
    """Unit quaternions of rotation vectors (axis × angle in radians; ``w = cos(angle / 2)``).

    Args:
        rotvec: (..., 3) rotation vectors.
        scalar_first: return ``(w, x, y, z)`` if True, else ``(x, y, z, w)``.

    Returns:
        (..., 4) unit quaternions.
    """
    rotvec = np.asarray(rotvec, dtype=np.float64)
    return _out_quat(Rotation.from_rotvec(rotvec.reshape(-1, 3)).as_quat(), rotvec.shape[:-1], scalar_first)


def rotvec_to_matrix(rotvec: Float[np.ndarray, "... 3"]) -> Float[np.ndarray, "... 3 3"]:
    """Rotation matrices of rotation vectors (axis × angle in radians): Rodrigues' formula.

    Args:
        rotvec: (..., 3) rotation vectors.

    Returns:
        (..., 3, 3) rotation matrices.
    """
    rotvec = np.asarray(rotvec, dtype=np.float64)
    return Rotation.from_rotvec(rotvec.reshape(-1, 3)).as_matrix().reshape(rotvec.shape[:-1] + (3, 3))


def compose_rotvecs(a: Float[np.ndarray, "... 3"], b: Float[np.ndarray, "... 3"]) -> Float[np.ndarray, "... 3"]:
    """Rotation vector (angle in [0, π]) of the rotation ``R(a) · R(b)`` (``b`` applied first).

    Args:
        a: (..., 3) rotation vectors, applied second.
        b: (..., 3) rotation vectors of the same shape, applied first.

    Returns:
        (..., 3) rotation vectors.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    rot = Rotation.from_rotvec(a.reshape(-1, 3)) * Rotation.from_rotvec(b.reshape(-1, 3))
    return rot.as_rotvec().reshape(a.shape)


def quat_multiply(
    a: Float[np.ndarray, "... 4"], b: Float[np.ndarray, "... 4"], *, scalar_first: bool
) -> Float[np.ndarray, "... 4"]:
    """Hamilton product ``a ⊗ b`` of quaternions, not normalised.

    Kept by hand: it also multiplies non-unit quaternions (the dual parts of dual quaternions),
    which scipy's ``Rotation`` (unit quaternions only, renormalised) cannot represent.

    Args:
        a: (..., 4) quaternions, ``(w, x, y, z)`` if ``scalar_first`` else ``(x, y, z, w)``.
        b: (..., 4) quaternions (broadcast against ``a``), in the same order.
        scalar_first: the quaternion order of ``a``, ``b`` and the result.

    Returns:
        (..., 4) the product.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if not scalar_first:
        a, b = a[..., _TO_WXYZ], b[..., _TO_WXYZ]
    q = np.einsum("...j,...k,jki->...i", a, b, HAMILTON_SIGNS)
    return q if scalar_first else q[..., _TO_XYZW]


def quat_slerp(
    q0: Float[np.ndarray, " 4"], q1: Float[np.ndarray, " 4"], u: float, *, scalar_first: bool
) -> Float[np.ndarray, " 4"]:
    """Spherical linear interpolation along the shorter arc (glTF's slerp; scipy's ``Slerp``).

    Args:
        q0: (4,) the rotation at ``u = 0`` (normalised first), in the order given by ``scalar_first``.
        q1: (4,) the rotation at ``u = 1`` (normalised first; its sign does not matter).
        u: the interpolation parameter in [0, 1] (0 gives ``q0``, with its sign).
        scalar_first: ``(w, x, y, z)`` if True, else ``(x, y, z, w)`` (glTF).

    Returns:
        (4,) the unit quaternion at ``u``.
    """
    keys = _as_rotation(np.stack([np.asarray(q0, dtype=np.float64), np.asarray(q1, dtype=np.float64)]), scalar_first)
    q = Slerp([0.0, 1.0], keys)(float(u)).as_quat()
    return _out_quat(q, (), scalar_first)


# ----------------------------------------------------------------------------------------------
# Transforms and forward kinematics


def affine_matrix(
    linear: Float[np.ndarray, "... 3 3"], translation: Float[np.ndarray, "... 3"]
) -> Float[np.ndarray, "... 4 4"]:
    """Homogeneous transforms ``x ↦ linear · x + translation``.

    Args:
        linear: (..., 3, 3) linear parts (rotations, or rotations times scales).
        translation: (..., 3) translations.

    Returns:
        (..., 4, 4) transforms with bottom row (0, 0, 0, 1).
    """
    linear = np.asarray(linear, dtype=np.float64)
    translation = np.asarray(translation, dtype=np.float64)
    m = np.zeros(np.broadcast_shapes(linear.shape[:-2], translation.shape[:-1]) + (4, 4))
    m[..., :3, :3] = linear
    m[..., :3, 3] = translation
    m[..., 3, 3] = 1.0
    return m


def trs_matrix(
    translation: Float[np.ndarray, "... 3"],
    rotation: Float[np.ndarray, "... 4"],
    scale: Float[np.ndarray, "... 3"],
    *,
    scalar_first: bool,
) -> Float[np.ndarray, "... 4 4"]:
    """Local transforms ``T · R · S`` (glTF's node transform) from translations, quaternions and scales.

    Args:
        translation: (..., 3) translations.
        rotation: (..., 4) quaternions (normalised first), ``(x, y, z, w)`` for glTF (``scalar_first=False``).
        scale: (..., 3) scales along the local axes.
        scalar_first: the quaternion order.

    Returns:
        (..., 4, 4) transforms.
    """
    r = quat_to_matrix(rotation, scalar_first=scalar_first) * np.asarray(scale, dtype=np.float64)[..., None, :]
    return affine_matrix(r, translation)


def joint_local_transforms(
    rest_positions: Float[np.ndarray, "J 3"],
    parents: Int[np.ndarray, " J"],
    rotations: Float[np.ndarray, "J 3 3"],
    root_translation: Float[np.ndarray, " 3"] | None = None,
) -> Float[np.ndarray, "J 4 4"]:
    """Local transforms of joint frames that turn about the joints.

    The convention of :func:`ncflow.skeleton.forward_kinematics` and of MANO / SMPL: frame j has
    its origin at joint j and rest-aligned axes; its local transform, relative to the parent's
    frame, is ``[R_j | P_j − P_parent]`` (a root: ``[R_j | P_j + root_translation]``), so that
    :func:`forward_kinematics` gives ``x ↦ R_j^world x + t_j`` with ``t_j`` the posed joint.

    Args:
        rest_positions: (J, 3) joint positions P in the rest pose.
        parents: (J,) parent indices, −1 for roots.
        rotations: (J, 3, 3) local joint rotations R.
        root_translation: (3,) added to every root's position (default: none).

    Returns:
        (J, 4, 4) local transforms.
    """
    positions = np.asarray(rest_positions, dtype=np.float64)
    parents = np.asarray(parents, dtype=np.int64)
    root = parents < 0
    offsets = np.where(root[:, None], positions, positions - positions[np.maximum(parents, 0)])
    if root_translation is not None:
        offsets[root] = positions[root] + np.asarray(root_translation, dtype=np.float64).reshape(3)
    return affine_matrix(rotations, offsets)


def forward_kinematics(
    local: Float[np.ndarray, "J 4 4"], parents: Int[np.ndarray, " J"], order: Int[np.ndarray, " J"] | None = None
) -> Float[np.ndarray, "J 4 4"]:
    """World transforms of a tree of frames: ``world_j = world_parent(j) · local_j`` (roots: ``local_j``).

    Args:
        local: (J, 4, 4) local transforms (relative to the parent frame).
        parents: (J,) parent indices, −1 for roots.
        order: (J,) an order that visits parents before children (default: 0..J−1, which then
            must be topological: ``parents[j] < j``).

    Returns:
        (J, 4, 4) world transforms.

    Raises:
        ValueError: without ``order``, a parent that comes after its child.
    """
    local = np.asarray(local, dtype=np.float64)
    parents = np.asarray(parents, dtype=np.int64)
    if order is None:
        if np.any(parents >= np.arange(parents.shape[0])):
            raise ValueError("joints must be in topological order (parents[j] < j), or give an order")
        order = np.arange(parents.shape[0])
    world = np.empty_like(local)
    for j in order:
        p = parents[j]
        world[j] = local[j] if p < 0 else world[p] @ local[j]
    return world


# ----------------------------------------------------------------------------------------------
# Skinning


def skinning_matrices(
    world: Float[np.ndarray, "J 4 4"], rest_positions: Float[np.ndarray, "J 3"]
) -> Float[np.ndarray, "J 4 4"]:
    """Skinning transforms ``x ↦ A_j (x − P_j) + t_j`` of joint frames bound at their rest positions.

    The joint frames' world transforms are ``[A_j | t_j]``; the inverse bind matrix of joint j is
    the translation by ``−P_j``.

    Args:
        world: (J, 4, 4) world transforms of the joint frames (:func:`forward_kinematics`).
        rest_positions: (J, 3) joint positions in the rest (bind) pose.

    Returns:
        (J, 4, 4) ``[A_j | t_j − A_j P_j]``.
    """
    world = np.asarray(world, dtype=np.float64)
    out = world.copy()
    rest = np.asarray(rest_positions, dtype=np.float64)
    out[:, :3, 3] = world[:, :3, 3] - np.einsum("jab,jb->ja", world[:, :3, :3], rest)
    return out


def dense_weights(
    joints: Int[np.ndarray, "V K"], weights: Float[np.ndarray, "V K"], n_joints: int
) -> Float[np.ndarray, "V J"]:
    """Dense (V, J) weights from per-vertex influence lists (glTF's ``JOINTS_n`` / ``WEIGHTS_n``).

    Repeated joints of a vertex add up.
    """
    joints = np.asarray(joints, dtype=np.int64)
    out = np.zeros((joints.shape[0], int(n_joints)))
    rows = np.repeat(np.arange(joints.shape[0]), joints.shape[1])
    np.add.at(out, (rows, joints.reshape(-1)), np.asarray(weights, dtype=np.float64).reshape(-1))
    return out


def linear_blend_skinning(
    vertices: Float[np.ndarray, "V 3"], weights: Float[np.ndarray, "V J"], transforms: Float[np.ndarray, "J 4 4"]
) -> Float[np.ndarray, "V 3"]:
    """Linear blend skinning ``x'_v = Σ_j w_vj (A_j x_v + b_j)`` with transforms ``[A_j | b_j]``.

    Weights are used as given (normalise them first); transforms are affine (the bottom row is
    ignored).

    Args:
        vertices: (V, 3) rest positions.
        weights: (V, J) dense weights.
        transforms: (J, 4, 4) skinning transforms (:func:`skinning_matrices`, or glTF's
            ``world(joint) · inverseBind``).

    Returns:
        (V, 3) skinned positions.
    """
    transforms = np.asarray(transforms, dtype=np.float64)
    blended = np.einsum("vj,jab->vab", np.asarray(weights, dtype=np.float64), transforms[:, :3, :])  # (V, 3, 4)
    return np.einsum("vab,vb->va", blended[:, :, :3], np.asarray(vertices, dtype=np.float64)) + blended[:, :, 3]


def sparse_linear_blend_skinning(
    vertices: Float[np.ndarray, "V 3"],
    joints: Int[np.ndarray, "V K"],
    weights: Float[np.ndarray, "V K"],
    transforms: Float[np.ndarray, "J 4 4"],
) -> Float[np.ndarray, "V 3"]:
    """:func:`linear_blend_skinning` with glTF's per-vertex influence lists (through :func:`dense_weights`).

    ``x'_v = Σ_k weights[v, k] · transforms[joints[v, k]] · (vertices[v], 1)``.

    Args:
        vertices: (V, 3) rest positions.
        joints: (V, K) joint index of every influence.
        weights: (V, K) influence weights (normalise them first).
        transforms: (J, 4, 4) skinning transforms.

    Returns:
        (V, 3) skinned positions.
    """
    return linear_blend_skinning(vertices, dense_weights(joints, weights, np.shape(transforms)[0]), transforms)


def dual_quaternion_skinning(
    vertices: Float[np.ndarray, "V 3"], weights: Float[np.ndarray, "V J"], transforms: Float[np.ndarray, "J 4 4"]
) -> Float[np.ndarray, "V 3"]:
    """Dual-quaternion skinning (Kavan et al. 2008) with dense weights and rigid transforms.

    Each transform ``x ↦ R_j x + c_j`` becomes a unit dual quaternion ``(r_j, ½ (0, c_j) ⊗ r_j)``;
    per vertex the dual quaternions are blended with signs aligned to the vertex's heaviest joint,
    normalised, and applied. Kept by hand: scipy has no dual quaternions (the differentiable JAX
    version is :mod:`ncflow.skeleton.dualquat`).

    Args:
        vertices: (V, 3) rest positions.
        weights: (V, J) weights (normalise them first).
        transforms: (J, 4, 4) rigid skinning transforms (:func:`skinning_matrices`).

    Returns:
        (V, 3) skinned positions.
    """
    transforms = np.asarray(transforms, dtype=np.float64)
    weights = np.asarray(weights, dtype=np.float64)
    r = matrix_to_quat(transforms[:, :3, :3], scalar_first=True)
    c = transforms[:, :3, 3]
    dual = 0.5 * quat_multiply(np.concatenate([np.zeros((c.shape[0], 1)), c], axis=1), r, scalar_first=True)
    pivot = r[np.argmax(weights, axis=1)]  # (V, 4)
    sign = np.sign(pivot @ r.T)  # (V, J)
    sign[sign == 0] = 1.0
    ws = weights * sign
    b0 = ws @ r
    be = ws @ dual
    n0 = np.linalg.norm(b0, axis=1, keepdims=True)
    b0, be = b0 / n0, be / n0
    w0, v0 = b0[:, :1], b0[:, 1:]
    we, ve = be[:, :1], be[:, 1:]
    x = np.asarray(vertices, dtype=np.float64)
    x = x + 2.0 * np.cross(v0, np.cross(v0, x) + w0 * x)
    return x + 2.0 * (w0 * ve - we * v0 + np.cross(v0, ve))
