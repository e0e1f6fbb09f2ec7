"""Reading a MANO hand model (Romero et al. 2017) as plain arrays; the model itself is never shipped.

:func:`load_mano` reads a ``.npz`` of plain arrays with MANO's keys, or the ``.pkl`` as MANO
distributes it — a Python-2 pickle of chumpy objects and a sparse joint regressor — without
chumpy. Keys, dtypes and shapes are checked, each problem one :class:`~ncflow.errors.InputError`
line naming the file and the key. Posing the model is in :mod:`ncflow.synthetic.mano`.

A pickle can run any code when it is loaded, so the ``.pkl`` is read by a restricted unpickler
that resolves only an allow-list of globals: NumPy's array and dtype reconstructors (``numpy.core``
and ``numpy._core`` paths alike), ``scipy.sparse`` CSC / CSR matrices (any module path), chumpy
classes and ``copyreg._reconstructor`` (for old protocols). Chumpy objects and sparse matrices are
unpickled as inert stubs that only keep their state; a sparse matrix is rebuilt from its parts
after they are checked (indices in range) and only then made dense. ``numpy.ndarray`` is handed
out as a token that only the array reconstructor accepts, so a pickle cannot allocate an array
by calling the class. Any other global is refused ("refusing to load ... global X"). The file is
read whole and its opcodes walked before unpickling, so lengths that claim more than the file
holds fail first; values of the model's keys must be arrays (or the stubs), never nested lists.

Limits: arrays in a model file total at most :data:`MAX_MANO_BYTES`; at most
:data:`~ncflow.geometry.skeleton.MAX_JOINTS` joints.
"""

from __future__ import annotations

import dataclasses
import io
import math
import os
import pickle
from pathlib import Path

import numpy as np

from ncflow.errors import InputError, first_line
from ncflow.geometry.skeleton import MAX_JOINTS
from ncflow.io.files import check_regular_file, dtype_text, read_npz_arrays, short_repr

MAX_MANO_BYTES = 256 * 2**20
"""Largest total size of the arrays of a MANO model file (256 MiB; the real model holds about 4 MiB)."""

MANO_JOINT_NAMES = (
    "wrist",
    "index1",
    "index2",
    "index3",
    "middle1",
    "middle2",
    "middle3",
    "little1",
    "little2",
    "little3",
    "ring1",
    "ring2",
    "ring3",
    "thumb1",
    "thumb2",
    "thumb3",
)


@dataclasses.dataclass(frozen=True, eq=False)
class ManoModel:
    """A MANO hand model as plain arrays (see ``load_mano``).

    Attributes:
        v_template: (V, 3) rest vertices.
        faces: (F, 3) triangles.
        weights: (V, J) skinning weights (J = 16).
        J_regressor: (J, V) joint regressor (dense).
        parents: (J,) parent joint, -1 for the root.
        posedirs: (V, 3, 9 (J − 1)) pose blend shapes driven by vec(R_j − I), j = 1..J−1.
        shapedirs: (V, 3, S) identity blend shapes, or None.
        hands_components: (45, 45) PCA basis of the finger pose (rows), or None.
        hands_mean: (45,) mean finger pose, or None.
        hands_coeffs: (N, 45) PCA coefficients of captured poses, or None.
        name: the file.
    """

    v_template: np.ndarray
    faces: np.ndarray
    weights: np.ndarray
    J_regressor: np.ndarray
    parents: np.ndarray
    posedirs: np.ndarray
    shapedirs: np.ndarray | None = None
    hands_components: np.ndarray | None = None
    hands_mean: np.ndarray | None = None
    hands_coeffs: np.ndarray | None = None
    name: str | None = None

    @property
    def n_joints(self) -> int:
        return int(self.parents.shape[0])


class _Stub:
    """Stands in for an object of a pickled class that must not run: keeps its pickled state only."""

    def __init__(self, *args, **kwargs):
        pass

    def __setstate__(self, state):
        if isinstance(state, tuple) and len(state) == 2 and isinstance(state[0], dict):
            state = state[0]  # (dict, slots) as pickled for classes with __slots__
        if isinstance(state, dict):
            self.__dict__.update({str(k): v for k, v in state.items()})
        else:
            self.__dict__["_state"] = state


class _ChumpyStub(_Stub):
    """Stands in for chumpy objects when unpickling a MANO ``.pkl`` (keeps their state)."""


class _CscStub(_Stub):
    """Stands in for a ``scipy.sparse`` CSC matrix; rebuilt from ``data``, ``indices``, ``indptr``, ``_shape``."""

    format = "csc"


class _CsrStub(_Stub):
    """Stands in for a ``scipy.sparse`` CSR matrix (see :class:`_CscStub`)."""

    format = "csr"


