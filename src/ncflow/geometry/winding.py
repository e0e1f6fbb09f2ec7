"""Generalised winding numbers and the signed volume of a triangle soup (NumPy, chunked).

The winding number of a point with respect to a closed, outward-wound surface is 1 inside and 0
outside: the solid angles of the triangles (van Oosterom & Strackee) summed and divided by 4π. For
an open surface it still tells inside from outside away from the holes. Used by the remeshing
checks (every joint inside the extracted surface), :func:`ncflow.skeleton.check_inside` and, with
the signed volume, to orient meshes outward.

Kept by hand: trimesh's ``contains`` casts rays (and needs rtree) and is defined for watertight
meshes only; the winding number is exact for any triangle soup.
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Float, Int


def winding_numbers(
    points: Float[np.ndarray, "n 3"], triangles: Float[np.ndarray, "F 3 3"], chunk: int = 200_000
) -> Float[np.ndarray, " n"]:
    """Generalised winding numbers of points w.r.t. a triangle soup (1 inside a closed outward surface, 0 outside).

    Args:
        points: (n, 3) query points.
        triangles: (F, 3, 3) triangle corners (``vertices[faces]``).
        chunk: at most about this many (point, triangle) pairs at a time (memory ~ 100 bytes each);
            the result does not depend on it.

    Returns:
        (n,) float64 winding numbers.
    """
    points = np.asarray(points, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.float64)
    out = np.zeros(points.shape[0])
    per = max(1, chunk // max(1, tri.shape[0]))
    corners = tri.transpose(1, 2, 0)  # (3 corners, 3 coordinates, F): one (p, F) array per component
    for s in range(0, points.shape[0], per):
        q = points[s : s + per].T[:, :, None]  # (3, p, 1)
        (ax, ay, az), (bx, by, bz), (cx, cy, cz) = (corners[k][:, None, :] - q for k in range(3))
        la, lb, lc = (np.sqrt(x * x + y * y + z * z) for x, y, z in ((ax, ay, az), (bx, by, bz), (cx, cy, cz)))
        num = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
        den = la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (bx * cx + by * cy + bz * cz) * la
        den += (cx * ax + cy * ay + cz * az) * lb
        out[s : s + per] = np.arctan2(num, den).sum(axis=1) / (2.0 * np.pi)
    return out


def signed_volume(vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"]) -> float:
    """Signed volume Σ a · (b × c) / 6 over the faces (positive for a closed outward-wound surface).

    :func:`ncflow.geometry.mesh.enclosed_volume` is its absolute value after closing holes; trimesh's
    ``volume`` integrates differently (equal to rounding, not bit for bit).
    """
    t = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0)
