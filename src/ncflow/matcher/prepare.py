"""Step 1 of a match: inputs → the normalised problem (DESIGN.md "Pipeline", first steps).

Loads and checks the meshes and the skeleton, repairs the meshes for the match (the intake step,
:func:`ncflow.matcher.inputs.intake`), fits the one similarity that normalises source, target and
skeleton (same identity, same scale), makes the working-resolution copy of the source, builds the
topology tables, draws the soft-tissue centroids (fTetWild once per source, cached:
:func:`ncflow.tissue.tissue_centroids`) and chooses where the skeleton-driven field takes its bone
weights. The result, a :class:`Setup`, is everything the compiled programs depend on
(:mod:`ncflow.matcher.programs`); the target is placed by the next step (:mod:`ncflow.matcher.place`).
"""

from __future__ import annotations

import dataclasses
import time

import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from ncflow.flow.bone_weights import core_clearance, skin_contact
from ncflow.geometry.cloud import PointCloud
from ncflow.geometry.decimate import Decimation, decimate
from ncflow.geometry.laplacian import lumped_mass
from ncflow.geometry.mesh import Mesh, face_edge_lengths, outward_vertex_normals
from ncflow.geometry.normalize import Normalization, fit_normalization
from ncflow.geometry.overlap import self_overlap
from ncflow.geometry.repair import Repair
from ncflow.geometry.topology import Topology, mesh_topology
from ncflow.matcher.inputs import (
    check_meshes,
    check_skeleton_placement,
    cloud_surface,
    cloud_warning,
    intake,
    load_inputs,
)
from ncflow.skeleton import Skeleton
from ncflow.skeleton.checks import (
    bones_partly_outside,
    clear_axial_ranges,
    clear_joint_ranges,
    flesh_radius,
    inside_axial_ranges,
)
from ncflow.skeleton.suggest import BASES, suggest_skeletons
from ncflow.tissue import centroids_digest, load_tissue_file, tissue_centroids

DTYPE = jnp.float32  # training dtype (DESIGN.md: float32 for training)