_SPARSE_STUBS = {"csc_matrix": _CscStub, "csr_matrix": _CsrStub, "csc_array": _CscStub, "csr_array": _CsrStub}


def _latin1_encode(text, encoding="utf-8", errors="strict"):
    """``_codecs.encode`` as Python 3 pickles bytes with protocols < 3 (only the latin-1 codec)."""
    if not isinstance(text, str) or str(encoding).lower().replace("_", "-") not in ("latin1", "latin-1"):
        raise pickle.UnpicklingError("_codecs.encode is only accepted for latin-1 text")
    return text.encode("latin-1", errors="strict")


def _reconstructor(cls, base, state):
    """``copyreg._reconstructor`` limited to the stubs (how protocols 0 and 1 pickle plain objects)."""
    if not (isinstance(cls, type) and issubclass(cls, _Stub) and base is object and state is None):
        raise pickle.UnpicklingError("copyreg._reconstructor is only accepted for chumpy / sparse objects")
    return cls()


def _multiarray():
    try:
        from numpy._core import multiarray, numeric
    except ImportError:  # NumPy 1
        from numpy.core import multiarray, numeric
    return multiarray, numeric


class _NdarrayRef:
    """What the pickle gets for ``numpy.ndarray``: only :func:`_reconstruct` turns it into the class.

    (The class itself would let a pickle call ``ndarray(shape)`` and allocate any size.)
    """


def _reconstruct(cls, shape, dtype):
    """``numpy...._reconstruct`` for plain ndarrays of at most :data:`MAX_MANO_BYTES` (pickles pass shape (0,))."""
    if cls is not _NdarrayRef:
        raise pickle.UnpicklingError("_reconstruct is only accepted for numpy.ndarray")
    dtype = np.dtype(dtype)
    if math.prod(int(n) for n in shape) * max(dtype.itemsize, 1) > MAX_MANO_BYTES:
        raise pickle.UnpicklingError(f"an array larger than {MAX_MANO_BYTES} bytes")
    return _multiarray()[0]._reconstruct(np.ndarray, shape, dtype)


def _numpy_globals() -> dict:
    """The NumPy callables an ndarray / dtype / scalar pickle needs, by name."""
    multiarray, numeric = _multiarray()
    return {
        "_reconstruct": _reconstruct,
        "scalar": multiarray.scalar,
        "_frombuffer": numeric._frombuffer,
        "ndarray": _NdarrayRef,
        "dtype": np.dtype,
    }


_NUMPY_MODULES = {
    "numpy": ("ndarray", "dtype"),
    "numpy.core.multiarray": ("_reconstruct", "scalar"),
    "numpy._core.multiarray": ("_reconstruct", "scalar"),
    "numpy.core.numeric": ("_frombuffer",),
    "numpy._core.numeric": ("_frombuffer",),
}


class _ManoUnpickler(pickle.Unpickler):
    """Unpickler resolving only the allow-listed globals (module docstring); refuses every other one."""

    def __init__(self, file, path, **kwargs):
        super().__init__(file, **kwargs)
        self.path = path

    def find_class(self, module, name):
        if module.split(".")[0] == "chumpy":
            return _ChumpyStub
        if (module == "scipy.sparse" or module.startswith("scipy.sparse.")) and name in _SPARSE_STUBS:
            return _SPARSE_STUBS[name]
        if name in _NUMPY_MODULES.get(module, ()):
            return _numpy_globals()[name]
        if (module, name) == ("_codecs", "encode"):
            return _latin1_encode
        if module in ("copy_reg", "copyreg") and name == "_reconstructor":
            return _reconstructor
        if module in ("__builtin__", "builtins") and name == "object":
            return object
        raise InputError(f"refusing to load the pickle: it needs global {short_repr(f'{module}.{name}')}", self.path)


def _check_bytes(nbytes: int, key: str, path) -> None:
    if nbytes > MAX_MANO_BYTES:
        raise InputError(f"MANO key {key!r} holds {nbytes} bytes, over the limit of {MAX_MANO_BYTES}", path)


