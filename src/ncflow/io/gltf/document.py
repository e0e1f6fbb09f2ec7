"""glTF 2.0 documents: parsing, buffers, the accessor decoder, the node hierarchy and rest transforms.

Reads ``.glb`` and ``.gltf`` files with embedded, data-URI or external buffers. pygltflib parses the
JSON and the GLB chunks but leaves the binary data undecoded, so accessors are decoded here: any
component type, normalised integers, ``byteStride``, the 4-byte column alignment and column-major
order of matrices, and sparse accessors, each problem one :class:`~ncflow.errors.InputError` line
naming the file. A node's local transform is read as TRS or as a column-major ``matrix`` (then
also decomposed into TRS); the node hierarchy must be a forest (no cycles, no shared children).
Required extensions that change how positions, skins or animations are stored are refused with
the advice to decompress the file first.

What is done with a document is in :mod:`ncflow.io.gltf.skins` (skins, skinned meshes, posing)
and :mod:`ncflow.io.gltf.animation` (clips and their sampling).
"""

from __future__ import annotations

import base64
import json
import urllib.parse
from pathlib import Path

import numpy as np

from ncflow.errors import InputError
from ncflow.geometry.rigid import matrix_to_quat, trs_matrix

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
# required extensions that do not change how positions, skins and animations are stored
_SUPPORTED_REQUIRED = {"KHR_mesh_quantization", "KHR_materials_unlit", "KHR_texture_transform", "KHR_texture_basisu"}


# ----------------------------------------------------------------------------------------------
# Reading the file


def get_field(obj, key, default=None):
    """Attribute or dict access (pygltflib returns either for nested and extension objects)."""
    if obj is None:
        return default
    if isinstance(obj, dict):
        return obj.get(key, default)
    return getattr(obj, key, default)


def load_document(path: Path):
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
    version = str(get_field(doc.asset, "version", "") or "")
    if not version.startswith("2"):
        raise InputError(f"glTF version {version or '(missing)'} is not supported; need 2.x", path)
    unsupported = sorted(set(get_field(doc, "extensionsRequired") or []) - _SUPPORTED_REQUIRED)
    if unsupported:
        raise InputError(
            f"needs glTF extension(s) {', '.join(unsupported)}, which ncflow cannot read "
            "(decompress the file first, e.g. with gltf-transform)",
            path,
        )
    return doc