@dataclasses.dataclass(frozen=True)
class Setup:
    """One matching problem in normalised coordinates, before the target is placed.

    Attributes:
        source, target, skeleton: the inputs as given (user coordinates).
        normalization: the similarity applied to all three.
        source_vertices: (V, 3) normalised source vertices (float64), full resolution, every vertex of
            the source as given (the outputs have a row for each).
        working: the normalised source the training runs on (:func:`working_source`): the source after
            the intake step, or a decimated copy made of its vertices when it has more than
            ``working_vertices`` vertices.
        target_vertices: (W, 3) normalised vertices of the target after the intake step, as given
            (not placed): the mesh the data terms see.
        target_faces: (G, 3) its faces, wound as the source's
            (:func:`~ncflow.matcher.inputs.target_faces_like_source`).
        target_points: (Vt, 3) every vertex of the target as given, normalised (not placed): the
            points the correspondence maps.
        source_repair, target_repair: the intake step's repairs (:func:`~ncflow.matcher.inputs.intake`),
            with the maps from the repaired meshes back to the given ones.
        skeleton_normalized: the skeleton in normalised coordinates.
        source_topology: edge table of the working source.
        target_topology: edge table of the target (``target_faces``).
        bone_radii: (B,) bone-sample radius factor per bone (:func:`bone_radii`).
        bone_ranges: (B, 2) the part of each bone (z / L) its samples and rigid core cover: the part of
            its axis inside the working source (:func:`ncflow.skeleton.checks.inside_axial_ranges`) and,
            with the rigid cores, clear of other bones' samples
            (:func:`ncflow.skeleton.checks.clear_axial_ranges`).
        bone_inside: (B,) the share of each bone's axis inside the working source.
        centroids: (K, 3) soft-tissue tet centroids of the normalised source ((0, 3) when disabled).
        tissue_info: how the centroids were obtained (cache hit, counts, seconds).
        tissue_seconds: wall time of obtaining the centroids.
        warnings: what the intake step, :func:`~ncflow.matcher.inputs.check_meshes` and
            :func:`~ncflow.matcher.inputs.check_skeleton_placement` found (polygons
            split, meshes repaired, a mesh far from the origin, a target of somewhat another size or
            wound the other way, joints slightly outside the source surface).
        skinning_weights: the skeleton-driven field's weight mode and why (:func:`skinning_weight_mode`).
        skeleton_suggested: what :func:`suggested_skeleton` says of a skeleton suggested because none was
            given, or None.
        target_cloud: for a point-cloud target (``target`` then holds its points and no faces), what
            :func:`~ncflow.matcher.inputs.cloud_surface` did to make the surface the match sees; else None.
        alternatives: the same problem with each other suggested skeleton (:func:`suggested_skeletons`: its
            limbs' base joints put another way) when none was given and ``skeleton_bases`` is "choose";
            the pose search chooses (:func:`ncflow.matcher.place.place_suggested`).
    """

    source: Mesh
    target: Mesh
    skeleton: Skeleton
    normalization: Normalization
    source_vertices: Float[np.ndarray, "V 3"]
    working: Decimation
    target_vertices: Float[np.ndarray, "W 3"]
    target_faces: np.ndarray
    target_points: Float[np.ndarray, "Vt 3"]
    source_repair: Repair
    target_repair: Repair
    skeleton_normalized: Skeleton
    source_topology: Topology
    target_topology: Topology
    bone_radii: Float[np.ndarray, " B"]
    bone_ranges: Float[np.ndarray, "B 2"]
    bone_inside: Float[np.ndarray, " B"]
    centroids: Float[np.ndarray, "K 3"]
    tissue_info: dict
    tissue_seconds: float
    warnings: tuple[str, ...]
    skinning_weights: dict
    skeleton_suggested: dict | None = None
    target_cloud: dict | None = None
    alternatives: tuple[Setup, ...] = ()

    @property
    def working_edge(self) -> float:
        """The median length of the working source's face edges (normalised units; each interior edge
        counted from both faces): what a ``metric = "auto"`` phase compares its σ with
        (:func:`ncflow.matcher.stages.stage_metric`).
        """
        lengths = face_edge_lengths(self.working.vertices, self.working.faces)
        return float(np.median(lengths)) if lengths.size else 0.0


def bone_radii(config, skeleton: Skeleton, flesh: Float[np.ndarray, " B"]) -> Float[np.ndarray, " B"]:
    """(B,) the bone samples' radius factors ρ_b: the skeleton's own or ``sampling.bone_radius``; with the
    skeleton-driven field's rigid cores (ramp ``flow.rigid_core``), no more than
    flesh_b / ((1 + ramp) L_b), so that the core around the samples and its ramp end inside the bone's
    flesh (``flesh``: :func:`ncflow.skeleton.checks.flesh_radius`) and the skin keeps the whole Flow-Net:
    a thin limb's samples lie closer to its axis.
    """
    radii = skeleton.bone_radii(config.sampling.bone_radius)
    ramp = config.flow.rigid_core
    if config.flow.skinning and ramp > 0:
        return np.minimum(radii, np.asarray(flesh) / ((1.0 + ramp) * np.asarray(skeleton.bone_lengths)))
    return radii


def suggested_skeleton(src, message=lambda text: None, others=(), bases: str = "auto") -> tuple[Skeleton, dict]:
    """A skeleton suggested for the repaired source, its limbs' base joints put as ``bases`` says
    (:func:`suggested_skeletons`).
    """
    return suggested_skeletons(src, message, others, bases=(bases,))[0]