def _sparse_to_dense(value: _Stub, key: str, path) -> np.ndarray:
    """A dense array from a sparse-matrix stub, its parts checked (shape, index ranges) before densifying."""
    import scipy.sparse

    state = value.__dict__
    try:
        shape = tuple(int(s) for s in state.get("_shape", state.get("shape")))
        parts = [state[k] for k in ("data", "indices", "indptr")]
    except Exception:
        raise InputError(f"MANO key {key!r}: malformed sparse matrix", path) from None
    if not all(isinstance(p, np.ndarray) for p in parts):
        raise InputError(f"MANO key {key!r}: malformed sparse matrix parts", path)
    if len(shape) != 2 or min(shape) < 0:
        raise InputError(f"MANO key {key!r}: sparse matrix shape {short_repr(shape)} is not 2-D", path)
    _check_bytes(shape[0] * shape[1] * 8, key, path)
    if any(p.ndim != 1 or p.dtype.kind not in "biuf" for p in parts) or parts[1].dtype.kind == "f":
        raise InputError(f"MANO key {key!r}: malformed sparse matrix parts", path)
    cls = scipy.sparse.csc_matrix if value.format == "csc" else scipy.sparse.csr_matrix
    try:
        matrix = cls(tuple(parts), shape=shape)
        matrix.check_format(full_check=True)
        return np.asarray(matrix.toarray())
    except Exception as exc:
        raise InputError(f"MANO key {key!r}: malformed sparse matrix ({first_line(exc)[:80]})", path) from None


def _plain(value, key: str, path):
    """A NumPy array from an ndarray, a scipy sparse stub or a chumpy stub (its stored values)."""
    for _ in range(8):  # chumpy objects may wrap others; a pickle may even make them cyclic
        if not isinstance(value, _ChumpyStub):
            break
        attr = next((a for a in ("x", "r", "_x") if a in value.__dict__), None)
        if attr is None:
            raise InputError(f"MANO key {key!r} is a chumpy object without stored values", path)
        value = value.__dict__[attr]
    if value is None:
        return None
    if isinstance(value, _ChumpyStub):
        raise InputError(f"MANO key {key!r}: chumpy objects nested too deeply", path)
    if isinstance(value, (_CscStub, _CsrStub)):
        return _sparse_to_dense(value, key, path)
    if not isinstance(value, np.ndarray):  # not np.asarray: nested lists sharing parts could be huge
        raise InputError(f"MANO key {key!r} is not an array (got {short_repr(type(value).__name__, 40)})", path)
    _check_bytes(value.nbytes, key, path)
    return value


_KEYS = (
    "v_template",
    "faces",
    "weights",
    "J_regressor",
    "kintree_table",
    "posedirs",
    "shapedirs",
    "hands_components",
    "hands_mean",
    "hands_coeffs",
)
_REQUIRED = ("v_template", "faces", "weights", "J_regressor", "kintree_table", "posedirs")


def _read_pickle(path: Path) -> dict:
    """The dict of a MANO ``.pkl``, through the restricted unpickler.

    The file is read whole (at most :data:`MAX_MANO_BYTES`) and its opcodes walked once first, so
    that a length field claiming more bytes than the file holds fails before anything is allocated.
    """
    import pickletools

    if path.stat().st_size > MAX_MANO_BYTES:
        raise InputError(f"MANO model file is larger than {MAX_MANO_BYTES} bytes", path)
    raw = path.read_bytes()
    for _ in pickletools.genops(raw):
        pass
    data = _ManoUnpickler(io.BytesIO(raw), path, encoding="latin1").load()
    if not isinstance(data, dict):
        raise InputError("expected a pickled dict of MANO arrays", path)
    return {str(k): v for k, v in data.items()}


def _read_file(path: Path) -> dict:
    """Key → value of a MANO ``.npz`` or ``.pkl`` (values not yet checked)."""
    suffix = path.suffix.lower()
    if suffix not in (".npz", ".pkl"):
        raise InputError(f"unsupported MANO model format {suffix or '(none)'!r}; use .npz or .pkl", path)
    check_regular_file(path, "MANO model")
    if suffix == ".npz":
        return read_npz_arrays(path, optional=(*_KEYS, "f"), max_bytes=MAX_MANO_BYTES)
    try:
        return _read_pickle(path)
    except InputError:
        raise
    except Exception as exc:  # a broken pickle raises many kinds of errors
        raise InputError(f"cannot read MANO model ({first_line(exc)[:80]})", path) from None


def _numeric(arr: np.ndarray, key: str, path, ndim: int, integer: bool = False) -> np.ndarray:
    """``arr`` as float64 (int64 when ``integer``), checked: numbers, ``ndim`` dimensions, finite, integral."""
    if arr.dtype.kind not in "biuf":
        raise InputError(f"MANO key {key!r} must hold numbers, got dtype {dtype_text(arr.dtype)}", path)
    if arr.ndim != ndim:
        raise InputError(f"MANO key {key!r} must be {ndim}-D, got shape {short_repr(arr.shape)}", path)
    out = arr.astype(np.float64)
    if not np.all(np.isfinite(out)):
        raise InputError(f"MANO key {key!r} has NaN or infinite values", path)
    if not integer:
        return out
    if (arr.dtype.kind in "iu" and arr.dtype.itemsize <= 4) or arr.dtype.kind == "b":
        return arr.astype(np.int64)
    if (arr.dtype.kind == "u" and np.any(arr > 2**62)) or np.any(np.abs(out) > 2**62) or np.any(out != np.round(out)):
        raise InputError(f"MANO key {key!r} must hold integers in range", path)
    return arr.astype(np.int64) if arr.dtype.kind in "iu" else out.astype(np.int64)


