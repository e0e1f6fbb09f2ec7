"""Evaluation: metrics, geodesics, scoring a result folder, plots, aggregation and reports
(docs/evaluation.md). Running many pairs (batches, benchmarks) is :mod:`ncflow.runs`.

Also re-exports the ground-truth readers (:mod:`ncflow.io.ground_truth`) and the surface-point
helpers (:mod:`ncflow.geometry.closest`, :mod:`ncflow.geometry.barycentric`) that the metrics take
their inputs from.
"""

from ncflow.evaluate.geodesics import GeodesicInfo, insert_surface_points, pair_geodesic_distances
from ncflow.evaluate.metrics import (
    TAU_MAX,
    auc,
    bone_violation,
    chamfer_distances,
    conformal_distortion,
    error_summary,
    evaluate_correspondence,
    geodesic_errors,
    inverted_triangles,
    pck_curve,
    triangle_singular_values,
    unit_cube_scale,
    volume_change,
)
from ncflow.geometry.barycentric import surface_points, vertex_surface_points
from ncflow.geometry.closest import closest_points_on_surface, point_triangle_closest
from ncflow.io.ground_truth import (
    GT_FORMATS,
    GroundTruth,
    ground_truth_from_vertex_map,
    load_ground_truth,
    read_index_file,
    save_ground_truth,
)

__all__ = [
    "GT_FORMATS",
    "TAU_MAX",
    "GeodesicInfo",
    "GroundTruth",
    "auc",
    "bone_violation",
    "chamfer_distances",
    "closest_points_on_surface",
    "conformal_distortion",
    "error_summary",
    "evaluate_correspondence",
    "geodesic_errors",
    "ground_truth_from_vertex_map",
    "insert_surface_points",
    "inverted_triangles",
    "load_ground_truth",
    "pair_geodesic_distances",
    "pck_curve",
    "point_triangle_closest",
    "read_index_file",
    "save_ground_truth",
    "surface_points",
    "triangle_singular_values",
    "unit_cube_scale",
    "vertex_surface_points",
    "volume_change",
]

# Scoring a result folder (ncflow evaluate) and the benchmark report: appended exports.
from ncflow.evaluate.report import write_benchmark_report
from ncflow.evaluate.score import Evaluation, evaluate_result, evaluation_text, write_evaluation
from ncflow.io.arrays import json_safe

__all__ += [
    "Evaluation",
    "evaluate_result",
    "evaluation_text",
    "json_safe",
    "write_benchmark_report",
    "write_evaluation",
]
