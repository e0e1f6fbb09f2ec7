"""Soft-tissue samples: tetrahedralise the source once, split large tetrahedra, sample centroids.

Paper §4.4 "Uniform Volumetric Sampling", Fig. 5; DESIGN.md "Soft tissue"; reference-notes §7.1.

Pipeline, run once on the (normalised) source surface:

1. :func:`tetrahedralize_surface` — fTetWild through the compiled extension of ``pytetwild``.
   Open surfaces are first closed with :func:`ncflow.geometry.topology.close_boundary` (a fan of
   triangles to each boundary loop's centroid, the same closing used for the enclosed volume), so
   the tets fill the volume that :func:`ncflow.geometry.mesh.enclosed_volume` measures. Tets are
   re-oriented to positive volume (fTetWild returns them negatively oriented) and zero-volume tets
   are dropped.
2. :func:`split_tets` — a few passes of longest-edge bisection of every tet whose volume exceeds
   ``volume_factor`` × the current mean volume (optionally also of tets whose longest/shortest
   edge ratio exceeds ``edge_ratio``, the release's second criterion). Bisection at the midpoint
   of the longest edge gives two tets of exactly half the volume each, so the total is unchanged.
   This narrows the volume distribution from above; it cannot merge small tets (reference-notes
   §7.1: splitting does not equalise volume in general).
3. :func:`tet_centroids` — the sample locations; :func:`sample_tissue` draws n of them without
   replacement from a JAX key at every training step.

:func:`soft_tissue` runs 1–3 and returns a :class:`Tissue`; :func:`tissue_centroids` is what the
matcher calls: 1–3 with the configured settings, cached per surface (below).

pytetwild quirks handled here (DESIGN.md "Machine facts"): pytetwild 0.4.2 imports pyvista at
package import although the numpy path does not need it, so the compiled ``PyfTetWildWrapper``
extension is loaded directly without executing ``pytetwild/__init__.py``; fTetWild writes
``__tracked_surface.stl`` into the current directory, so it runs inside a temporary directory.

Reproducibility: fTetWild is **not deterministic** (repeated calls on the same surface return
different meshes, and it has no seed; measurements in docs/tuning.md), while everything after it
(splitting, keyed sampling) is. So :func:`tissue_centroids` caches the first tetrahedralisation of
each surface and settings (``$NCFLOW_CACHE_DIR``, default ``~/.cache/ncflow``) and reuses it;
outside the matcher, keep the :class:`Tissue` arrays (e.g. ``np.savez``) to reproduce a run.
"""

from __future__ import annotations

import functools
import glob
import hashlib
import importlib.machinery
import importlib.util
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from ncflow.errors import InputError
from ncflow.geometry.topology import close_boundary
from ncflow.io.atomic import atomic_path, computed_once
from ncflow.io.files import read_npz_arrays
from ncflow.jit.buckets import draw_rows
from ncflow.jit.cache import cache_root

DEFAULT_EDGE_LENGTH_FAC = 0.1
"""Ideal tet edge length relative to the bounding-box diagonal (the release uses 0.05; coarser here)."""
DEFAULT_EPSILON = 5e-3
"""fTetWild envelope size relative to the bounding-box diagonal (fTetWild default 1e-3; coarser here)."""
DEFAULT_VOLUME_FACTOR = 1.25
"""Split tets whose volume exceeds this multiple of the current mean volume (the release's value)."""
DEFAULT_SPLIT_PASSES = 3
"""Number of bisection passes (the release runs 2 with an additional edge-ratio criterion)."""

MIN_THICKNESS = 1e-3
"""Surfaces whose thinnest principal extent is below this share of the widest are refused before
fTetWild (which keeps no tet of them, and sometimes crashes on them)."""

# the six edges of a tet as pairs of local vertex slots
_TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])


class Tissue(NamedTuple):
    """Tetrahedral filling of a closed (or closed-up) surface and its centroids.

    Attributes:
        vertices: (P, 3) tet vertices (fTetWild's plus the bisection midpoints), float64.
        tets: (K, 4) positively oriented tets, int64.
        centroids: (K, 3) mean of each tet's four vertices — the soft-tissue sample locations.
        volumes: (K,) tet volumes (all > 0).
        n_tets_initial: number of tets fTetWild returned, before splitting.
    """

    vertices: Float[np.ndarray, "P 3"]
    tets: Int[np.ndarray, "K 4"]
    centroids: Float[np.ndarray, "K 3"]
    volumes: Float[np.ndarray, " K"]
    n_tets_initial: int


# ----------------------------------------------------------------------------------------------
# fTetWild