def suggested_skeletons(src, message=lambda text: None, others=(), bases=BASES) -> list[tuple[Skeleton, dict]]:
    """Skeletons suggested for the repaired source, one per ``bases``
    (:func:`ncflow.skeleton.suggest.suggest_skeletons`; the repaired target or frames ``others``, meshes
    of the same body in other poses, show where the source's limbs bend), each with what ``metrics.json``
    says of it (``n_joints``, ``n_leaves``, ``moved_inside``, ``bends_seen``, ``bases``, ``seconds``).
    """
    message("no skeleton given: suggesting one from the source ...")
    t0 = time.perf_counter()
    poses = [(m.vertices, m.faces) for m in others if m.faces.shape[0] >= 20]
    name = f"{src.name or 'source'} (suggested)"
    found = suggest_skeletons(src.vertices, src.faces, name=name, other_poses=poses, bases=bases)
    seconds = time.perf_counter() - t0
    return [
        (
            f.skeleton,
            {
                "n_joints": f.skeleton.n_joints,
                "n_leaves": f.n_leaves,
                "moved_inside": f.moved_inside,
                "bends_seen": f.bends_seen,
                "bases": f.bases,
                "seconds": seconds,
                "file": "skeleton_source.tgf",
            },
        )
        for f in found
    ]


def skinning_width(config, skeleton: Skeleton) -> float:
    """τ of the skeleton-driven field's bone weights: ``flow.skinning_width`` × the median bone length."""
    return config.flow.skinning_width * float(np.median(skeleton.bone_lengths))


def uses_tissue(config) -> bool:
    """Whether the configuration trains with the soft-tissue term (samples and weight both on)."""
    return config.sampling.tissue_samples > 0 and config.weights.tissue > 0


def working_source(src: Mesh, config, message=lambda text: None) -> tuple[Normalization, Decimation]:
    """The source's normalisation and the normalised working copy the training runs on
    (:func:`~ncflow.geometry.decimate.decimate` to ``working_vertices``; the source itself when it is
    not larger). ``src``: the source after the intake step (:func:`~ncflow.matcher.inputs.intake`).
    """
    norm = fit_normalization(src.vertices, src.faces)
    if config.working_vertices is not None and src.n_vertices > config.working_vertices:
        message(f"decimating the source to about {config.working_vertices} vertices for training ...")
    return norm, decimate(norm.apply(src.vertices), src.faces, config.working_vertices or src.n_vertices)


def source_tissue(work: Decimation, config, message=lambda text: None) -> tuple[np.ndarray, dict]:
    """(K, 3) soft-tissue centroids of the working source and how they were obtained: none when the
    tissue term is off, the exact tissue of ``tissue.file`` when one is given, else
    :func:`~ncflow.tissue.tissue_centroids` (cached).
    """
    if not uses_tissue(config):
        return np.zeros((0, 3)), {"disabled": True}
    if config.tissue.file:
        c = load_tissue_file(config.tissue.file, work.vertices)
        return c, {"file": config.tissue.file, "n_centroids": int(c.shape[0]), "sha256": centroids_digest(c)}
    message("tetrahedralising the source for soft-tissue samples ...")
    return tissue_centroids(work.vertices, work.faces, config.tissue)


