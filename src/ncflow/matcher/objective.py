"""The training objective (paper Eqs. 22–26; DESIGN.md "Constraints (MDMM)"), a pure function.

Per step one point set is flowed through the fixed-grid integrator: all source vertices, fresh
bone samples (``sampling.bone_samples`` per bone) and a fresh tissue stencil (4 points per tissue
sample, :func:`ncflow.tissue.sample_tissue` + :func:`ncflow.losses.tissue_stencil`). The objective is

    L = d(X(1), Y)/⟨Y, Y⟩ + μ_surf L_surf + μ_soft L_soft + C(g) + μ_leash L_leash,

with the data term relative to the target's self-energy (so one set of weights works across
meshes, scales and σ), L_surf the ARAP term against the GSO-Net on ``sampling.surface_edges``
random edges (:func:`ncflow.losses.surface_distortion`), L_soft the tissue stencil term (a stencil's
points anchored at its sample where :func:`tissue_anchored`), L_leash the
Flow-Net's size at the bone samples (:func:`leash_term`, weight ``flow.leash``), and C the
bone-constraint term. With MDMM, C = w · (c_EP · M(g^EP, λ^EP) + c_TR · τ · M(g^TR, λ^TR)) with
M = :func:`ncflow.optim.mdmm.mdmm_term` (mean over bones) at the level margin · ε; with soft
constraints (the ARC-Flow baseline) C = w_soft · (c_EP mean(g^EP/ε) + c_TR τ mean(g^TR/ε)).
c_EP, c_TR are the phase's constraint weights (c_TR = 0 in phases without the trajectory term).

The skeleton pose of the constraints is eliminated: at every step it is set to the least-squares
articulated fit of the flowed bone samples (:func:`ncflow.matcher.pose_fit.fit_pose`, warm-started
Gauss–Newton) weighted by the current multipliers, so it minimises the constraint term over the
pose and g_k measures only the flow's departure from an articulated rigid motion.
"""

from __future__ import annotations

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from ncflow.flow import GSONet, integrate, time_grid
from ncflow.flow.islands import surface_skin
from ncflow.geometry.mesh import outward_vertex_normals
from ncflow.geometry.topology import Topology
from ncflow.jit.buckets import bucket, pad_mesh
from ncflow.losses import (
    bone_constraints,
    edge_points,
    leash_energy,
    sample_edges,
    surface_distortion,
    tissue_distortion,
    tissue_stencil,
)
from ncflow.matcher.pose_fit import constraint_fit_weights, fit_pose
from ncflow.matcher.prepare import DTYPE, Setup
from ncflow.measures.partial import restrict
from ncflow.measures.registry import get_metric
from ncflow.optim.mdmm import mdmm_term, soft_constraint_term
from ncflow.skeleton import Skeleton, rigid_reference, sample_bones
from ncflow.skeleton.kinematics import Pose
from ncflow.tissue import sample_tissue


class Params(eqx.Module):
    """The trained networks: the flow field (its skeleton pose included) and the GSO-Net."""

    flow: eqx.Module
    gso: GSONet


