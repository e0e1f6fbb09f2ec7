"""Evaluation: correspondence, Chamfer and distortion metrics, ground-truth readers (docs/evaluation.md)."""

from ncflow.evaluate.geodesics import (
    GeodesicInfo,
    insert_surface_points,
    pair_geodesic_distances,
    surface_points,
    vertex_surface_points,
)
from ncflow.evaluate.ground_truth import (
    GT_FORMATS,
    GroundTruth,
    ground_truth_from_vertex_map,
    load_ground_truth,
    read_index_file,
    save_ground_truth,
)
from ncflow.evaluate.metrics import (
    TAU_MAX,
    auc,
    bone_violation,
    chamfer_distances,
    closest_points_on_surface,
    conformal_distortion,
    error_summary,
    evaluate_correspondence,
    geodesic_errors,
    inverted_triangles,
    pck_curve,
    point_triangle_closest,
    triangle_singular_values,
    unit_cube_scale,
    volume_change,
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

# Reports (ncflow evaluate) and the benchmark runner (ncflow benchmark): appended exports.
from ncflow.evaluate.benchmark import (
    ABLATIONS,
    BenchmarkResult,
    PairSpec,
    benchmark_methods,
    read_pairs_csv,
    run_benchmark,
)
from ncflow.evaluate.report import (
    Evaluation,
    evaluate_result,
    evaluation_text,
    json_safe,
    write_benchmark_report,
    write_evaluation,
)

__all__ += [
    "ABLATIONS",
    "BenchmarkResult",
    "Evaluation",
    "PairSpec",
    "benchmark_methods",
    "evaluate_result",
    "evaluation_text",
    "json_safe",
    "read_pairs_csv",
    "run_benchmark",
    "write_benchmark_report",
    "write_evaluation",
]
