"""Ground-truth correspondences: for target vertices, the true point on the source surface.

Formats (``fmt``; auto-detected from the suffix unless given):

``"identity"``
    Same vertex order (the string ``"identity"`` instead of a path); the meshes must have the
    same number of vertices.
``"vts"`` (suffix ``.vts``)
    Text, one 1-based source vertex index per line, one line per target vertex (the convention
    of FAUST/SCAPE/TOPKIDS template maps). Blank lines and lines starting with ``#`` are skipped.
``"index"`` (suffixes ``.txt``, ``.npy``)
    0-based source vertex indices, one per target vertex: a text file with one integer per line,
    or a 1-D integer ``.npy`` array (the format of ``p2p_tgt_to_src.txt``).
``"npz"`` (suffix ``.npz``)
    Arrays ``face`` (n,) int and ``bary`` (n, 3) float — the source face and barycentric
    coordinates of each target vertex (the format of ``map_tgt_to_src.npz``); an optional array
    ``target_index`` (n,) makes it partial (only those target vertices have ground truth).
``"template"`` (a pair of paths)
    Two ``.vts`` files mapping a common template's sample points to the source's and the
    target's vertices (1-based, one line per template point, same number of lines: the
    FAUST_r/SCAPE_r/SHREC'19 convention). Line k says source vertex S[k] ↔ target vertex T[k];
    the result is partial (target vertices listed; the first line wins for repeats).

Vertex maps become surface points on the lowest-index face containing the vertex, with one-hot
barycentrics. Every problem raises :class:`~ncflow.errors.InputError` with one line naming the file.
Arrays are read without pickles and their headers checked before allocating
(:func:`ncflow.io.files.read_npy_array`); a ``.npz`` is inflated only for ``face``, ``bary`` and
``target_index``, and only when they total at most :func:`npz_byte_limit` bytes (what a map of the
target's vertices can need).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError, first_line
from ncflow.geometry.barycentric import vertex_surface_points
from ncflow.geometry.mesh import Mesh
from ncflow.io.atomic import atomic_path
from ncflow.io.files import MAX_ARRAY_BYTES, check_regular_file, dtype_text, read_npy_array, read_npz_arrays, short_repr

GT_FORMATS = ("identity", "vts", "index", "npz", "template")
_SUFFIX_FORMAT = {".vts": "vts", ".txt": "index", ".npy": "index", ".npz": "npz"}
BARY_TOL = 1e-4


@dataclasses.dataclass(frozen=True)
class GroundTruth:
    """True source points of (some) target vertices.

    Attributes:
        face: (K,) source face index of each entry.
        bary: (K, 3) barycentric coordinates in that face (≥ 0, summing to 1).
        target_index: (K,) the target vertex of each entry (``arange(n_target)`` when complete).
        n_target: number of target vertices.
        name: where it came from.
    """

    face: Int[np.ndarray, " K"]
    bary: Float[np.ndarray, "K 3"]
    target_index: Int[np.ndarray, " K"]
    n_target: int
    name: str | None = None

    @property
    def complete(self) -> bool:
        """Every target vertex has ground truth, in order."""
        return self.target_index.size == self.n_target and bool(np.all(self.target_index == np.arange(self.n_target)))


def ground_truth_from_vertex_map(
    source_vertex: Int[np.ndarray, " K"],
    source: Mesh,
    n_target: int,
    target_index: Int[np.ndarray, " K"] | None = None,
    name: str | None = None,
) -> GroundTruth:
    """Ground truth from 0-based source vertex indices (one per target vertex, or per ``target_index``)."""
    idx = np.asarray(source_vertex, dtype=np.int64)
    try:
        face, bary = vertex_surface_points(idx, source.faces, source.n_vertices)
    except ValueError as exc:
        raise InputError(f"ground truth: {exc} of the source mesh", name) from None
    ti = np.arange(n_target) if target_index is None else np.asarray(target_index, dtype=np.int64)
    return GroundTruth(face=face, bary=bary, target_index=ti, n_target=int(n_target), name=name)


# ----------------------------------------------------------------------------------------------
# Reading


def npz_byte_limit(n_target: int) -> int:
    """Largest total size of the arrays read from a ground-truth ``.npz`` for a target of ``n_target`` vertices.

    ``face``, ``bary`` (three values) and ``target_index`` take at most 5 × 16 bytes per target
    vertex; the limit is twice that plus 1 MiB, and at most :data:`~ncflow.io.files.MAX_ARRAY_BYTES`.
    """
    return min(MAX_ARRAY_BYTES, 160 * int(n_target) + 2**20)


class _Where:
    """Names entries in messages (``entry 6``, ``line 7``) without building one string per entry."""

    def __init__(self, prefix: str, numbers: list[int] | None = None):
        self.prefix, self.numbers = prefix, numbers

    def __getitem__(self, k: int) -> str:
        return f"{self.prefix} {k if self.numbers is None else self.numbers[k]}"


def _parse_integers(path: Path, values: np.ndarray, where) -> np.ndarray:
    """Integers from a numeric array; NaN, infinite, huge and non-integral values are errors."""
    nan = np.isnan(values)
    if np.any(nan):
        raise InputError(f"{int(nan.sum())} entries are NaN (first: {where[int(np.argmax(nan))]})", path)
    frac = (values != np.round(values)) | (np.abs(values) > 2**62)
    if np.any(frac):
        k = int(np.argmax(frac))
        raise InputError(f"{where[k]}: expected an integer vertex index, got {values[k]:g}", path)
    return values.astype(np.int64)


def read_index_file(path: str | os.PathLike) -> Int[np.ndarray, " n"]:
    """Integers of a text file (one per line; blank and ``#`` lines skipped) or of a 1-D ``.npy`` array.

    Raises:
        InputError: missing/unreadable file, several values on a line, a non-number, NaN, a
            non-integral value, or a ``.npy`` array that is not 1-D.
    """
    return _read_indices(Path(path))[0]


def _read_indices(path: Path) -> tuple[np.ndarray, _Where]:
    """(integers, where each came from: "line 7" or "entry 6")."""
    check_regular_file(path, "ground-truth")
    if path.suffix.lower() == ".npy":
        with open(path, "rb") as fh:
            magic = fh.read(6)
        if magic != b"\x93NUMPY":
            raise InputError("cannot read .npy array (not a NumPy .npy file)", path)
        arr = read_npy_array(path)
        if arr.ndim == 2 and 1 in arr.shape:
            arr = arr.reshape(-1)
        if arr.ndim != 1:
            raise InputError(f"expected a 1-D array of vertex indices, got shape {arr.shape}", path)
        where = _Where("entry")
        if arr.size == 0:
            raise InputError("empty array", path)
        if np.issubdtype(arr.dtype, np.integer):
            if arr.dtype == np.uint64 and np.any(arr > 2**62):
                raise InputError("vertex indices out of range (above 2**62)", path)
            return arr.astype(np.int64), where
        if not np.issubdtype(arr.dtype, np.floating):
            raise InputError(f"expected integer vertex indices, got dtype {dtype_text(arr.dtype)}", path)
        return _parse_integers(path, arr.astype(np.float64), where), where
    try:
        text = path.read_text(errors="strict")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read text ({first_line(exc)})", path) from None
    values, lines = [], []
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        tokens = s.replace(",", " ").split()
        if len(tokens) != 1:
            raise InputError(f"line {lineno}: expected one vertex index per line, got {len(tokens)} values", path)
        try:
            values.append(float(tokens[0]))
        except ValueError:
            raise InputError(f"line {lineno}: not a number: {tokens[0][:40]!r}", path) from None
        lines.append(lineno)
    if not values:
        raise InputError("no vertex indices in file (empty?)", path)
    where = _Where("line", lines)
    return _parse_integers(path, np.asarray(values), where), where


def _check_range(idx: np.ndarray, where: _Where, path, one_based: bool, mesh: str, n: int) -> None:
    lo = 1 if one_based else 0
    hi = n - 1 + lo
    bad = (idx < lo) | (idx > hi)
    if np.any(bad):
        k = int(np.argmax(bad))
        base = "1-based" if one_based else "0-based"
        raise InputError(
            f"{where[k]}: {mesh} vertex {int(idx[k])} is out of range [{lo}, {hi}] ({base} indices, the {mesh} has "
            f"{n} vertices; {int(bad.sum())} entries out of range)",
            path,
        )


def _check_count(got: int, expected: int, path) -> None:
    if got != expected:
        raise InputError(f"wrong number of entries: expected {expected} (one per target vertex), got {got}", path)


def _load_vertex_map(path: Path, source: Mesh, target: Mesh, one_based: bool) -> GroundTruth:
    idx, where = _read_indices(path)
    _check_count(idx.size, target.n_vertices, path)
    _check_range(idx, where, path, one_based, "source", source.n_vertices)
    return ground_truth_from_vertex_map(idx - int(one_based), source, target.n_vertices, name=str(path))


def _load_npz(path: Path, source: Mesh, target: Mesh, bary_tol: float) -> GroundTruth:
    check_regular_file(path, "ground-truth")
    arrays = read_npz_arrays(path, ("face", "bary"), ("target_index",), max_bytes=npz_byte_limit(target.n_vertices))
    face, bary = arrays["face"], arrays["bary"]
    if face.ndim != 1:
        raise InputError(f"array 'face' must be 1-D, got shape {face.shape}", path)
    if bary.ndim != 2 or bary.shape[1] != 3:
        raise InputError(f"array 'bary' must have shape (n, 3), got {bary.shape}", path)
    if bary.shape[0] != face.shape[0]:
        raise InputError(f"arrays 'face' ({face.shape[0]}) and 'bary' ({bary.shape[0]}) differ in length", path)
    if "target_index" in arrays:
        ti = arrays["target_index"]
        if ti.ndim != 1 or ti.shape[0] != face.shape[0] or not np.issubdtype(ti.dtype, np.integer):
            got = f"{dtype_text(ti.dtype)} {short_repr(ti.shape, 40)}"
            raise InputError(f"array 'target_index' must be integers of shape ({face.shape[0]},), got {got}", path)
        bad = (ti < 0) | (ti >= target.n_vertices)
        if np.any(bad):
            k = int(np.argmax(bad))
            raise InputError(
                f"target_index entry {k} is {int(ti[k])}, out of range [0, {target.n_vertices - 1}] for the target",
                path,
            )
        if np.unique(ti).size != ti.size:
            raise InputError("array 'target_index' lists a target vertex twice", path)
        ti = ti.astype(np.int64)
    else:
        _check_count(face.shape[0], target.n_vertices, path)
        ti = np.arange(target.n_vertices)
    if np.issubdtype(face.dtype, np.floating):
        face = _parse_integers(path, face.astype(np.float64), _Where("face entry"))
    elif not np.issubdtype(face.dtype, np.integer):
        raise InputError(f"array 'face' must hold integers, got dtype {dtype_text(face.dtype)}", path)
    face = face.astype(np.int64)
    bad = (face < 0) | (face >= source.n_faces)
    if np.any(bad):
        k = int(np.argmax(bad))
        raise InputError(
            f"entry {k} is source face {int(face[k])}, out of range [0, {source.n_faces - 1}] "
            f"({int(bad.sum())} entries out of range)",
            path,
        )
    bary = _check_bary(bary, path, bary_tol)
    return GroundTruth(face=face, bary=bary, target_index=ti, n_target=target.n_vertices, name=str(path))


def _check_bary(bary: np.ndarray, path, tol: float) -> np.ndarray:
    if not np.issubdtype(bary.dtype, np.floating) and not np.issubdtype(bary.dtype, np.integer):
        raise InputError(f"array 'bary' must hold numbers, got dtype {dtype_text(bary.dtype)}", path)
    b = bary.astype(np.float64)
    nan = ~np.all(np.isfinite(b), axis=1)
    if np.any(nan):
        raise InputError(
            f"{int(nan.sum())} barycentric rows are NaN or infinite (first: entry {int(np.argmax(nan))})", path
        )
    s = b.sum(1)
    off = np.abs(s - 1.0) > tol
    if np.any(off):
        k = int(np.argmax(off))
        raise InputError(
            f"barycentric coordinates of entry {k} sum to {s[k]:.6g}, not 1 "
            f"(tolerance {tol:g}; {int(off.sum())} entries)",
            path,
        )
    neg = b.min(1) < -tol
    if np.any(neg):
        k = int(np.argmax(neg))
        raise InputError(
            f"barycentric coordinates of entry {k} have a negative component {b[k].min():.6g} (tolerance {tol:g}; "
            f"{int(neg.sum())} entries)",
            path,
        )
    b = np.clip(b, 0.0, None)
    return b / b.sum(1, keepdims=True)


def _load_template(paths, source: Mesh, target: Mesh) -> GroundTruth:
    ps, pt = (Path(p) for p in paths)
    s, ws = _read_indices(ps)
    t, wt = _read_indices(pt)
    if s.size != t.size:
        raise InputError(
            f"template maps differ in length: {ps} has {s.size} entries, {pt} has {t.size} "
            "(one line per template point in both)"
        )
    _check_range(s, ws, ps, True, "source", source.n_vertices)
    _check_range(t, wt, pt, True, "target", target.n_vertices)
    tgt, first = np.unique(t - 1, return_index=True)
    return ground_truth_from_vertex_map(s[first] - 1, source, target.n_vertices, target_index=tgt, name=f"{ps}+{pt}")


def load_ground_truth(
    spec: str | os.PathLike | tuple | list,
    source: Mesh,
    target: Mesh,
    fmt: str | None = None,
    *,
    bary_tol: float = BARY_TOL,
) -> GroundTruth:
    """Read ground-truth correspondences for a (source, target) pair.

    Args:
        spec: ``"identity"``, a file path, or a pair of ``.vts`` paths (``fmt="template"``).
        source: the source mesh the file refers to (for sizes and faces).
        target: the target mesh the file refers to.
        fmt: one of :data:`GT_FORMATS`; default from the suffix (``.vts`` → vts, ``.txt``/``.npy``
            → index, ``.npz`` → npz), ``"identity"`` for that string and ``"template"`` for a pair.
        bary_tol: allowed deviation of barycentric sums from 1 and of components below 0
            (components are then clipped to ≥ 0 and renormalised).

    Returns:
        :class:`GroundTruth`.

    Raises:
        InputError: one line naming the file and the problem (wrong number of entries, index out
            of range, bad barycentrics, NaN, missing arrays, unreadable file, unknown format).
    """
    if fmt is not None and fmt not in GT_FORMATS:
        raise InputError(f"unknown ground-truth format {fmt!r}; use one of {', '.join(GT_FORMATS)}")
    if isinstance(spec, (tuple, list)):
        if fmt not in (None, "template") or len(spec) != 2:
            raise InputError("a pair of files is only accepted as template maps (fmt='template', two .vts files)")
        return _load_template(spec, source, target)
    if fmt == "template":
        raise InputError("fmt='template' needs two files (source and target template maps)", spec)
    if fmt is None:
        if isinstance(spec, str) and spec.strip().lower() == "identity":
            fmt = "identity"
        else:
            suffix = Path(spec).suffix.lower()
            if suffix not in _SUFFIX_FORMAT:
                raise InputError(
                    f"cannot tell the ground-truth format from the suffix {suffix or '(none)'!r}; "
                    f"name it .vts, .txt, .npy or .npz, or pass fmt= one of {', '.join(GT_FORMATS)}",
                    spec,
                )
            fmt = _SUFFIX_FORMAT[suffix]
    if fmt == "identity":
        if source.n_vertices != target.n_vertices:
            raise InputError(
                f"identity ground truth needs meshes with the same vertices: source has {source.n_vertices}, "
                f"target has {target.n_vertices}"
            )
        return ground_truth_from_vertex_map(np.arange(target.n_vertices), source, target.n_vertices, name="identity")
    path = Path(spec)
    if fmt == "npz":
        return _load_npz(path, source, target, bary_tol)
    return _load_vertex_map(path, source, target, one_based=(fmt == "vts"))


def save_ground_truth(path: str | os.PathLike, gt: GroundTruth) -> None:
    """Write ground truth as ``.npz`` with ``face``, ``bary`` (and ``target_index`` when partial), atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {"face": np.asarray(gt.face, dtype=np.int64), "bary": np.asarray(gt.bary, dtype=np.float64)}
    if not gt.complete:
        arrays["target_index"] = np.asarray(gt.target_index, dtype=np.int64)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)  # through a file object: no ".npz" is appended to other names
