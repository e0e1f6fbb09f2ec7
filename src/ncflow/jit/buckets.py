"""Size buckets: arrays padded to a few sizes so that inputs of similar size share compiled
programs.

A compiled program is specific to the shapes of its arrays. The arrays whose size varies from one
input to the next — the working source's vertices, edges and faces, the tissue centroids, the
points a trained flow moves — are padded to :func:`bucket` sizes, with rows that represent nothing
(:func:`ncflow.geometry.topology.pad_topology`: degenerate edges and faces, of zero length and
area) or that random draws step around (:func:`draw_rows`). The cached executables of
:mod:`ncflow.jit.cache` then serve every input whose sizes fall in the same buckets.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int, PRNGKeyArray, PyTree

from ncflow.geometry.topology import Topology, pad_topology

MESH_PER_OCTAVE = 8
"""Size buckets per doubling for the arrays of a mesh (vertices, edges, faces, measures, flowed
points): at most 12.5 % of padding."""


def bucket(n: int, per_octave: int = 4, smallest: int = 8) -> int:
    """The size an array of ``n`` rows is padded to so that similar sizes share compiled programs:
    the smallest multiple of 2^⌊log2 n⌋ / ``per_octave`` that is ≥ n (``per_octave`` sizes per
    doubling, at most 1/``per_octave`` of padding; 1: the next power of two), at least ``smallest``.
    """
    n = max(int(n), int(smallest), 1)
    step = max((1 << (n.bit_length() - 1)) // int(per_octave), 1)
    return -(-n // step) * step


def draw_rows(key: PRNGKeyArray, size: int, n: int, valid: Bool[Array, " size"] | None = None) -> Int[Array, " m"]:
    """Indices of ``n`` of ``size`` rows drawn uniformly without replacement (a random permutation's
    prefix; all rows in random order when ``n`` ≥ ``size``: m = min(n, size)). ``valid`` marks the
    real rows of an array padded to a bucket: the draw is the first real rows of the same
    permutation, so with every row real it equals the draw without ``valid``; rows past the real
    ones are padding (drawn last). Jit-compatible (``size`` and ``n`` static).
    """
    perm = jax.random.permutation(key, size)
    if valid is not None:
        perm = perm[jnp.argsort(~jnp.asarray(valid)[perm], stable=True)]  # real rows first, order kept
    return perm[: min(int(n), size)]


def pad_rows(tree: PyTree, size: int) -> PyTree:
    """Every array leaf of ``tree`` (a measure: centres, normals, weights, all of N rows) with zero
    rows appended up to ``size`` rows; a weighted measure's zero-weight rows add nothing to any
    kernel sum, so its inner products are unchanged.
    """

    def pad(a):
        extra = size - a.shape[0]
        if extra < 0:
            raise ValueError(f"pad_rows pads; {a.shape[0]} rows do not fit in {size}")
        return jnp.concatenate([a, jnp.zeros((extra, *a.shape[1:]), a.dtype)]) if extra else a

    return jax.tree_util.tree_map(pad, tree)


def pad_points(points: Float[ArrayLike, "N C"]) -> Float[Array, "M C"]:
    """Rows (N, C): points or their normals, with copies of the first appended up to their size bucket (M =
    :func:`bucket` (N, :data:`MESH_PER_OCTAVE`); N = 0 stays empty): the rows a flow moves each on
    its own, so the copies change no real row and point sets of similar size share compiled programs.
    """
    points = jnp.asarray(points)
    n = points.shape[0]
    size = bucket(n, per_octave=MESH_PER_OCTAVE) if n else 0
    if size == n:
        return points
    return jnp.concatenate([points, jnp.broadcast_to(points[:1], (size - n, points.shape[1]))])


def pad_mesh(vertices: Float[ArrayLike, "V 3"], topology: Topology) -> tuple[Float[Array, "W 3"], Topology]:
    """A mesh padded to its size buckets (:data:`MESH_PER_OCTAVE` per doubling): the vertices by
    :func:`pad_points`, the faces, edges and boundary vertices by
    :func:`~ncflow.geometry.topology.pad_topology` (rows of zero weight in every measure, so the
    padded mesh's Varifold and Normal Cycle are the mesh's). The real rows come first in each table.
    """

    def grow(n):
        return bucket(n, per_octave=MESH_PER_OCTAVE)

    n_boundary = grow(topology.boundary_vertices.size) if topology.has_boundary else 0
    padded = pad_topology(topology, grow(topology.faces.shape[0]), grow(topology.n_edges), n_boundary)
    return pad_points(vertices), padded
