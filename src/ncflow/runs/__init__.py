"""Many pairs at once: ``pairs.csv`` (:func:`read_pairs_csv`), the Dask engine and cluster, batches of
matches (:func:`run_batch`, ``ncflow batch``) and benchmarks that score them (:func:`run_benchmark`,
``ncflow benchmark``).
"""

from ncflow.runs.batch import BatchResult, run_batch
from ncflow.runs.benchmark import ABLATIONS, BenchmarkResult, benchmark_methods, run_benchmark
from ncflow.runs.pairs_csv import PairSpec, read_pairs_csv

__all__ = [
    "ABLATIONS",
    "BatchResult",
    "BenchmarkResult",
    "PairSpec",
    "benchmark_methods",
    "read_pairs_csv",
    "run_batch",
    "run_benchmark",
]
