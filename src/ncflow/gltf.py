"""Skinned glTF 2.0 / GLB characters: reading, animation sampling and posing.

Animated characters give source/target pairs with exact ground truth: posing one skinned mesh at
two animation times moves the same vertices, so vertex ``i`` of both poses is the same body point.

What is read (glTF 2.0, ``.glb`` or ``.gltf`` with embedded, data-URI or external buffers):

* the node hierarchy, each node's local transform given as TRS or as a column-major ``matrix``;
* one skin (the first, or the one chosen by index): its joints, in the skin's order, and its
  inverse bind matrices (identity when the skin has none);
* the first node that uses that skin with a mesh: all primitives of that mesh concatenated
  (``POSITION``, ``JOINTS_n`` / ``WEIGHTS_n`` for every set n present, ``indices``; triangle lists,
  strips and fans), with any accessor component type, normalised integers, ``byteStride`` and
  sparse accessors;
* animations: ``translation`` / ``rotation`` / ``scale`` channels (``weights`` channels, i.e.
  morph targets, are ignored) with ``LINEAR`` (slerp for rotations), ``STEP`` and ``CUBICSPLINE``
  samplers.

Conventions:

* Coordinates are the scene's world coordinates. Skinning follows the glTF specification:
  vertex ``v`` of the mesh moves to ``Σ_k w_k · world(joint_k) · inverseBind_k · v``; the transform
  of the node holding the skinned mesh is ignored (the spec's "MUST be ignored"). Writing the
  result in the mesh node's coordinates and then applying that node's world transform, as some
  viewers do, gives the same points.
* The **bind pose** (``time=None`` and no ``joint_rotations``) is the pose the mesh is bound in:
  every skin matrix is the identity, the vertices are the file's ``POSITION`` values, and joint
  ``j`` sits at the translation of ``inverse(inverseBind_j)``.
* **Animation time** is in seconds on the file's own timeline (the keyframe times as stored; clips
  conventionally start at 0, and then this is "seconds into the clip"). It is clamped to the
  clip's range ``[start, end]`` (the smallest and largest keyframe time over the clip's
  channels); channels shorter than the clip hold their end values. Nodes that no channel of the
  clip targets keep their rest transform (the node's TRS or matrix).
* **Joint rotations** are quaternions ``(x, y, z, w)`` (glTF order), one per joint in the skin's
  joint order; they *replace* the local rotation of the joint's node (the rest rotation, or the
  animated one when a time is given) while its translation and scale stay. They are normalised;
  pass the node's own rotation (see :attr:`GltfSkin.rest_rotations`) to keep it.
* **Skin weights** are normalised to sum 1 per vertex (as three.js does); a vertex whose weights
  are all zero is an error.
* **Skeleton parents**: the parent of a joint is its nearest ancestor *node* that is also a joint
  of the skin (intermediate non-joint nodes are skipped). If several joints have no joint
  ancestor, the one nearest the top of the node hierarchy (fewest ancestors; ties: first in the
  skin's joint list) becomes the root and every other such joint is attached to it, so the
  skeleton is one tree.
* **Welding**: seam duplicates (exactly equal bind-pose positions) become one vertex, using
  :func:`ncflow.mesh.weld_vertices` on the bind-pose positions; the posed positions are taken at
  the same first occurrences (``file_index``), so every pose has the same vertex order. Faces
  that become degenerate (a repeated vertex) are dropped.
"""

from __future__ import annotations

import base64
import dataclasses
import json
import math
import os
import urllib.parse
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError

__all__ = [
    "AnimationInfo",
    "GltfSkin",
    "PosedMesh",
    "load_gltf_skin",
    "gltf_animations",
    "gltf_skeleton",
    "pose_gltf",
    "interpolate_keyframes",
    "quat_slerp",
    "quat_to_matrix",
    "matrix_to_quat",
    "trs_matrix",
    "skin_vertices",
    "merge_zero_length_bones",
    "GLTF_SUFFIXES",
]

GLTF_SUFFIXES = (".glb", ".gltf")

_COMPONENT_DTYPES = {
    5120: np.dtype("<i1"),
    5121: np.dtype("<u1"),
    5122: np.dtype("<i2"),
    5123: np.dtype("<u2"),
    5125: np.dtype("<u4"),
    5126: np.dtype("<f4"),
}
_TYPE_SHAPES = {
    "SCALAR": (1,),
    "VEC2": (2,),
    "VEC3": (3,),
    "VEC4": (4,),
    "MAT2": (2, 2),
    "MAT3": (3, 3),
    "MAT4": (4, 4),
}
_INTERPOLATIONS = ("LINEAR", "STEP", "CUBICSPLINE")
_PATHS = ("translation", "rotation", "scale")
# required extensions that do not change how positions, skins and animations are stored
_SUPPORTED_REQUIRED = {"KHR_mesh_quantization", "KHR_materials_unlit", "KHR_texture_transform", "KHR_texture_basisu"}


# ----------------------------------------------------------------------------------------------
# Quaternion and transform maths (quaternions in glTF order (x, y, z, w))


