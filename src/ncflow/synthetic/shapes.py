"""Procedural test surfaces: spheres, tubes, capsules, (rounded) boxes, and bending.

Used by the tests, the benchmarks and the command ``ncflow make-shape``; each builder returns
``(vertices (V, 3) float64, faces (F, 3) int64)`` with outward-facing, consistently wound faces.
Different resolutions of one builder give different triangulations of (nearly) the same surface.
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Float, Int

from ncflow.geometry.mesh import weld_vertices

MeshArrays = tuple[Float[np.ndarray, "V 3"], Int[np.ndarray, "F 3"]]


def sphere(subdivisions: int = 3, radius: float = 1.0) -> MeshArrays:
    """Icosphere (trimesh) with 20·4^subdivisions faces."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=int(subdivisions), radius=radius)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def _grid_faces(n_u: int, n_v: int, periodic_u: bool, diagonal: str) -> np.ndarray:
    """Quads of a (n_v rows × n_u columns) vertex grid split into triangles."""
    cols = n_u if periodic_u else n_u - 1
    i, j = np.meshgrid(np.arange(n_v - 1), np.arange(cols), indexing="ij")
    i, j = i.ravel(), j.ravel()
    a = i * n_u + j
    b = i * n_u + (j + 1) % n_u
    c = (i + 1) * n_u + (j + 1) % n_u
    d = (i + 1) * n_u + j
    if diagonal == "right":
        flip = np.zeros_like(a, dtype=bool)
    elif diagonal == "left":
        flip = np.ones_like(a, dtype=bool)
    elif diagonal == "alternate":
        flip = (i + j) % 2 == 1
    else:
        raise ValueError(f"diagonal must be 'right', 'left' or 'alternate', got {diagonal!r}")
    t1 = np.where(flip[:, None], np.stack([a, b, d], 1), np.stack([a, b, c], 1))
    t2 = np.where(flip[:, None], np.stack([b, c, d], 1), np.stack([a, c, d], 1))
    return np.concatenate([t1, t2]).astype(np.int64)


def tube(
    radius: float = 0.5, length: float = 2.0, n_around: int = 32, n_along: int = 24, diagonal: str = "right"
) -> MeshArrays:
    """Open cylinder along z, centred at the origin (two boundary loops), outward normals."""
    theta = 2 * np.pi * np.arange(n_around) / n_around
    z = np.linspace(-length / 2, length / 2, n_along)
    zz, tt = np.meshgrid(z, theta, indexing="ij")
    v = np.stack([radius * np.cos(tt), radius * np.sin(tt), zz], -1).reshape(-1, 3)
    return v, _grid_faces(n_around, n_along, True, diagonal)


