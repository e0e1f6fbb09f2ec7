"""Fixed-grid integration of the flow ODE dx/dt = F(x, t) and dense output.

Paper Eq. 13; DESIGN.md "Flow"; reference-notes §8.3.

Grid t_k = k/(T−1), k = 0..T−1, step h = 1/(T−1). The recursion is the one the release's
probabilistic solver (IWP(1) prior, EK0, fixed grid) reduces to exactly:

    v₀ = F(x₀, 0);   for k = 0..T−2:  x̃ = x_k + h v_k,  v_{k+1} = F(x̃, t_{k+1}),
                                      x_{k+1} = x_k + h/2 (v_k + v_{k+1}).

It is a Heun-type scheme (second order: the stored slope v_k is F at the predicted point, which is
within O(h²) of F(x_k, t_k)); T−1 field evaluations after the first, one per step. Off-grid
states are the cubic Hermite interpolant of (x_k, v_k), (x_{k+1}, v_{k+1}) — the smoother's
posterior mean. Each point's trajectory depends only on its own start, so any point set (e.g. the
full-resolution mesh) can be moved by a trained field (:func:`flow_points`).

A field is any callable ``field(x (N, 3), t scalar) -> (N, 3)``; Equinox modules and closures
both work. States and slopes are kept in the dtype of x0 (field outputs are cast to it).

Written here rather than taken from an ODE library: the recursion is a few lines of ``lax.scan``,
and a library's Heun method evaluates the slope at x_k as well as at the predicted point (two
field evaluations per step), which is not the release's scheme and gives other numbers.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ncflow.jit.buckets import pad_points

Field = Callable[[Float[Array, "N 3"], Float[Array, ""]], Float[Array, "N 3"]]


def time_grid(n_times: int = 10, dtype=jnp.float32) -> Float[Array, " T"]:
    """t_k = k/(T−1), k = 0..T−1 (T = ``n_times`` ≥ 2)."""
    if n_times < 2:
        raise ValueError(f"n_times must be at least 2, got {n_times}")
    return jnp.arange(n_times, dtype=dtype) / (n_times - 1)


def integrate(
    field: Field,
    x0: Float[Array, "N 3"],
    n_times: int = 10,
    checkpoint: bool = True,
    normals: Float[ArrayLike, "N C"] | None = None,
    anchors: Float[ArrayLike, "N 3"] | None = None,
) -> tuple[Float[Array, "T N 3"], Float[Array, "T N 3"]]:
    """Grid states and stored slopes of the Heun-type recursion above.

    Args:
        field: F(x (N, 3), t) -> (N, 3).
        x0: start points (N, 3).
        n_times: T, the number of grid times including 0 and 1 (default 10, as the release).
        checkpoint: rematerialise each step of the recursion in the backward pass (default): only the
            states carried from step to step are kept for it, and each step's field evaluations run
            again. Under differentiation on a CPU this is faster as well as smaller — the saved
            activations of every step cost more to write and read back than to recompute (a skinned
            field of the ``fast`` preset, 3,900 points, 21 bones with rigid cores, T = 10, forward and
            backward on one core: 300 → 165 ms; the paper's bare Flow-Net: 140 → 48 ms;
            benchmarks/RESULTS.md, session 54). Without differentiation it changes nothing.
        normals: (N, 3) the surface normals at the start points (zero rows where a point has none),
            read only by a field whose weights depend on them (a :class:`~ncflow.flow.SkinnedField`
            with ``weight_mode="surface"``).
        anchors: (N, 3) where a field whose weights are those of the start takes each point's weights
            (default x0): a tissue stencil's points anchored at its centre share one blend of the bones'
            rigid velocities, itself rigid.

    Returns:
        xs (T, N, 3) with xs[0] = x0 and xs[-1] the state at t = 1, and vs (T, N, 3) the slopes v_k.

    A field with an ``on_grid(n_times, dtype, x0, n0)`` method (:class:`~ncflow.flow.SkinnedField`) is
    replaced by what it returns: the same field with its time-only parts tabulated on the grid and
    its parts that depend on each point's start (the skinned field's bone weights) computed at x0
    (and ``normals``). When that grid field has an articulated part it can step in closed form
    (``articulated_step``), the recursion moves points by it exactly and applies the Heun-type update to
    the rest (:func:`_integrate_split`).
    """
    x0 = jnp.asarray(x0)
    ts = time_grid(n_times, x0.dtype)
    if hasattr(field, "on_grid"):
        field = field.on_grid(n_times, x0.dtype, x0 if anchors is None else jnp.asarray(anchors, x0.dtype), normals)
    h = jnp.asarray(1.0 / (n_times - 1), x0.dtype)

    def f(x, t):
        return field(x, t).astype(x0.dtype)

    if hasattr(field, "articulated_step"):
        return _integrate_split(field, x0, ts, h, checkpoint)
    v0 = f(x0, ts[0])

    def step(carry, t_next):
        x, v = carry
        v_next = f(x + h * v, t_next)
        x_next = x + 0.5 * h * (v + v_next)
        return (x_next, v_next), (x_next, v_next)

    _, (xs, vs) = jax.lax.scan(_remat(step, checkpoint), (x0, v0), ts[1:])
    return jnp.concatenate([x0[None], xs]), jnp.concatenate([v0[None], vs])


def _integrate_split(field, x0, ts, h, checkpoint):
    """The recursion above for a field F = S + R whose articulated part S moves points by bones' rigid
    motions known in closed form (a skinned field on the grid, :meth:`articulated_step`): each step
    carries x_k by S exactly (no error however far a bone turns in one step) and adds R by the same
    Heun-type update, x̃ = S_k(x_k) + h r_k, r_{k+1} = R(x̃, t_{k+1}), x_{k+1} = S_k(x_k) + h/2 (r_k + r_{k+1});
    the stored slopes are v_k = S'(x_k, t_k) + r_k (for the dense output).
    """

    def r(x, t):
        return field.residual_velocity(x, t).astype(x0.dtype)

    w0 = field.weights_at(x0, 0)
    r0 = r(x0, ts[0])
    v0 = field.articulated_velocity(x0, 0, w0).astype(x0.dtype) + r0

    def step(carry, inputs):
        x, r_k, w = carry
        k, t_next = inputs
        y = field.articulated_step(x, k, w).astype(x0.dtype)
        r_next = r(y + h * r_k, t_next)
        x_next = y + 0.5 * h * (r_k + r_next)
        w_next = field.weights_at(x_next, k + 1)
        v_next = field.articulated_velocity(x_next, k + 1, w_next).astype(x0.dtype) + r_next
        return (x_next, r_next, w_next), (x_next, v_next)

    _, (xs, vs) = jax.lax.scan(_remat(step, checkpoint), (x0, r0, w0), (jnp.arange(ts.shape[0] - 1), ts[1:]))
    return jnp.concatenate([x0[None], xs]), jnp.concatenate([v0[None], vs])


def _remat(step, checkpoint: bool):
    """The scan's step, rematerialised in the backward pass when ``checkpoint`` (:func:`integrate`)."""
    return jax.checkpoint(step) if checkpoint else step