def prepare(source, target, skeleton, config, message=lambda text: None) -> Setup:
    """Load, repair, check and normalise the inputs; the working source, its tissue centroids (when the
    tissue term is on), the edge tables and the bone-weight mode.

    Args:
        source: the source mesh or its file.
        target: the target mesh or its file.
        skeleton: the source's skeleton or its file.
        config: a validated :class:`ncflow.config.Config`.
        message: called with one-line progress notes (warnings, tetrahedralisation).
    """
    src, tgt, skel = load_inputs(source, target, skeleton)
    cloud = None
    if isinstance(tgt, PointCloud):
        surface, cloud = cloud_surface(tgt)
        message(f"note: {cloud_warning(tgt, cloud)}")
        tgt = Mesh(tgt.points, np.zeros((0, 3), np.int64), name=tgt.name)
    else:
        surface = tgt
    (src_c, src_r, src_note), (tgt_c, tgt_r, tgt_note) = (
        intake(src, "source", config),
        intake(surface, "target", config),
    )
    tgt_f, mesh_warnings = check_meshes(src_c, tgt_c)
    bases = BASES[:2] if config.skeleton_bases == "choose" else (config.skeleton_bases,)
    found = [(skel, None)] if skel is not None else suggested_skeletons(src_c, message, [tgt_c], bases)
    warned = []
    for skel, suggested in found:
        warnings = src_note + tgt_note + mesh_warnings + check_skeleton_placement(skel, src_c)
        if suggested is not None:
            warnings.insert(
                0,
                f"no skeleton given: one was suggested from the source ({suggested['n_joints']} joints, "
                f"{suggested['n_leaves']} limb tips; ncflow skeleton suggest), written as skeleton_source.tgf",
            )
        warned.append(warnings)
    for w in warned[0]:  # an alternative's notes are said if it is chosen (its Setup keeps them)
        message(f"warning: {w}")
    norm, work = working_source(src_c, config, message)
    t0 = time.perf_counter()
    centroids, tissue_info = source_tissue(work, config, message)
    tissue_seconds = time.perf_counter() - t0
    source_topology = mesh_topology(work.faces, work.vertices.shape[0], name=src.name)
    target_topology = mesh_topology(tgt_f, tgt_c.n_vertices, name=tgt.name)
    setups = []
    for k, ((skel, suggested), warnings) in enumerate(zip(found, warned, strict=True)):
        shown = message if k == 0 else (lambda text: None)
        skel_n = skel.with_positions(norm.apply(skel.positions))
        ranges, inside = inside_axial_ranges(skel_n, work.vertices, work.faces)
        weights = skinning_weight_mode(config, work.vertices, work.faces, tgt_c.vertices, tgt_f, skel_n, ranges)
        radii = bone_radii(config, skel_n, flesh_radius(skel_n, work.vertices))
        if config.flow.skinning and config.flow.rigid_core > 0:  # samples and cores where no other bone's are
            ranges = clear_axial_ranges(skel_n, ranges, radii)
            if config.flow.clear_joints:
                ranges = clear_joint_ranges(skel_n, ranges, radii, core_clearance(config.flow.rigid_core), inside > 0)
        warnings.extend(bones_partly_outside(skel, inside))
        if weights["mode"] == "surface" and config.flow.skinning_weights == "auto":
            shown(
                f"the source's limbs touch ({weights['source_contact']:.1%} of its area lies nearer another "
                "limb's bone than its own): bone weights taken at each point's start, from the bones under its skin"
            )
        if weights["mode"] == "start" and config.flow.skinning_weights == "auto":
            shown(
                f"the target passes through itself ({weights['target_overlap']:.1%} of its area, the source "
                f"{weights['source_overlap']:.1%}): bone weights taken at each point's start"
            )
        setups.append(
            Setup(
                source=src,
                target=tgt,
                skeleton=skel,
                normalization=norm,
                source_vertices=norm.apply(src.vertices),
                working=work,
                target_vertices=norm.apply(tgt_c.vertices),
                target_faces=tgt_f,
                target_points=norm.apply(tgt.vertices),
                source_repair=src_r,
                target_repair=tgt_r,
                skeleton_normalized=skel_n,
                source_topology=source_topology,
                target_topology=target_topology,
                bone_radii=radii,
                bone_ranges=ranges,
                bone_inside=inside,
                centroids=centroids,
                tissue_info=tissue_info,
                tissue_seconds=tissue_seconds,
                warnings=tuple(warnings),
                skinning_weights=weights,
                skeleton_suggested=suggested,
                target_cloud=cloud,
            )
        )
    return dataclasses.replace(setups[0], alternatives=tuple(setups[1:]))


def with_joints(setup: Setup, n_joints: int) -> Setup:
    """Of ``setup`` and its :attr:`Setup.alternatives`, the first whose skeleton has ``n_joints`` joints
    (an earlier result's, to start from), without alternatives; ``setup`` when none has.
    """
    for s in (setup, *setup.alternatives):
        if s.skeleton.n_joints == n_joints:
            return dataclasses.replace(s, alternatives=())
    return setup


