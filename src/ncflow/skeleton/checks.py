"""Placement checks of a skeleton against its mesh: joints that are not inside the surface.

:func:`check_inside` returns one warning line per joint outside the surface (generalised winding
number below ½) and farther from it than a tolerance relative to the mesh size, so joints placed
on the surface, as fingertip joints often are, pass. It works for open meshes too (a hand open at
the wrist), where it still tells inside from outside away from the holes. ``ncflow skeleton info``
prints these warnings, and the matcher refuses a skeleton whose joints lie far outside the source
(usually a skeleton in other coordinates than its mesh).
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Float, Int

from ncflow.geometry.skeleton import Skeleton
from ncflow.geometry.topology import mesh_topology
from ncflow.geometry.winding import winding_numbers


def _surface_distance(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    import trimesh

    dist = np.empty(points.shape[0])
    for k, p in enumerate(points):
        cp = trimesh.triangles.closest_point(triangles, np.broadcast_to(p, (triangles.shape[0], 3)))
        dist[k] = float(np.min(np.linalg.norm(cp - p, axis=1)))
    return dist


DEFAULT_TOLERANCES = (0.005, 0.05)
"""(surface_tol, far) of :func:`check_inside`."""


def check_inside(
    skeleton: Skeleton,
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    *,
    surface_tol: float = DEFAULT_TOLERANCES[0],
    far: float = DEFAULT_TOLERANCES[1],
) -> list[str]:
    """Warnings (one line each) for joints that are not where a skeleton inside the mesh should be.

    A joint counts as outside when its generalised winding number w.r.t. the surface is below ½
    (for closed meshes the same answer as trimesh's ``contains``, without its rtree dependency;
    for open meshes, such as a hand open at the wrist, it still tells inside from outside away
    from the holes). Closed meshes: an outside joint farther than ``surface_tol`` × (bounding-box
    diagonal) from the surface is reported (joints placed on the surface, as fingertip joints
    often are, pass). Open meshes: an outside joint is reported when it is farther than
    ``far`` × diagonal from the surface.
    """
    return check_inside_at(skeleton, vertices, faces, [(surface_tol, far)])[0]


def check_inside_at(
    skeleton: Skeleton,
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    tolerances: list[tuple[float, float]],
) -> list[list[str]]:
    """:func:`check_inside` at several (surface_tol, far) pairs, the joints' winding numbers and
    distances to the surface measured once (the costly part: every joint against every triangle).
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    tri = vertices[faces]
    diag = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    closed = not mesh_topology(faces, vertices.shape[0]).has_boundary
    pts = skeleton.positions
    outside = np.abs(winding_numbers(pts, tri)) < 0.5
    dist = _surface_distance(pts, tri)
    where = "the mesh" if closed else "the (open) mesh"
    return [
        [
            f"{skeleton.label(int(j))} is outside {where} (distance {dist[j]:.4g}, "
            f"{100 * dist[j] / diag:.1f}% of the mesh size)"
            for j in np.flatnonzero(outside & (dist > (surface_tol if closed else far) * diag))
        ]
        for surface_tol, far in tolerances
    ]
