"""Geometric measures of surfaces: Varifolds, Normal Cycles, kernel sums, Nyström compression and merged Diracs."""

from ncflow.measures.compression import CompressionReport, compress_normal_cycle, compress_varifold, leverage_scores
from ncflow.measures.kernels import kernel_matvec, kernel_self_sum, kernel_sum
from ncflow.measures.merge import merge_diracs
from ncflow.measures.normal_cycles import NormalCycle, normal_cycle, normal_cycle_distance, normal_cycle_inner
from ncflow.measures.partial import restrict, restrict_normal_cycle, restrict_varifold
from ncflow.measures.registry import METRICS, Metric, get_metric
from ncflow.measures.varifold import Varifold, varifold, varifold_distance, varifold_inner

__all__ = [
    "METRICS",
    "Metric",
    "get_metric",
    "CompressionReport",
    "NormalCycle",
    "Varifold",
    "compress_normal_cycle",
    "compress_varifold",
    "kernel_matvec",
    "kernel_self_sum",
    "kernel_sum",
    "leverage_scores",
    "merge_diracs",
    "normal_cycle",
    "normal_cycle_distance",
    "normal_cycle_inner",
    "restrict",
    "restrict_normal_cycle",
    "restrict_varifold",
    "varifold",
    "varifold_distance",
    "varifold_inner",
]