@dataclasses.dataclass(frozen=True)
class Settings:
    """The numbers of the configuration the objective reads (static under ``jit``)."""

    metrics: tuple[str, ...]  # the data terms one compiled step chooses among (by a traced index)
    n_bone_samples: int
    n_tissue: int
    n_edges: int  # surface edges drawn per step; 0: all edges
    tissue_delta: float
    n_times: int
    interp: str
    eps: float
    aim: float  # margin · ε: the level MDMM holds the constraints at
    mode: str  # "mdmm" or "soft"
    constraint_weight: float
    damping: float
    trajectory_weight: float
    soft_weight: float
    surface_weight: float
    tissue_weight: float
    leash_weight: float = 0.0
    tissue_anchor: bool = False  # a tissue stencil's points take its centre's bone weights

    @classmethod
    def from_config(
        cls,
        config,
        metrics: str | tuple[str, ...],
        n_edges_total: int,
        n_centroids: int,
        weight_mode: str = "current",
    ) -> Settings:
        """Settings of ``config`` for the data terms ``metrics`` (one name or several: one step
        compiled for all stages); ``sampling.surface_edges`` ≤ 0, or at least the source's
        ``n_edges_total`` real edges, means all edges (``n_edges`` 0). ``weight_mode``: the
        skeleton-driven field's (:func:`ncflow.matcher.prepare.skinning_weight_mode`), which
        ``flow.tissue_anchor = "auto"`` reads (:func:`tissue_anchored`).
        """
        c, s = config.constraints, config.sampling
        return cls(
            metrics=(metrics,) if isinstance(metrics, str) else tuple(metrics),
            n_bone_samples=s.bone_samples,
            n_tissue=min(s.tissue_samples, n_centroids),
            n_edges=s.surface_edges if 0 < s.surface_edges < n_edges_total else 0,
            tissue_delta=s.tissue_delta,
            n_times=config.flow.n_times,
            interp=config.interp,
            eps=c.eps,
            aim=c.margin * c.eps,
            mode=c.mode,
            constraint_weight=c.weight,
            damping=c.damping,
            trajectory_weight=c.trajectory_weight,
            soft_weight=c.soft_weight,
            surface_weight=config.weights.surface,
            tissue_weight=config.weights.tissue,
            leash_weight=config.flow.leash if config.flow.skinning else 0.0,
            tissue_anchor=tissue_anchored(config, weight_mode),
        )


def start_normals(
    vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], problem: Setup
) -> Float[np.ndarray, "V C"]:
    """(V, 3) outward vertex normals of a source mesh in the problem's normalised coordinates, or (V, 3 + B)
    where its bone weights see the skin (:func:`ncflow.flow.islands.surface_skin`: the islands too).
    """
    if problem.skinning_weights["mode"] == "surface":
        skeleton = problem.skeleton_normalized
        return surface_skin(vertices, faces, skeleton.positions, skeleton.parents)
    return outward_vertex_normals(vertices, faces)


def tissue_anchored(config, weight_mode: str) -> bool:
    """Whether a tissue stencil's points take the bone weights of its centre (``flow.tissue_anchor``:
    "on", "off", or "auto": where the weights are those of the start seeing the skin, ``"surface"``, the
    weight mode of sources whose limbs touch). The stencil's articulated velocity is then one blend of
    rigid bone velocities with fixed weights, itself rigid, so the tissue term reads the Flow-Net's
    distortion, not a stencil torn where its points' weights jump between limbs (a fist's fingertips on
    its palm; docs/tuning.md).
    Only a field whose weights are those of the start reads it (:func:`ncflow.flow.integrate`'s ``anchors``).
    """
    setting = config.flow.tissue_anchor
    return bool(config.flow.skinning) and (setting == "on" or (setting == "auto" and weight_mode == "surface"))