class DocumentReader:
    """Accessor reading for one parsed document (buffers cached)."""

    def __init__(self, doc, path: Path):
        self.doc = doc
        self.path = path
        self._buffers: dict[int, bytes] = {}

    def fail(self, message: str):
        """Raise an InputError naming the file."""
        raise InputError(message, self.path)

    def buffer(self, index: int) -> bytes:
        """The bytes of buffer ``index`` (GLB chunk, data URI or external file), read once."""
        if index in self._buffers:
            return self._buffers[index]
        buffers = self.doc.buffers or []
        if not 0 <= index < len(buffers):
            self.fail(f"buffer {index} does not exist")
        uri = get_field(buffers[index], "uri")
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
        length = get_field(buffers[index], "byteLength")
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
        data = np.frombuffer(self.buffer(int(get_field(view, "buffer", 0))), dtype=np.uint8)
        start = int(get_field(view, "byteOffset", 0) or 0)
        view_len = int(get_field(view, "byteLength", 0) or 0)
        csize = dtype.itemsize
        if len(shape) == 2:  # matrix columns start on 4-byte boundaries
            rows = shape[0]
            col_stride = -(-rows * csize // 4) * 4
            byte_pos = np.concatenate([c * col_stride + np.arange(rows * csize) for c in range(shape[1])])
        else:
            byte_pos = np.arange(int(np.prod(shape)) * csize)
        elem_size = int(byte_pos[-1]) + 1 if byte_pos.size else 0
        elem_size = -(-elem_size // 4) * 4 if len(shape) == 2 else elem_size
        stride = int(get_field(view, "byteStride", 0) or 0) or elem_size
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
        ctype = get_field(acc, "componentType")
        atype = get_field(acc, "type")
        count = int(get_field(acc, "count", 0) or 0)
        if ctype not in _COMPONENT_DTYPES:
            self.fail(f"{what}: unknown accessor component type {ctype}")
        if atype not in _TYPE_SHAPES:
            self.fail(f"{what}: unknown accessor type {atype!r}")
        dtype, shape = _COMPONENT_DTYPES[ctype], _TYPE_SHAPES[atype]
        view = get_field(acc, "bufferView")
        if view is None:
            out = np.zeros((count,) + shape, dtype=dtype)
        else:
            out = self._elements(int(view), int(get_field(acc, "byteOffset", 0) or 0), count, dtype, shape, what).copy()
        sparse = get_field(acc, "sparse")
        if sparse is not None and int(get_field(sparse, "count", 0) or 0) > 0:
            n = int(get_field(sparse, "count"))
            ind, val = get_field(sparse, "indices"), get_field(sparse, "values")
            if get_field(ind, "bufferView") is None or get_field(val, "bufferView") is None:
                self.fail(f"{what}: sparse accessor without indices / values buffer views")
            itype = get_field(ind, "componentType")
            if itype not in (5121, 5123, 5125):
                self.fail(f"{what}: sparse indices have invalid component type {itype}")
            at = (
                self._elements(
                    int(get_field(ind, "bufferView")),
                    int(get_field(ind, "byteOffset", 0) or 0),
                    n,
                    _COMPONENT_DTYPES[itype],
                    (1,),
                    what,
                )
                .reshape(-1)
                .astype(np.int64)
            )
            vals = self._elements(
                int(get_field(val, "bufferView")), int(get_field(val, "byteOffset", 0) or 0), n, dtype, shape, what
            )
            if at.size and (at.min() < 0 or at.max() >= count):
                self.fail(f"{what}: sparse index out of range")
            out[at] = vals
        if len(shape) == 2:  # glTF matrices are column-major
            out = np.swapaxes(out, -1, -2)
        if dtype.kind == "f":
            return out.astype(np.float64)
        if get_field(acc, "normalized", False):
            info = np.iinfo(dtype)
            f = out.astype(np.float64) / float(info.max)
            return np.maximum(f, -1.0) if info.min < 0 else f
        return out.astype(np.int64)


def node_hierarchy(doc, reader: DocumentReader) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(parents (N,), parents-first order (N,), depth (N,)); InputError on cycles / shared children."""
    nodes = doc.nodes or []
    n = len(nodes)
    parents = np.full(n, -1, dtype=np.int64)
    for i, node in enumerate(nodes):
        for c in get_field(node, "children") or []:
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


def node_rest(doc, reader: DocumentReader) -> tuple[np.ndarray, ...]:
    """Rest local matrices (N, 4, 4), TRS (N,3), (N,4), (N,3) and matrix flags (N,).

    Rotations are unit quaternions ``(x, y, z, w)``; a node given by a matrix is decomposed into
    translation, rotation (``w ≥ 0``) and scale (the first scale negative for a mirroring matrix).
    """
    nodes = doc.nodes or []
    n = len(nodes)
    local = np.tile(np.eye(4), (n, 1, 1))
    trans, rots, scales = np.zeros((n, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)), np.ones((n, 3))
    has_matrix = np.zeros(n, dtype=bool)
    for i, node in enumerate(nodes):
        matrix = get_field(node, "matrix")
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
                rots[i], scales[i] = matrix_to_quat(a / s, scalar_first=False), s
            continue
        t = get_field(node, "translation")
        r = get_field(node, "rotation")
        s = get_field(node, "scale")
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
        local[i] = trs_matrix(trans[i], rots[i], scales[i], scalar_first=False)
    return local, trans, rots, scales, has_matrix


def unique_names(raw: list[str | None]) -> list[str]:
    """Names made unique (``name_2``, ``name_3``, …); a missing name becomes ``joint{j}``."""
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
