"""The matcher: correspondence-free matching and interpolation of two poses (paper §4, Eq. 22–27).

Pipeline (DESIGN.md "Pipeline"): validate inputs → one similarity normalises source, target and
skeleton → topology and target measures (Varifold / Normal Cycles, compressed per length scale
when larger than ``config.compress``) → soft-tissue samples (fTetWild once, cached) → optimise the
flow net F_θ (with the ``fast`` preset a :class:`~ncflow.flow.SkinnedField`: blended rigid bone
velocities of a trained skeleton pose plus the Flow-Net), the GSO rotation net and the per-bone
multipliers, phase by phase → flow the full source, interpolate frames and the skeleton,
project the target for the correspondence → :class:`MatchResult` in the user's coordinates.

Per step, one point set is flowed through the fixed-grid integrator: all source vertices, fresh
bone samples (``sampling.bone_samples`` per bone) and a fresh tissue stencil (4 points per
tissue sample). The objective is

    L = d(X(1), Y)/⟨Y, Y⟩ + μ_surf L_surf + μ_soft L_soft + C(g),

with the data term relative to the target's self-energy (so one set of weights works across
meshes, scales and σ), L_surf the ARAP term against the GSO-Net on ``sampling.surface_edges``
random edges, L_soft the tissue stencil term, and C the bone-constraint term: with MDMM,
C = w · mean_k(λ_k Γ_k + (δ/2) Γ_k²) with Γ_k = max(g_k − mε, 0) (m = ``constraints.margin``, so
the values that MDMM settles at stay under ε) for the endpoint and (in phases with
``trajectory``) the trajectory constraints. The skeleton pose of the constraints is eliminated: at every
step it is set to the least-squares articulated fit of the flowed bone samples (:func:`fit_pose`,
warm-started Gauss–Newton) weighted by the current multipliers (:func:`constraint_fit_weights`),
so it minimises the constraint term over the pose and g_k measures only the flow's departure
from an articulated rigid motion. Multipliers follow a normalised
(sign) ascent projected on λ ≥ 0, λ ← max(0, λ + η_t sign(g_k − mε)), with η_t ramping linearly
from 0 to 2η over the run: the shape is matched first while λ is small, then the bones are
tightened (the release moves its multipliers with its sign-like Adam steps, the same
normalisation). The soft mode (ARC-Flow baseline) uses C = w_soft · mean_k g_k/ε with fixed weights.
A :class:`DivergenceGuard` rolls a stage back to its last healthy snapshot, at half the learning
rate, when the data term or the largest bone violation runs away (``config.divergence_guard``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any, Callable

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np

from ncflow import __version__
from ncflow.config import Config, PhaseConfig, config_to_dict, preset, validate_config
from ncflow.errors import InputError, NcflowError
from ncflow.flow import GSONet, SkinnedField, flow_points, integrate, make_flow_field, time_grid
from ncflow.losses import arap_energy, bone_constraints, sample_edges, tissue_distortion, tissue_stencil
from ncflow.measures import (
    compress_normal_cycle,
    compress_varifold,
    normal_cycle,
    normal_cycle_inner,
    varifold,
    varifold_inner,
)
from ncflow.mesh import Mesh, Normalization, fit_normalization, load_mesh, mesh_topology
from ncflow.optim import adabelief_cautious, vectoradam_cautious
from ncflow.optim.schedules import warmup_constant, warmup_cosine
from ncflow.skeleton import Skeleton, check_inside, interpolate_joints, load_skeleton, rigid_reference, sample_bones
from ncflow.skeleton.kinematics import Pose, rest_pose

__all__ = ["Matcher", "MatchResult", "TrainingError", "match"]

DTYPE = jnp.float32
FINAL_BONE_SAMPLES = 200  # per bone, for the reported g_k (fresh samples, so an estimate of the integral)


class TrainingError(NcflowError):
    """The optimisation failed (a non-finite loss); nothing is written."""


# ----------------------------------------------------------------------------------------------
# progress display


class Progress:
    """Phase, step, loss, largest bone violation and ETA on stderr (one updating line on a
    terminal, a line every ~5% otherwise); silent when ``quiet``."""

    def __init__(self, total: int, quiet: bool = False, stream=None):
        self.total = max(1, total)
        self.quiet = quiet
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.start = time.perf_counter()
        self.every = max(1, self.total // 20)
        self.last_line = ""

    def message(self, text: str) -> None:
        if not self.quiet:
            if self.tty and self.last_line:
                self.stream.write("\n")
                self.last_line = ""
            self.stream.write(text + "\n")
            self.stream.flush()

    def update(self, done: int, phase: str, loss: float, violation: float) -> None:
        if self.quiet:
            return
        elapsed = time.perf_counter() - self.start
        eta = elapsed / max(done, 1) * (self.total - done)
        line = (
            f"[{phase}] step {done}/{self.total}  loss {loss:.4g}  max bone g/eps {violation:.3g}  "
            f"elapsed {elapsed:.0f}s  ETA {eta:.0f}s"
        )
        if self.tty:
            self.stream.write("\r" + line.ljust(len(self.last_line)))
            self.last_line = line
            self.stream.flush()
        elif done % self.every == 0 or done == self.total:
            self.stream.write(line + "\n")
            self.stream.flush()

    def close(self) -> None:
        if self.tty and self.last_line and not self.quiet:
            self.stream.write("\n")
            self.stream.flush()


# ----------------------------------------------------------------------------------------------
# result


@dataclasses.dataclass
class MatchResult:
    """Everything a match produced, in the user's coordinates.

    Attributes:
        source, target: the input meshes.
        skeleton: the source skeleton; ``skeleton_target`` the fitted target pose of it.
        deformed_source: (V, 3) source vertices flowed to t = 1.
        frame_times: (K,) times in [0, 1]; ``frames`` (K, V, 3) the interpolation.
        skeleton_frames: (K, J, 3) joint positions per frame.
        maps: correspondence (:func:`ncflow.export.correspondence_maps`).
        metrics: losses, per-bone constraints, timings, config, versions, seed.
        normalization: the similarity used for training.
    """

    source: Mesh
    target: Mesh
    skeleton: Skeleton
    skeleton_target: Skeleton
    deformed_source: np.ndarray
    frame_times: np.ndarray
    frames: np.ndarray
    skeleton_frames: np.ndarray
    maps: dict
    metrics: dict
    normalization: Normalization
    field: Any = dataclasses.field(repr=False, default=None)
    n_times: int = 10

    def flow(self, points: np.ndarray, times: np.ndarray | None = None) -> np.ndarray:
        """Move any points (user coordinates, e.g. a higher-resolution source) by the trained field.

        Returns (N, 3) at t = 1, or (Q, N, 3) at the given times.
        """
        p = jnp.asarray(self.normalization.apply(np.asarray(points, np.float64)), DTYPE)
        if times is None:
            out = flow_points(self.field, p, self.n_times)[-1]
        else:
            out = flow_points(self.field, p, self.n_times, times=jnp.asarray(times, DTYPE))
        return self.normalization.invert(np.asarray(out, np.float64))

    def save(self, out_dir: str | os.PathLike, overwrite: bool = False) -> Path:
        """Write the output contract of DESIGN.md into ``out_dir`` (atomically)."""
        from ncflow.export import write_result

        return write_result(
            out_dir,
            deformed_source=self.deformed_source,
            source_faces=self.source.faces,
            maps=self.maps,
            frames=self.frames,
            frame_times=self.frame_times,
            skeleton_target=self.skeleton_target,
            skeleton_frames=self.skeleton_frames,
            parents=self.skeleton.parents,
            joint_names=list(self.skeleton.names) if self.skeleton.names else None,
            metrics=self.metrics,
            overwrite=overwrite,
        )


# ----------------------------------------------------------------------------------------------
# helpers


def _cache_dir() -> Path:
    base = os.environ.get("NCFLOW_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "ncflow"
    )
    return Path(base)


def tissue_centroids(vertices: np.ndarray, faces: np.ndarray, config: Config) -> tuple[np.ndarray, dict]:
    """Tet centroids of the (normalised) source; cached per surface and settings.

    fTetWild is not deterministic (the same surface gives slightly different tets from run to run),
    so the first tetrahedralisation of a surface is cached (``$NCFLOW_CACHE_DIR``, default
    ``~/.cache/ncflow``) and reused: repeated runs on one machine are then reproducible.
    """
    from ncflow.tissue import soft_tissue

    tc = config.tissue
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(vertices, np.float64).tobytes())
    h.update(np.ascontiguousarray(faces, np.int64).tobytes())
    h.update(repr((tc.edge_length_fac, tc.epsilon, tc.split_passes)).encode())
    path = _cache_dir() / "tissue" / f"{h.hexdigest()[:32]}.npz"
    info = {"cached": False}
    if tc.cache and path.exists():
        try:
            data = np.load(path)
            info.update(cached=True, n_centroids=int(data["centroids"].shape[0]), seconds=0.0)
            return np.asarray(data["centroids"]), info
        except Exception:  # a broken cache entry is recomputed
            pass
    t0 = time.perf_counter()
    tissue = soft_tissue(
        vertices, faces, edge_length_fac=tc.edge_length_fac, epsilon=tc.epsilon, passes=tc.split_passes
    )
    info.update(
        n_tets_initial=int(tissue.n_tets_initial),
        n_centroids=int(tissue.centroids.shape[0]),
        seconds=time.perf_counter() - t0,
    )
    if tc.cache:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix(f".tmp{os.getpid()}.npz")
            np.savez(tmp, centroids=tissue.centroids)
            os.replace(tmp, path)
        except OSError:
            pass
    return np.asarray(tissue.centroids), info


def _load_inputs(source, target, skeleton) -> tuple[Mesh, Mesh, Skeleton]:
    src = source if isinstance(source, Mesh) else load_mesh(source)
    tgt = target if isinstance(target, Mesh) else load_mesh(target)
    skel = skeleton if isinstance(skeleton, Skeleton) else load_skeleton(skeleton)
    return src, tgt, skel


def _check_skeleton_placement(skel: Skeleton, src: Mesh) -> list[str]:
    """Warnings for joints slightly outside; an error for joints far outside the source."""
    far = check_inside(skel, src.vertices, src.faces, surface_tol=0.15, far=0.15)
    if far:
        raise InputError(
            f"skeleton does not fit the source mesh {src.name or ''}: {far[0]}"
            + (f" (and {len(far) - 1} more)" if len(far) > 1 else "")
            + "; is it in the same coordinates as the source?",
            skel.name,
        )
    return check_inside(skel, src.vertices, src.faces)


@dataclasses.dataclass
class _Stage:
    phase: int
    phase_config: PhaseConfig
    metric: str
    sigma: float
    steps: int
    start: int  # step within the phase at which this stage starts


def _stages(config: Config) -> list[_Stage]:
    stages = []
    for i, p in enumerate(config.phases):
        n = len(p.sigmas)
        bounds = np.linspace(0, p.steps, n + 1).round().astype(int)
        for k, sigma in enumerate(p.sigmas):
            if bounds[k + 1] > bounds[k]:
                stages.append(_Stage(i, p, p.metric, float(sigma), int(bounds[k + 1] - bounds[k]), int(bounds[k])))
    return stages


def _phase_schedule(p: PhaseConfig) -> Callable[[int], float]:
    if p.lr_end is None:
        sched = warmup_constant(p.lr, p.warmup)
    else:
        sched = warmup_cosine(p.lr, p.lr_end, p.warmup, max(p.steps, p.warmup + 1))
    return lambda s: float(sched(s))


class DivergenceGuard:
    """Watches a stage and rolls the optimisation back when it runs away.

    Two signals, each smoothed by an exponential moving average (weight ``smooth``) and compared
    with its best value in the stage (after ``settle`` steps, since a stage starts at a new σ):
    the data term d̄ (runs away when d̄ > ``factor``·best — the constraints overpowering the
    match) and the largest bone violation v̄ = max_k g_k/ε (runs away when v̄ > 5·``factor``·best
    and v̄ > ``min_violation`` — a bone torn apart, e.g. a finger drifting into a half-turn
    twist; watched from the second stage on, since the first starts from the identity flow,
    where every g_k is 0). While both are near their best (≤ 1.2·best) a snapshot of the state is taken every
    ``every`` steps. On a runaway :meth:`observe` answers ``"rollback"``: the caller restores
    :attr:`snapshot` and multiplies its learning rate by :attr:`lr_scale` (halved at each
    roll-back); after ``max_trips`` roll-backs in one stage it answers ``"stop"`` (restore and
    end the stage). ``factor`` = 0 disables it (always ``"ok"``).
    """

    def __init__(
        self,
        factor: float = 2.0,
        every: int = 20,
        smooth: float = 0.1,
        settle: int = 10,
        max_trips: int = 3,
        min_violation: float = 20.0,
    ):
        self.factor, self.every, self.smooth, self.settle = factor, every, smooth, settle
        self.max_trips, self.min_violation = max_trips, min_violation
        self.lr_scale = 1.0
        self.events: list[dict] = []
        self.start_stage(None)

    def start_stage(self, state, watch_violation: bool = True) -> None:
        self.watch_violation = watch_violation
        self.ema: np.ndarray | None = None
        self.best = np.full(2, np.inf)
        self.seen = 0
        self.trips = 0
        self.snapshot = state
        self.snapshot_ema: np.ndarray | None = None

    def observe(self, data: float, state, step: int, violation: float = 0.0) -> str:
        """Feed the data term and the largest g_k/ε of the step just taken and the state after it."""
        if not self.factor:
            return "ok"
        x = np.array([data, violation], float)
        self.ema = x if self.ema is None else (1 - self.smooth) * self.ema + self.smooth * x
        self.seen += 1
        if self.seen <= self.settle:
            return "ok"
        self.best = np.minimum(self.best, self.ema)
        d, v = self.ema
        torn = self.watch_violation and v > 5 * self.factor * self.best[1] and v > self.min_violation
        if d > self.factor * self.best[0] or torn:
            self.trips += 1
            self.lr_scale *= 0.5
            self.events.append(
                {
                    "step": step,
                    "data_smoothed": float(d),
                    "data_best": float(self.best[0]),
                    "violation_smoothed": float(v),
                    "violation_best": float(self.best[1]),
                    "lr_scale": self.lr_scale,
                }
            )
            self.ema = self.snapshot_ema
            return "stop" if self.trips >= self.max_trips else "rollback"
        if self.seen % self.every == 0 and np.all(self.ema <= 1.2 * self.best):
            self.snapshot, self.snapshot_ema = state, self.ema
        return "ok"


# ----------------------------------------------------------------------------------------------
# the matcher


class Params(eqx.Module):
    flow: eqx.Module
    gso: GSONet


def fit_pose(
    skeleton: Skeleton,
    pose: Pose,
    rest_points,
    flowed,
    times,
    interp: str,
    iterations: int = 2,
    max_step: float = 0.02,
    weights=None,
) -> Pose:
    """Least-squares articulated fit of flowed bone samples: Gauss–Newton on the pose parameters.

    Minimises Σ_t Σ_k w_t,k Σ_s ‖p̄_k,s(t; pose) − x_k,s(t)‖² over the joint rotations and the root
    translation; ``weights`` (broadcastable to (T, B); default :func:`constraint_fit_weights` with
    equal multipliers, i.e. the endpoint counts as much as the whole interior trajectory, as in
    g^EP + g^TR). Warm-started from ``pose`` (Levenberg damping ∝ tr(JᵀJ)/P handles the gauge
    directions: quaternion scale, rotations of leaf joints; 1e-3 in the code); each step is capped at ``max_step`` per
    parameter (a trust region, so a poor flow early on cannot fling the skeleton). ``flowed``
    (T, B, n, 3) is treated as data.
    """
    flat0, unravel = jax.flatten_util.ravel_pytree(pose)
    n_times = flowed.shape[0]
    if weights is None:
        weights = constraint_fit_weights(n_times, flowed.shape[1], flowed.dtype)
    root = jnp.sqrt(jnp.broadcast_to(jnp.asarray(weights, flowed.dtype), flowed.shape[:2]))[:, :, None, None]

    def residual(flat):
        return (root * (rigid_reference(skeleton, unravel(flat), rest_points, times, interp) - flowed)).reshape(-1)

    def gauss_newton(_, flat):
        r = residual(flat)
        jac = jax.jacfwd(residual)(flat)
        a = jac.T @ jac
        mu = 1e-3 * jnp.trace(a) / a.shape[0] + 1e-12
        delta = jnp.linalg.solve(a + mu * jnp.eye(a.shape[0], dtype=a.dtype), jac.T @ r)
        delta = delta * jnp.minimum(1.0, max_step / (jnp.max(jnp.abs(delta)) + 1e-12))  # trust region
        new = unravel(flat - delta)
        rot = new.rotations / jnp.linalg.norm(new.rotations, axis=-1, keepdims=True)
        return jax.flatten_util.ravel_pytree(Pose(rot, new.translation))[0]

    return unravel(jax.lax.fori_loop(0, iterations, gauss_newton, flat0))


def constraint_fit_weights(n_times: int, n_bones: int, dtype=DTYPE, lam_ep=None, lam_tr=None, trajectory: float = 1.0):
    """(T, B) per-time, per-bone weights under which the pose fit minimises the constraint term.

    The constraint term is Σ_k (1 + λ^EP_k) g^EP_k + τ (1 + λ^TR_k) g^TR_k with g^TR the mean over the
    T − 2 interior grid times: the endpoint state gets weight 1 + λ^EP, each interior state
    τ (1 + λ^TR)/(T − 2), t = 0 none (its residual is zero). With no multipliers the endpoint counts
    as much as the whole interior trajectory.
    """
    lam_ep = jnp.zeros((n_bones,), dtype) if lam_ep is None else jnp.asarray(lam_ep, dtype)
    lam_tr = jnp.zeros((n_bones,), dtype) if lam_tr is None else jnp.asarray(lam_tr, dtype)
    interior = trajectory * (1.0 + lam_tr) / max(n_times - 2, 1)
    rows = [jnp.zeros((n_bones,), dtype)] + [interior] * (n_times - 2) + [1.0 + lam_ep]
    return jnp.stack(rows[-n_times:]).astype(dtype)


class Matcher:
    """Precomputes everything for one (source, target, skeleton) and runs the optimisation.

    Args:
        source, target: meshes (or paths); the target may have any triangulation and resolution.
        skeleton: the source's skeleton (or a path: TGF, JSON, glTF).
        config: a :class:`~ncflow.config.Config` (default: the ``fast`` preset).
        quiet: no progress display.
    """

    def __init__(self, source, target, skeleton, config: Config | None = None, *, quiet: bool = False, stream=None):
        t0 = time.perf_counter()
        self.config = validate_config(config or preset("fast"))
        self.source, self.target, self.skeleton = _load_inputs(source, target, skeleton)
        self.progress = Progress(self.config.total_steps, quiet, stream)
        self.warnings = _check_skeleton_placement(self.skeleton, self.source)
        for w in self.warnings:
            self.progress.message(f"warning: {w}")
        cfg = self.config
        self.norm = fit_normalization(self.source.vertices, self.source.faces)
        self.src_v = self.norm.apply(self.source.vertices)
        self.tgt_v = self.norm.apply(self.target.vertices)
        self.skel_n = self.skeleton.with_positions(self.norm.apply(self.skeleton.positions))
        self.src_topo = mesh_topology(self.source.faces, self.source.n_vertices, name=self.source.name)
        self.tgt_topo = mesh_topology(self.target.faces, self.target.n_vertices, name=self.target.name)
        self.edges = jnp.asarray(self.src_topo.edges)
        self.radii = self.skel_n.bone_radii(cfg.sampling.bone_radius)
        self.timings = {"setup": 0.0}
        # soft tissue
        t1 = time.perf_counter()
        if cfg.sampling.tissue_samples > 0 and cfg.weights.tissue > 0:
            self.progress.message("tetrahedralising the source for soft-tissue samples ...")
            self.centroids, self.tissue_info = tissue_centroids(self.src_v, self.source.faces, cfg)
        else:
            self.centroids, self.tissue_info = np.zeros((0, 3)), {"disabled": True}
        self.timings["tissue"] = time.perf_counter() - t1
        # target measures per stage (compressed per length scale)
        t1 = time.perf_counter()
        self.stages = _stages(cfg)
        self.targets: dict[tuple[str, float, float], tuple[Any, float, dict]] = {}
        ty = jnp.asarray(self.tgt_v, DTYPE)
        full = {"varifold": varifold(ty, self.target.faces), "normal-cycles": normal_cycle(ty, self.tgt_topo)}
        for st in self.stages:
            key = (st.metric, st.sigma, st.phase_config.sigma_normal)
            if key in self.targets:
                continue
            y = full[st.metric]
            report = {"n": int(y.size), "m": int(y.size), "relative_error": 0.0, "seconds": 0.0}
            if cfg.compress and y.size > cfg.compress:
                self.progress.message(
                    f"compressing the target ({st.metric}, sigma={st.sigma:g}) to {cfg.compress} points ..."
                )
                if st.metric == "varifold":
                    y, rep = compress_varifold(y, cfg.compress, st.sigma, st.phase_config.sigma_normal, seed=cfg.seed)
                else:
                    y, rep = compress_normal_cycle(y, cfg.compress, st.sigma, seed=cfg.seed)
                report = rep.to_dict()
            if st.metric == "varifold":
                yy = float(varifold_inner(y, y, st.sigma, st.phase_config.sigma_normal))
            else:
                yy = float(normal_cycle_inner(y, y, st.sigma))
            if not np.isfinite(yy) or yy <= 0:
                raise InputError("the target has no measurable surface (zero self-energy)", self.target.name)
            self.targets[key] = (y, yy, report)
        self.timings["target"] = time.perf_counter() - t1
        self.timings["setup"] = time.perf_counter() - t0

    # -- the training step ---------------------------------------------------------------------

    def _optimizer(self):
        cfg = self.config
        make = adabelief_cautious if cfg.optimizer == "adabelief" else vectoradam_cautious
        return make(1.0, weight_decay=cfg.weight_decay, clip_norm=cfg.clip_norm)

    def _make_step(self, metric: str, optimizer):
        cfg = self.config
        skel = self.skel_n
        faces = np.asarray(self.source.faces)
        topo = self.src_topo
        src = jnp.asarray(self.src_v, DTYPE)
        nv = src.shape[0]
        edges = self.edges
        n_edges = cfg.sampling.surface_edges if cfg.sampling.surface_edges > 0 else int(edges.shape[0])
        centroids = jnp.asarray(self.centroids, DTYPE)
        n_tissue = min(cfg.sampling.tissue_samples, int(centroids.shape[0]))
        delta = cfg.sampling.tissue_delta
        n_bone = cfg.sampling.bone_samples
        n_times = cfg.flow.n_times
        times = time_grid(n_times, DTYPE)
        radii = self.radii
        eps = cfg.constraints.eps
        aim = cfg.constraints.margin * eps  # the multipliers' target, a margin below the reported tolerance
        c = cfg.constraints
        w = cfg.weights
        interp = cfg.interp

        def losses(params: Params, pose, target, sigma, sigma_n, yy, cw, lam, key):
            kb, kt, ke = jax.random.split(key, 3)
            bones = sample_bones(skel, kb, n_bone, radius=radii, dtype=DTYPE).points  # (B, n, 3)
            nb = bones.shape[0] * bones.shape[1]
            parts = [src, bones.reshape(-1, 3)]
            if n_tissue:
                tissue = centroids[jax.random.permutation(kt, centroids.shape[0])[:n_tissue]]
                parts.append(tissue_stencil(tissue, delta))
            xs, _ = integrate(params.flow, jnp.concatenate(parts), n_times)
            surf = xs[:, :nv]
            flowed_bones = xs[:, nv : nv + nb].reshape(n_times, *bones.shape)
            deformed = surf[-1]
            if metric == "varifold":
                x = varifold(deformed, faces)
                data = varifold_inner(x, x, sigma, sigma_n) - 2.0 * varifold_inner(x, target, sigma, sigma_n) + yy
            else:
                x = normal_cycle(deformed, topo)
                data = normal_cycle_inner(x, x, sigma) - 2.0 * normal_cycle_inner(x, target, sigma) + yy
            data = data / yy
            # surface ARAP on random edges, rotations from the GSO-Net at both ends
            e = sample_edges(ke, edges, n_edges)
            ends = jnp.concatenate([surf[1:, e[:, 0]], surf[1:, e[:, 1]]], axis=1)  # (T-1, 2n, 3)
            rot = jax.vmap(params.gso)(ends, times[1:])
            rest = jnp.concatenate([src[e[:, 0]], src[e[:, 1]]])
            local = jnp.stack([jnp.arange(e.shape[0]), e.shape[0] + jnp.arange(e.shape[0])], axis=1)
            surf_loss = arap_energy(rest, local, ends, rot.astype(DTYPE))
            soft = tissue_distortion(xs[:, nv + nb :], delta) if n_tissue else jnp.zeros((), DTYPE)
            fw = constraint_fit_weights(
                n_times, bones.shape[0], DTYPE, lam[0] * cw[0], lam[1] * cw[1], c.trajectory_weight
            )
            pose = fit_pose(skel, pose, bones, jax.lax.stop_gradient(flowed_bones), times, interp, weights=fw)
            pose = jax.lax.stop_gradient(pose)
            reference = rigid_reference(skel, pose, bones, times, interp)
            g_ep, g_tr = bone_constraints(flowed_bones, reference)
            gam_ep = jnp.maximum(g_ep - aim, 0.0)
            gam_tr = jnp.maximum(g_tr - aim, 0.0)
            if c.mode == "mdmm":
                term = lambda lam_, gam: jnp.mean(lam_ * gam + 0.5 * c.damping * gam**2)  # noqa: E731
                cons = c.weight * (cw[0] * term(lam[0], gam_ep) + cw[1] * c.trajectory_weight * term(lam[1], gam_tr))
            else:
                cons = c.soft_weight * (
                    cw[0] * jnp.mean(g_ep / eps) + cw[1] * c.trajectory_weight * jnp.mean(g_tr / eps)
                )
            total = data + w.surface * surf_loss + w.tissue * soft + cons
            aux = {
                "loss": total,
                "data": data,
                "surface": surf_loss,
                "tissue": soft,
                "constraint": cons,
                "g_ep": g_ep,
                "g_tr": g_tr,
                "pose": pose,
                "watch": jnp.stack([data, jnp.maximum(jnp.max(g_ep), jnp.max(g_tr)) / eps]),
            }
            return total, aux

        @eqx.filter_jit
        def step(params, pose, opt_state, lam, target, sigma, sigma_n, yy, cw, lr, progress, key):
            (_, aux), grads = eqx.filter_value_and_grad(losses, has_aux=True)(
                params, pose, target, sigma, sigma_n, yy, cw, lam, key
            )
            updates, opt_state = optimizer.update(grads, opt_state, eqx.filter(params, eqx.is_inexact_array))
            updates = jax.tree_util.tree_map(lambda u: lr * u, updates)
            if isinstance(params.flow, SkinnedField):
                updates = eqx.tree_at(
                    lambda u: u.flow.pose,
                    updates,
                    replace_fn=lambda p: jax.tree_util.tree_map(lambda a: cfg.flow.pose_lr_scale * a, p),
                )
            params = eqx.apply_updates(params, updates)
            if c.mode == "mdmm":
                g = jnp.stack([aux["g_ep"], aux["g_tr"]])
                active = (cw > 0).astype(lam.dtype)[:, None]
                rate = c.multiplier_lr * 2.0 * progress  # ramps 0 -> 2η: free early, tight late
                lam = jnp.maximum(lam + rate * active * jnp.sign(g - aim), 0.0)
            return params, aux.pop("pose"), opt_state, lam, aux

        return step

    def _init_params(self, key) -> Params:
        cfg = self.config
        kf, kg = jax.random.split(key)
        field = make_flow_field(kf, width=cfg.flow.width, depth=cfg.flow.depth, div_free=cfg.flow.div_free, dtype=DTYPE)
        if cfg.flow.skinning:
            width = cfg.flow.skinning_width * float(np.median(self.skel_n.bone_lengths))
            field = SkinnedField(field, self.skel_n, width=width, interp=cfg.interp, dtype=DTYPE)
        gso = GSONet(kg, width=cfg.flow.gso_width, depth=cfg.flow.gso_depth, dtype=DTYPE)
        return Params(field, gso)

    # -- running -------------------------------------------------------------------------------

    def run(self) -> MatchResult:
        """Optimise, then build the result (user coordinates)."""
        cfg = self.config
        t_train = time.perf_counter()
        self.progress.start = t_train
        key = jax.random.key(cfg.seed)
        k_init, k_train, k_eval = jax.random.split(key, 3)
        params = self._init_params(k_init)
        pose = rest_pose(self.skel_n, DTYPE)
        optimizer = self._optimizer()
        opt_state = optimizer.init(eqx.filter(params, eqx.is_inexact_array))
        lam = jnp.zeros((2, self.skel_n.n_bones), DTYPE)
        steps_fn = {}
        history = []
        done = 0
        aux = None
        guard = DivergenceGuard(cfg.divergence_guard)
        for st in self.stages:
            if st.metric not in steps_fn:
                steps_fn[st.metric] = self._make_step(st.metric, optimizer)
            step = steps_fn[st.metric]
            target, yy, _ = self.targets[(st.metric, st.sigma, st.phase_config.sigma_normal)]
            schedule = _phase_schedule(st.phase_config)
            pw = st.phase_config.constraint_weight
            cw = jnp.asarray([pw, pw if st.phase_config.trajectory else 0.0], DTYPE)
            phase_name = st.phase_config.name or st.metric
            guard.start_stage((params, pose, opt_state, lam), watch_violation=done > 0)
            for s in range(st.steps):
                lr = jnp.asarray(schedule(st.start + s) * guard.lr_scale, DTYPE)
                params, pose, opt_state, lam, aux = step(
                    params,
                    pose,
                    opt_state,
                    lam,
                    target,
                    jnp.asarray(st.sigma, DTYPE),
                    jnp.asarray(st.phase_config.sigma_normal, DTYPE),
                    jnp.asarray(yy, DTYPE),
                    cw,
                    lr,
                    jnp.asarray(done / cfg.total_steps, DTYPE),
                    jax.random.fold_in(k_train, done),
                )
                done += 1
                watch = np.asarray(aux["watch"], np.float64)  # one transfer: data term, largest g/ε
                verdict = guard.observe(float(watch[0]), (params, pose, opt_state, lam), done, float(watch[1]))
                if verdict != "ok":
                    params, pose, opt_state, lam = guard.snapshot
                    ev = guard.events[-1]
                    self.progress.message(
                        f"[{phase_name} σ={st.sigma:g}] step {done}: the run went astray (data {ev['data_smoothed']:.3g}, "
                        f"best {ev['data_best']:.3g}; bone g/eps {ev['violation_smoothed']:.3g}, best {ev['violation_best']:.3g}); "
                        + ("rolled back, learning rate halved" if verdict == "rollback" else "rolled back, stage ended")
                    )
                    if verdict == "stop":
                        break
                report = done % max(1, self.progress.every // 4 or 1) == 0 or s == st.steps - 1 or self.progress.tty
                if report:
                    loss = float(aux["loss"])
                    if not np.isfinite(loss):
                        self.progress.close()
                        raise TrainingError(
                            f"training diverged at step {done} ({phase_name}, sigma={st.sigma:g}): non-finite loss; "
                            "try a smaller learning rate (e.g. phases.lr) or check the inputs"
                        )
                    viol = float(watch[1])
                    self.progress.update(done, f"{phase_name} σ={st.sigma:g}", loss, viol)
            history.append(
                {
                    "phase": phase_name,
                    "metric": st.metric,
                    "sigma": st.sigma,
                    "steps": st.steps,
                    **{k: float(aux[k]) for k in ("loss", "data", "surface", "tissue", "constraint")},
                }
            )
        self.progress.close()
        leaves = jax.tree_util.tree_leaves(eqx.filter(params, eqx.is_inexact_array))
        if not all(bool(jnp.all(jnp.isfinite(leaf))) for leaf in leaves):
            raise TrainingError("training produced non-finite parameters")
        train_seconds = time.perf_counter() - t_train
        t_out = time.perf_counter()
        result = self._result(params, pose, lam, cw, history, k_eval)
        result.metrics["timings"].update(
            train=train_seconds, per_step=train_seconds / max(done, 1), outputs=time.perf_counter() - t_out
        )
        result.metrics["rollbacks"] = guard.events
        result.metrics["timings"]["total"] = sum(
            v for k, v in result.metrics["timings"].items() if k in ("setup", "train", "outputs")
        )
        return result

    def _final_pose(self, params: Params, pose: Pose, lam, cw, key) -> tuple[Pose, np.ndarray, np.ndarray]:
        """The output pose and its (g^EP, g^TR): the training pose refined on FINAL_BONE_SAMPLES fresh
        samples per bone with the final multiplier weights (the per-step fit sees only a few samples)."""
        cfg = self.config
        c = cfg.constraints
        bones = sample_bones(self.skel_n, key, FINAL_BONE_SAMPLES, radius=self.radii, dtype=DTYPE).points
        xs = flow_points(params.flow, bones.reshape(-1, 3), cfg.flow.n_times).reshape(cfg.flow.n_times, *bones.shape)
        times = time_grid(cfg.flow.n_times, DTYPE)
        fw = constraint_fit_weights(
            cfg.flow.n_times, bones.shape[0], DTYPE, lam[0] * cw[0], lam[1] * cw[1], c.trajectory_weight
        )
        pose = fit_pose(self.skel_n, pose, bones, xs, times, cfg.interp, iterations=3, weights=fw)
        ref = rigid_reference(self.skel_n, pose, bones, times, cfg.interp)
        g_ep, g_tr = bone_constraints(xs, ref)
        return pose, np.asarray(g_ep, np.float64), np.asarray(g_tr, np.float64)

    def _result(self, params: Params, pose: Pose, lam, cw, history, key) -> MatchResult:
        from ncflow.export import correspondence_maps

        cfg = self.config
        norm = self.norm
        frame_times = np.linspace(0.0, 1.0, cfg.frames)
        src = jnp.asarray(self.src_v, DTYPE)
        frames_n = np.asarray(
            flow_points(params.flow, src, cfg.flow.n_times, times=jnp.asarray(frame_times, DTYPE)), np.float64
        )
        frames_n[0] = self.src_v  # t = 0 is the source exactly
        deformed_n = frames_n[-1]  # Hermite output at a grid time is the grid state: the state at t = 1
        if not (np.all(np.isfinite(frames_n)) and np.all(np.isfinite(deformed_n))):
            raise TrainingError("the trained flow produced non-finite positions")
        pose, g_ep, g_tr = self._final_pose(params, pose, lam, cw, key)
        joints = np.stack(
            [np.asarray(interpolate_joints(self.skel_n, pose, float(t), cfg.interp), np.float64) for t in frame_times]
        )
        maps = correspondence_maps(self.src_v, self.source.faces, deformed_n, self.tgt_v, self.target.faces)
        eps = cfg.constraints.eps
        names = self.skeleton.names or tuple(f"joint {j}" for j in range(self.skeleton.n_joints))
        bones = [
            {
                "bone": f"{names[self.skeleton.parents[j]]} -> {names[j]}",
                "g_endpoint": float(g_ep[j - 1]),
                "g_trajectory": float(g_tr[j - 1]),
                "rms_distance_endpoint": float(np.sqrt(g_ep[j - 1]) / norm.scale),
                "satisfied": bool(g_ep[j - 1] <= eps and g_tr[j - 1] <= eps),
                "multiplier_endpoint": float(lam[0, j - 1]),
                "multiplier_trajectory": float(lam[1, j - 1]),
            }
            for j in range(1, self.skeleton.n_joints)
        ]
        import scipy
        import trimesh

        metrics = {
            "ncflow_version": __version__,
            "seed": cfg.seed,
            "source": self.source.name,
            "target": self.target.name,
            "skeleton": self.skeleton.name,
            "n_source_vertices": self.source.n_vertices,
            "n_target_vertices": self.target.n_vertices,
            "n_bones": self.skeleton.n_bones,
            "phases": history,
            "constraints": {
                "mode": cfg.constraints.mode,
                "eps": eps,
                "units": "g = mean squared distance in normalised units (source volume 4*pi/3); rms_distance in user units",
                "max_g_endpoint": float(g_ep.max()),
                "max_g_trajectory": float(g_tr.max()),
                "max_violation_ratio": float(max(g_ep.max(), g_tr.max()) / eps),
                "all_satisfied": bool(np.all(g_ep <= eps) and np.all(g_tr <= eps)),
                "bones": bones,
            },
            "correspondence": {
                "mean_distance_target_to_flowed_source": float(np.mean(maps["dist_tgt_to_src"]) / norm.scale),
                "mean_distance_flowed_source_to_target": float(np.mean(maps["dist_src_to_tgt"]) / norm.scale),
            },
            "compression": {f"{k[0]} sigma={k[1]:g}": v[2] for k, v in self.targets.items()},
            "tissue": self.tissue_info,
            "normalization": norm.to_dict(),
            "warnings": list(self.warnings),
            "timings": dict(self.timings),
            "config": config_to_dict(cfg),
            "versions": {
                "python": platform.python_version(),
                "jax": jax.__version__,
                "numpy": np.__version__,
                "scipy": scipy.__version__,
                "trimesh": trimesh.__version__,
                "equinox": eqx.__version__,
                "platform": platform.platform(),
                "device": str(jax.devices()[0]),
            },
        }
        skeleton_target = self.skeleton.with_positions(norm.invert(joints[-1]))
        return MatchResult(
            source=self.source,
            target=self.target,
            skeleton=self.skeleton,
            skeleton_target=skeleton_target,
            deformed_source=norm.invert(deformed_n),
            frame_times=frame_times,
            frames=norm.invert(frames_n),
            skeleton_frames=norm.invert(joints),
            maps=maps,
            metrics=metrics,
            normalization=norm,
            field=params.flow,
            n_times=cfg.flow.n_times,
        )


def match(source, target, skeleton, config: Config | None = None, *, quiet: bool = False, stream=None) -> MatchResult:
    """Match ``source`` to ``target`` with the source's ``skeleton`` (meshes/skeleton or file paths).

    Returns a :class:`MatchResult` (call ``.save(out_dir)`` for the output contract).
    """
    return Matcher(source, target, skeleton, config, quiet=quiet, stream=stream).run()
