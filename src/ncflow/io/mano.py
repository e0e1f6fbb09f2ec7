"""Reading a MANO hand model (Romero et al. 2017) as plain arrays; the model itself is never shipped.

:func:`load_mano` reads a ``.npz`` of plain arrays with MANO's keys, or the ``.pkl`` as MANO
distributes it — a Python-2 pickle of chumpy objects and a sparse joint regressor — without
chumpy: chumpy classes are unpickled as a stub that keeps their stored values, and NumPy 1 module
paths are mapped to NumPy 2. Keys and shapes are checked, each problem one
:class:`~ncflow.errors.InputError` line. Posing the model is in :mod:`ncflow.synthetic.mano`.
"""

from __future__ import annotations

import dataclasses
import os
import pickle
from pathlib import Path

import numpy as np

from ncflow.errors import InputError

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


class _ChumpyStub:
    """Stands in for chumpy objects when unpickling a MANO ``.pkl`` (keeps their state)."""

    def __init__(self, *args, **kwargs):
        pass

    def __setstate__(self, state):
        if isinstance(state, dict):
            self.__dict__.update(state)
        else:
            self.__dict__["_state"] = state


class _ManoUnpickler(pickle.Unpickler):
    def find_class(self, module, name):
        if module.split(".")[0] == "chumpy":
            return _ChumpyStub
        if module.startswith("scipy.sparse"):
            import scipy.sparse

            return getattr(scipy.sparse, name)
        if module == "numpy.core" or module.startswith("numpy.core."):
            import importlib.util

            if importlib.util.find_spec("numpy._core") is not None:  # NumPy 2 (numpy.core is a deprecated alias)
                module = "numpy._core" + module[len("numpy.core") :]
        return super().find_class(module, name)


def _plain(value, key: str, path):
    """A NumPy array from an ndarray, a scipy sparse matrix or a chumpy stub."""
    if value is None:
        return None
    if isinstance(value, _ChumpyStub):
        for attr in ("x", "r", "_x"):
            if attr in value.__dict__:
                return _plain(value.__dict__[attr], key, path)
        raise InputError(f"MANO key {key!r} is a chumpy object without stored values", path)
    if hasattr(value, "toarray"):
        return np.asarray(value.toarray())
    return np.asarray(value)


def load_mano(path: str | os.PathLike) -> ManoModel:
    """Read a MANO model: a ``.npz`` of plain arrays (keys as in MANO: ``v_template``, ``faces`` or
    ``f``, ``weights``, ``J_regressor``, ``kintree_table``, ``posedirs``, optional ``shapedirs``,
    ``hands_components``, ``hands_mean``, ``hands_coeffs``) or the ``.pkl`` as MANO distributes it
    (a Python-2 pickle with chumpy objects and a sparse regressor; read without chumpy).

    Raises:
        InputError: unreadable file, missing keys or inconsistent shapes.
    """
    path = Path(path)
    if not path.exists():
        raise InputError("no such file", path)
    suffix = path.suffix.lower()
    try:
        if suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                data = {k: np.asarray(z[k]) for k in z.files}
        elif suffix == ".pkl":
            with open(path, "rb") as fh:
                data = _ManoUnpickler(fh, encoding="latin1").load()
            if not isinstance(data, dict):
                raise InputError("expected a pickled dict of MANO arrays", path)
        else:
            raise InputError(f"unsupported MANO model format {suffix or '(none)'!r}; use .npz or .pkl", path)
    except InputError:
        raise
    except Exception as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"cannot read MANO model ({msg})", path) from None
    if "faces" not in data and "f" in data:
        data["faces"] = data["f"]
    missing = [
        k for k in ("v_template", "faces", "weights", "J_regressor", "kintree_table", "posedirs") if k not in data
    ]
    if missing:
        raise InputError(f"MANO model lacks {', '.join(missing)}", path)
    arr = {
        k: _plain(data.get(k), k, path)
        for k in (
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
    }
    v = arr["v_template"].astype(np.float64)
    nv = v.shape[0]
    kt = arr["kintree_table"].astype(np.int64)
    nj = kt.shape[1]
    parents = np.full(nj, -1, dtype=np.int64)
    id_to_col = {int(i): c for c, i in enumerate(kt[1])}
    for c in range(nj):
        p = int(kt[0, c])
        parents[c] = id_to_col.get(p, -1) if 0 <= p < 2**31 else -1
    model = ManoModel(
        v_template=v,
        faces=arr["faces"].astype(np.int64),
        weights=arr["weights"].astype(np.float64),
        J_regressor=arr["J_regressor"].astype(np.float64),
        parents=parents,
        posedirs=arr["posedirs"].astype(np.float64),
        shapedirs=None if arr["shapedirs"] is None else arr["shapedirs"].astype(np.float64),
        hands_components=None if arr["hands_components"] is None else arr["hands_components"].astype(np.float64),
        hands_mean=None if arr["hands_mean"] is None else arr["hands_mean"].astype(np.float64).reshape(-1),
        hands_coeffs=None if arr["hands_coeffs"] is None else arr["hands_coeffs"].astype(np.float64),
        name=str(path),
    )
    checks = [
        (model.faces.ndim == 2 and model.faces.shape[1] == 3, f"faces must be (F, 3), got {model.faces.shape}"),
        (model.weights.shape == (nv, nj), f"weights must be ({nv}, {nj}), got {model.weights.shape}"),
        (model.J_regressor.shape == (nj, nv), f"J_regressor must be ({nj}, {nv}), got {model.J_regressor.shape}"),
        (
            model.posedirs.shape == (nv, 3, 9 * (nj - 1)),
            f"posedirs must be ({nv}, 3, {9 * (nj - 1)}), got {model.posedirs.shape}",
        ),
        (int(np.sum(parents < 0)) == 1, "kintree_table must have exactly one root"),
    ]
    for ok, msg in checks:
        if not ok:
            raise InputError(f"MANO model: {msg}", path)
    return model
