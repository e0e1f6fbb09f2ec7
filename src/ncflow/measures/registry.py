"""One table from metric name to (represent, inner product, compress): the only Varifold / Normal Cycles dispatch.

Used by the matcher's data term and target preparation, ``ncflow distance`` and the ablations.

Every entry takes the same arguments: ``represent(vertices, topology)`` builds the measure of a
mesh (the :class:`~ncflow.geometry.topology.Topology` carries the faces the Varifold needs and the
edge tables the Normal Cycle needs); ``inner(x, y, sigma, sigma_normal)`` is the kernel inner
product (the Normal Cycle kernel has no normal scale and ignores ``sigma_normal``);
``compress(y, m, sigma, sigma_normal, seed)`` is the Nyström compression of Algorithm 2;
``distance(x, y, sigma, sigma_normal)`` = ⟨X, X⟩ + ⟨Y, Y⟩ − 2⟨X, Y⟩.

``"varifold-q4"`` is the Varifold integrated at four points a face
(:data:`ncflow.measures.varifold.QUADRATURE`): a phase's ``metric = "varifold"`` with ``quadrature = 4``
(:func:`metric_key`). A measure of another shape, so it is a metric of its own to the compiled step.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from ncflow.measures.compression import CompressionReport, compress_normal_cycle, compress_varifold
from ncflow.measures.normal_cycles import normal_cycle, normal_cycle_distance, normal_cycle_inner
from ncflow.measures.varifold import varifold, varifold_distance, varifold_inner


@dataclasses.dataclass(frozen=True)
class Metric:
    """The three operations of one shape metric (see the module docstring for their arguments)."""

    name: str
    represent: Callable[..., Any]
    inner: Callable[..., Any]
    compress: Callable[..., tuple[Any, CompressionReport]]
    distance: Callable[..., Any]


def metric_key(metric: str, quadrature: int = 1) -> str:
    """The name in :data:`METRICS` of a phase's data term: ``metric`` integrated at ``quadrature`` points a
    face (the Varifold only; the Normal Cycle of a mesh has its points on the edges).
    """
    if quadrature == 1:
        return metric
    if metric != "varifold":
        raise ValueError(f"quadrature {quadrature} applies to the Varifold only, not to {metric!r}")
    return f"{metric}-q{quadrature}"


def _varifold_metric(quadrature: int) -> Metric:
    return Metric(
        name=metric_key("varifold", quadrature),
        represent=lambda vertices, topology: varifold(vertices, topology.faces, quadrature),
        inner=lambda x, y, sigma, sigma_normal: varifold_inner(x, y, sigma, sigma_normal),
        compress=lambda y, m, sigma, sigma_normal, seed: compress_varifold(y, m, sigma, sigma_normal, seed=seed),
        distance=lambda x, y, sigma, sigma_normal: varifold_distance(x, y, sigma, sigma_normal),
    )


METRICS: dict[str, Metric] = {
    m.name: m
    for m in (
        _varifold_metric(1),
        _varifold_metric(4),
        Metric(
            name="normal-cycles",
            represent=lambda vertices, topology: normal_cycle(vertices, topology),
            inner=lambda x, y, sigma, sigma_normal: normal_cycle_inner(x, y, sigma),
            compress=lambda y, m, sigma, sigma_normal, seed: compress_normal_cycle(y, m, sigma, seed=seed),
            distance=lambda x, y, sigma, sigma_normal: normal_cycle_distance(x, y, sigma),
        ),
    )
}


def get_metric(name: str) -> Metric:
    """The :class:`Metric` called ``name`` (``"varifold"``, ``"varifold-q4"`` or ``"normal-cycles"``)."""
    try:
        return METRICS[name]
    except KeyError:
        raise ValueError(f"unknown metric {name!r}; use one of {', '.join(METRICS)}") from None