def capsule(
    radius: float = 0.5, length: float = 2.0, n_around: int = 32, n_along: int = 24, diagonal: str = "right"
) -> MeshArrays:
    """Closed capsule along z: a cylinder of ``length`` with hemispherical caps, total length + 2·radius.

    Built as a latitude–longitude grid with a single vertex at each pole (no degenerate faces).
    """
    n_cap = max(2, n_around // 4)
    # profile: (r, z) from the south pole to the north pole, excluding the poles
    south = [(radius * np.sin(a), -length / 2 - radius * np.cos(a)) for a in np.linspace(0, np.pi / 2, n_cap + 1)[1:]]
    body = [(radius, z) for z in np.linspace(-length / 2, length / 2, n_along)[1:-1]]
    north = [(radius * np.sin(a), length / 2 + radius * np.cos(a)) for a in np.linspace(np.pi / 2, 0, n_cap + 1)[:-1]]
    prof = np.asarray(south + body + north)
    theta = 2 * np.pi * np.arange(n_around) / n_around
    rings = np.stack(
        [prof[:, 0:1] * np.cos(theta)[None], prof[:, 0:1] * np.sin(theta)[None], np.repeat(prof[:, 1:2], n_around, 1)],
        -1,
    ).reshape(-1, 3)
    n_rings = prof.shape[0]
    faces = [_grid_faces(n_around, n_rings, True, diagonal)]
    sp, np_ = rings.shape[0], rings.shape[0] + 1
    j = np.arange(n_around)
    faces.append(np.stack([np.full(n_around, sp), (j + 1) % n_around, j], 1))
    top = (n_rings - 1) * n_around
    faces.append(np.stack([np.full(n_around, np_), top + j, top + (j + 1) % n_around], 1))
    v = np.concatenate([rings, [[0, 0, -length / 2 - radius], [0, 0, length / 2 + radius]]])
    return v, np.concatenate(faces).astype(np.int64)


def rounded_box(size: float = 2.0, rounding: float = 0.0, subdivisions: int = 8) -> MeshArrays:
    """Axis-aligned cube of edge ``size`` whose edges and corners are rounded with radius ``rounding``.

    Every rounding value gives the same connectivity (a cube with ``subdivisions``² quads per side),
    so a sharp and a rounded copy differ only in geometry.
    """
    n = int(subdivisions) + 1
    s = np.linspace(-1, 1, n)
    verts, faces = [], []
    offset = 0
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u, w = np.meshgrid(s, s, indexing="ij")
            p = np.zeros((n, n, 3))
            a1, a2 = (axis + 1) % 3, (axis + 2) % 3
            p[..., axis] = sign
            p[..., a1] = u
            p[..., a2] = w
            f = _grid_faces(n, n, False, "alternate")
            if sign < 0:
                f = f[:, ::-1]
            verts.append(p.reshape(-1, 3))
            faces.append(f + offset)
            offset += n * n
    import trimesh

    v, f, _ = weld_vertices(np.concatenate(verts), np.concatenate(faces), tol=1e-9)
    half = size / 2.0
    v = v * half
    r = float(np.clip(rounding, 0.0, half))
    if r > 0:
        inner = np.clip(v, -(half - r), half - r)
        d = v - inner
        v = inner + r * d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    m = trimesh.Trimesh(v, f, process=False)
    if m.volume < 0:
        f = f[:, ::-1]
    return v, f.astype(np.int64)


def bend(
    vertices: Float[np.ndarray, "V 3"], angle_deg: float, axis: int = 2, start: float = 0.0, bend_axis: int = 0
) -> Float[np.ndarray, "V 3"]:
    """Bend a shape: points with coordinate ``axis`` beyond ``start`` are rotated by ``angle_deg``
    about the line through (axis = start) parallel to coordinate ``bend_axis`` (a rigid elbow).
    """
    v = np.array(vertices, dtype=np.float64)
    ang = np.deg2rad(angle_deg)
    other = 3 - axis - bend_axis
    sel = v[:, axis] > start
    a, o = v[sel, axis] - start, v[sel, other]
    c, s = np.cos(ang), np.sin(ang)
    v[sel, axis] = start + c * a - s * o
    v[sel, other] = s * a + c * o
    return v


SHAPES = {
    "sphere": lambda res: sphere(subdivisions=max(1, res // 8)),
    "capsule": lambda res: capsule(n_around=res, n_along=res),
    "tube": lambda res: tube(n_around=res, n_along=res),
    "box": lambda res: rounded_box(subdivisions=max(1, res // 2)),
    "rounded-box": lambda res: rounded_box(rounding=0.3, subdivisions=max(1, res // 2)),
}


def make_shape(kind: str, resolution: int = 24, bend_deg: float = 0.0) -> MeshArrays:
    """One of :data:`SHAPES` at a resolution (points around), optionally bent at its middle about x."""
    if kind not in SHAPES:
        raise ValueError(f"unknown shape {kind!r}; choose from {', '.join(SHAPES)}")
    v, f = SHAPES[kind](int(resolution))
    if bend_deg:
        v = bend(v, bend_deg)
    return v, f
