"""Target measures per length scale: the target's Varifold / Normal Cycle, compressed once per
(metric, σ, σ_n) when larger than ``config.compress`` (Algorithm 2; DESIGN.md "Compression"), with
its self-energy ⟨Y, Y⟩ that normalises the data term. The target mesh is padded to its size
buckets first (:func:`ncflow.jit.buckets.pad_mesh`: rows of zero weight in its measures), so targets of
similar size share the compiled programs of their measures, their compression and the training step.

A partial target (:mod:`ncflow.matcher.partial`) has its cut borders left out of its measures before they
are compressed, and every target measure travels with the source's weights ω of what the target shows
(:class:`TargetMeasure`; all ones for a whole target), which the training's data term restricts the
flowed source's measure by (:func:`ncflow.measures.partial.restrict`).
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ncflow.errors import InputError
from ncflow.jit.buckets import pad_mesh, pad_points
from ncflow.matcher.partial import Shown
from ncflow.matcher.place import Placed
from ncflow.matcher.prepare import DTYPE, Setup
from ncflow.matcher.stages import Stage
from ncflow.measures.partial import restrict
from ncflow.measures.registry import get_metric

TargetKey = tuple[str, float, float]  # (metric, sigma, sigma_normal)


class TargetMeasure(eqx.Module):
    """A target measure (Varifold or Normal Cycle, perhaps compressed) and the weights ω of the working
    source's vertices (padded to its size bucket) that the target shows (:mod:`ncflow.matcher.partial`).
    """

    measure: Any
    source_weights: Any  # (V,) training dtype


def source_rows(problem: Setup) -> int:
    """The working source's vertex rows in the training (padded to its size bucket)."""
    return int(pad_points(np.zeros((problem.working.vertices.shape[0], 3))).shape[0])


def target_measures(
    problem: Setup, placed: Placed, stages: list[Stage], config, message=lambda text: None, shown: Shown | None = None
) -> dict[TargetKey, tuple[TargetMeasure, float, dict]]:
    """For every distinct (metric, σ, σ_n) of the stages: (target measure, ⟨Y, Y⟩, compression report),
    of the target placed as ``placed`` says; ``shown``: what it shows of the source (None: all of it).

    Raises:
        InputError: the target has no measurable surface (a non-finite or zero self-energy).
    """
    targets: dict[TargetKey, tuple[Any, float, dict]] = {}
    placed_vertices = placed.placement.apply(problem.target_vertices)
    ty, topology = pad_mesh(jnp.asarray(placed_vertices, DTYPE), problem.target_topology)
    rows = source_rows(problem)
    weights = np.ones(rows)
    if shown is not None and shown.active:
        weights[: shown.source.shape[0]] = shown.source
    source_weights = jnp.asarray(weights, DTYPE)
    target_weights = None
    if shown is not None and shown.active:
        target_weights = np.ones(ty.shape[0])
        target_weights[: shown.target.shape[0]] = shown.target
        target_weights = jnp.asarray(target_weights, DTYPE)
    full = {}
    for st in stages:
        key = (st.metric, st.sigma, st.phase_config.sigma_normal)
        if key in targets:
            continue
        metric = get_metric(st.metric)
        if st.metric not in full:  # jitted: one program, not one per operation

            def target_measure(v, w, m=metric):
                y = m.represent(v, topology)
                return y if w is None else restrict(y, topology, w)

            full[st.metric] = jax.jit(target_measure)(ty, target_weights), _rows(problem, metric)
        y, n = full[st.metric]  # the padded mesh's measure (the target's, with rows of zero weight), its real rows
        report = {"n": n, "m": n, "relative_error": 0.0, "seconds": 0.0}
        if compressed(n, config):
            message(f"compressing the target ({st.metric}, sigma={st.sigma:g}) to {config.compress} points ...")
            y, rep = metric.compress(y, config.compress, st.sigma, st.phase_config.sigma_normal, config.seed)
            report = rep.to_dict()
        yy = float(jax.jit(lambda y, s, n, m=metric: m.inner(y, y, s, n))(y, st.sigma, st.phase_config.sigma_normal))
        if not np.isfinite(yy) or yy <= 0:
            raise InputError("the target has no measurable surface (zero self-energy)", problem.target.name)
        targets[key] = (TargetMeasure(y, source_weights), yy, report)
    return targets


def compressed(size: int, config) -> bool:
    """Whether a target measure of ``size`` points is compressed (to ``config.compress`` rows)."""
    return bool(config.compress and size > config.compress)


def target_stand_ins(problem: Setup, stages: list[Stage], config) -> dict[TargetKey, tuple[TargetMeasure, float, dict]]:
    """What :func:`target_measures` returns, in shape only: zero measures of the rows the target's
    would have (``compress``, or its size bucket) and ⟨Y, Y⟩ = 1, without placing or compressing
    anything — the target's size does not change when it is placed. For compiling the training
    step ahead (:mod:`ncflow.jit.ahead`).
    """
    out: dict[TargetKey, tuple[Any, float, dict]] = {}
    shapes = {}
    for st in stages:
        if st.metric not in shapes:
            metric = get_metric(st.metric)
            shape = _represented(problem, metric, padded=True)
            rows = config.compress if compressed(_rows(problem, metric), config) else shape.centers.shape[0]
            shapes[st.metric] = jax.tree_util.tree_map(lambda a, r=rows: jnp.zeros((r, *a.shape[1:]), a.dtype), shape)
        stand_in = TargetMeasure(shapes[st.metric], jnp.ones(source_rows(problem), DTYPE))
        out[(st.metric, st.sigma, st.phase_config.sigma_normal)] = (stand_in, 1.0, {})
    return out


def _represented(problem: Setup, metric, padded: bool):
    """The shapes of the target's measure in ``metric`` (nothing computed), of the mesh padded to its
    size buckets (:func:`ncflow.jit.buckets.pad_mesh`) or as it is.
    """

    def measure(v):
        topology = problem.target_topology
        if padded:
            v, topology = pad_mesh(v, topology)
        return metric.represent(v, topology)

    return jax.eval_shape(measure, jax.ShapeDtypeStruct(problem.target_vertices.shape, DTYPE))


def _rows(problem: Setup, metric) -> int:
    """The number of points of the target's measure in ``metric``, padding not counted."""
    return int(_represented(problem, metric, padded=False).centers.shape[0])
