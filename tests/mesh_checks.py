"""Brute-force checks of a mesh's topology (Python loops over faces): the oracles of the intake step's
guarantees (ncflow.geometry.repair), shared by the tests."""

from collections import defaultdict

import numpy as np


def brute_edge_faces(faces):
    """{undirected edge: faces on it}, by a Python loop."""
    out = defaultdict(list)
    for i, (a, b, c) in enumerate(np.asarray(faces).tolist()):
        for p, q in ((a, b), (b, c), (c, a)):
            out[(min(p, q), max(p, q))].append(i)
    return out


def brute_fans(faces, vertex, edges=None):
    """The number of fans of faces around ``vertex``: groups of its faces joined through edges of exactly
    two faces."""
    edges = brute_edge_faces(faces) if edges is None else edges
    around = [i for i, f in enumerate(np.asarray(faces).tolist()) if vertex in f]
    parent = {i: i for i in around}

    def find(i):
        while parent[i] != i:
            i = parent[i]
        return i

    for (p, q), fs in edges.items():
        if vertex in (p, q) and len(fs) == 2:
            parent[find(fs[0])] = find(fs[1])
    return len({find(i) for i in around})


def check_repaired(vertices, faces) -> str | None:
    """What breaks the guarantees of the intake step in a mesh (None when nothing): a face out of range
    or with a repeated corner, an edge in more than two faces, a vertex of several fans, a vertex in no
    face."""
    f = np.asarray(faces, np.int64)
    nv = np.asarray(vertices).shape[0]
    if f.size and (f.min() < 0 or f.max() >= nv):
        return "face index out of range"
    if any(len(set(face)) < 3 for face in f.tolist()):
        return "a face with a repeated corner"
    edges = brute_edge_faces(f)
    most = max((len(fs) for fs in edges.values()), default=0)
    if most > 2:
        return f"an edge in {most} faces"
    corners = defaultdict(set)
    for face in f.tolist():
        for v in face:
            corners[v].add(tuple(face))
    several = sum(brute_fans(f, v, edges) > 1 for v in corners)
    if several:
        return f"{several} vertices of several fans"
    unused = nv - len(corners)
    if unused:
        return f"{unused} vertices in no face"
    return None
