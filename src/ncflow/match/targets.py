"""Target measures per length scale: the target's Varifold / Normal Cycle, compressed once per
(metric, σ, σ_n) when larger than ``config.compress`` (Algorithm 2; DESIGN.md "Compression"), with
its self-energy ⟨Y, Y⟩ that normalises the data term. A target left uncompressed is padded to a
size bucket with rows of zero weight (:func:`ncflow.buckets.pad_rows`), so targets of similar size
share the compiled step.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ncflow.buckets import MESH_PER_OCTAVE, bucket, pad_rows
from ncflow.errors import InputError
from ncflow.match.prepare import DTYPE, Problem
from ncflow.match.stages import Stage
from ncflow.measures.registry import get_metric

TargetKey = tuple[str, float, float]  # (metric, sigma, sigma_normal)


def target_measures(
    problem: Problem, stages: list[Stage], config, message=lambda text: None
) -> dict[TargetKey, tuple[Any, float, dict]]:
    """For every distinct (metric, σ, σ_n) of the stages: (target measure, ⟨Y, Y⟩, compression report).

    Raises:
        InputError: the target has no measurable surface (a non-finite or zero self-energy).
    """
    targets: dict[TargetKey, tuple[Any, float, dict]] = {}
    ty = jnp.asarray(problem.target_vertices, DTYPE)
    full = {}
    for st in stages:
        key = (st.metric, st.sigma, st.phase_config.sigma_normal)
        if key in targets:
            continue
        metric = get_metric(st.metric)
        if st.metric not in full:  # jitted: one program, not one per operation
            full[st.metric] = jax.jit(lambda v, m=metric: m.represent(v, problem.target_topology))(ty)
        y = full[st.metric]
        report = {"n": int(y.size), "m": int(y.size), "relative_error": 0.0, "seconds": 0.0}
        if compressed(y.size, config):
            message(f"compressing the target ({st.metric}, sigma={st.sigma:g}) to {config.compress} points ...")
            y, rep = metric.compress(y, config.compress, st.sigma, st.phase_config.sigma_normal, config.seed)
            report = rep.to_dict()
        else:  # compressed targets all have ``compress`` rows; the others are padded to a size bucket
            y = jax.jit(pad_rows, static_argnums=1)(y, bucket(y.size, per_octave=MESH_PER_OCTAVE))
        yy = float(jax.jit(lambda y, s, n, m=metric: m.inner(y, y, s, n))(y, st.sigma, st.phase_config.sigma_normal))
        if not np.isfinite(yy) or yy <= 0:
            raise InputError("the target has no measurable surface (zero self-energy)", problem.target.name)
        targets[key] = (y, yy, report)
    return targets


def compressed(size: int, config) -> bool:
    """Whether a target measure of ``size`` points is compressed (to ``config.compress`` rows)."""
    return bool(config.compress and size > config.compress)


def target_stand_ins(problem: Problem, stages: list[Stage], config) -> dict[TargetKey, tuple[Any, float, dict]]:
    """What :func:`target_measures` returns, in shape only: zero measures of the rows the target's
    would have (``compress``, or its size bucket) and ⟨Y, Y⟩ = 1, without placing or compressing
    anything — the target's size does not change when it is placed. For compiling the training
    step ahead (:mod:`ncflow.match.ahead`).
    """
    out: dict[TargetKey, tuple[Any, float, dict]] = {}
    vertices = jax.ShapeDtypeStruct(problem.target_vertices.shape, DTYPE)
    for st in stages:
        metric = get_metric(st.metric)
        shape = jax.eval_shape(lambda v, m=metric: m.represent(v, problem.target_topology), vertices)
        n = shape.centers.shape[0]
        rows = config.compress if compressed(n, config) else bucket(n, per_octave=MESH_PER_OCTAVE)
        y = jax.tree_util.tree_map(lambda a, r=rows: jnp.zeros((r, *a.shape[1:]), a.dtype), shape)
        out[(st.metric, st.sigma, st.phase_config.sigma_normal)] = (y, 1.0, {})
    return out