@dataclasses.dataclass(frozen=True)
class Arrays:
    """The problem's constant arrays in the training dtype (closed over by the jitted step, as
    arguments of its executable: :func:`ncflow.jit.cache.share_executables`).

    Padded to size buckets (:mod:`ncflow.jit.buckets`) so that sources of similar size share the
    compiled step: the working source's vertices (copies of vertex 0 appended; the flow moves each
    point on its own), its faces, edges and boundary vertices
    (:func:`~ncflow.geometry.topology.pad_topology`: rows of zero weight in every measure) to
    :data:`ncflow.jit.buckets.MESH_PER_OCTAVE` sizes per doubling, and the tissue centroids (whose count varies from
    one tetrahedralisation to the next) to the next power of two. ``n_vertices`` and ``n_edges``
    count the real rows, ``edge_valid`` and ``centroid_valid`` mark them.
    """

    source: Float[Array, "V 3"]
    normals: Float[Array, "V 3"]  # outward unit vertex normals (zero on padding and where none: a sheet)
    topology: Topology
    edges: Int[Array, "E 2"]
    edge_valid: Bool[Array, " E"]
    n_vertices: int
    n_edges: int
    centroids: Float[Array, "K 3"]
    centroid_valid: Bool[Array, " K"]
    skeleton: Skeleton
    radii: np.ndarray
    ranges: np.ndarray  # (B, 2) the part of each bone its samples and rigid core cover
    inside: np.ndarray  # (B,) the share of each bone's axis inside the source

    @classmethod
    def from_problem(cls, problem: Setup, pad: bool = True) -> Arrays:
        """Training-dtype copies of a :class:`~ncflow.matcher.prepare.Setup`'s arrays (the working
        source), padded to size buckets unless ``pad`` is False.
        """
        k = problem.centroids.shape[0]
        size = bucket(k, per_octave=1) if k else 0
        centroids = np.zeros((size, 3))
        centroids[:k] = problem.centroids
        topo, v = problem.source_topology, np.asarray(problem.working.vertices)
        nv, ne = v.shape[0], topo.n_edges
        normals = start_normals(v, np.asarray(problem.working.faces), problem)
        if pad:
            v, topo = pad_mesh(v, topo)
            normals = np.concatenate([normals, np.zeros((v.shape[0] - nv, normals.shape[1]))])
        return cls(
            source=jnp.asarray(v, DTYPE),
            normals=jnp.asarray(normals, DTYPE),
            topology=topo,
            edges=jnp.asarray(topo.edges),
            edge_valid=jnp.asarray(np.arange(topo.n_edges) < ne),
            n_vertices=nv,
            n_edges=ne,
            centroids=jnp.asarray(centroids, DTYPE),
            centroid_valid=jnp.asarray(np.arange(size) < k),
            skeleton=problem.skeleton_normalized,
            radii=problem.bone_radii,
            ranges=problem.bone_ranges,
            inside=problem.bone_inside,
        )


def bone_cores(
    skeleton: Skeleton,
    radii: float | Float[np.ndarray, " B"],
    ramp: float,
    inside: Float[np.ndarray, " B"] | None = None,
) -> tuple[Float[np.ndarray, " B"], Float[np.ndarray, " B"]]:
    """The rigid cores of :class:`ncflow.flow.SkinnedField` (``flow.rigid_core`` = ``ramp``): per bone its
    core radius c_b, the radius of its sample cylinder ρ_b · L_b (radius factors ``radii``, as
    :func:`ncflow.skeleton.sample_bones` draws them, :func:`ncflow.matcher.prepare.bone_radii`), and the
    radius (1 + ramp) c_b where the Flow-Net is whole again; c_b = 0 (no core) for a bone whose axis is
    nowhere inside the source (``inside``, :func:`ncflow.skeleton.checks.inside_axial_ranges`).
    """
    cores = np.asarray(radii, np.float64) * np.asarray(skeleton.bone_lengths, np.float64)
    if inside is not None:
        cores = np.where(np.asarray(inside) > 0, cores, 0.0)
    return cores, (1.0 + ramp) * cores


def fit_start(field, pose: Pose) -> Pose:
    """Where the per-step pose fit starts: the pose the skeleton-driven field moves its bones by (its
    swing pose: its cores carry the bone samples with exactly that motion, so the fit starts at its
    answer), else ``pose`` (the previous step's fit). The fit's steps are capped (a trust region), so a
    start from the previous step's fit lagged behind a pose that trains quickly and left a g the flow
    did not make.
    """
    return jax.lax.stop_gradient(field.swing_pose()) if hasattr(field, "swing_pose") else pose