def _parents(kt: np.ndarray, path) -> np.ndarray:
    """Parent joint of every column of the (2, J) kintree table (ids in row 1, parent ids in row 0)."""
    nj = kt.shape[1]
    if kt.shape[0] != 2 or not 2 <= nj <= MAX_JOINTS:
        raise InputError(f"MANO key 'kintree_table' must be (2, J) with 2 <= J <= {MAX_JOINTS}, got {kt.shape}", path)
    id_to_col = {int(i): c for c, i in enumerate(kt[1])}
    parents = np.asarray([id_to_col.get(int(p), -1) for p in kt[0]], dtype=np.int64)
    if parents[0] != -1 or np.any(parents[1:] < 0) or np.any(parents[1:] >= np.arange(1, nj)):
        raise InputError("MANO key 'kintree_table' must list the root first and every parent before its children", path)
    return parents


def _check_shape(arr, key: str, shape: tuple, path) -> None:
    """InputError unless ``arr.shape == shape`` (``None`` entries match any size)."""
    if len(arr.shape) != len(shape) or any(s is not None and a != s for a, s in zip(arr.shape, shape)):
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise InputError(f"MANO model: {key} must be {want}, got {tuple(arr.shape)}", path)


def load_mano(path: str | os.PathLike) -> ManoModel:
    """Read a MANO model: a ``.npz`` of plain arrays (keys as in MANO: ``v_template``, ``faces`` or
    ``f``, ``weights``, ``J_regressor``, ``kintree_table``, ``posedirs``, optional ``shapedirs``,
    ``hands_components``, ``hands_mean``, ``hands_coeffs``) or the ``.pkl`` as MANO distributes it
    (a Python-2 pickle with chumpy objects and a sparse regressor; read without chumpy, through the
    restricted unpickler of the module docstring).

    Raises:
        InputError: unreadable file, a refused pickle global, missing keys, non-numeric,
            non-finite or inconsistently shaped arrays (naming the key).
    """
    path = Path(path)
    if not path.exists():
        raise InputError("no such file", path)
    data = _read_file(path)
    if "faces" not in data and "f" in data:
        data["faces"] = data["f"]
    missing = [k for k in _REQUIRED if k not in data]
    if missing:
        raise InputError(f"MANO model lacks {', '.join(missing)}", path)
    arr = {k: _plain(data.get(k), k, path) for k in _KEYS}
    ndims = {"posedirs": 3, "shapedirs": 3, "hands_mean": None}
    out = {}
    for key in _KEYS:
        if arr[key] is None:
            continue
        ndim = ndims.get(key, 2)
        a = arr[key].reshape(-1) if ndim is None else arr[key]
        out[key] = _numeric(a, key, path, ndim or 1, integer=key in ("faces", "kintree_table"))
    v, faces, parents = out["v_template"], out["faces"], _parents(out["kintree_table"], path)
    nv, nj = v.shape[0], parents.shape[0]
    _check_shape(v, "v_template", (None, 3), path)
    _check_shape(faces, "faces", (None, 3), path)
    _check_shape(out["weights"], "weights", (nv, nj), path)
    _check_shape(out["J_regressor"], "J_regressor", (nj, nv), path)
    _check_shape(out["posedirs"], "posedirs", (nv, 3, 9 * (nj - 1)), path)
    if "shapedirs" in out:
        _check_shape(out["shapedirs"], "shapedirs", (nv, 3, None), path)
    if "hands_components" in out:
        _check_shape(out["hands_components"], "hands_components", (None, 3 * (nj - 1)), path)
    if "hands_mean" in out:
        _check_shape(out["hands_mean"], "hands_mean", (3 * (nj - 1),), path)
    if "hands_coeffs" in out:
        k = out["hands_components"].shape[0] if "hands_components" in out else None
        _check_shape(out["hands_coeffs"], "hands_coeffs", (None, k), path)
    if nv == 0 or faces.shape[0] == 0:
        raise InputError("MANO model: no vertices or no faces", path)
    if faces.min() < 0 or faces.max() >= nv:
        raise InputError(f"MANO model: faces refer to vertices outside [0, {nv})", path)
    return ManoModel(
        v_template=v,
        faces=faces,
        weights=out["weights"],
        J_regressor=out["J_regressor"],
        parents=parents,
        posedirs=out["posedirs"],
        shapedirs=out.get("shapedirs"),
        hands_components=out.get("hands_components"),
        hands_mean=out.get("hands_mean"),
        hands_coeffs=out.get("hands_coeffs"),
        name=str(path),
    )
