"""Skin islands: the bones a surface point may not take because its skin is cut off from their limb.

The weights that see the skin (:func:`ncflow.flow.bone_weights.surface_skinning_weights`) leave out a bone in
front of a point's skin. A captured fist's fingertip sunk into the palm has its bone *behind* the palm's
skin, nearer than the palm's own bone, where that test cannot tell; along the surface, though, the palm's
skin is cut off from the fingertip's limb. :func:`skin_islands` finds such pieces on a mesh and
:func:`surface_skin` hands them to the field as extra columns of the start normals
(:class:`ncflow.flow.SkinnedField` with ``weight_mode="surface"`` reads them). Pure NumPy and a graph's
connected components: a per-mesh precomputation, written here because no library assigns skin to bones by
connectivity.
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Bool, Float, Int

from ncflow.geometry.laplacian import lumped_mass
from ncflow.geometry.mesh import outward_vertex_normals
from ncflow.geometry.skeleton import shared_joints
from ncflow.geometry.topology import vertex_components

_CHUNK = 65536
"""Vertices per block of :func:`skin_islands`' (V, B) products (bounded memory on large meshes)."""


def skin_islands(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    normals: Float[np.ndarray, "V 3"],
    heads: Float[np.ndarray, "B 3"],
    tails: Float[np.ndarray, "B 3"],
    adjacent: Bool[np.ndarray, "B B"],
    max_rounds: int = 8,
) -> Bool[np.ndarray, "V B"]:
    """Bones each vertex may not take in :func:`~ncflow.flow.bone_weights.surface_skinning_weights`: those
    whose skin would be an island, cut off from the body along the surface.

    A vertex's bone is the nearest one not in front of its skin. Kept are the mesh edges whose two
    vertices have the same bone or ``adjacent`` ones (bones that share a joint); the skin of a body
    is then one connected piece from the root's bones out to every tip, and a patch in another piece is
    skin given to a limb that lies *behind* it without covering it: a captured fist's fingertip sunk
    into the palm (its bone inside the palm, under the palm's skin, where the front test cannot see
    it), a thumb pressed into a finger. Each such patch loses its bone, and the bones are chosen again,
    until every vertex's bone is in the largest piece (by area) or ``max_rounds`` is reached. Pure
    NumPy and a SciPy graph: a per-mesh precomputation, done once, in float64 with a rounding tolerance
    on the front test (the field's float32 test, ``> 0``, would make the exclusions depend on units and
    placement where a joint lies on the skin).
    """
    v, f = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    n, a, b = (np.asarray(z, np.float64) for z in (normals, heads, tails))
    ab = b - a
    ab2 = np.maximum(np.sum(ab * ab, 1), 1e-300)
    dist = np.empty((len(v), len(a)))
    tol = 1e-6 * float(np.ptp(v, axis=0).max(initial=0.0))  # a joint on the skin (to rounding) is not in front
    for lo in range(0, len(v), _CHUNK):  # (V, B) products only, a chunk of vertices at a time
        x, nx = v[lo : lo + _CHUNK], n[lo : lo + _CHUNK]
        ap_ab = x @ ab.T - np.sum(a * ab, 1)  # (x − a)·(b − a)
        u = np.clip(ap_ab / ab2, 0.0, 1.0)
        d2 = np.sum(x * x, 1)[:, None] - 2.0 * x @ a.T + np.sum(a * a, 1) - 2.0 * u * ap_ab + u * u * ab2
        front = nx @ a.T + u * (nx @ ab.T) - np.sum(x * nx, 1)[:, None] > tol  # (nearest point − x)·n
        dist[lo : lo + _CHUNK] = np.where(front, np.inf, np.sqrt(np.maximum(d2, 0.0)))
    excluded = np.zeros(dist.shape, bool)
    if f.shape[0] == 0 or dist.shape[1] < 2:
        return excluded
    area = lumped_mass(v, f)
    for _ in range(max_rounds):
        d = np.where(excluded, np.inf, dist)
        bone = np.where(np.isfinite(d).any(1), d.argmin(1), -1)
        one, other = bone[f], bone[f[:, [1, 2, 0]]]  # (F, 3) the bones at each face edge's two ends
        joined = (one >= 0) & (other >= 0) & adjacent[np.maximum(one, 0), np.maximum(other, 0)]
        label = vertex_components(f, len(v), joined)
        size = np.bincount(label, weights=area)
        island = (label != size.argmax()) & (bone >= 0)
        if not island.any():
            break
        excluded[np.nonzero(island)[0], bone[island]] = True
    return excluded


def surface_skin(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    positions: Float[np.ndarray, "J 3"],
    parents: Int[np.ndarray, " J"],
) -> Float[np.ndarray, "V C"]:
    """What a :class:`~ncflow.flow.SkinnedField` with ``weight_mode="surface"`` reads as a mesh's start
    normals, C = 3 + B: the outward vertex normals, then one column per bone (parents[j] → j, j = 1..J−1,
    the order of :attr:`ncflow.skeleton.Skeleton.bones`) of the skeleton at ``positions`` (the mesh's
    coordinates), 1 where :func:`skin_islands` leaves the bone out (bones that share a joint are adjacent).
    """
    v, f = np.asarray(vertices, np.float64), np.asarray(faces)
    pos, par = np.asarray(positions, np.float64), np.asarray(parents, np.int64)
    normals = outward_vertex_normals(v, f)
    islands = skin_islands(v, f, normals, pos[par[1:]], pos[1:], shared_joints(par))
    return np.concatenate([normals, islands.astype(np.float64)], axis=1)