def objective(
    params: Params,
    pose: Pose,
    targets: tuple,
    which: Int[Array, ""] | int,
    sigma: Float[Array, ""],
    sigma_normal: Float[Array, ""],
    yy: Float[Array, ""],
    phase_weights: Float[Array, 2],
    lam: Float[Array, "2 B"],
    key: PRNGKeyArray,
    *,
    arrays: Arrays,
    settings: Settings,
) -> tuple[Float[Array, ""], dict]:
    """The loss L and its parts (see the module docstring).

    Args:
        params: flow field and GSO-Net.
        pose: the pose of the previous step (warm start of the per-step pose fit).
        targets: one (compressed) target measure per metric of ``settings.metrics``; only the
            one of the stage's metric is read.
        which: index of this stage's metric in ``settings.metrics`` (traced: one compiled step
            serves the Varifold and the Normal Cycle stages, whose other parts are the same).
        sigma: the kernel scale σ of this stage.
        sigma_normal: the Varifold's normal scale σ_n (unused by Normal Cycles).
        yy: the target's self-energy ⟨Y, Y⟩.
        phase_weights: (2,) constraint weights (endpoint, trajectory) of the phase.
        lam: (2, B) multipliers (endpoint, trajectory).
        key: this step's random key (bone samples, tissue samples, surface edges).
        arrays: the problem's constant arrays.
        settings: the configuration's numbers.

    Returns:
        (L, aux) with aux: ``loss``, ``data``, ``surface``, ``tissue``, ``constraint``, ``leash``, ``g_ep`` (B,),
        ``g_tr`` (B,), ``pose`` (the fitted pose) and ``watch`` (2,) = (data term, max_k g_k/ε).
    """
    s = settings
    kb, kt, ke = jax.random.split(key, 3)
    src, nv = arrays.source, arrays.source.shape[0]
    times = time_grid(s.n_times, DTYPE)
    bones = sample_bones(
        arrays.skeleton, kb, s.n_bone_samples, radius=arrays.radii, axial_range=arrays.ranges, dtype=DTYPE
    ).points  # (B, n, 3)
    nb = bones.shape[0] * bones.shape[1]
    parts = [src, bones.reshape(-1, 3)]
    anchors = None
    if s.n_tissue:
        tissue = sample_tissue(kt, arrays.centroids, s.n_tissue, arrays.centroid_valid)
        parts.append(tissue_stencil(tissue, s.tissue_delta))
        if s.tissue_anchor:
            anchors = jnp.concatenate([*parts[:2], jnp.tile(tissue, (4, 1))])
    points = jnp.concatenate(parts)
    none = jnp.zeros((points.shape[0] - nv, arrays.normals.shape[1]), DTYPE)  # samples: no normal
    normals = jnp.concatenate([arrays.normals, none])
    xs, _ = integrate(params.flow, points, s.n_times, normals=normals, anchors=anchors)
    surf = xs[:, :nv]
    flowed_bones = xs[:, nv : nv + nb].reshape(s.n_times, *bones.shape)
    data = _data_term(s.metrics, which, surf[-1], arrays, targets, sigma, sigma_normal, yy)
    # surface ARAP on random edges, rotations from the GSO-Net at both ends
    # with all edges (n_edges 0) the padding's degenerate edges come too: zero energy, so the mean over
    # the drawn rows is rescaled to the mean over the real ones (the count read from the array, not
    # written into the program)
    n_drawn = s.n_edges or arrays.edges.shape[0]
    e = sample_edges(ke, arrays.edges, n_drawn, arrays.edge_valid)
    rest, local = edge_points(src, e)
    ends = jnp.concatenate([surf[:, e[:, 0]], surf[:, e[:, 1]]], axis=1)  # (T, 2n, 3): the flowed edge points
    n_real = jnp.minimum(n_drawn, jnp.sum(arrays.edge_valid)).astype(DTYPE)
    surf_loss = surface_distortion(params.gso, rest, local, ends) * (n_drawn / n_real)
    soft = tissue_distortion(xs[:, nv + nb :], s.tissue_delta) if s.n_tissue else jnp.zeros((), DTYPE)
    fw = constraint_fit_weights(
        s.n_times, bones.shape[0], DTYPE, lam[0] * phase_weights[0], lam[1] * phase_weights[1], s.trajectory_weight
    )
    start = fit_start(params.flow, pose)
    pose = fit_pose(arrays.skeleton, start, bones, jax.lax.stop_gradient(flowed_bones), times, s.interp, weights=fw)
    pose = jax.lax.stop_gradient(pose)
    reference = rigid_reference(arrays.skeleton, pose, bones, times, s.interp)
    g_ep, g_tr = bone_constraints(flowed_bones, reference)
    cons = constraint_term(g_ep, g_tr, lam, phase_weights, s)
    leash = leash_term(params.flow, flowed_bones, times, s.eps) if s.leash_weight else jnp.zeros((), DTYPE)
    total = data + s.surface_weight * surf_loss + s.tissue_weight * soft + cons + s.leash_weight * leash
    aux = {
        "loss": total,
        "data": data,
        "surface": surf_loss,
        "tissue": soft,
        "constraint": cons,
        "leash": leash,
        "g_ep": g_ep,
        "g_tr": g_tr,
        "pose": pose,
        "watch": jnp.stack([data, jnp.maximum(jnp.max(g_ep), jnp.max(g_tr)) / s.eps]),
    }
    return total, aux