@functools.lru_cache(maxsize=1)
def _ftetwild_extension():
    """The compiled ``pytetwild.PyfTetWildWrapper`` module, loaded without ``pytetwild/__init__.py``."""
    name = "pytetwild.PyfTetWildWrapper"
    if name in sys.modules:  # pytetwild was imported normally (pyvista present): reuse it
        return sys.modules[name]
    spec = importlib.util.find_spec("pytetwild")
    if spec is None or not spec.submodule_search_locations:
        raise InputError(
            "soft-tissue sampling needs fTetWild: install the 'pytetwild' package, or disable the soft-tissue term"
        )
    candidates = []
    for directory in spec.submodule_search_locations:
        candidates += sorted(glob.glob(os.path.join(directory, "PyfTetWildWrapper*.so")))
        candidates += sorted(glob.glob(os.path.join(directory, "PyfTetWildWrapper*.pyd")))
    if not candidates:
        raise InputError("the installed 'pytetwild' package has no compiled PyfTetWildWrapper extension")
    loader = importlib.machinery.ExtensionFileLoader(name, candidates[0])
    ext_spec = importlib.util.spec_from_file_location(name, candidates[0], loader=loader)
    module = importlib.util.module_from_spec(ext_spec)
    loader.exec_module(module)
    # registered so that a later regular ``import pytetwild`` reuses it instead of initialising twice
    sys.modules[name] = module
    return module