AUTO_OVERLAP = 0.005
"""``flow.skinning_weights = "auto"`` takes the weights at the start when the target's self-overlap
exceeds the source's by more than this share of the area."""


def skinning_weight_mode(
    config,
    source_vertices,
    source_faces,
    target_vertices,
    target_faces,
    skeleton: Skeleton | None = None,
    ranges: Float[np.ndarray, "B 2"] | None = None,
) -> dict:
    """Where the skeleton-driven field takes its bone weights (:class:`ncflow.flow.SkinnedField`).

    ``flow.skinning_weights`` "current", "start" or "surface" is used as it is. With "auto" (the
    default):

    * "surface" when the source's limbs touch: more than :data:`AUTO_CONTACT` of its area has its
      nearest bone of ``skeleton`` (in the source's coordinates) in front of its skin, a bone
      :data:`CONTACT_HOPS` or more joints away from the one under it (a fist's palm under its
      fingertips; :func:`ncflow.flow.bone_weights.skin_contact`, on the bones' parts inside the source,
      ``ranges`` of :func:`~ncflow.skeleton.checks.inside_axial_ranges`, found when not given). The
      plain weights would give that skin to the touching limb.
    * else "start" when the target passes through itself (:func:`ncflow.geometry.overlap.self_overlap`)
      over more than :data:`AUTO_OVERLAP` more of its area than the source does: a flow of space
      cannot make a surface pass through itself, so such a target (the fingertips of a captured or
      rigged fist sunk into the palm) needs the weights of the start;
    * otherwise "current", the diffeomorphic flow.

    Returns ``{"setting", "mode", "source_contact", "source_overlap", "target_overlap"}`` (None where
    not measured: a fixed setting, no skeleton-driven field, no ``skeleton``, or decided by the contact).
    """
    setting = config.flow.skinning_weights
    out = {"setting": setting, "mode": "current" if setting == "auto" else setting}
    out.update(source_contact=None, source_overlap=None, target_overlap=None)
    if setting != "auto" or not config.flow.skinning:
        return out
    if skeleton is not None and skeleton.n_bones:
        v, f = np.asarray(source_vertices, np.float64), np.asarray(source_faces)
        areas = lumped_mass(v, f)  # each vertex's share of the area
        pos, bones = np.asarray(skeleton.positions), np.asarray(skeleton.bones)
        heads, tails = pos[bones[:, 0]], pos[bones[:, 1]]
        if ranges is None:  # a bone's part outside the skin touches nothing
            ranges = inside_axial_ranges(skeleton, v, f)[0]
        heads, tails = heads + ranges[:, :1] * (tails - heads), heads + ranges[:, 1:] * (tails - heads)
        counted = skeleton.bone_hops >= CONTACT_HOPS
        contact = skin_contact(v, outward_vertex_normals(v, f), areas, heads, tails, counted)
        out["source_contact"] = contact
        if contact > AUTO_CONTACT:
            out["mode"] = "surface"
            return out
    src, tgt = self_overlap(source_vertices, source_faces), self_overlap(target_vertices, target_faces)
    out.update(source_overlap=src, target_overlap=tgt)
    if tgt - src > AUTO_OVERLAP:
        out["mode"] = "start"
    return out


AUTO_CONTACT = 0.015
"""``flow.skinning_weights = "auto"`` takes the skin-aware weights of the start ("surface") when more
than this share of the source's area has another limb's bone in front of its skin, nearer than its own.
Measured on the hand benchmark's 41 MANO sources: fists and a pinch into the palm 0.018–0.066, the
others at most 0.013; bodies and animals of the hard set at most 0.009 (docs/tuning.md)."""

CONTACT_HOPS = 3
"""Bones this many joints apart or more count as different limbs in the contact share (a fingertip
and its own finger's base bone are 3 apart; a neck and head bone 1)."""