def quat_to_matrix(q: Float[np.ndarray, "... 4"]) -> Float[np.ndarray, "... 3 3"]:
    """Rotation matrices of quaternions ``(x, y, z, w)`` (normalised first)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quat(r: Float[np.ndarray, "3 3"]) -> Float[np.ndarray, " 4"]:
    """Unit quaternion ``(x, y, z, w)`` of a rotation matrix (Shepperd's method)."""
    r = np.asarray(r, dtype=np.float64)
    tr = np.trace(r)
    if tr > 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, 0.25 * s]
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = 2.0 * math.sqrt(max(1.0 + r[0, 0] - r[1, 1] - r[2, 2], 1e-300))
        q = [0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s, (r[2, 1] - r[1, 2]) / s]
    elif r[1, 1] > r[2, 2]:
        s = 2.0 * math.sqrt(max(1.0 + r[1, 1] - r[0, 0] - r[2, 2], 1e-300))
        q = [(r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s, (r[0, 2] - r[2, 0]) / s]
    else:
        s = 2.0 * math.sqrt(max(1.0 + r[2, 2] - r[0, 0] - r[1, 1], 1e-300))
        q = [(r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s, (r[1, 0] - r[0, 1]) / s]
    q = np.asarray(q)
    return q / np.linalg.norm(q)


def trs_matrix(
    translation: Float[np.ndarray, "... 3"], rotation: Float[np.ndarray, "... 4"], scale: Float[np.ndarray, "... 3"]
) -> Float[np.ndarray, "... 4 4"]:
    """Local transforms ``T · R · S`` (glTF's node transform) from translations, quaternions ``(x, y, z, w)`` and scales."""
    translation = np.asarray(translation, dtype=np.float64)
    r = quat_to_matrix(rotation) * np.asarray(scale, dtype=np.float64)[..., None, :]
    m = np.zeros(translation.shape[:-1] + (4, 4))
    m[..., :3, :3] = r
    m[..., :3, 3] = translation
    m[..., 3, 3] = 1.0
    return m


def quat_slerp(q0: Float[np.ndarray, " 4"], q1: Float[np.ndarray, " 4"], u: float) -> Float[np.ndarray, " 4"]:
    """Spherical linear interpolation along the shorter arc (glTF's reference slerp), ``u`` in [0, 1]."""
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    q0 = q0 / np.linalg.norm(q0)
    q1 = q1 / np.linalg.norm(q1)
    d = float(np.dot(q0, q1))
    if d < 0.0:
        q1, d = -q1, -d
    if d > 1.0 - 1e-12:  # (almost) the same rotation: lerp is exact to rounding
        q = (1.0 - u) * q0 + u * q1
    else:
        a = math.acos(min(d, 1.0))
        q = (math.sin((1.0 - u) * a) * q0 + math.sin(u * a) * q1) / math.sin(a)
    return q / np.linalg.norm(q)


def interpolate_keyframes(
    times: Float[np.ndarray, " K"],
    values: Float[np.ndarray, "K C"] | Float[np.ndarray, "K 3 C"],
    t: float,
    interpolation: str = "LINEAR",
    rotation: bool = False,
) -> Float[np.ndarray, " C"]:
    """Value of one animation sampler at time ``t`` (clamped to the keyframe range).

    Args:
        times: (K,) increasing keyframe times.
        values: (K, C) keyframe values for LINEAR / STEP; (K, 3, C) for CUBICSPLINE, each key
            holding (in-tangent, value, out-tangent) as glTF stores them.
        t: the time.
        interpolation: ``"LINEAR"``, ``"STEP"`` or ``"CUBICSPLINE"``.
        rotation: the values are quaternions ``(x, y, z, w)``: LINEAR uses slerp and the
            CUBICSPLINE result is normalised.

    Returns:
        (C,) the interpolated value.
    """
    times = np.asarray(times, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    cubic = interpolation == "CUBICSPLINE"
    key = (lambda k: values[k, 1]) if cubic else (lambda k: values[k])
    n = times.shape[0]
    if n == 1 or t <= times[0]:
        out = key(0)
    elif t >= times[-1]:
        out = key(n - 1)
    else:
        k = int(np.searchsorted(times, t, side="right")) - 1
        td = times[k + 1] - times[k]
        u = (t - times[k]) / td if td > 0 else 1.0
        if interpolation == "STEP":
            out = key(k)
        elif interpolation == "LINEAR":
            out = quat_slerp(values[k], values[k + 1], u) if rotation else (1.0 - u) * values[k] + u * values[k + 1]
        elif cubic:
            u2, u3 = u * u, u * u * u
            out = (
                (2 * u3 - 3 * u2 + 1) * values[k, 1]
                + td * (u3 - 2 * u2 + u) * values[k, 2]
                + (-2 * u3 + 3 * u2) * values[k + 1, 1]
                + td * (u3 - u2) * values[k + 1, 0]
            )
        else:
            raise ValueError(f"unknown interpolation {interpolation!r}")
    out = np.array(out, dtype=np.float64)
    if rotation:
        out = out / np.linalg.norm(out)
    return out


def skin_vertices(
    positions: Float[np.ndarray, "V 3"],
    joints: Int[np.ndarray, "V K"],
    weights: Float[np.ndarray, "V K"],
    skin_matrices: Float[np.ndarray, "J 4 4"],
) -> Float[np.ndarray, "V 3"]:
    """Linear blend skinning: ``Σ_k weights[v,k] · skin_matrices[joints[v,k]] · (positions[v], 1)``.

    Weights are used as given (normalise them first); matrices are affine (bottom row 0 0 0 1).
    """
    positions = np.asarray(positions, dtype=np.float64)
    m = np.asarray(skin_matrices, dtype=np.float64)[:, :3, :]  # (J, 3, 4)
    blended = np.einsum("vk,vkij->vij", np.asarray(weights, dtype=np.float64), m[np.asarray(joints)])
    return np.einsum("vij,vj->vi", blended[:, :, :3], positions) + blended[:, :, 3]


def merge_zero_length_bones(
    positions: Float[np.ndarray, "J 3"], parents: Int[np.ndarray, " J"], rel_tol: float = 1e-6
) -> tuple[Int[np.ndarray, " K"], Int[np.ndarray, " K"]]:
    """Drop joints that coincide with their (kept) parent joint, re-attaching their children.

    Rigs often stack joints at one point (Fox.glb: ``_rootJoint`` and ``b_Root_00`` both at the
    origin); a skeleton for matching needs bones of positive length. Joints are visited
    parents first; a joint closer than ``rel_tol`` × (bounding-box diagonal of the joints) to its
    nearest kept ancestor is merged into it. The root is always kept.

    Args:
        positions: (J, 3) joint positions (use the bind pose so the choice is the same for every pose).
        parents: (J,) parent indices, -1 for the single root.

    Returns:
        (kept joint indices (K,) in increasing order, their parents (K,) as indices into the kept list).
    """
    positions = np.asarray(positions, dtype=np.float64)
    parents = np.asarray(parents, dtype=np.int64)
    n = parents.shape[0]
    depth = np.zeros(n, dtype=np.int64)
    for j in range(n):
        p = parents[j]
        while p >= 0 and depth[j] <= n:
            depth[j] += 1
            p = parents[p]
    threshold = rel_tol * float(np.linalg.norm(np.ptp(positions, axis=0))) if n else 0.0
    rep = np.arange(n)  # kept joint each joint is represented by
    for j in np.argsort(depth, kind="stable"):
        p = parents[j]
        if p >= 0 and np.linalg.norm(positions[j] - positions[rep[p]]) <= threshold:
            rep[j] = rep[p]
    keep = np.flatnonzero(rep == np.arange(n))
    index = np.full(n, -1, dtype=np.int64)
    index[keep] = np.arange(keep.size)
    new_parents = np.where(parents[keep] < 0, -1, index[rep[np.maximum(parents[keep], 0)]])
    return keep, new_parents.astype(np.int64)


# ----------------------------------------------------------------------------------------------
# Reading the file


def _get(obj, key, default=None):
    """Attribute or dict access (pygltflib returns either for nested and extension objects)."""
    if obj is None:
        return default
    if isinstance(obj, dict):
        return obj.get(key, default)
    return getattr(obj, key, default)


def _load_document(path: Path):
    """Parse a .glb or .gltf file with pygltflib; InputError if it is not one."""
    import pygltflib

    if not path.exists():
        raise InputError("no such file", path)
    if path.is_dir():
        raise InputError("is a directory, expected a glTF file", path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror or exc})", path) from None
    try:
        if data[:4] == b"glTF":
            if len(data) < 20:
                raise ValueError("truncated GLB header")
            doc = pygltflib.GLTF2.load_from_bytes(data)
        else:
            text = data.decode("utf-8-sig")
            parsed = json.loads(text)
            if not isinstance(parsed, dict) or "asset" not in parsed:
                raise ValueError("JSON without an 'asset' entry")
            doc = pygltflib.GLTF2.gltf_from_json(text)
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise InputError("not a glTF 2.0 file (neither GLB nor glTF JSON)", path) from None
    except Exception as exc:  # pygltflib raises many kinds of errors for broken files
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"not a readable glTF 2.0 file ({msg})", path) from None
    if doc is None:
        raise InputError("not a readable glTF 2.0 file (no JSON chunk)", path)
    version = str(_get(doc.asset, "version", "") or "")
    if not version.startswith("2"):
        raise InputError(f"glTF version {version or '(missing)'} is not supported; need 2.x", path)
    unsupported = sorted(set(_get(doc, "extensionsRequired") or []) - _SUPPORTED_REQUIRED)
    if unsupported:
        raise InputError(
            f"needs glTF extension(s) {', '.join(unsupported)}, which ncflow cannot read "
            "(decompress the file first, e.g. with gltf-transform)",
            path,
        )
    return doc


class _Reader:
    """Accessor reading for one parsed document (buffers cached)."""

    def __init__(self, doc, path: Path):
        self.doc = doc
        self.path = path
        self._buffers: dict[int, bytes] = {}

    def fail(self, message: str):
        raise InputError(message, self.path)

    def buffer(self, index: int) -> bytes:
        if index in self._buffers:
            return self._buffers[index]
        buffers = self.doc.buffers or []
        if not 0 <= index < len(buffers):
            self.fail(f"buffer {index} does not exist")
        uri = _get(buffers[index], "uri")
        if uri is None:
            blob = self.doc.binary_blob() if index == 0 else None
            if blob is None:
                self.fail(f"buffer {index} has no data (no uri and no GLB binary chunk)")
            data = bytes(blob)
        elif uri.startswith("data:"):
            try:
                data = base64.b64decode(uri.split(",", 1)[1])
            except Exception:
                self.fail(f"buffer {index} has a malformed data URI")
        else:
            file = self.path.parent / urllib.parse.unquote(uri)
            try:
                data = file.read_bytes()
            except OSError:
                self.fail(f"buffer {index}: cannot read external file {uri!r}")
        length = _get(buffers[index], "byteLength")
        if length is not None and len(data) < int(length):
            self.fail(f"buffer {index} is shorter ({len(data)} bytes) than its byteLength {length}")
        self._buffers[index] = data
        return data

    def _elements(
        self, view_index: int, offset: int, count: int, dtype: np.dtype, shape: tuple, what: str
    ) -> np.ndarray:
        """(count, *shape) elements from a buffer view (byteStride and matrix column padding honoured)."""
        views = self.doc.bufferViews or []
        if not 0 <= view_index < len(views):
            self.fail(f"{what}: bufferView {view_index} does not exist")
        view = views[view_index]
        data = np.frombuffer(self.buffer(int(_get(view, "buffer", 0))), dtype=np.uint8)
        start = int(_get(view, "byteOffset", 0) or 0)
        view_len = int(_get(view, "byteLength", 0) or 0)
        csize = dtype.itemsize
        if len(shape) == 2:  # matrix columns start on 4-byte boundaries
            rows = shape[0]
            col_stride = -(-rows * csize // 4) * 4
            byte_pos = np.concatenate([c * col_stride + np.arange(rows * csize) for c in range(shape[1])])
        else:
            byte_pos = np.arange(int(np.prod(shape)) * csize)
        elem_size = int(byte_pos[-1]) + 1 if byte_pos.size else 0
        elem_size = -(-elem_size // 4) * 4 if len(shape) == 2 else elem_size
        stride = int(_get(view, "byteStride", 0) or 0) or elem_size
        if count == 0:
            return np.zeros((0,) + shape, dtype=dtype)
        last = offset + (count - 1) * stride + int(byte_pos[-1]) + 1
        if offset < 0 or last > view_len or start + view_len > data.size:
            self.fail(f"{what} reads past the end of its buffer view")
        idx = start + offset + np.arange(count)[:, None] * stride + byte_pos[None, :]
        raw = np.ascontiguousarray(data[idx])
        return raw.view(dtype).reshape((count,) + shape)

    def accessor(self, index: int | None, what: str) -> np.ndarray:
        """Accessor ``index`` as (count, *element shape): float64 for float / normalised data, int64 otherwise."""
        accessors = self.doc.accessors or []
        if index is None or not 0 <= int(index) < len(accessors):
            self.fail(f"{what}: accessor {index} does not exist")
        acc = accessors[int(index)]
        ctype = _get(acc, "componentType")
        atype = _get(acc, "type")
        count = int(_get(acc, "count", 0) or 0)
        if ctype not in _COMPONENT_DTYPES:
            self.fail(f"{what}: unknown accessor component type {ctype}")
        if atype not in _TYPE_SHAPES:
            self.fail(f"{what}: unknown accessor type {atype!r}")
        dtype, shape = _COMPONENT_DTYPES[ctype], _TYPE_SHAPES[atype]
        view = _get(acc, "bufferView")
        if view is None:
            out = np.zeros((count,) + shape, dtype=dtype)
        else:
            out = self._elements(int(view), int(_get(acc, "byteOffset", 0) or 0), count, dtype, shape, what).copy()
        sparse = _get(acc, "sparse")
        if sparse is not None and int(_get(sparse, "count", 0) or 0) > 0:
            n = int(_get(sparse, "count"))
            ind, val = _get(sparse, "indices"), _get(sparse, "values")
            if _get(ind, "bufferView") is None or _get(val, "bufferView") is None:
                self.fail(f"{what}: sparse accessor without indices / values buffer views")
            itype = _get(ind, "componentType")
            if itype not in (5121, 5123, 5125):
                self.fail(f"{what}: sparse indices have invalid component type {itype}")
            at = (
                self._elements(
                    int(_get(ind, "bufferView")),
                    int(_get(ind, "byteOffset", 0) or 0),
                    n,
                    _COMPONENT_DTYPES[itype],
                    (1,),
                    what,
                )
                .reshape(-1)
                .astype(np.int64)
            )
            vals = self._elements(
                int(_get(val, "bufferView")), int(_get(val, "byteOffset", 0) or 0), n, dtype, shape, what
            )
            if at.size and (at.min() < 0 or at.max() >= count):
                self.fail(f"{what}: sparse index out of range")
            out[at] = vals
        if len(shape) == 2:  # glTF matrices are column-major
            out = np.swapaxes(out, -1, -2)
        if dtype.kind == "f":
            return out.astype(np.float64)
        if _get(acc, "normalized", False):
            info = np.iinfo(dtype)
            f = out.astype(np.float64) / float(info.max)
            return np.maximum(f, -1.0) if info.min < 0 else f
        return out.astype(np.int64)


@dataclasses.dataclass(frozen=True)
class _Channel:
    node: int
    path: str  # translation / rotation / scale
    interpolation: str
    times: np.ndarray  # (K,)
    values: np.ndarray  # (K, C) or (K, 3, C)


@dataclasses.dataclass(frozen=True)
class AnimationInfo:
    """One animation clip.

    Attributes:
        index: position in the file's animation list.
        name: the clip's name ("" when the file gives none).
        start: first keyframe time (seconds, file timeline).
        end: last keyframe time.
        n_channels: number of transform channels (translation / rotation / scale).
    """

    index: int
    name: str
    start: float
    end: float
    n_channels: int

    @property
    def duration(self) -> float:
        """``end - start`` in seconds."""
        return self.end - self.start


@dataclasses.dataclass(frozen=True)
class PosedMesh:
    """A posed skinned mesh and its skeleton.

    Attributes:
        vertices: (V, 3) posed positions (world coordinates), welded unless asked otherwise.
        faces: (F, 3) triangles, 0-based.
        joint_positions: (J, 3) world positions of the skin's joints in the same pose.
        parents: (J,) parent joint index, -1 for the root.
        names: J joint names.
        file_index: (V,) index of each vertex in the file's vertex list (all primitives of the
            skinned mesh concatenated in order); identity when not welded.
        time: the animation time used (after clamping), None for the bind / rest pose.
        animation: the clip's name used (None when no animation was sampled).
    """

    vertices: Float[np.ndarray, "V 3"]
    faces: Int[np.ndarray, "F 3"]
    joint_positions: Float[np.ndarray, "J 3"]
    parents: Int[np.ndarray, " J"]
    names: list[str]
    file_index: Int[np.ndarray, " V"]
    time: float | None = None
    animation: str | None = None

    def to_mesh(self, name: str | None = None):
        """The surface as an :class:`ncflow.mesh.Mesh`."""
        from ncflow.mesh import Mesh

        return Mesh(vertices=self.vertices, faces=self.faces, name=name, file_index=self.file_index)


@dataclasses.dataclass(frozen=True)
class GltfSkin:
    """A skin of a glTF file with its node hierarchy, animations and (optionally) skinned geometry.

    Attributes:
        path: the file.
        skin_index: which skin of the file.
        node_parents: (N,) parent node of every node, -1 for scene roots.
        node_order: (N,) nodes ordered parents-first.
        node_depth: (N,) number of ancestors of every node.
        rest_local: (N, 4, 4) every node's local transform as written (TRS or matrix).
        rest_translations, rest_rotations, rest_scales: (N, 3), (N, 4) ``(x, y, z, w)``, (N, 3)
            local TRS of every node (decomposed from the matrix for matrix nodes).
        has_matrix: (N,) nodes given by a matrix.
        joint_nodes: (J,) node index of each joint, in the skin's order.
        inverse_bind: (J, 4, 4) inverse bind matrices.
        names: J joint names (node names; ``joint{j}`` when missing; made unique).
        parents: (J,) skeleton parents (see module docstring), -1 for the root.
        animations: clip summaries; ``channels`` holds the sampled data per clip.
        positions: (Vf, 3) bind-pose positions of the skinned mesh (file vertex order), or None.
        faces: (F, 3) triangles into ``positions``, or None.
        joints: (Vf, K) joint indices (skin order) influencing each vertex, or None.
        weights: (Vf, K) their weights, normalised to sum 1, or None.
        mesh_node: the node holding the skinned mesh (None when geometry was not read).
    """

    path: str
    skin_index: int
    node_parents: np.ndarray
    node_order: np.ndarray
    node_depth: np.ndarray
    rest_local: np.ndarray
    rest_translations: np.ndarray
    rest_rotations: np.ndarray
    rest_scales: np.ndarray
    has_matrix: np.ndarray
    joint_nodes: np.ndarray
    inverse_bind: np.ndarray
    names: list[str]
    parents: np.ndarray
    animations: list[AnimationInfo]
    channels: list[list[_Channel]] = dataclasses.field(repr=False)
    positions: np.ndarray | None = None
    faces: np.ndarray | None = None
    joints: np.ndarray | None = None
    weights: np.ndarray | None = None
    mesh_node: int | None = None

    @property
    def n_joints(self) -> int:
        return int(self.joint_nodes.shape[0])

    # -- selection ---------------------------------------------------------------------------

    def find_animation(self, animation: str | int | None) -> AnimationInfo:
        """The clip named or numbered ``animation`` (None: the first). A string that is no clip's name
        but an integer selects by index."""
        if not self.animations:
            raise InputError("has no animations (only the bind pose is available)", self.path)
        if animation is None:
            return self.animations[0]
        if isinstance(animation, (int, np.integer)) and not isinstance(animation, bool):
            index = int(animation)
        else:
            for info in self.animations:
                if info.name == str(animation):
                    return info
            try:
                index = int(str(animation).strip())
            except ValueError:
                raise InputError(
                    f"no animation named {str(animation)!r}; clips: {self._clip_list()}", self.path
                ) from None
        if not 0 <= index < len(self.animations):
            raise InputError(f"animation index {index} out of range (clips: {self._clip_list()})", self.path)
        return self.animations[index]

    def _clip_list(self) -> str:
        return ", ".join(f"{a.index}:{a.name or '(unnamed)'}" for a in self.animations)

    # -- posing ------------------------------------------------------------------------------

    def local_transforms(
        self,
        time: float | None = None,
        animation: str | int | None = None,
        joint_rotations: Float[np.ndarray, "J 4"] | None = None,
    ) -> Float[np.ndarray, "N 4 4"]:
        """Local transform of every node at an animation time and/or with replaced joint rotations."""
        t_, r_, s_ = self.rest_translations.copy(), self.rest_rotations.copy(), self.rest_scales.copy()
        changed = np.zeros(self.node_parents.shape[0], dtype=bool)
        if time is not None:
            time = _check_time(time, self.path)
            info = self.find_animation(animation)
            t = min(max(time, info.start), info.end)
            target = {"translation": t_, "rotation": r_, "scale": s_}
            for ch in self.channels[info.index]:
                target[ch.path][ch.node] = interpolate_keyframes(
                    ch.times, ch.values, t, ch.interpolation, rotation=ch.path == "rotation"
                )
                changed[ch.node] = True
        if joint_rotations is not None:
            q = np.asarray(joint_rotations, dtype=np.float64)
            if q.shape != (self.n_joints, 4):
                raise InputError(f"joint rotations must have shape ({self.n_joints}, 4), got {q.shape}")
            norm = np.linalg.norm(q, axis=1)
            if not np.all(np.isfinite(q)) or np.any(norm < 1e-12):
                raise InputError("joint rotations must be finite non-zero quaternions (x, y, z, w)")
            r_[self.joint_nodes] = q / norm[:, None]
            changed[self.joint_nodes] = True
        local = self.rest_local.copy()
        local[changed] = trs_matrix(t_[changed], r_[changed], s_[changed])
        return local

    def world_transforms(self, local: Float[np.ndarray, "N 4 4"]) -> Float[np.ndarray, "N 4 4"]:
        """World transform of every node from the local ones (parents first)."""
        world = np.empty_like(local)
        for n in self.node_order:
            p = self.node_parents[n]
            world[n] = local[n] if p < 0 else world[p] @ local[n]
        return world

    def joint_world(
        self,
        time: float | None = None,
        animation: str | int | None = None,
        joint_rotations: Float[np.ndarray, "J 4"] | None = None,
    ) -> Float[np.ndarray, "J 4 4"]:
        """World transforms of the joints: the bind pose (inverse of the inverse bind matrices)
        when neither a time nor rotations are given, else the animated / rotated node hierarchy."""
        if time is None and joint_rotations is None:
            if animation is not None:
                self.find_animation(animation)  # validate even though the bind pose ignores it
            return np.linalg.inv(self.inverse_bind)
        world = self.world_transforms(self.local_transforms(time, animation, joint_rotations))
        return world[self.joint_nodes]

    def pose(
        self,
        time: float | None = None,
        animation: str | int | None = None,
        joint_rotations: Float[np.ndarray, "J 4"] | None = None,
        weld: bool = True,
    ) -> PosedMesh:
        """The skinned mesh posed by linear blend skinning; see :func:`pose_gltf`."""
        if self.positions is None:
            raise InputError("no skinned mesh was read for this skin", self.path)
        joint_world = self.joint_world(time, animation, joint_rotations)
        if time is None and joint_rotations is None:
            posed = self.positions.copy()  # every skin matrix is the identity
        else:
            posed = skin_vertices(self.positions, self.joints, self.weights, joint_world @ self.inverse_bind)
        faces = self.faces
        file_index = np.arange(self.positions.shape[0])
        if weld:
            from ncflow.mesh import weld_vertices

            _, faces, file_index = weld_vertices(self.positions, self.faces)
            posed = posed[file_index]
            keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])
            faces = faces[keep]
        clip = None
        used_time = None
        if time is not None:
            info = self.find_animation(animation)
            clip = info.name
            used_time = min(max(float(time), info.start), info.end)
        return PosedMesh(
            vertices=posed,
            faces=np.asarray(faces, dtype=np.int64),
            joint_positions=joint_world[:, :3, 3].copy(),
            parents=self.parents.copy(),
            names=list(self.names),
            file_index=np.asarray(file_index, dtype=np.int64),
            time=used_time,
            animation=clip,
        )


def _check_time(time, path) -> float:
    try:
        t = float(time)
    except (TypeError, ValueError):
        raise InputError(f"animation time must be a number (got {time!r})", path) from None
    if not math.isfinite(t):
        raise InputError(f"animation time must be finite (got {t})", path)
    return t


def _node_hierarchy(doc, reader: _Reader) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(parents (N,), parents-first order (N,), depth (N,)); InputError on cycles / shared children."""
    nodes = doc.nodes or []
    n = len(nodes)
    parents = np.full(n, -1, dtype=np.int64)
    for i, node in enumerate(nodes):
        for c in _get(node, "children") or []:
            c = int(c)
            if not 0 <= c < n:
                reader.fail(f"node {i} has a child {c} that does not exist")
            if parents[c] >= 0 or c == i:
                reader.fail(f"node {c} has more than one parent (not a tree)")
            parents[c] = i
    depth = np.full(n, -1, dtype=np.int64)
    order: list[int] = []
    children = [[] for _ in range(n)]
    for c in range(n):
        if parents[c] >= 0:
            children[parents[c]].append(c)
    stack = [i for i in range(n) if parents[i] < 0][::-1]
    for r in stack:
        depth[r] = 0
    while stack:
        i = stack.pop()
        order.append(i)
        for c in reversed(children[i]):
            depth[c] = depth[i] + 1
            stack.append(c)
    if len(order) != n:
        reader.fail("the node hierarchy has a cycle")
    return parents, np.asarray(order, dtype=np.int64), depth


def _node_rest(doc, reader: _Reader) -> tuple[np.ndarray, ...]:
    """Rest local matrices (N, 4, 4), TRS (N,3), (N,4), (N,3) and matrix flags (N,)."""
    nodes = doc.nodes or []
    n = len(nodes)
    local = np.tile(np.eye(4), (n, 1, 1))
    trans, rots, scales = np.zeros((n, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)), np.ones((n, 3))
    has_matrix = np.zeros(n, dtype=bool)
    for i, node in enumerate(nodes):
        matrix = _get(node, "matrix")
        if matrix is not None and len(matrix) > 0:
            m = np.asarray(matrix, dtype=np.float64)
            if m.shape != (16,) or not np.all(np.isfinite(m)):
                reader.fail(f"node {i} has a malformed matrix")
            m = m.reshape(4, 4).T  # column-major
            local[i] = m
            has_matrix[i] = True
            trans[i] = m[:3, 3]
            a = m[:3, :3]
            s = np.linalg.norm(a, axis=0)
            if np.linalg.det(a) < 0:
                s[0] = -s[0]
            if np.any(s == 0):
                rots[i], scales[i] = [0.0, 0.0, 0.0, 1.0], s
            else:
                rots[i], scales[i] = matrix_to_quat(a / s), s
            continue
        t = _get(node, "translation")
        r = _get(node, "rotation")
        s = _get(node, "scale")
        try:
            if t is not None:
                trans[i] = np.asarray(t, dtype=np.float64).reshape(3)
            if r is not None:
                rots[i] = np.asarray(r, dtype=np.float64).reshape(4)
            if s is not None:
                scales[i] = np.asarray(s, dtype=np.float64).reshape(3)
        except ValueError:
            reader.fail(f"node {i} has a malformed translation / rotation / scale")
        if not (np.all(np.isfinite(trans[i])) and np.all(np.isfinite(rots[i])) and np.all(np.isfinite(scales[i]))):
            reader.fail(f"node {i} has a non-finite transform")
        if np.linalg.norm(rots[i]) < 1e-12:
            reader.fail(f"node {i} has a zero rotation quaternion")
        rots[i] = rots[i] / np.linalg.norm(rots[i])
        local[i] = trs_matrix(trans[i], rots[i], scales[i])
    return local, trans, rots, scales, has_matrix


def _skeleton_parents(joint_nodes: np.ndarray, node_parents: np.ndarray, node_depth: np.ndarray) -> np.ndarray:
    """Parent joint of every joint: nearest joint ancestor node; extra roots attached to the top-most root."""
    where = {int(node): j for j, node in enumerate(joint_nodes)}
    parents = np.full(joint_nodes.shape[0], -1, dtype=np.int64)
    for j, node in enumerate(joint_nodes):
        p = int(node_parents[node])
        while p >= 0 and p not in where:
            p = int(node_parents[p])
        parents[j] = where[p] if p >= 0 else -1
    roots = np.flatnonzero(parents < 0)
    if roots.size > 1:
        root = int(roots[np.lexsort((roots, node_depth[joint_nodes[roots]]))[0]])
        parents[roots[roots != root]] = root
    return parents


def _unique_names(raw: list[str | None]) -> list[str]:
    names: list[str] = []
    seen: set[str] = set()
    for j, name in enumerate(raw):
        base = name if name else f"joint{j}"
        candidate, k = base, 2
        while candidate in seen:
            candidate, k = f"{base}_{k}", k + 1
        seen.add(candidate)
        names.append(candidate)
    return names


def _read_animations(doc, reader: _Reader, n_nodes: int) -> tuple[list[AnimationInfo], list[list[_Channel]]]:
    infos, all_channels = [], []
    for a, anim in enumerate(doc.animations or []):
        samplers = _get(anim, "samplers") or []
        channels = []
        for c, channel in enumerate(_get(anim, "channels") or []):
            target = _get(channel, "target")
            path = _get(target, "path")
            node = _get(target, "node")
            if path not in _PATHS or node is None:
                continue  # morph-target weights, or a channel of an extension (KHR_animation_pointer)
            node = int(node)
            if not 0 <= node < n_nodes:
                reader.fail(f"animation {a} channel {c} targets node {node}, which does not exist")
            s = _get(channel, "sampler")
            if s is None or not 0 <= int(s) < len(samplers):
                reader.fail(f"animation {a} channel {c} uses sampler {s}, which does not exist")
            sampler = samplers[int(s)]
            interpolation = _get(sampler, "interpolation") or "LINEAR"
            if interpolation not in _INTERPOLATIONS:
                reader.fail(f"animation {a} sampler {s}: unknown interpolation {interpolation!r}")
            what = f"animation {a} sampler {s}"
            times = reader.accessor(_get(sampler, "input"), what + " input").reshape(-1).astype(np.float64)
            values = reader.accessor(_get(sampler, "output"), what + " output").astype(np.float64)
            width = 4 if path == "rotation" else 3
            if values.ndim != 2 or values.shape[1] != width:
                reader.fail(f"{what}: {path} output must have {width} components, got shape {values.shape}")
            if times.size == 0:
                reader.fail(f"{what} has no keyframes")
            if not np.all(np.isfinite(times)) or np.any(np.diff(times) < 0):
                reader.fail(f"{what}: keyframe times are not finite and increasing")
            if not np.all(np.isfinite(values)):
                reader.fail(f"{what}: non-finite keyframe values")
            per_key = 3 if interpolation == "CUBICSPLINE" else 1
            if values.shape[0] != per_key * times.size:
                reader.fail(
                    f"{what}: {values.shape[0]} output values for {times.size} keyframes "
                    f"({interpolation} needs {per_key} per keyframe)"
                )
            if per_key == 3:
                values = values.reshape(times.size, 3, width)
            if path == "rotation" and interpolation != "CUBICSPLINE":
                if np.any(np.linalg.norm(values, axis=-1) < 1e-12):
                    reader.fail(f"{what}: zero rotation quaternion")
            channels.append(_Channel(node, path, interpolation, times, values))
        if channels:
            start = float(min(ch.times[0] for ch in channels))
            end = float(max(ch.times[-1] for ch in channels))
        else:
            start = end = 0.0
        infos.append(AnimationInfo(a, _get(anim, "name") or "", start, end, len(channels)))
        all_channels.append(channels)
    return infos, all_channels


_MODES = {4: "triangles", 5: "strip", 6: "fan"}


def _triangles(indices: np.ndarray, mode: int) -> np.ndarray:
    """(F, 3) triangles from a triangle list, strip or fan index sequence."""
    if mode == 4:
        return indices[: indices.size // 3 * 3].reshape(-1, 3)
    n = indices.size - 2
    if n <= 0:
        return np.zeros((0, 3), dtype=np.int64)
    k = np.arange(n)
    if mode == 5:  # strips alternate winding
        even = k % 2 == 0
        a = indices[k]
        b = np.where(even, indices[k + 1], indices[k + 2])
        c = np.where(even, indices[k + 2], indices[k + 1])
        return np.stack([a, b, c], 1)
    return np.stack([np.full(n, indices[0]), indices[k + 1], indices[k + 2]], 1)


def _read_geometry(doc, reader: _Reader, mesh_index: int, n_joints: int):
    """(positions (V,3), faces (F,3), joints (V,K), weights (V,K)) of all primitives of a mesh."""
    meshes = doc.meshes or []
    if not 0 <= mesh_index < len(meshes):
        reader.fail(f"mesh {mesh_index} does not exist")
    prims = _get(meshes[mesh_index], "primitives") or []
    pos_all, face_all, jnt_all, wgt_all = [], [], [], []
    offset = 0
    n_sets = None
    for p, prim in enumerate(prims):
        what = f"mesh {mesh_index} primitive {p}"
        mode = _get(prim, "mode")
        mode = 4 if mode is None else int(mode)
        if mode not in _MODES:
            reader.fail(f"{what} is not made of triangles (mode {mode})")
        attrs = _get(prim, "attributes")
        pos = reader.accessor(_get(attrs, "POSITION"), what + " POSITION").astype(np.float64)
        if pos.ndim != 2 or pos.shape[1] != 3:
            reader.fail(f"{what}: POSITION must be VEC3")
        sets = []
        k = 0
        while _get(attrs, f"JOINTS_{k}") is not None and _get(attrs, f"WEIGHTS_{k}") is not None:
            j = reader.accessor(_get(attrs, f"JOINTS_{k}"), f"{what} JOINTS_{k}")
            w = reader.accessor(_get(attrs, f"WEIGHTS_{k}"), f"{what} WEIGHTS_{k}").astype(np.float64)
            if j.shape != (pos.shape[0], 4) or w.shape != (pos.shape[0], 4):
                reader.fail(f"{what}: JOINTS_{k} / WEIGHTS_{k} must be VEC4 with one entry per vertex")
            if j.dtype.kind == "f":
                reader.fail(f"{what}: JOINTS_{k} must be unsigned integers")
            sets.append((j, w))
            k += 1
        if not sets:
            reader.fail(f"{what} has no JOINTS_0 / WEIGHTS_0 (not skinned)")
        if n_sets is None:
            n_sets = len(sets)
        # primitives with fewer influence sets are padded with zero weights
        while len(sets) < n_sets:
            sets.append((np.zeros((pos.shape[0], 4), np.int64), np.zeros((pos.shape[0], 4))))
        if len(sets) > n_sets:
            pad = len(sets) - n_sets
            for q in range(len(jnt_all)):
                jnt_all[q] = np.concatenate([jnt_all[q], np.zeros((jnt_all[q].shape[0], 4 * pad), np.int64)], 1)
                wgt_all[q] = np.concatenate([wgt_all[q], np.zeros((wgt_all[q].shape[0], 4 * pad))], 1)
            n_sets = len(sets)
        joints = np.concatenate([s[0] for s in sets], 1).astype(np.int64)
        weights = np.concatenate([s[1] for s in sets], 1)
        if _get(prim, "indices") is not None:
            idx = reader.accessor(_get(prim, "indices"), what + " indices").reshape(-1)
            if idx.dtype.kind == "f":
                reader.fail(f"{what}: indices must be integers")
        else:
            idx = np.arange(pos.shape[0], dtype=np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= pos.shape[0]):
            reader.fail(f"{what}: vertex index out of range ({int(idx.max())} >= {pos.shape[0]} vertices)")
        faces = _triangles(idx.astype(np.int64), mode)
        pos_all.append(pos)
        face_all.append(faces + offset)
        jnt_all.append(joints)
        wgt_all.append(weights)
        offset += pos.shape[0]
    if not pos_all or offset == 0:
        reader.fail(f"mesh {mesh_index} has no vertices")
    positions = np.concatenate(pos_all)
    faces = np.concatenate(face_all)
    joints = np.concatenate(jnt_all)
    weights = np.concatenate(wgt_all)
    if faces.shape[0] == 0:
        reader.fail(f"mesh {mesh_index} has no triangles")
    if not np.all(np.isfinite(positions)):
        reader.fail(f"mesh {mesh_index}: non-finite vertex positions")
    if not np.all(np.isfinite(weights)) or np.any(weights < 0):
        reader.fail(f"mesh {mesh_index}: skin weights must be finite and non-negative")
    used = weights > 0
    if np.any(used & ((joints < 0) | (joints >= n_joints))):
        reader.fail(f"mesh {mesh_index}: a skin joint index is out of range (the skin has {n_joints} joints)")
    joints = np.where(used, joints, 0)
    total = weights.sum(1)
    if np.any(total <= 0):
        bad = np.flatnonzero(total <= 0)
        reader.fail(f"mesh {mesh_index}: {bad.size} vertices have no skin weight (first: vertex {int(bad[0])})")
    return positions, faces, joints, weights / total[:, None]


def load_gltf_skin(path: str | os.PathLike, skin: int | None = None, *, geometry: bool = True) -> GltfSkin:
    """Read a skin of a glTF 2.0 / GLB file (hierarchy, joints, animations and skinned mesh).

    Args:
        path: a ``.glb`` or ``.gltf`` file.
        skin: which skin (None: the first).
        geometry: also read the skinned mesh (the first node using the skin with a mesh);
            False reads the skeleton and animations only.

    Raises:
        InputError: not a glTF file, no skin, no skinned mesh (when ``geometry``), malformed data.
    """
    path = Path(path)
    try:
        return _load_gltf_skin(path, skin, geometry)
    except InputError:
        raise
    except (TypeError, ValueError, KeyError, IndexError, AttributeError) as exc:  # malformed JSON structure
        msg = str(exc).splitlines()[0] if str(exc) else ""
        raise InputError(f"malformed glTF ({type(exc).__name__}{': ' + msg if msg else ''})", path) from None


def _load_gltf_skin(path: Path, skin: int | None, geometry: bool) -> GltfSkin:
    doc = _load_document(path)
    reader = _Reader(doc, path)
    skins = doc.skins or []
    if not skins:
        raise InputError("has no skin (not a rigged character)", path)
    skin_index = 0 if skin is None else int(skin)
    if not 0 <= skin_index < len(skins):
        raise InputError(f"skin {skin_index} does not exist (the file has {len(skins)})", path)
    nodes = doc.nodes or []
    node_parents, node_order, node_depth = _node_hierarchy(doc, reader)
    rest_local, trans, rots, scales, has_matrix = _node_rest(doc, reader)
    joint_nodes = np.asarray(_get(skins[skin_index], "joints") or [], dtype=np.int64)
    if joint_nodes.size == 0:
        reader.fail(f"skin {skin_index} has no joints")
    if joint_nodes.min() < 0 or joint_nodes.max() >= len(nodes):
        reader.fail(f"skin {skin_index} refers to a joint node that does not exist")
    if np.unique(joint_nodes).size != joint_nodes.size:
        reader.fail(f"skin {skin_index} lists a joint node twice")
    n_joints = joint_nodes.size
    ibm_index = _get(skins[skin_index], "inverseBindMatrices")
    if ibm_index is None:
        inverse_bind = np.tile(np.eye(4), (n_joints, 1, 1))
    else:
        inverse_bind = reader.accessor(ibm_index, f"skin {skin_index} inverseBindMatrices")
        if inverse_bind.shape != (n_joints, 4, 4):
            reader.fail(
                f"skin {skin_index}: need {n_joints} MAT4 inverse bind matrices, got shape {inverse_bind.shape}"
            )
        if not np.all(np.isfinite(inverse_bind)):
            reader.fail(f"skin {skin_index}: non-finite inverse bind matrices")
        inverse_bind = inverse_bind.copy()
        inverse_bind[:, 3, :] = [0.0, 0.0, 0.0, 1.0]  # affine by definition; clears float noise
        dets = np.linalg.det(inverse_bind[:, :3, :3])
        if np.any(np.abs(dets) < 1e-12 * np.max(np.abs(inverse_bind[:, :3, :3]), axis=(1, 2)) ** 3):
            reader.fail(f"skin {skin_index}: singular inverse bind matrix (joint {int(np.argmin(np.abs(dets)))})")
    names = _unique_names([_get(nodes[int(n)], "name") for n in joint_nodes])
    parents = _skeleton_parents(joint_nodes, node_parents, node_depth)
    infos, channels = _read_animations(doc, reader, len(nodes))
    positions = faces = joints = weights = None
    mesh_node = None
    if geometry:
        for i, node in enumerate(nodes):
            if (
                _get(node, "skin") is not None
                and int(_get(node, "skin")) == skin_index
                and _get(node, "mesh") is not None
            ):
                mesh_node = i
                break
        if mesh_node is None:
            reader.fail(f"no node uses skin {skin_index} with a mesh (nothing to pose)")
        positions, faces, joints, weights = _read_geometry(doc, reader, int(_get(nodes[mesh_node], "mesh")), n_joints)
    return GltfSkin(
        path=str(path),
        skin_index=skin_index,
        node_parents=node_parents,
        node_order=node_order,
        node_depth=node_depth,
        rest_local=rest_local,
        rest_translations=trans,
        rest_rotations=rots,
        rest_scales=scales,
        has_matrix=has_matrix,
        joint_nodes=joint_nodes,
        inverse_bind=inverse_bind,
        names=names,
        parents=parents,
        animations=infos,
        channels=channels,
        positions=positions,
        faces=faces,
        joints=joints,
        weights=weights,
        mesh_node=mesh_node,
    )


# ----------------------------------------------------------------------------------------------
# Public entry points


def gltf_animations(path: str | os.PathLike) -> list[AnimationInfo]:
    """The animation clips of a glTF file (index, name, start, end, duration, channel count)."""
    path = Path(path)
    doc = _load_document(path)
    reader = _Reader(doc, path)
    try:
        infos, _ = _read_animations(doc, reader, len(doc.nodes or []))
    except InputError:
        raise
    except (TypeError, ValueError, KeyError, IndexError, AttributeError) as exc:
        raise InputError(f"malformed glTF animations ({type(exc).__name__})", path) from None
    return infos


def gltf_skeleton(
    path: str | os.PathLike,
    time: float | None = None,
    animation: str | int | None = None,
    *,
    skin: int | None = None,
) -> tuple[Float[np.ndarray, "J 3"], Int[np.ndarray, " J"], list[str]]:
    """The skeleton of a skinned glTF file.

    Args:
        path: ``.glb`` / ``.gltf`` file.
        time: seconds on the clip's timeline (clamped to the clip); None: the bind pose, taken
            from the inverse bind matrices (the pose the mesh is bound in).
        animation: clip name or index (None: the first clip); only used with ``time``.
        skin: which skin (None: the first).

    Returns:
        (joint world positions (J, 3), parents (J,) with -1 for the root, joint names), in the
        skin's joint order. Parents: nearest ancestor node that is a joint; several joint roots
        are joined under the top-most one (see the module docstring).

    Raises:
        InputError: not a glTF file, no skin, unknown animation, time not finite.
    """
    rig = load_gltf_skin(path, skin, geometry=False)
    world = rig.joint_world(time, animation)
    return world[:, :3, 3].copy(), rig.parents.copy(), list(rig.names)


def pose_gltf(
    path: str | os.PathLike,
    time: float | None = None,
    animation: str | int | None = None,
    joint_rotations: Float[np.ndarray, "J 4"] | None = None,
    weld: bool = True,
    *,
    skin: int | None = None,
) -> PosedMesh:
    """Pose the skinned mesh of a glTF file by linear blend skinning.

    Args:
        path: ``.glb`` / ``.gltf`` file.
        time: seconds on the clip's timeline (clamped to the clip's range); None: no animation.
        animation: clip name or index (None: the first clip).
        joint_rotations: (J, 4) local rotations ``(x, y, z, w)`` per joint (skin order) replacing
            the joint nodes' rotations (rest rotations, or animated ones at ``time``).
        weld: merge seam duplicates (exactly coincident bind-pose positions) into one vertex.
        skin: which skin (None: the first).

    With neither ``time`` nor ``joint_rotations`` the result is the bind pose (the file's vertex
    positions; joints from the inverse bind matrices); ``animation`` is then only checked to
    exist. ``joint_rotations`` without ``time`` rotate the nodes' rest transforms. For several poses of one file, read it
    once with :func:`load_gltf_skin` and call :meth:`GltfSkin.pose`: all poses share vertex order
    and faces, so vertex ``i`` is the same body point in every pose.

    Returns:
        :class:`PosedMesh` in world coordinates.

    Raises:
        InputError: not a glTF file, no skin or skinned mesh, unknown animation, bad time or rotations.
    """
    return load_gltf_skin(path, skin).pose(time, animation, joint_rotations, weld)
