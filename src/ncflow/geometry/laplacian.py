"""The cotangent Laplacian and lumped mass matrix of a triangle mesh (linear finite elements).

:func:`cotangent_laplacian` is the matrix ``L`` of libigl's ``cotmatrix`` convention: off-diagonal
``L_ij = ½ (cot α_ij + cot β_ij)`` over the (one or two) triangles sharing edge ij, diagonal
``L_ii = −Σ_j L_ij``, so ``L`` is symmetric negative semi-definite and ``−uᵀ L u`` is the Dirichlet
energy ∫|∇u|² of the piecewise-linear function u; its kernel holds the functions constant on each
connected component. :func:`lumped_mass` gives the barycentric (one third of the incident
triangle areas) lumped mass ``M``.

Degenerate triangles (zero area, collinear or repeated corners) have no finite cotangent. Both
functions use the *intrinsic mollification* of Sharp & Crane ("A Laplacian for Nonmanifold
Triangle Meshes", SGP 2020, §4.5): every edge length is increased by one global ε, the smallest
that makes every triangle satisfy the triangle inequality with margin δ (``δ = mollify`` × the
mean edge length), and cotangents and areas come from the lengths (law of cosines, Heron's
formula). A well-shaped mesh gets ε = 0 (the usual cotangent Laplacian exactly); a degenerate
triangle becomes a thin but valid one, so ``−L`` stays positive semi-definite with the same
kernel (clamping cotangents one by one would not: it can make a triangle's stiffness indefinite).

Written by hand (a few lines of NumPy and SciPy): potpourri3d's ``cotan_laplacian`` has no
mollification (a zero-area triangle gives infinite or huge weights), and robust-laplacian /
libigl are not dependencies of ncflow.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from jaxtyping import Float, Int

__all__ = ["cotangent_laplacian", "lumped_mass", "mollified_lengths"]

DEFAULT_MOLLIFY = 1e-5
"""δ of the intrinsic mollification, as a fraction of the mean edge length (robust-laplacian's default)."""


def mollified_lengths(
    vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], mollify: float = DEFAULT_MOLLIFY
) -> Float[np.ndarray, "F 3"]:
    """Edge lengths per triangle, ``lengths[f, i]`` the edge opposite corner i, mollified.

    Every length is increased by the one ε ≥ 0 that makes ``l_a + l_b − l_c ≥ δ`` for every
    triangle and corner (``δ = mollify · mean edge length``); see the module docstring.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    p = v[f]  # (F, 3, 3)
    lengths = np.linalg.norm(p[:, [2, 0, 1]] - p[:, [1, 2, 0]], axis=2)  # opposite corners 0, 1, 2
    if lengths.size == 0:
        return lengths
    delta = float(mollify) * float(np.mean(lengths))
    slack = lengths.sum(1, keepdims=True) - 2.0 * lengths  # l_a + l_b − l_c for each c
    eps = max(0.0, delta - float(slack.min()))
    return lengths + eps


def _angles_cot_area(lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cotangent at each corner (F, 3), triangle areas (F,)) from mollified edge lengths."""
    a, b, c = lengths[:, 0], lengths[:, 1], lengths[:, 2]
    s = 0.5 * (a + b + c)
    area = np.sqrt(np.maximum(s * (s - a) * (s - b) * (s - c), 0.0))
    sq = lengths**2
    # cot of the angle at corner i (opposite edge l_i) = (l_j² + l_k² − l_i²) / (4 · area)
    num = sq.sum(1, keepdims=True) - 2.0 * sq
    with np.errstate(divide="ignore", invalid="ignore"):
        cot = np.where(area[:, None] > 0, num / (4.0 * area[:, None]), 0.0)
    return cot, area


def cotangent_laplacian(
    vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], *, mollify: float = DEFAULT_MOLLIFY
) -> sp.csr_matrix:
    """The (V, V) cotangent Laplacian ``L`` (negative semi-definite, rows sum to 0; module docstring).

    Args:
        vertices: (V, 3) positions.
        faces: (F, 3) triangles (0-based); vertices in no triangle get an all-zero row.
        mollify: δ of the intrinsic mollification as a fraction of the mean edge length (0: none;
            degenerate triangles then contribute nothing).

    Returns:
        ``scipy.sparse.csr_matrix`` of shape (V, V), float64.
    """
    f = np.asarray(faces, dtype=np.int64)
    n = np.asarray(vertices).shape[0]
    cot, _ = _angles_cot_area(mollified_lengths(vertices, f, mollify))
    # the cotangent at corner i weighs the edge between the two other corners j, k
    j = f[:, [1, 2, 0]].reshape(-1)
    k = f[:, [2, 0, 1]].reshape(-1)
    w = 0.5 * cot.reshape(-1)
    off = sp.coo_matrix((np.concatenate([w, w]), (np.concatenate([j, k]), np.concatenate([k, j]))), shape=(n, n))
    off = off.tocsr()
    return (off - sp.diags(np.asarray(off.sum(axis=1)).reshape(-1))).tocsr()


def lumped_mass(
    vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], *, mollify: float = DEFAULT_MOLLIFY
) -> Float[np.ndarray, " V"]:
    """(V,) barycentric lumped mass: one third of the (mollified) area of every incident triangle.

    A vertex in no triangle has mass 0.
    """
    f = np.asarray(faces, dtype=np.int64)
    _, area = _angles_cot_area(mollified_lengths(vertices, f, mollify))
    mass = np.zeros(np.asarray(vertices).shape[0])
    np.add.at(mass, f.reshape(-1), np.repeat(area / 3.0, 3))
    return mass
