"""Training: the optimiser, the jitted step and the loop over stages (paper §4.6; DESIGN.md "Optimiser").

The optimiser is the configured Adam-family transform (cautious AdaBelief or VectorAdam) behind one
global-norm clip, with the learning rate injected per step (:func:`optax.inject_hyperparams`; the
schedule and the divergence guard's scale are applied to it) and the skeleton pose's learning rate
scaled by ``flow.pose_lr_scale`` through :func:`optax.multi_transform`. Multipliers follow the
ramped sign ascent on the running mean of g of :func:`ncflow.optim.mdmm.update_multipliers`. A
:class:`~ncflow.matcher.guard.DivergenceGuard` rolls a stage back to its last healthy snapshot, at
half the learning rate, when the data term or the largest bone violation runs away.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from ncflow.errors import NcflowError
from ncflow.flow import GSONet, SkinnedField, make_flow_field
from ncflow.jit.cache import jit_run_once
from ncflow.matcher.guard import DivergenceGuard
from ncflow.matcher.objective import Arrays, Params, Settings, bone_cores, objective
from ncflow.matcher.prepare import DTYPE, skinning_width
from ncflow.matcher.progress import Progress
from ncflow.matcher.stages import Stage, phase_schedule
from ncflow.optim import adabelief_cautious, vectoradam_cautious
from ncflow.optim.mdmm import Multipliers, init_multipliers, multiplier_rate, update_multipliers
from ncflow.skeleton import Skeleton
from ncflow.skeleton.kinematics import Pose, rest_pose


class TrainingError(NcflowError):
    """The optimisation failed (a non-finite loss); nothing is written."""


def init_params(
    key,
    config,
    skeleton: Skeleton,
    pose: Pose | None = None,
    weight_mode: str = "current",
    arrays: Arrays | None = None,
) -> Params:
    """Flow field (skeleton-driven when ``flow.skinning``, starting at ``pose``, default the rest pose,
    its bone weights by ``weight_mode``, with rigid cores when ``flow.rigid_core``:
    :func:`~ncflow.matcher.objective.bone_cores` of the problem's ``arrays`` — around its bone samples,
    over the part of each bone inside the source — or, without them, at ``sampling.bone_radius`` over
    the samples' default range) and GSO-Net, initialised from ``key``.
    """
    kf, kg = jax.random.split(key)
    f = config.flow
    field = make_flow_field(kf, width=f.width, depth=f.depth, div_free=f.div_free, dtype=DTYPE)
    if f.skinning:
        core = outer = ranges = None
        if f.rigid_core > 0:
            radii = skeleton.bone_radii(config.sampling.bone_radius) if arrays is None else arrays.radii
            core, outer = bone_cores(skeleton, radii, f.rigid_core, None if arrays is None else arrays.inside)
            ranges = None if arrays is None else arrays.ranges
        field = SkinnedField(
            field,
            skeleton,
            pose=pose,
            width=skinning_width(config, skeleton),
            interp=config.interp,
            dtype=DTYPE,
            weight_mode=weight_mode,
            core=core,
            core_outer=outer,
            core_ranges=ranges,
        )
    return Params(field, GSONet(kg, width=f.gso_width, depth=f.gso_depth, dtype=DTYPE))


def parameter_labels(params: Params):
    """``"pose"`` on the leaves of a skeleton-driven field's pose, ``"frozen"`` on its bone-weight width
    τ (an array only so that compiled programs do not depend on it), ``"net"`` on every other leaf.
    """
    labels = jax.tree_util.tree_map(lambda _: "net", params)
    if isinstance(params.flow, SkinnedField):
        labels = eqx.tree_at(
            lambda p: p.flow.pose, labels, replace_fn=lambda sub: jax.tree_util.tree_map(lambda _: "pose", sub)
        )
        labels = eqx.tree_at(lambda p: p.flow.width, labels, "frozen")
        if params.flow.core is not None:
            labels = eqx.tree_at(lambda p: p.flow.core, labels, "frozen")
    return labels


def build_optimizer(config) -> optax.GradientTransformation:
    """Global-norm clip → per group (network / pose) the configured optimiser at the injected learning
    rate, the pose group's updates scaled by ``flow.pose_lr_scale``.
    """
    make = adabelief_cautious if config.optimizer == "adabelief" else vectoradam_cautious

    def factory(learning_rate):
        def group():
            return make(learning_rate, weight_decay=config.weight_decay, clip_norm=None)

        clip = optax.clip_by_global_norm(config.clip_norm) if config.clip_norm is not None else optax.identity()
        groups = {
            "net": group(),
            "pose": optax.chain(group(), optax.scale(config.flow.pose_lr_scale)),
            "frozen": optax.set_to_zero(),
        }
        return optax.chain(clip, optax.multi_transform(groups, parameter_labels))

    return optax.inject_hyperparams(factory, hyperparam_dtype=DTYPE)(learning_rate=1.0)


def make_step(arrays: Arrays, settings: Settings, optimizer: optax.GradientTransformation, constraints):
    """The jitted training step, one for every stage (the stage's metric is the traced ``which``).

    ``step(params, pose, opt_state, mult, targets, which, sigma, sigma_n, yy, cw, pose_rate, lr, progress, key)`` →
    ``(params, pose, opt_state, mult, aux)``: value and gradient of :func:`~ncflow.matcher.objective.objective`,
    one optimiser update at learning rate ``lr`` (the skeleton-driven field's pose moved by ``pose_rate`` of
    its update: 0 holds it, :func:`stage_inputs`), and (MDMM) one step of the multiplier rule
    (:func:`~ncflow.optim.mdmm.update_multipliers` with ``constraints``' rate and average; ``mult`` a
    :class:`~ncflow.optim.mdmm.Multipliers` of (2, B) arrays) at the rate ramped by ``progress`` (step / total
    steps).
    """
    c = constraints
    loss = functools.partial(objective, arrays=arrays, settings=settings)

    @eqx.filter_jit
    def step(params, pose, opt_state, mult, targets, which, sigma, sigma_n, yy, cw, pose_rate, lr, progress, key):
        (_, aux), grads = eqx.filter_value_and_grad(loss, has_aux=True)(
            params, pose, targets, which, sigma, sigma_n, yy, cw, mult.lam, key
        )
        opt_state = opt_state._replace(hyperparams={**opt_state.hyperparams, "learning_rate": lr})
        updates, opt_state = optimizer.update(grads, opt_state, eqx.filter(params, eqx.is_inexact_array))
        if hasattr(updates.flow, "pose"):  # a skeleton-driven field
            held = jax.tree_util.tree_map(lambda u: u * pose_rate, updates.flow.pose)
            updates = eqx.tree_at(lambda u: u.flow.pose, updates, held)
        params = eqx.apply_updates(params, updates)
        if settings.mode == "mdmm":
            g = jnp.stack([aux["g_ep"], aux["g_tr"]])
            active = (cw > 0).astype(mult.lam.dtype)[:, None]
            rate = multiplier_rate(c.multiplier_lr, progress)
            mult = update_multipliers(mult, g, settings.aim, rate, active, decay=c.multiplier_average)
        return params, aux.pop("pose"), opt_state, mult, aux

    return step


@dataclasses.dataclass(frozen=True)
class TrainingPrograms:
    """What the training compiles, built once per problem so that it can be compiled ahead
    (:mod:`ncflow.jit.ahead`) and then called: the parameter initialisation ``init(key, pose)``,
    the optimiser, the objective's settings and the jitted step (:func:`make_step`; one for every
    stage, the metric chosen by the traced index into ``settings.metrics``).
    """

    init: Callable
    optimizer: optax.GradientTransformation
    settings: Settings
    step: Callable
    weight_mode: str = "current"


def training_programs(
    arrays: Arrays, stages: list[Stage], config, n_centroids: int, weight_mode: str = "current"
) -> TrainingPrograms:
    """The :class:`TrainingPrograms` of a problem (nothing is compiled yet)."""
    cfg = config

    def initial_params(k, p):  # one program, not one per layer shape and operation
        return init_params(k, cfg, arrays.skeleton, p, weight_mode, arrays)

    optimizer = build_optimizer(cfg)
    metrics = tuple(dict.fromkeys(st.metric for st in stages))
    settings = Settings.from_config(cfg, metrics, arrays.n_edges, n_centroids, weight_mode)
    step = make_step(arrays, settings, optimizer, cfg.constraints)
    return TrainingPrograms(jit_run_once(initial_params), optimizer, settings, step, weight_mode)


@dataclasses.dataclass(frozen=True)
class TrainState:
    """What the training carries from step to step and hands on: the networks (the field's pose
    included), the pose of the per-step fit and the multiplier rule's state (:class:`~ncflow.optim.mdmm.Multipliers`
    of (2, B) arrays: endpoint, trajectory); a later match may start from it (:func:`train`'s ``start``).
    """

    params: Params
    pose: Pose
    multipliers: Multipliers

    @property
    def lam(self) -> jax.Array:
        """(2, B) the multipliers λ (endpoint, trajectory)."""
        return self.multipliers.lam


@dataclasses.dataclass(frozen=True)
class Trained:
    """What :func:`train` returns.

    Attributes:
        state: the trained :class:`TrainState`.
        phase_weights: (2,) the last stage's constraint weights (endpoint, trajectory).
        history: per stage, its phase, metric, σ, steps and final loss parts.
        steps: the steps run.
        rollbacks: the divergence guard's events.
    """

    state: TrainState
    phase_weights: jax.Array
    history: tuple[dict, ...]
    steps: int
    rollbacks: tuple[dict, ...]


def initial_state(
    programs: TrainingPrograms, skeleton: Skeleton, key, initial_pose: Pose | None, start: TrainState | None = None
):
    """(params, pose, optimiser state, multiplier state) at the start of training: fresh networks at
    ``initial_pose`` (default the rest pose), or the state of an earlier training (``start``) with a
    fresh optimiser state.
    """
    if start is not None:
        params, pose, mult = start.params, start.pose, start.multipliers
    else:
        params = programs.init(key, initial_pose)
        pose = rest_pose(skeleton, DTYPE) if initial_pose is None else initial_pose
        mult = init_multipliers(jnp.zeros((2, skeleton.n_bones), DTYPE))
    opt_state = programs.optimizer.init(eqx.filter(params, eqx.is_inexact_array))
    return params, pose, opt_state, mult


def stage_inputs(
    stage: Stage, metrics: tuple[str, ...], targets: dict, placeholders: dict, held_phases: tuple[int, ...] = ()
) -> tuple:
    """The step's per-stage arguments: (targets, which, σ, σ_n, ⟨Y, Y⟩, phase weights, pose rate). The other
    metrics' slots hold a target of the same shape (compression makes one per σ): unread. The pose rate
    is 0 in the phases ``held_phases`` (the skeleton-driven field's pose held where it is), else 1.
    """
    target, yy, _ = targets[(stage.metric, stage.sigma, stage.phase_config.sigma_normal)]
    stage_targets = tuple(target if m == stage.metric else placeholders[m] for m in metrics)
    pw = stage.phase_config.constraint_weight
    cw = jnp.asarray([pw, pw if stage.phase_config.trajectory else 0.0], DTYPE)
    which = jnp.asarray(metrics.index(stage.metric), jnp.int32)
    sigma, sigma_n, yy = (jnp.asarray(v, DTYPE) for v in (stage.sigma, stage.phase_config.sigma_normal, yy))
    pose_rate = jnp.asarray(0.0 if stage.phase in held_phases else 1.0, DTYPE)
    return stage_targets, which, sigma, sigma_n, yy, cw, pose_rate


def held_phases(config, weight_mode: str) -> tuple[int, ...]:
    """The phases in which the skeleton-driven field's pose is held at the pose search's: the first of
    several when the source's limbs touch (bone weights ``"surface"``,
    :func:`ncflow.matcher.prepare.skinning_weight_mode`) and ``flow.hold_contact_pose`` is on. At the first
    phase's coarse σ touching limbs merge in the data term: trained there, the pose moved fingers the
    search had right onto their neighbours (docs/tuning.md).
    """
    hold = weight_mode == "surface" and config.flow.hold_contact_pose and len(config.phases) > 1
    return (0,) if hold else ()


def stage_placeholders(stages: list[Stage], targets: dict) -> dict:
    """Per metric, the target of its last stage (what :func:`stage_inputs` puts in unread slots)."""
    return {st.metric: targets[(st.metric, st.sigma, st.phase_config.sigma_normal)][0] for st in stages}


def compile_step(programs: TrainingPrograms, skeleton: Skeleton, stages: list[Stage], targets: dict, key, pose):
    """Compile the step (and the initialisation) for ``targets`` — real ones or stand-ins of their
    shapes (:func:`ncflow.matcher.targets.target_stand_ins`) — without running it: the same
    arguments :func:`train` passes, so its first call finds the executable.
    """
    k_init, k_train = key
    params, pose, opt_state, mult = initial_state(programs, skeleton, k_init, pose)
    metrics = programs.settings.metrics
    inputs = stage_inputs(stages[0], metrics, targets, stage_placeholders(stages, targets))
    scalars = (jnp.asarray(1.0, DTYPE), jnp.asarray(0.0, DTYPE), jax.random.fold_in(k_train, 0))
    programs.step.lower(params, pose, opt_state, mult, *inputs, *scalars).compile()


def train(
    programs: TrainingPrograms,
    skeleton: Skeleton,
    targets: dict,
    stages: list[Stage],
    config,
    key,
    progress: Progress,
    initial_pose: Pose | None = None,
    start: TrainState | None = None,
    placeholders: dict | None = None,
) -> Trained:
    """Run every stage of ``stages`` with ``programs`` (:func:`training_programs`, perhaps compiled ahead).

    ``initial_pose`` (from :mod:`ncflow.matcher.pose_search`) starts the skeleton-driven field and the
    per-step pose fit; default the rest pose. ``start``: the state of an earlier training to go on
    from (a warm start; ``initial_pose`` is then not used). ``key``: (initialisation, training) keys.
    ``placeholders``: per metric of the step, a target of its shape for the slots of metrics no stage of
    ``stages`` reads (:func:`stage_placeholders`; needed when ``stages`` are some of those the step was
    built for). The multipliers' rate ramps over the steps of ``stages``.

    Raises:
        TrainingError: a non-finite loss or non-finite trained parameters.
    """
    cfg = config
    k_init, k_train = key
    params, pose, opt_state, mult = initial_state(programs, skeleton, k_init, initial_pose, start)
    metrics = programs.settings.metrics
    step = programs.step
    placeholders = {**(placeholders or {}), **stage_placeholders(stages, targets)}
    total = sum(st.steps for st in stages)
    held = held_phases(cfg, programs.weight_mode)
    history = []
    done = 0
    aux = None
    cw = None
    guard = DivergenceGuard(cfg.divergence_guard)
    for st in stages:
        stage_targets, which, sigma, sigma_n, yy, cw, pose_rate = stage_inputs(st, metrics, targets, placeholders, held)
        schedule = phase_schedule(st.phase_config)
        phase_name = st.phase_config.name or st.metric
        guard.start_stage((params, pose, opt_state, mult), watch_violation=done > 0)
        for s in range(st.steps):
            lr = jnp.asarray(schedule(st.start + s) * guard.lr_scale, DTYPE)
            params, pose, opt_state, mult, aux = step(
                params,
                pose,
                opt_state,
                mult,
                stage_targets,
                which,
                sigma,
                sigma_n,
                yy,
                cw,
                pose_rate,
                lr,
                jnp.asarray(done / total, DTYPE),
                jax.random.fold_in(k_train, done),
            )
            done += 1
            watch = np.asarray(aux["watch"], np.float64)  # one transfer: data term, largest g/ε
            verdict = guard.observe(float(watch[0]), (params, pose, opt_state, mult), done, float(watch[1]))
            if verdict != "ok":
                params, pose, opt_state, mult = guard.snapshot
                ev = guard.events[-1]
                progress.message(
                    f"[{phase_name} σ={st.sigma:g}] step {done}: the run went astray (data {ev['data_smoothed']:.3g}, "
                    f"best {ev['data_best']:.3g}; bone g/eps {ev['violation_smoothed']:.3g}, "
                    f"best {ev['violation_best']:.3g}); "
                    + ("rolled back, learning rate halved" if verdict == "rollback" else "rolled back, stage ended")
                )
                if verdict == "stop":
                    break
            if progress.wants_update(done, last=s == st.steps - 1):
                loss = float(aux["loss"])
                if not np.isfinite(loss):
                    progress.close()
                    raise TrainingError(
                        f"training diverged at step {done} ({phase_name}, sigma={st.sigma:g}): non-finite loss; "
                        "try a smaller learning rate (e.g. phases.lr) or check the inputs"
                    )
                progress.update(done, f"{phase_name} σ={st.sigma:g}", loss, float(watch[1]))
        guard.end_stage((params, pose, opt_state, mult), f"{phase_name} σ={st.sigma:g}")
        history.append(
            {
                "phase": phase_name,
                "metric": st.metric,
                "sigma": st.sigma,
                "steps": st.steps,
                **{k: float(aux[k]) for k in ("loss", "data", "surface", "tissue", "constraint", "leash")},
            }
        )
    params, pose, opt_state, mult = guard.finish((params, pose, opt_state, mult), done)
    if guard.events and "restored_stage_end" in guard.events[-1]:
        ev = guard.events[-1]
        progress.message(
            f"the last stage tore a bone (g/eps {ev['violation_smoothed']:.3g}, {ev['violation_best']:.3g} at the end "
            f"of {ev['restored_stage_end']}): the state at the end of {ev['restored_stage_end']} is kept"
        )
    progress.close()
    leaves = jax.tree_util.tree_leaves(eqx.filter(params, eqx.is_inexact_array))
    if not all(np.all(np.isfinite(np.asarray(leaf))) for leaf in leaves):  # on the host: no program per leaf shape
        raise TrainingError("training produced non-finite parameters")
    return Trained(TrainState(params, pose, mult), cw, tuple(history), done, tuple(guard.events))
