"""A triangle surface from an oriented point cloud: the zero set of an implicit moving-least-squares
distance, extracted by marching cubes in a band around the points.

    f(x) = Σ_i w_i(x) n_i · (x − p_i) / Σ_i w_i(x),   w_i(x) = exp(−|x − p_i|² / σ²)

over the k nearest points p_i of x with outward unit normals n_i (Kolluri 2008, "Provably good moving
least squares"; Hoppe et al. 1992 is the one-neighbour case): negative inside, positive outside, smooth
(σ is a few point spacings, so noise along the normal averages out). Inside a finger thinner than σ both
sides say "inside"; between two fingers both say "outside": neighbouring parts stay apart as long as the
grid resolves their gap.

f is evaluated only on grid corners (:data:`CELL` spacings apart) within :data:`BAND` spacings of a point and
marching cubes (scikit-image's Lewiner variant) runs only there (its ``mask``), so where the scan saw nothing —
holes, the far side of a single view — no surface is invented: the result is open there.

Written by hand (NumPy, SciPy's cKDTree, scikit-image's marching cubes): Poisson and ball-pivoting
reconstruction live in Open3D or PyMeshLab, too heavy for one function; screened Poisson would also
close every hole with a smooth cap, a surface the scan does not show.
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Float, Int

from ncflow.geometry.cloud import occupancy_grid

CELLS = 128
"""Most grid cells along the cloud's longest side."""

CELL = 0.5
"""The grid's cell, in point spacings (where :data:`CELLS` allows)."""

KERNEL = 1.0
"""σ of the weights, in point spacings (or cells, where the cells are the larger)."""

BAND = 1.5
"""Grid corners farther than this many spacings (or cells) from every point are outside the band (no surface
there)."""

K = 10
"""Nearest points that enter f at a grid corner."""


def reconstruct_surface(
    points: Float[np.ndarray, "N 3"],
    normals: Float[np.ndarray, "N 3"],
    spacing: float,
    cells: int = CELLS,
) -> tuple[Float[np.ndarray, "V 3"], Int[np.ndarray, "F 3"]]:
    """The surface of an oriented cloud (see the module docstring): (vertices (V, 3), faces (F, 3)) wound
    with normals outward, possibly open where the cloud has holes.

    Args:
        points: (N, 3) the points (outliers left out).
        normals: (N, 3) their outward unit normals.
        spacing: the cloud's typical point spacing (:func:`ncflow.geometry.cloud.point_spacing`).
        cells: most grid cells along the longest side; the cell is :data:`CELL` spacings where that fits.
    """
    from scipy import ndimage
    from scipy.spatial import cKDTree
    from skimage.measure import marching_cubes

    p = np.asarray(points, np.float64)
    n = np.asarray(normals, np.float64)
    h = max(CELL * float(spacing), float(np.ptp(p, axis=0).max()) / cells)
    band_cells = BAND * max(float(spacing), h) / h
    origin, occupied = occupancy_grid(p, h, int(np.ceil(band_cells)) + 2)
    shape = occupied.shape
    r = int(np.ceil(band_cells))
    ball = np.linalg.norm(np.mgrid[-r : r + 1, -r : r + 1, -r : r + 1], axis=0) <= band_cells
    band = ndimage.binary_dilation(occupied, structure=ball)
    corners = np.argwhere(band)
    x = origin + corners * h
    sigma = KERNEL * max(float(spacing), h)
    k = min(K, p.shape[0])
    d, idx = cKDTree(p).query(x, k=k)
    w = np.exp(-((d / sigma) ** 2))
    w_sum = w.sum(axis=1)
    w = np.where(w_sum[:, None] > 1e-12, w / np.maximum(w_sum[:, None], 1e-300), 1.0 / k)  # far: plain mean
    signed = np.einsum("nkj,nkj->nk", n[idx], x[:, None, :] - p[idx])
    values = np.full(shape, 1.0)
    values[tuple(corners.T)] = np.einsum("nk,nk->n", w, signed) / h
    whole = np.zeros(shape, bool)  # skimage reads a cube's mask at its upper corner: all eight corners in the band
    whole[1:, 1:, 1:] = True
    for di, dj, dk in np.ndindex(2, 2, 2):
        whole[1:, 1:, 1:] &= band[di : shape[0] - 1 + di, dj : shape[1] - 1 + dj, dk : shape[2] - 1 + dk]
    verts, faces, _, _ = marching_cubes(values, level=0.0, spacing=(h, h, h), mask=whole, allow_degenerate=False)
    verts = verts + origin
    faces = faces.astype(np.int64)
    if faces.shape[0] and _facing(verts, faces, p, n) < 0:
        faces = faces[:, ::-1].copy()
    return verts, faces


def _facing(verts: np.ndarray, faces: np.ndarray, points: np.ndarray, normals: np.ndarray) -> float:
    """Σ over faces of (area-weighted face normal) · (normal of the nearest point): > 0 when the faces wind outward."""
    from scipy.spatial import cKDTree

    a, b, c = (verts[faces[:, i]] for i in range(3))
    fn = np.cross(b - a, c - a)
    _, j = cKDTree(points).query((a + b + c) / 3.0)
    return float(np.einsum("ij,ij->", fn, normals[j]))
