"""Values of the source carried to the target through the continuous map ``map_tgt_to_src``.

Each target vertex j corresponds to the point of source face ``face[j]`` with barycentric
coordinates ``bary[j]`` (DESIGN.md "Output contract"); a per-vertex quantity of the source is read
there by barycentric interpolation (continuous values) or at the corner of largest weight (labels,
indices).
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Float, Int

__all__ = ["interpolate", "nearest_corner"]


def interpolate(
    values: Float[np.ndarray, "Vs ..."],
    source_faces: Int[np.ndarray, "Fs 3"],
    face: Int[np.ndarray, " Vt"],
    bary: Float[np.ndarray, "Vt 3"],
) -> Float[np.ndarray, "Vt ..."]:
    """Barycentric interpolation: (Vt, *C) = Σ_i bary[:, i] · values[faces[face, i]].

    Exact for any function linear on each source triangle (positions, linear fields).
    """
    values = np.asarray(values, np.float64)
    corners = values[np.asarray(source_faces)[np.asarray(face)]]  # (Vt, 3, *C)
    w = np.asarray(bary, np.float64).reshape(bary.shape + (1,) * (values.ndim - 1))
    return np.sum(w * corners, axis=1)


def nearest_corner(
    values: np.ndarray,
    source_faces: Int[np.ndarray, "Fs 3"],
    face: Int[np.ndarray, " Vt"],
    bary: Float[np.ndarray, "Vt 3"],
) -> np.ndarray:
    """(Vt, *C): the value at the corner of each mapped point with the largest barycentric weight
    (labels and indices, which must not be averaged; ties go to the first corner).
    """
    corner = np.argmax(np.asarray(bary), axis=1)
    return np.asarray(values)[np.asarray(source_faces)[np.asarray(face), corner]]
