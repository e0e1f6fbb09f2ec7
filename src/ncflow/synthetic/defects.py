"""Imperfect targets with exact ground truth: the defects of meshes from modelling tools, converters and scanners.

:func:`add_defects` takes a :class:`~ncflow.synthetic.pairs.Pair` and gives its target one or more
defects, each drawn from the pair's seed:

``soup``        every face with corners of its own (a triangle soup: three vertices per face);
``degenerate``  zero-area faces, 1.6 % of the faces: edges collapsed (a vertex moved onto its
                neighbour) and faces with a repeated corner;
``duplicates``  2 % of the faces written twice (half of them wound the other way);
``stray``       vertices in no face (1 % of the vertex count, inside the bounding box);
``fins``        extra triangles standing on 1 % of the edges (at least 30), a third of those edges
                with a second fin (edges shared by three and four faces), three fins meeting at a
                tenth of the fins' first vertices;
``fragment``    a flat patch of "floor" below the shape, 3 % of its area (``fragment-flipped``: wound
                downwards);
``pinch``       a small closed tetrahedron touching the surface at one vertex (a non-manifold vertex).

Vertices that come from the target keep their ground truth (a soup's copies of a vertex all get
the vertex's); the new ones (fins, fragment, pinch, stray) have none, so the ground truth becomes
partial (:attr:`~ncflow.io.ground_truth.GroundTruth.target_index`). Defects are applied in the
order given.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ncflow.errors import InputError
from ncflow.geometry.mesh import Mesh, face_areas, vertex_normals
from ncflow.io.ground_truth import GroundTruth

DEFECTS = ("soup", "degenerate", "duplicates", "stray", "fins", "fragment", "fragment-flipped", "pinch")


def _edges(faces: np.ndarray) -> np.ndarray:
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(e, axis=0)


def _soup(v, f, origin, rng):
    return v[f].reshape(-1, 3), np.arange(3 * f.shape[0]).reshape(-1, 3), origin[f.reshape(-1)]


def _degenerate(v, f, origin, rng, share: float = 0.016):
    n_bad = max(2, int(round(share * f.shape[0])))
    v, origin = v.copy(), origin.copy()
    edges = _edges(f)
    moved = np.zeros(v.shape[0], bool)
    collapsed = 0
    for a, b in edges[rng.permutation(edges.shape[0])]:
        if collapsed >= n_bad // 2:
            break
        if moved[a] or moved[b]:
            continue
        v[b] = v[a]  # the two faces on edge (a, b) lose their area
        origin[b] = origin[a]
        moved[[a, b]] = True
        collapsed += 2
    rows = rng.choice(f.shape[0], n_bad - collapsed, replace=False)
    repeated = f[rows].copy()
    repeated[:, 2] = repeated[:, 1]
    return v, np.concatenate([f, repeated]), origin


def _duplicates(v, f, origin, rng, share: float = 0.02):
    rows = rng.choice(f.shape[0], max(1, int(round(share * f.shape[0]))), replace=False)
    copies = f[rows].copy()
    copies[::2] = copies[::2, ::-1]
    return v, np.concatenate([f, copies]), origin


def _stray(v, f, origin, rng, share: float = 0.01):
    n = max(1, int(round(share * v.shape[0])))
    lo, hi = v.min(0), v.max(0)
    extra = lo + rng.random((n, 3)) * (hi - lo)
    return np.concatenate([v, extra]), f, np.concatenate([origin, np.full(n, -1)])


def _fins(v, f, origin, rng, share: float = 0.01):
    edges = _edges(f)
    n = min(edges.shape[0], max(30, int(round(share * edges.shape[0]))))
    pick = edges[rng.choice(edges.shape[0], n, replace=False)]
    # a third of those edges get a second fin; at a tenth of their first vertices, three fins meet
    crowd = []
    taken = {tuple(e) for e in pick.tolist()}
    for a in pick[: max(1, n // 10), 0]:
        around = [e for e in edges[(edges[:, 0] == a) | (edges[:, 1] == a)].tolist() if tuple(e) not in taken]
        chosen = [around[i] for i in rng.permutation(len(around))[:3]]
        taken.update(tuple(e) for e in chosen)
        crowd.append(np.asarray(chosen, np.int64).reshape(-1, 2))
    pick = np.concatenate([pick, pick[: n // 3], *crowd])
    normals = vertex_normals(v, f)
    length = np.linalg.norm(v[pick[:, 0]] - v[pick[:, 1]], axis=1)[:, None]
    side = rng.normal(size=(pick.shape[0], 3)) * 0.3
    tips = v[pick].mean(1) + length * (normals[pick].mean(1) + side)
    new = v.shape[0] + np.arange(pick.shape[0])
    fins = np.stack([pick[:, 0], pick[:, 1], new], axis=1)
    return np.concatenate([v, tips]), np.concatenate([f, fins]), np.concatenate([origin, np.full(len(new), -1)])


def _fragment(v, f, origin, rng, share: float = 0.03, flipped: bool = False):
    area = face_areas(v, f).sum() * share
    lo, hi = v.min(0), v.max(0)
    side = np.sqrt(area)
    k = 6
    u, w = np.meshgrid(np.linspace(0, side, k + 1), np.linspace(0, side, k + 1), indexing="ij")
    centre = 0.5 * (lo + hi)
    y = lo[1] - 0.02 * np.linalg.norm(hi - lo)
    grid = np.stack([centre[0] - side / 2 + u.ravel(), np.full(u.size, y), centre[2] - side / 2 + w.ravel()], 1)
    idx = np.arange((k + 1) ** 2).reshape(k + 1, k + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    quad = np.concatenate([np.stack([a, d, c], 1), np.stack([a, c, b], 1)])  # normals up (+y)
    if flipped:
        quad = quad[:, ::-1]
    n0 = v.shape[0]
    return (
        np.concatenate([v, grid]),
        np.concatenate([f, quad + n0]),
        np.concatenate([origin, np.full(grid.shape[0], -1)]),
    )


def _pinch(v, f, origin, rng):
    normals = vertex_normals(v, f)
    a = int(rng.integers(v.shape[0]))
    size = 0.05 * np.linalg.norm(v.max(0) - v.min(0))
    frame = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    tip = v[a] + size * normals[a]
    extra = tip + 0.5 * size * frame
    n0 = v.shape[0]
    p, q, r = n0, n0 + 1, n0 + 2
    tet = np.array([[a, p, q], [a, q, r], [a, r, p], [p, r, q]])
    if np.dot(np.cross(extra[1] - extra[0], extra[2] - extra[0]), extra.mean(0) - v[a]) > 0:
        tet = tet[:, ::-1]
    return np.concatenate([v, extra]), np.concatenate([f, tet]), np.concatenate([origin, np.full(3, -1)])


_APPLY = {
    "soup": _soup,
    "degenerate": _degenerate,
    "duplicates": _duplicates,
    "stray": _stray,
    "fins": _fins,
    "fragment": _fragment,
    "fragment-flipped": lambda v, f, o, rng: _fragment(v, f, o, rng, flipped=True),
    "pinch": _pinch,
}


def parse_defects(text: str) -> tuple[str, ...]:
    """Defect names from a comma-separated list; one-line :class:`InputError` for unknown ones."""
    names = tuple(t.strip() for t in text.split(",") if t.strip())
    unknown = [n for n in names if n not in DEFECTS]
    if not names or unknown:
        raise InputError(f"unknown defect {unknown[0] if unknown else text!r}; choose from {', '.join(DEFECTS)}")
    return names


def defective_mesh(vertices: np.ndarray, faces: np.ndarray, defects, seed: int = 0):
    """(vertices, faces, origin) of a mesh with ``defects`` (names of :data:`DEFECTS`, in order);
    ``origin`` (V',) is, per new vertex, the input vertex whose ground truth it takes, or -1.
    """
    rng = np.random.default_rng([int(seed), 4848])
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    origin = np.arange(v.shape[0])
    for name in defects:
        v, f, origin = _APPLY[name](v, f, origin, rng)
    return v, f, origin


def add_defects(pair, defects, seed: int | None = None):
    """The pair with its target given ``defects`` (names of :data:`DEFECTS`) and its ground truth kept
    for the target's own vertices (module docstring). ``seed`` defaults to the pair's ``info["seed"]``.
    """
    names = tuple(defects)
    unknown = [n for n in names if n not in DEFECTS]
    if unknown:
        raise InputError(f"unknown defect {unknown[0]!r}; choose from {', '.join(DEFECTS)}")
    seed = int(pair.info.get("seed", 0)) if seed is None else int(seed)
    t = pair.target
    v, f, origin = defective_mesh(t.vertices, t.faces, names, seed)
    gt = pair.ground_truth
    row = np.full(t.n_vertices, -1, np.int64)
    row[gt.target_index] = np.arange(gt.target_index.size)
    kept = np.flatnonzero(origin >= 0)
    kept = kept[row[origin[kept]] >= 0]
    truth = GroundTruth(
        face=gt.face[row[origin[kept]]],
        bary=gt.bary[row[origin[kept]]],
        target_index=kept,
        n_target=v.shape[0],
        name=gt.name,
    )
    target = Mesh(vertices=v, faces=f, name=t.name, file_index=np.arange(v.shape[0]))
    info = dict(pair.info, defects=list(names), n_target=int(v.shape[0]))
    name = f"{pair.name}+{'+'.join(names)}"
    return dataclasses.replace(pair, name=name, target=target, ground_truth=truth, info=info)
