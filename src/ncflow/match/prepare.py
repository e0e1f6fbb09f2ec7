"""Inputs → the normalised problem the matcher trains on (DESIGN.md "Pipeline", first steps).

Loads and checks the meshes and the skeleton, fits the one similarity that normalises source,
target and skeleton (same identity, same scale), places the target rigidly on the source
(:mod:`ncflow.match.placement`), builds the topology tables and draws the
soft-tissue centroids (fTetWild once per source, cached: :func:`ncflow.tissue.tissue_centroids`).
"""

from __future__ import annotations

import dataclasses
import time

import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from ncflow.errors import InputError
from ncflow.geometry.mesh import Mesh
from ncflow.geometry.normalize import Normalization, fit_normalization
from ncflow.geometry.topology import Topology, mesh_topology
from ncflow.io.meshes import load_mesh
from ncflow.match.placement import Placement, place_target
from ncflow.skeleton import Skeleton, check_inside, load_skeleton
from ncflow.tissue import tissue_centroids

DTYPE = jnp.float32  # training dtype (DESIGN.md: float32 for training)


@dataclasses.dataclass(frozen=True)
class Problem:
    """One matching problem in normalised coordinates.

    Attributes:
        source, target, skeleton: the inputs as given (user coordinates).
        normalization: the similarity applied to all three.
        source_vertices: (V, 3) normalised source vertices (float64).
        target_vertices: (W, 3) normalised target vertices, placed on the source (float64).
        placement: the rigid motion that placed them (:mod:`ncflow.match.placement`).
        skeleton_normalized: the skeleton in normalised coordinates.
        source_topology, target_topology: edge tables of both meshes.
        bone_radii: (B,) bone-sample radius factor per bone.
        centroids: (K, 3) soft-tissue tet centroids of the normalised source ((0, 3) when disabled).
        tissue_info: how the centroids were obtained (cache hit, counts, seconds).
        warnings: joints slightly outside the source surface.
        tissue_seconds: wall time of obtaining the centroids.
    """

    source: Mesh
    target: Mesh
    skeleton: Skeleton
    normalization: Normalization
    source_vertices: Float[np.ndarray, "V 3"]
    target_vertices: Float[np.ndarray, "W 3"]
    placement: Placement
    skeleton_normalized: Skeleton
    source_topology: Topology
    target_topology: Topology
    bone_radii: Float[np.ndarray, " B"]
    centroids: Float[np.ndarray, "K 3"]
    tissue_info: dict
    warnings: tuple[str, ...]
    tissue_seconds: float = 0.0
    placement_seconds: float = 0.0


def load_inputs(source, target, skeleton) -> tuple[Mesh, Mesh, Skeleton]:
    """Meshes and skeleton from objects or file paths (validated at the file boundary)."""
    src = source if isinstance(source, Mesh) else load_mesh(source)
    tgt = target if isinstance(target, Mesh) else load_mesh(target)
    skel = skeleton if isinstance(skeleton, Skeleton) else load_skeleton(skeleton)
    return src, tgt, skel


def check_skeleton_placement(skel: Skeleton, src: Mesh) -> list[str]:
    """Warnings for joints slightly outside; an :class:`InputError` for joints far outside the source."""
    far = check_inside(skel, src.vertices, src.faces, surface_tol=0.15, far=0.15)
    if far:
        raise InputError(
            f"skeleton does not fit the source mesh {src.name or ''}: {far[0]}"
            + (f" (and {len(far) - 1} more)" if len(far) > 1 else "")
            + "; is it in the same coordinates as the source?",
            skel.name,
        )
    return check_inside(skel, src.vertices, src.faces)


def prepare(source, target, skeleton, config, message=lambda text: None) -> Problem:
    """Load, check and normalise the inputs; tissue centroids when the tissue term is on.

    Args:
        source: the source mesh or its file.
        target: the target mesh or its file.
        skeleton: the source's skeleton or its file.
        config: a validated :class:`ncflow.config.Config`.
        message: called with one-line progress notes (warnings, tetrahedralisation).
    """
    src, tgt, skel = load_inputs(source, target, skeleton)
    warnings = check_skeleton_placement(skel, src)
    for w in warnings:
        message(f"warning: {w}")
    norm = fit_normalization(src.vertices, src.faces)
    src_v = norm.apply(src.vertices)
    skel_n = skel.with_positions(norm.apply(skel.positions))
    tgt_v = norm.apply(tgt.vertices)
    t_place = time.perf_counter()
    if config.placement == "auto":
        message("placing the target on the source ...")
        placement = place_target(src_v, src.faces, tgt_v, tgt.faces, seed=config.seed)
        tgt_v = placement.apply(tgt_v)
    else:
        placement = Placement.identity()
    t_place = time.perf_counter() - t_place
    t0 = time.perf_counter()
    if config.sampling.tissue_samples > 0 and config.weights.tissue > 0:
        message("tetrahedralising the source for soft-tissue samples ...")
        centroids, tissue_info = tissue_centroids(src_v, src.faces, config.tissue)
    else:
        centroids, tissue_info = np.zeros((0, 3)), {"disabled": True}
    return Problem(
        source=src,
        target=tgt,
        skeleton=skel,
        normalization=norm,
        source_vertices=src_v,
        target_vertices=tgt_v,
        placement=placement,
        skeleton_normalized=skel_n,
        source_topology=mesh_topology(src.faces, src.n_vertices, name=src.name),
        target_topology=mesh_topology(tgt.faces, tgt.n_vertices, name=tgt.name),
        bone_radii=skel_n.bone_radii(config.sampling.bone_radius),
        centroids=centroids,
        tissue_info=tissue_info,
        warnings=tuple(warnings),
        tissue_seconds=time.perf_counter() - t0,
        placement_seconds=t_place,
    )
