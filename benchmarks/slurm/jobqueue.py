"""``ncflow batch`` on SLURM through dask-jobqueue: this process holds the scheduler, SLURM jobs hold the workers.

Run it on a login node (or in a small job) with ncflow and dask-jobqueue installed
(``pip install dask-jobqueue``); inputs and --out on a file system the compute nodes see:

    python benchmarks/slurm/jobqueue.py pairs/pairs.csv results/ --jobs 32 -- --preset fast --steps 300

Each SLURM job runs one worker process with one task at a time (``cores=1``) and ``--cpus-per-task``
CPUs for JAX (``job_cpu``, ``PJRT_NPROC``). The scheduler gives up on a pair at the first worker death
and hands out one pair per worker (ncflow retries a failed pair once itself). The cluster is scaled
to a fixed number of jobs: ``ncflow batch --scheduler`` submits every pair at once, so
``cluster.adapt(minimum_jobs=1, maximum_jobs=N)`` also works instead.
"""

from __future__ import annotations

import argparse
import subprocess
import sys


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pairs")
    ap.add_argument("out")
    ap.add_argument("--jobs", type=int, default=8, help="SLURM jobs (one worker each)")
    ap.add_argument("--cpus", type=int, default=1, help="CPUs per job (JAX threads; one per worker is the fastest)")
    ap.add_argument("--memory", default="4GB")
    ap.add_argument("--walltime", default="04:00:00")
    ap.add_argument("--queue", default=None, help="SLURM partition")
    ap.add_argument("ncflow_args", nargs=argparse.REMAINDER, help="options after -- go to ncflow batch")
    a = ap.parse_args()

    import dask
    from dask_jobqueue import SLURMCluster

    dask.config.set({"distributed.scheduler.allowed-failures": 0, "distributed.scheduler.worker-saturation": 1.0})
    cluster = SLURMCluster(
        cores=1,  # one pair at a time per worker
        processes=1,
        job_cpu=a.cpus,
        memory=a.memory,
        walltime=a.walltime,
        queue=a.queue,
        job_script_prologue=[
            f"export PJRT_NPROC={a.cpus}",
            'export XLA_FLAGS="${XLA_FLAGS:-} --xla_cpu_multi_thread_eigen=false"',
            "export OMP_NUM_THREADS=1",
            # the nanny would set MALLOC_TRIM_THRESHOLD_=65536, which makes XLA:CPU's allocations 4x slower
            """export DASK_DISTRIBUTED__NANNY__PRE_SPAWN_ENVIRON='{"MALLOC_TRIM_THRESHOLD_": None}'""",
        ],
    )
    print(cluster.job_script(), flush=True)
    cluster.scale(jobs=a.jobs)
    try:
        extra = [x for x in a.ncflow_args if x != "--"]
        cmd = ["ncflow", "batch", a.pairs, "--out", a.out, "--scheduler", cluster.scheduler_address, *extra]
        return subprocess.call(cmd)
    finally:
        cluster.close()


if __name__ == "__main__":
    sys.exit(main())