def _validate_surface(vertices: np.ndarray, faces: np.ndarray) -> None:
    if vertices.ndim != 2 or vertices.shape[1] != 3 or vertices.shape[0] < 4:
        raise InputError(f"tetrahedralisation needs vertices of shape (V >= 4, 3), got {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.shape[0] < 4:
        raise InputError(f"tetrahedralisation needs triangle faces of shape (F >= 4, 3), got {faces.shape}")
    if not np.all(np.isfinite(vertices)):
        raise InputError("tetrahedralisation: surface has non-finite vertex coordinates")
    if faces.min() < 0 or faces.max() >= vertices.shape[0]:
        raise InputError(f"tetrahedralisation: face indices outside 0..{vertices.shape[0] - 1}")
    # fTetWild 0.4.2 crashes the process (segfault) on some coplanar inputs, e.g. a flat square
    # given as four triangles: refuse flat surfaces before calling it
    used = vertices[np.unique(faces)]
    spread = np.linalg.svd(used - used.mean(axis=0), compute_uv=False)
    if spread[0] == 0.0 or spread[-1] <= 1e-9 * spread[0]:
        raise InputError("tetrahedralisation: the surface is flat (all vertices on one plane) and encloses no volume")
    # it also crashes now and then on nearly flat ones (a slab 1e-4 thick: a segfault in one test run
    # of twenty-odd); far thinner than the envelope, fTetWild would keep no tet of them anyway
    if spread[-1] <= MIN_THICKNESS * spread[0]:
        raise InputError(
            "tetrahedralisation: no tetrahedra — the surface is nearly flat (thinner than "
            f"{MIN_THICKNESS:.1%} of its width) and encloses no volume at this resolution"
        )


def tetrahedralize_surface(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    edge_length_fac: float = DEFAULT_EDGE_LENGTH_FAC,
    epsilon: float = DEFAULT_EPSILON,
    optimize: bool = True,
    num_threads: int = 0,
    num_opt_iter: int = 80,
    stop_energy: float = 10.0,
) -> tuple[Float[np.ndarray, "P 3"], Int[np.ndarray, "K 4"]]:
    """Fill the volume enclosed by a triangle surface with tetrahedra (fTetWild, Hu et al. 2020).

    Args:
        vertices: (V, 3) surface vertices.
        faces: (F, 3) triangles. Open surfaces are closed first by
            :func:`ncflow.mesh.close_boundary` (fans to the boundary-loop centroids).
        edge_length_fac: ideal tet edge length relative to the bounding-box diagonal (fTetWild
            ``-l``; default 0.1, coarse — the release uses 0.05).
        epsilon: envelope size relative to the bounding-box diagonal, the maximal distance of the
            tet boundary from the input surface (fTetWild ``-e``; default 5e-3, coarse — fTetWild's
            default is 1e-3). Larger values simplify more and run faster; the tet volume is then
            typically 1–2 % below the enclosed volume.
        optimize: run fTetWild's quality optimisation (default True; without it tets are far
            from uniform).
        num_threads: fTetWild threads (0: all cores).
        num_opt_iter: maximal number of fTetWild optimisation passes (its default, 80).
        stop_energy: fTetWild stops optimising once the worst tet's AMIPS energy is below this
            (its default, 10).

    Returns:
        (vertices (P, 3) float64, tets (K, 4) int64), every tet positively oriented
        (det[v1 − v0, v2 − v0, v3 − v0] > 0); zero-volume tets are dropped.

    Not deterministic (see the module docstring). Runs in a temporary working directory, so
    fTetWild's ``__tracked_surface.stl`` does not leak into the caller's directory; quiet.

    Raises:
        InputError: pytetwild is missing, the surface is malformed, fTetWild fails, or it returns
            no tetrahedra.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    _validate_surface(vertices, faces)
    if not 0.0 < edge_length_fac <= 1.0:
        raise InputError(f"tetrahedralisation: edge_length_fac must be in (0, 1], got {edge_length_fac}")
    if not epsilon > 0.0:
        raise InputError(f"tetrahedralisation: epsilon must be positive, got {epsilon}")
    v, f = close_boundary(vertices, faces.astype(np.int64))
    ext = _ftetwild_extension()
    cwd = os.getcwd()
    with tempfile.TemporaryDirectory(prefix="ncflow-ftetwild-") as tmp:
        os.chdir(tmp)
        try:
            tv, tt = ext.tetrahedralize_mesh(
                np.ascontiguousarray(v, dtype=np.float64),
                np.ascontiguousarray(f, dtype=np.uint32),
                bool(optimize),
                False,  # skip_simplify
                float(edge_length_fac),
                0.0,  # edge_length_abs: 0 → use edge_length_fac
                float(epsilon),
                float(stop_energy),
                False,  # coarsen
                int(num_threads),
                int(num_opt_iter),
                6,  # loglevel: minimal
                True,  # quiet
                False,  # vtk_ordering
                False,  # disable_filtering: keep the inside/outside filtering
                np.empty((0, 3), dtype=np.float64),  # no sizing field
                np.empty((0, 4), dtype=np.int32),
                np.empty(0, dtype=np.float64),
            )
        except Exception as exc:  # fTetWild raises RuntimeError (or worse) on bad input
            raise InputError(f"fTetWild failed to tetrahedralise the surface: {exc}") from exc
        finally:
            os.chdir(cwd)
    tv = np.asarray(tv, dtype=np.float64).reshape(-1, 3)
    tt = np.asarray(tt, dtype=np.int64).reshape(-1, 4)
    if tt.shape[0] == 0 or tv.shape[0] < 4:
        raise InputError(
            "fTetWild returned no tetrahedra: the surface encloses no volume at this resolution "
            "(is it a flat sheet, or much thinner than epsilon × bounding-box diagonal?)"
        )
    vol = tet_volumes(tv, tt)
    flip = vol < 0
    tt[flip] = tt[flip][:, [1, 0, 2, 3]]
    vol = np.abs(vol)
    keep = vol > 1e-12 * vol.max()
    if not np.any(keep):
        raise InputError("fTetWild returned only degenerate (zero-volume) tetrahedra")
    return tv, tt[keep]


# ----------------------------------------------------------------------------------------------
# splitting, centroids


def tet_volumes(vertices: Float[np.ndarray, "P 3"], tets: Int[np.ndarray, "K 4"]) -> Float[np.ndarray, " K"]:
    """Signed volumes det[v1 − v0, v2 − v0, v3 − v0] / 6, (K,)."""
    p = np.asarray(vertices, dtype=np.float64)[np.asarray(tets)]
    a, b, c = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]
    return np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0


def tet_centroids(vertices: Float[np.ndarray, "P 3"], tets: Int[np.ndarray, "K 4"]) -> Float[np.ndarray, "K 3"]:
    """Centroids (mean of the four vertices), (K, 3)."""
    return np.asarray(vertices, dtype=np.float64)[np.asarray(tets)].mean(axis=1)


def _bisect(vertices: np.ndarray, tets: np.ndarray, flag: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split the flagged tets at the midpoint m of their longest edge (a, b) into (…a→m…) and (…b→m…).

    Replacing one endpoint of an edge by its midpoint halves the signed volume (it is linear in each
    vertex), so both children keep the orientation and have exactly half the volume. Midpoints of an
    edge shared by several flagged tets are created once.
    """
    idx = np.flatnonzero(flag)
    if idx.size == 0:
        return vertices, tets
    sel = tets[idx]
    p = vertices[sel]
    length2 = np.sum((p[:, _TET_EDGES[:, 0]] - p[:, _TET_EDGES[:, 1]]) ** 2, axis=-1)  # (k, 6)
    longest = np.argmax(length2, axis=1)
    slot_a, slot_b = _TET_EDGES[longest, 0], _TET_EDGES[longest, 1]
    rows = np.arange(idx.size)
    a, b = sel[rows, slot_a], sel[rows, slot_b]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    keys, inverse = np.unique(np.stack([lo, hi], 1), axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    mids = 0.5 * (vertices[keys[:, 0]] + vertices[keys[:, 1]])
    m = vertices.shape[0] + inverse
    child_a = sel.copy()
    child_a[rows, slot_a] = m  # a replaced by m
    child_b = sel.copy()
    child_b[rows, slot_b] = m  # b replaced by m
    return np.concatenate([vertices, mids]), np.concatenate([tets[~flag], child_a, child_b])


def split_tets(
    vertices: Float[np.ndarray, "P 3"],
    tets: Int[np.ndarray, "K 4"],
    volume_factor: float = DEFAULT_VOLUME_FACTOR,
    passes: int = DEFAULT_SPLIT_PASSES,
    edge_ratio: float | None = None,
) -> tuple[Float[np.ndarray, "P2 3"], Int[np.ndarray, "K2 4"]]:
    """Longest-edge bisection towards near-uniform tet volume (paper §4.4; reference-notes §7.1).

    In each of up to ``passes`` passes, every tet with volume > ``volume_factor`` × (mean volume of
    the current tets) — or, when ``edge_ratio`` is given, with longest/shortest edge length >
    ``edge_ratio`` — is split at the midpoint of its longest edge into two tets of half its volume.
    Stops early when no tet is flagged. The total volume is preserved exactly (up to rounding), and
    orientation is kept. The resulting mesh is non-conforming (hanging midpoints), which does not
    matter for centroid sampling.

    The release uses ``volume_factor=1.25, edge_ratio=1.25, passes=2`` (≈ 4× tets: the edge-ratio
    test flags almost every tet); the default here is the volume criterion only, 3 passes (measured
    on an 8k-vertex capsule: 1620 → 3272 tets, max/mean volume 5.95 → 1.54, coefficient of
    variation 0.83 → 0.27).

    Returns:
        (vertices (P2, 3), tets (K2, 4)); the input vertices come first, unchanged.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64)
    if volume_factor <= 0:
        raise InputError(f"split_tets: volume_factor must be positive, got {volume_factor}")
    for _ in range(int(passes)):
        vol = np.abs(tet_volumes(vertices, tets))
        flag = vol > volume_factor * vol.mean()
        if edge_ratio is not None:
            p = vertices[tets]
            lengths = np.linalg.norm(p[:, _TET_EDGES[:, 0]] - p[:, _TET_EDGES[:, 1]], axis=-1)
            flag |= lengths.max(1) > edge_ratio * lengths.min(1)
        if not np.any(flag):
            break
        vertices, tets = _bisect(vertices, tets, flag)
    return vertices, tets


def soft_tissue(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    edge_length_fac: float = DEFAULT_EDGE_LENGTH_FAC,
    epsilon: float = DEFAULT_EPSILON,
    volume_factor: float = DEFAULT_VOLUME_FACTOR,
    passes: int = DEFAULT_SPLIT_PASSES,
    edge_ratio: float | None = None,
    num_threads: int = 0,
) -> Tissue:
    """Tetrahedralise a (normalised) source surface once, split, and return centroids (paper §4.4).

    :func:`tetrahedralize_surface` then :func:`split_tets`; see both for the arguments.
    """
    tv, tt = tetrahedralize_surface(
        vertices, faces, edge_length_fac=edge_length_fac, epsilon=epsilon, num_threads=num_threads
    )
    n0 = int(tt.shape[0])
    sv, st = split_tets(tv, tt, volume_factor=volume_factor, passes=passes, edge_ratio=edge_ratio)
    return Tissue(sv, st, tet_centroids(sv, st), tet_volumes(sv, st), n0)


# ----------------------------------------------------------------------------------------------
# per-step sampling


def sample_tissue(
    key: PRNGKeyArray, centroids: Float[Array, "K 3"], n: int, valid: Bool[Array, " K"] | None = None
) -> Float[Array, "n 3"]:
    """Draw ``n`` of the K centroids uniformly **without replacement** (a random permutation prefix).

    Keyed and deterministic given ``key``; jit-compatible (``n`` static). The rows keep the dtype of
    ``centroids``. When ``n`` ≥ K all K centroids are returned, in random order (shape (K, 3)).
    ``valid`` (K,) marks the real rows of centroids padded to a size bucket
    (:func:`ncflow.jit.buckets.bucket`): the draw is the first ``n`` real rows of the same
    permutation (so with every row real it is the draw without ``valid``); ``n`` must not exceed
    the number of real rows.
    """
    centroids = jnp.asarray(centroids)
    return centroids[draw_rows(key, centroids.shape[0], n, valid)]


def _tool_versions() -> str:
    from importlib.metadata import PackageNotFoundError, version

    out = []
    for name in ("ncflow", "pytetwild"):
        try:
            out.append(f"{name}={version(name)}")
        except PackageNotFoundError:
            out.append(f"{name}=?")
    return ",".join(out)


def centroids_digest(centroids: np.ndarray) -> str:
    """SHA-256 of the centroids (float64, C order): the identity of a tissue, recorded in ``metrics.json``."""
    return hashlib.sha256(np.ascontiguousarray(centroids, np.float64).tobytes()).hexdigest()


def load_tissue_file(path, vertices: np.ndarray) -> np.ndarray:
    """Centroids (K, 3) from a tissue file (an ``.npz`` with ``centroids``, e.g. a cache entry named
    in an earlier run's ``metrics.json``), checked: finite, (K, 3), inside the source's bounding box
    (normalised coordinates) up to 5 % of its size.
    """
    c = np.asarray(read_npz_arrays(path, ("centroids",), ())["centroids"], np.float64)
    if c.ndim != 2 or c.shape[1] != 3 or c.shape[0] < 1:
        raise InputError(f"tissue file: centroids must be (K, 3), got {c.shape}", path)
    if not np.all(np.isfinite(c)):
        raise InputError("tissue file: centroids are not all finite", path)
    lo, hi = vertices.min(0), vertices.max(0)
    pad = 0.05 * float(np.max(hi - lo))
    if np.any(c < lo - pad) or np.any(c > hi + pad):
        raise InputError("tissue file: centroids lie outside the source (made for another source?)", path)
    return c


def tissue_centroids(
    vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], settings
) -> tuple[np.ndarray, dict]:
    """Tet centroids of the (normalised) source; cached per surface, settings and tool versions.

    ``settings`` is a :class:`ncflow.config.TissueConfig` (``edge_length_fac``, ``epsilon``,
    ``split_passes``, ``cache``).

    fTetWild is not deterministic (the same surface gives slightly different tets from run to run),
    so the first tetrahedralisation of a surface is cached (``$NCFLOW_CACHE_DIR``, default
    ``~/.cache/ncflow``) and reused: repeated runs on one machine are then reproducible. Concurrent
    runs on one source take a lock, so one of them tetrahedralises and the others read its entry.
    The returned info holds the entry's path (``cache_file``, reusable with ``ncflow match
    --tissue``) and the centroids' SHA-256 (``sha256``).
    """
    tc = settings
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(vertices, np.float64).tobytes())
    h.update(np.ascontiguousarray(faces, np.int64).tobytes())
    h.update(repr((tc.edge_length_fac, tc.epsilon, tc.split_passes)).encode())
    h.update(_tool_versions().encode())
    path = cache_root() / "tissue" / f"{h.hexdigest()[:32]}.npz"
    if not tc.cache:
        return _tetrahedralise(vertices, faces, tc, {"cached": False})

    def read(entry):
        return np.asarray(read_npz_arrays(entry, ("centroids",), ())["centroids"]), None

    (c, info), entry, hit = computed_once(
        path,
        lambda: _tetrahedralise(vertices, faces, tc, {"cached": False}),
        read,
        lambda tmp, value: _save_centroids(tmp, value[0]),
    )
    if hit:
        info = {"cached": True, "n_centroids": int(c.shape[0]), "seconds": 0.0, "sha256": centroids_digest(c)}
    if entry is not None:
        info["cache_file"] = str(entry)
    return c, info


def write_tissue_file(path, centroids: np.ndarray) -> None:
    """Write centroids as a tissue file (``.npz`` with ``centroids``; read by :func:`load_tissue_file`),
    atomically: a reader never sees a half-written file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        _save_centroids(tmp, centroids)


def _save_centroids(file, centroids: np.ndarray) -> None:
    """The tissue file's format, written where told (a temporary sibling of the final name)."""
    np.savez(file, centroids=centroids)


def _tetrahedralise(vertices, faces, tc, info: dict) -> tuple[np.ndarray, dict]:
    t0 = time.perf_counter()
    tissue = soft_tissue(
        vertices, faces, edge_length_fac=tc.edge_length_fac, epsilon=tc.epsilon, passes=tc.split_passes
    )
    c = np.asarray(tissue.centroids)
    info.update(
        n_tets_initial=int(tissue.n_tets_initial),
        n_centroids=int(c.shape[0]),
        seconds=time.perf_counter() - t0,
        sha256=centroids_digest(c),
    )
    return c, info