LEASH_SAMPLES = 4
"""Bone samples per bone that :func:`leash_term` reads."""


def leash_term(field, flowed_bones: Float[Array, "T B n 3"], times: Float[Array, " T"], eps: float) -> Float[Array, ""]:
    """The leash on the Flow-Net: mean over grid times t_k and bone samples of ‖R_θ(x(t_k), t_k)‖² / ε, with
    R_θ the skeleton-driven field's Flow-Net itself (not faded by the rigid cores) at the flowed bone samples
    x(t_k) (held fixed: the term moves the network, not the pose).

    Not in the paper. With rigid cores the bones move by the pose alone and a turn of a bone can be undone on
    the skin by an opposite turn of the Flow-Net around it; the data term cannot tell the two apart, and
    without cores it is the constraint term on the bone samples that ties the Flow-Net to zero there. The
    leash restores that tie as a soft term while the cores keep the bones rigid by construction. ε (the
    constraint tolerance, a mean squared distance) makes a residual of the tolerance's size cost about 1.
    ``field`` is a skeleton-driven field (its Flow-Net ``residual``). The first :data:`LEASH_SAMPLES` samples of
    each bone are read (the samples are drawn afresh every step, so this is the same mean in expectation at
    a quarter of the default 16's cost: one more Flow-Net evaluation per sample and grid time).
    """
    at = jax.lax.stop_gradient(flowed_bones[:, :, :LEASH_SAMPLES].reshape(flowed_bones.shape[0], -1, 3))
    return leash_energy(jax.vmap(field.residual)(at, times), eps)


def _data_term(metrics, which, deformed, arrays: Arrays, targets, sigma, sigma_normal, yy) -> Float[Array, ""]:
    """‖X(1) − Y‖² / ⟨Y, Y⟩ in the metric ``metrics[which]``, with ⟨Y, Y⟩ precomputed (``lax.switch``
    calls a single metric's term directly); X(1) restricted to what the target shows (each target a
    :class:`~ncflow.matcher.targets.TargetMeasure`: its measure and the source's weights ω,
    :func:`ncflow.measures.partial.restrict`; ω ≡ 1 for a whole target).
    """

    def term(name, target, deformed):
        metric = get_metric(name)
        x = restrict(metric.represent(deformed, arrays.topology), arrays.topology, target.source_weights)
        y = target.measure
        return metric.inner(x, x, sigma, sigma_normal) - 2.0 * metric.inner(x, y, sigma, sigma_normal) + yy

    branches = [functools.partial(term, name, target) for name, target in zip(metrics, targets, strict=True)]
    return jax.lax.switch(which, branches, deformed) / yy


def constraint_term(
    g_ep: Float[Array, " B"],
    g_tr: Float[Array, " B"],
    lam: Float[Array, "2 B"],
    phase_weights: Float[Array, 2],
    settings: Settings,
) -> Float[Array, ""]:
    """C(g): the MDMM term at the level margin · ε (:func:`~ncflow.optim.mdmm.mdmm_term`, mean over
    bones), or the soft penalty w_soft · mean(g/ε) (:func:`~ncflow.optim.mdmm.soft_constraint_term`),
    for the endpoint and (weighted by τ) the trajectory constraints.
    """
    s = settings
    if s.mode == "mdmm":
        ep = mdmm_term(g_ep, lam[0], s.aim, s.damping, reduction="mean")
        tr = mdmm_term(g_tr, lam[1], s.aim, s.damping, reduction="mean")
        return s.constraint_weight * (phase_weights[0] * ep + phase_weights[1] * s.trajectory_weight * tr)
    ep = soft_constraint_term(g_ep / s.eps, 1.0, reduction="mean")
    tr = soft_constraint_term(g_tr / s.eps, 1.0, reduction="mean")
    return s.soft_weight * (phase_weights[0] * ep + phase_weights[1] * s.trajectory_weight * tr)