def hermite(xs: Float[Array, "T N 3"], vs: Float[Array, "T N 3"], t_query: Float[Array, " Q"]) -> Float[Array, "Q N 3"]:
    """Cubic Hermite interpolation of grid states and slopes at times t_query ⊂ [0, 1].

    On [t_k, t_{k+1}] with s = (t − t_k)/h:
    x(t) = (2s³−3s²+1) x_k + (s³−2s²+s) h v_k + (−2s³+3s²) x_{k+1} + (s³−s²) h v_{k+1}.
    Times that are grid times up to rounding return the grid state exactly; times outside [0, 1]
    extrapolate the first/last cubic.
    """
    n = xs.shape[0]
    t = jnp.atleast_1d(jnp.asarray(t_query, dtype=xs.dtype))
    h = 1.0 / (n - 1)
    u = t * (n - 1)
    k = jnp.clip(jnp.floor(u), 0, n - 2).astype(jnp.int32)
    s = (u - k)[:, None, None]
    s2, s3 = s * s, s * s * s
    cubic = (
        (2 * s3 - 3 * s2 + 1) * xs[k]
        + (s3 - 2 * s2 + s) * h * vs[k]
        + (-2 * s3 + 3 * s2) * xs[k + 1]
        + (s3 - s2) * h * vs[k + 1]
    )
    nearest = jnp.clip(jnp.round(u), 0, n - 1).astype(jnp.int32)
    on_grid = jnp.abs(u - nearest) <= 16 * jnp.finfo(xs.dtype).eps * (n - 1)
    return jnp.where(on_grid[:, None, None], xs[nearest], cubic)


@eqx.filter_jit
def _flow_jit(field, points, normals, n_times, times, checkpoint, chunk_size):
    n = points.shape[0]
    if chunk_size is None or n <= chunk_size:
        xs, vs = integrate(field, points, n_times, checkpoint, normals)
    else:
        pad = (-n) % chunk_size
        p = jnp.concatenate([points, jnp.broadcast_to(points[:1], (pad, 3))]).reshape(-1, chunk_size, 3)
        if normals is None:
            xs, vs = jax.lax.map(lambda c: integrate(field, c, n_times, checkpoint), p)  # (C, T, chunk, 3)
        else:
            q = jnp.concatenate([normals, jnp.broadcast_to(normals[:1], (pad, 3))]).reshape(-1, chunk_size, 3)
            xs, vs = jax.lax.map(lambda c: integrate(field, c[0], n_times, checkpoint, c[1]), (p, q))
        xs = jnp.moveaxis(xs, 0, 1).reshape(n_times, -1, 3)[:, :n]
        vs = jnp.moveaxis(vs, 0, 1).reshape(n_times, -1, 3)[:, :n]
    return xs if times is None else hermite(xs, vs, times)


def flow_points(
    field: Field,
    points: Float[Array, "N 3"],
    n_times: int = 10,
    times: Float[Array, " Q"] | None = None,
    checkpoint: bool = False,
    chunk_size: int | None = None,
    normals: Float[ArrayLike, "N C"] | None = None,
) -> Float[Array, "T_or_Q N 3"]:
    """Move any point set by a (trained) field: the grid states (T, N, 3), or the Hermite frames
    (Q, N, 3) at ``times`` when given; ``normals`` (N, 3) as :func:`integrate`'s. Identical to
    :func:`integrate` on the same points (each trajectory is independent), so the result is
    resolution-agnostic. ``chunk_size`` processes the
    points in chunks of that many rows (bounded memory for large meshes). Jitted; the points are
    padded to a size bucket (:func:`ncflow.jit.buckets.pad_points`, copies of the first point) so that
    point sets of similar size share the compiled program.
    """
    points = jnp.asarray(points)
    times = None if times is None else jnp.asarray(times, dtype=points.dtype)
    n = points.shape[0]
    if normals is not None:
        normals = pad_points(jnp.asarray(normals, points.dtype))
    out = _flow_jit(field, pad_points(points), normals, n_times, times, checkpoint, chunk_size)
    return out[:, :n] if out.shape[1] > n else out
