"""Sparse Nyström compression of a measure (paper Algorithm 2).

A measure μ = Σ_j k(·, z_j) w_j (varifold or Normal Cycle, in the scaled features where the kernel
is exp(−‖z − z'‖²)) is replaced by μ_c = Σ_{c ∈ C} k(·, z_c) β_c on m representatives C ⊂ {z_j}:

1. ridge leverage scores ℓ_i = [K_B (K_B + λI)⁻¹]_ii of the kernel, computed inside random
   blocks B of ``block_size`` points (default ⌊√N⌋, the paper's blocked approximation);
2. m representatives drawn without replacement with probability ∝ ℓ (NumPy generator seeded
   by ``seed``: the same seed gives the same representatives);
3. β = (K_CC + αI)⁻¹ K_CN W, the regularised projection of μ onto span{k(·, z_c)} (float64
   Cholesky solve; α = ``jitter`` since every K_ii = 1).

Only the atoms of nonzero weight are candidates: rows of zero weight (a mesh padded to a size
bucket has them) are not part of the measure.

The relative error reported is the RKHS one, ‖μ − μ_c‖² / ‖μ‖², i.e. d(Y, Y_c)/⟨Y, Y⟩ in the
metric being compressed. Compression depends on the kernel width: compress once per σ.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg
from jaxtyping import Array, Float

from ncflow.errors import InputError
from ncflow.jit.buckets import pad_rows
from ncflow.measures.kernels import kernel_matvec, kernel_self_sum
from ncflow.measures.normal_cycles import NormalCycle, _nc_features
from ncflow.measures.varifold import Varifold, varifold_features


@dataclasses.dataclass(frozen=True)
class CompressionReport:
    """What a compression did and what it cost.

    Attributes:
        n: points of nonzero weight before compression (:func:`carrying_mass`).
        m: representatives kept.
        relative_error: ‖μ − μ_c‖²/‖μ‖² in the compressed metric (NaN if not computed: it needs
            the full measure's self-energy, N² kernel terms, so it is skipped above
            :data:`ERROR_MAX_POINTS` points).
        seconds: wall time of the compression.
        indices: (m,) indices of the representatives in the original measure.
    """

    n: int
    m: int
    relative_error: float
    seconds: float
    indices: np.ndarray

    def to_dict(self) -> dict:
        """The scalar fields (``n``, ``m``, ``relative_error``, ``seconds``) as a plain dict; ``indices`` left out."""
        rel = self.relative_error if np.isfinite(self.relative_error) else None
        return {"n": self.n, "m": self.m, "relative_error": rel, "seconds": self.seconds}


# one compiled program per shape (called eagerly, each blocked scan would be traced and compiled anew)
_matvec = jax.jit(kernel_matvec, static_argnames="block")
_self_sum = jax.jit(kernel_self_sum, static_argnames="block")

ERROR_MAX_POINTS = 50_000  # above this the reported error (N² kernel terms) would cost more than the match


def _gram(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    k = a @ b.T
    k *= 2.0
    k -= (a * a).sum(1)[:, None]
    k -= (b * b).sum(1)[None, :]
    np.minimum(k, 0.0, out=k)
    return np.exp(k, out=k)


def leverage_scores(
    z: Float[np.ndarray, "N D"], ridge: float = 0.1, block_size: int | None = None, seed: int = 0
) -> Float[np.ndarray, " N"]:
    """Blocked ridge leverage scores ℓ_i = [K_B (K_B + λI)⁻¹]_ii of exp(−‖z − z'‖²).

    Blocks are consecutive runs of a seeded random permutation, of ``block_size`` points
    (default ⌊√N⌋ as in Algorithm 2). ℓ_i = 1 − λ [(K_B + λI)⁻¹]_ii, and with K_B + λI = LLᵀ the
    diagonal of the inverse is the column sums of squares of L⁻¹ (LAPACK's triangular inverse):
    a third of the work of solving for the whole inverse (a 200k-vertex target's three compressions
    spend most of their time here).
    """
    z = np.asarray(z, dtype=np.float64)
    n = z.shape[0]
    rng = np.random.default_rng(seed)
    perm = rng.permutation(n)
    if block_size is None:
        block_size = int(np.sqrt(n))
    block_size = max(1, min(block_size, n))
    scores = np.empty(n)
    for start in range(0, n, block_size):
        idx = perm[start : start + block_size]
        k = _gram(z[idx], z[idx])
        k[np.diag_indices_from(k)] += ridge
        low = scipy.linalg.cholesky(k, lower=True, overwrite_a=True, check_finite=False)
        inv, info = scipy.linalg.lapack.dtrtri(low, lower=1, overwrite_c=1)
        if info != 0:
            raise InputError(f"leverage scores: the kernel block is singular (LAPACK dtrtri info {info})")
        scores[idx] = 1.0 - ridge * np.einsum("ki,ki->i", inv, inv)
    return np.clip(scores, 1e-12, None)


def carrying_mass(w: Float[Array, "N K"]) -> np.ndarray:
    """Indices of the rows of a measure's weights (N, K) that are not all zero: the atoms the
    measure has. A mesh padded to a size bucket (:func:`ncflow.jit.buckets.pad_mesh`) adds rows of zero
    weight, which no kernel sum sees and compression does not pick.
    """
    return np.flatnonzero(np.any(np.asarray(w) != 0, axis=1))


def _nystrom(
    z: Array,
    w: Array,
    live: np.ndarray,
    m: int,
    seed: int,
    ridge: float,
    jitter: float,
    block_size: int | None,
    report_error: bool,
) -> tuple[np.ndarray, np.ndarray, float, float]:
    t0 = time.perf_counter()
    z_np = np.asarray(z, dtype=np.float64)[live]
    n = z_np.shape[0]
    scores = leverage_scores(z_np, ridge=ridge, block_size=block_size, seed=seed)
    rng = np.random.default_rng([seed, 1])
    pick = np.sort(rng.choice(n, size=m, replace=False, p=scores / scores.sum()))
    idx = live[pick]
    zc = jnp.asarray(z_np[pick], dtype=z.dtype)
    rhs = np.asarray(_matvec(zc, z, w), dtype=np.float64)  # K_CN W, (m, K); zero-weight rows add nothing
    kcc = _gram(z_np[pick], z_np[pick])
    kcc[np.diag_indices_from(kcc)] += jitter
    factor = scipy.linalg.cho_factor(kcc.T, overwrite_a=True, check_finite=False)  # F-ordered view: no copy
    beta = scipy.linalg.cho_solve(factor, rhs, check_finite=False)
    del factor
    rel = float("nan")
    if report_error and n <= ERROR_MAX_POINTS:
        kcc = _gram(z_np[pick], z_np[pick])
        yy = float(_self_sum(z, w))
        cross = float(np.sum(beta * rhs))
        cc = float(np.sum(beta * (kcc @ beta)))
        rel = (yy - 2.0 * cross + cc) / yy if yy > 0 else 0.0
    return idx, beta, rel, time.perf_counter() - t0


def _exact(y, live: np.ndarray, m: int):
    """A measure with at most ``m`` points of nonzero weight (``live``), kept exactly: as it is when it
    has at most ``m`` rows, else its rows of nonzero weight followed by rows of zero weight up to
    ``m`` rows, so that a compressed measure always has min(m, rows) rows (a flat region's Normal
    Cycle rows weigh nothing; a compressed target's shape is known before it is built).
    """
    report = CompressionReport(live.size, live.size, 0.0, 0.0, live)
    if y.size <= m:
        return y, report
    return pad_rows(jax.tree_util.tree_map(lambda a: a[live], y), m), report


def _compress(y, z, w, m, seed, ridge, jitter, block_size, report_error):
    """Both metrics' compression of ``y`` (features z, weights w): (the measure kept exactly, None,
    its report) when it has at most ``m`` points of nonzero weight (:func:`_exact`), else (None, β
    of the representatives, the report whose ``indices`` are the representatives' rows).
    """
    live = carrying_mass(w)
    n = live.size
    if _check_m(m, n) >= n:
        kept, report = _exact(y, live, int(m))
        return kept, None, report
    idx, beta, rel, secs = _nystrom(z, w, live, int(m), seed, ridge, jitter, block_size, report_error)
    return None, beta, CompressionReport(n, int(m), rel, secs, idx)


def _check_m(m: int, n: int) -> int:
    if int(m) < 1:
        raise InputError(f"compressed size m must be at least 1 (got {m})")
    return min(int(m), n)


def compress_varifold(
    y: Varifold,
    m: int,
    sigma: float,
    sigma_normal: float = 0.5,
    *,
    seed: int = 0,
    ridge: float = 0.1,
    jitter: float = 1e-6,
    block_size: int | None = None,
    report_error: bool = True,
) -> tuple[Varifold, CompressionReport]:
    """Compress a varifold to m representative faces for kernel widths (σ, σ_n) (Algorithm 2).

    Returns:
        (the compressed varifold: representatives' centres and normals with weights β,
        the :class:`CompressionReport`). If m ≥ N, the number of faces of nonzero weight
        (:func:`carrying_mass`), the varifold is kept exactly: as it is if it has at most m rows,
        else its N faces of nonzero weight padded with rows of zero weight to m rows.
    """
    kept, beta, report = _compress(
        y, *varifold_features(y, sigma, sigma_normal), m, seed, ridge, jitter, block_size, report_error
    )
    if kept is not None:
        return kept, report
    idx = report.indices
    normals = np.asarray(y.normals)[idx]
    scale = np.exp((normals * normals).sum(1) / (4.0 * sigma_normal**2))  # undo the feature weight factor
    dtype = y.centers.dtype
    out = Varifold(
        centers=jnp.asarray(np.asarray(y.centers)[idx], dtype),
        normals=jnp.asarray(normals, dtype),
        weights=jnp.asarray(beta[:, 0] / scale, dtype),
    )
    return out, report


def compress_normal_cycle(
    y: NormalCycle,
    m: int,
    sigma: float,
    *,
    seed: int = 0,
    ridge: float = 0.1,
    jitter: float = 1e-6,
    block_size: int | None = None,
    report_error: bool = True,
) -> tuple[NormalCycle, CompressionReport]:
    """Compress a Normal Cycle to m representative points for kernel width σ (Algorithm 2).

    Leverage scores use the positional kernel; β (m, 12) carries the edge and boundary terms.
    If m ≥ N, the number of points of nonzero weight (:func:`carrying_mass`), the measure is
    kept exactly: as it is if it has at most m rows, else its N points of nonzero weight padded
    with rows of zero weight to m rows.
    """
    kept, beta, report = _compress(y, *_nc_features(y, sigma), m, seed, ridge, jitter, block_size, report_error)
    if kept is not None:
        return kept, report
    dtype = y.centers.dtype
    centers = jnp.asarray(np.asarray(y.centers)[report.indices], dtype)
    return NormalCycle(centers=centers, weights=jnp.asarray(beta, dtype)), report
