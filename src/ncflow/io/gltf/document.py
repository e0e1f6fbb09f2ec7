"""glTF 2.0 documents: parsing, buffers, the accessor decoder, the node hierarchy and rest transforms.

Reads ``.glb`` and ``.gltf`` files with embedded, data-URI or external buffers. pygltflib parses the
JSON and the GLB chunks but leaves the binary data undecoded, so accessors are decoded here: any
component type, normalised integers, ``byteStride``, the 4-byte column alignment and column-major
order of matrices, and sparse accessors, each problem one :class:`~ncflow.errors.InputError` line
naming the file. A node's local transform is read as TRS or as a column-major ``matrix`` (then
also decomposed into TRS); the node hierarchy must be a forest (no cycles, no shared children).
Required extensions that change how positions, skins or animations are stored are refused with
the advice to decompress the file first.

Hostile files are refused before anything is allocated or read from elsewhere: a buffer or image
``uri`` that could lead out of the file's folder (:func:`check_resource_uris`); an external buffer
that is no regular file inside it (:func:`ncflow.io.files.read_confined`; only its first
``byteLength`` bytes are read, and messages never give the size of another file); an accessor
whose byte range leaves its buffer view, or a view its buffer (:func:`check_accessor_sizes`, from
the JSON alone); limits :data:`MAX_NODES`, :data:`MAX_BUFFER_BYTES`, :data:`MAX_ZERO_ACCESSOR_BYTES`
and :data:`READ_FACTOR`; JSON nested too deeply or with numbers too long to convert.

What is done with a document is in :mod:`ncflow.io.gltf.skins` (skins, skinned meshes, posing)
and :mod:`ncflow.io.gltf.animation` (clips and their sampling).
"""

from __future__ import annotations

import base64
import contextlib
import json
import re
from pathlib import Path

import numpy as np

from ncflow.errors import InputError, first_line
from ncflow.geometry.rigid import matrix_to_quat, trs_matrix
from ncflow.io.files import check_regular_file, confined_path, read_confined, short_repr

GLTF_SUFFIXES = (".glb", ".gltf")

MAX_NODES = 100_000
"""Most nodes a glTF document may have."""

MAX_BUFFER_BYTES = 2 * 2**30
"""Largest ``byteLength`` of one buffer (2 GiB)."""

MAX_ZERO_ACCESSOR_BYTES = 64 * 2**20
"""Largest accessor without a buffer view (all zeros plus sparse values; 64 MiB)."""

READ_FACTOR = 4
"""Decoded accessors total at most ``READ_FACTOR`` × the buffers' bytes + 64 MiB (no buffer decoded 1000s of times)."""

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


@contextlib.contextmanager
def malformed(path, what: str = "glTF"):
    """Turn the errors that a JSON structure of unexpected types causes into one InputError line."""
    try:
        yield
    except InputError:
        raise
    except (TypeError, ValueError, KeyError, IndexError, AttributeError, OverflowError, RecursionError) as exc:
        msg = first_line(exc)[:80] if str(exc) else ""
        raise InputError(f"malformed {what} ({type(exc).__name__}{': ' + msg if msg else ''})", path) from None


def load_document(path: Path):
    """Parse a .glb or .gltf file with pygltflib; InputError if it is not one."""
    import pygltflib

    path = check_regular_file(path, "glTF")
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
    except RecursionError:
        raise InputError("not a readable glTF 2.0 file (JSON nested too deeply)", path) from None
    except Exception as exc:  # pygltflib raises many kinds of errors for broken files
        raise InputError(f"not a readable glTF 2.0 file ({first_line(exc)[:80]})", path) from None
    if doc is None:
        raise InputError("not a readable glTF 2.0 file (no JSON chunk)", path)
    with malformed(path):
        _check_header(doc, path)
        check_resource_uris(doc, path)
    return doc


def _check_header(doc, path: Path) -> None:
    """Version, required extensions and the node count of a parsed document."""
    version = str(get_field(doc.asset, "version", "") or "")
    if not version.startswith("2"):
        shown = short_repr(version, 40) if version else "(missing)"
        raise InputError(f"glTF version {shown} is not supported; need 2.x", path)
    unsupported = sorted({str(e) for e in get_field(doc, "extensionsRequired") or []} - _SUPPORTED_REQUIRED)
    if unsupported:
        raise InputError(
            f"needs glTF extension(s) {short_repr(', '.join(unsupported))}, which ncflow cannot read "
            "(decompress the file first, e.g. with gltf-transform)",
            path,
        )
    for key in ("nodes", "meshes", "accessors", "bufferViews", "buffers", "skins", "animations", "scenes"):
        value = get_field(doc, key)
        if value is not None and not isinstance(value, list):
            raise InputError(f"malformed glTF ('{key}' is not a list)", path)
    if len(doc.nodes or []) > MAX_NODES:
        raise InputError(f"{len(doc.nodes)} nodes, more than the {MAX_NODES} a glTF file may have here", path)


_LONG_NUMBER = re.compile(r"\d{25,}")


def _count(value, what: str, key: str, fail, default=0) -> int:
    """A JSON field that must be a non-negative integer (``default`` when absent)."""
    if value is None:
        return default
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        if not (isinstance(value, float) and value.is_integer()):
            fail(f"{what}: {key} must be a non-negative integer, got {short_repr(value, 40)}")
    value = int(value)
    if value < 0:
        fail(f"{what}: {key} must be a non-negative integer, got {value}")
    return value


def _element_layout(dtype: np.dtype, shape: tuple) -> tuple[int, int, int]:
    """(columns, bytes per column, column stride) of one element; matrix columns start on 4-byte boundaries."""
    csize = dtype.itemsize
    if len(shape) == 2:
        rows, cols = shape
        return cols, rows * csize, -(-rows * csize // 4) * 4
    n = int(np.prod(shape)) * csize
    return 1, n, n


class DocumentReader:
    """Accessor reading for one parsed document (buffers cached)."""

    def __init__(self, doc, path: Path):
        self.doc = doc
        self.path = path
        self._buffers: dict[int, bytes] = {}
        self._decoded = 0  # bytes of accessor data decoded so far
        self._buffer_total: int | None = None

    def _count_decoded(self, nbytes: int, what: str) -> None:
        """Add to the bytes decoded from this document; InputError beyond :data:`READ_FACTOR` × its buffers."""
        if self._buffer_total is None:
            self._buffer_total = sum(self.buffer_length(i) for i in range(len(self.doc.buffers or [])))
        self._decoded += nbytes
        if self._decoded > READ_FACTOR * self._buffer_total + 64 * 2**20:
            self.fail(f"{what}: the accessors decoded add up to over {READ_FACTOR} times the file's buffers")

    def fail(self, message: str):
        """Raise an InputError naming the file (numbers from the file longer than 24 digits cut short)."""
        raise InputError(_LONG_NUMBER.sub(lambda m: m.group()[:20] + "...", message), self.path)

    def buffer_length(self, index: int) -> int:
        """The declared ``byteLength`` of buffer ``index`` (checked: an integer, at most :data:`MAX_BUFFER_BYTES`)."""
        buffers = self.doc.buffers or []
        if not 0 <= index < len(buffers):
            self.fail(f"buffer {index} does not exist")
        length = _count(get_field(buffers[index], "byteLength"), f"buffer {index}", "byteLength", self.fail, None)
        if length is None:
            self.fail(f"buffer {index} has no byteLength")
        if length > MAX_BUFFER_BYTES:
            self.fail(f"buffer {index}: byteLength {length} is over the limit of {MAX_BUFFER_BYTES}")
        return length

    def buffer(self, index: int) -> bytes:
        """The bytes of buffer ``index`` (GLB chunk, data URI or external file beside the glTF file), read once."""
        if index in self._buffers:
            return self._buffers[index]
        length = self.buffer_length(index)
        uri = get_field(self.doc.buffers[index], "uri")
        if uri is None:
            blob = self.doc.binary_blob() if index == 0 else None
            if blob is None:
                self.fail(f"buffer {index} has no data (no uri and no GLB binary chunk)")
            data = bytes(blob)
        elif not isinstance(uri, str):
            self.fail(f"buffer {index}: uri must be a string")
        elif uri.startswith("data:"):
            try:
                data = base64.b64decode(uri.split(",", 1)[1])
            except Exception:
                self.fail(f"buffer {index} has a malformed data URI")
        else:
            data = self._external(index, uri, length)
        if len(data) < length:
            self.fail(f"buffer {index} is shorter than its byteLength {length}")
        self._buffers[index] = data
        return data

    def _external(self, index: int, uri: str, length: int) -> bytes:
        """At most ``length`` bytes of an external buffer file confined to the glTF file's folder."""
        try:
            return read_confined(self.path.parent, uri, length, unquote=True)
        except ValueError as exc:
            self.fail(f"buffer {index}: refusing external file {short_repr(uri)} ({exc})")
        except OSError:
            self.fail(f"buffer {index}: cannot read external file {short_repr(uri)}")

    def view_range(self, view_index: int, what: str) -> tuple[int, int, int, int]:
        """(buffer, byteOffset, byteLength, byteStride or 0) of a buffer view, checked to lie in its buffer."""
        views = self.doc.bufferViews or []
        if not 0 <= view_index < len(views):
            self.fail(f"{what}: bufferView {view_index} does not exist")
        view = views[view_index]
        name = f"bufferView {view_index}"
        buffer = _count(get_field(view, "buffer"), name, "buffer", self.fail)
        start = _count(get_field(view, "byteOffset"), name, "byteOffset", self.fail)
        length = _count(get_field(view, "byteLength"), name, "byteLength", self.fail)
        stride = _count(get_field(view, "byteStride"), name, "byteStride", self.fail)
        if start + length > self.buffer_length(buffer):
            self.fail(f"{name} reaches past the end of buffer {buffer}")
        return buffer, start, length, stride

    def _check_range(self, view_index: int, offset: int, count: int, dtype: np.dtype, shape: tuple, what: str):
        """(buffer, first byte, stride, layout) of ``count`` elements in a view; InputError unless they fit in it."""
        buffer, start, view_len, stride = self.view_range(view_index, what)
        cols, col_bytes, col_stride = _element_layout(dtype, shape)
        span = (cols - 1) * col_stride + col_bytes  # bytes one element touches
        stride = stride or (-(-span // 4) * 4 if len(shape) == 2 else span)
        if stride < span:
            self.fail(f"{what}: byteStride {stride} is smaller than the element size {span}")
        if count and offset + (count - 1) * stride + span > view_len:
            self.fail(f"{what} reads past the end of its buffer view ({count} elements of {span} bytes)")
        return buffer, start + offset, stride, (cols, col_bytes, col_stride)

    def _elements(
        self, view_index: int, offset: int, count: int, dtype: np.dtype, shape: tuple, what: str
    ) -> np.ndarray:
        """(count, *shape) elements from a buffer view (byteStride and matrix column padding honoured)."""
        buffer, first, stride, (cols, col_bytes, col_stride) = self._check_range(
            view_index, offset, count, dtype, shape, what
        )
        if count == 0:
            return np.zeros((0,) + shape, dtype=dtype)
        data = np.frombuffer(self.buffer(buffer), dtype=np.uint8)
        raw = np.lib.stride_tricks.as_strided(  # bounds checked above: every byte lies inside the view
            data[first:], shape=(count, cols, col_bytes), strides=(stride, col_stride, 1), writeable=False
        )
        return np.ascontiguousarray(raw).view(dtype).reshape((count,) + shape)

    def _accessor_type(self, acc, what: str) -> tuple[np.dtype, tuple, int]:
        """(component dtype, element shape, count) of an accessor."""
        ctype = get_field(acc, "componentType")
        atype = get_field(acc, "type")
        count = _count(get_field(acc, "count"), what, "accessor count", self.fail)
        if not isinstance(ctype, int) or ctype not in _COMPONENT_DTYPES:
            self.fail(f"{what}: unknown accessor component type {short_repr(ctype, 40)}")
        if not isinstance(atype, str) or atype not in _TYPE_SHAPES:
            self.fail(f"{what}: unknown accessor type {short_repr(atype, 40)}")
        return _COMPONENT_DTYPES[ctype], _TYPE_SHAPES[atype], count

    def check_accessor(self, index: int, what: str) -> None:
        """Check that accessor ``index`` (dense and sparse parts) fits in its buffer views, decoding nothing."""
        accessors = self.doc.accessors or []
        if not 0 <= index < len(accessors):
            self.fail(f"{what}: accessor {index} does not exist")
        acc = accessors[index]
        dtype, shape, count = self._accessor_type(acc, what)
        view = get_field(acc, "bufferView")
        offset = _count(get_field(acc, "byteOffset"), what, "byteOffset", self.fail)
        if view is None:
            nbytes = count * int(np.prod(shape)) * dtype.itemsize
            if nbytes > MAX_ZERO_ACCESSOR_BYTES:
                self.fail(f"{what}: accessor without a bufferView of {nbytes} bytes, over {MAX_ZERO_ACCESSOR_BYTES}")
        else:
            self._check_range(_count(view, what, "bufferView", self.fail), offset, count, dtype, shape, what)
        sparse = get_field(acc, "sparse")
        n = _count(get_field(sparse, "count"), what, "sparse count", self.fail)
        if sparse is None or n == 0:
            return
        if n > count:
            self.fail(f"{what}: sparse count {n} exceeds the accessor count {count}")
        ind, val = get_field(sparse, "indices"), get_field(sparse, "values")
        if get_field(ind, "bufferView") is None or get_field(val, "bufferView") is None:
            self.fail(f"{what}: sparse accessor without indices / values buffer views")
        itype = get_field(ind, "componentType")
        if itype not in (5121, 5123, 5125):
            self.fail(f"{what}: sparse indices have invalid component type {short_repr(itype, 40)}")
        for part, dt, sh in ((ind, _COMPONENT_DTYPES[itype], (1,)), (val, dtype, shape)):
            v = _count(get_field(part, "bufferView"), what, "sparse bufferView", self.fail)
            self._check_range(v, _count(get_field(part, "byteOffset"), what, "byteOffset", self.fail), n, dt, sh, what)

    def accessor(self, index: int | None, what: str) -> np.ndarray:
        """Accessor ``index`` as (count, *element shape): float64 for float / normalised data, int64 otherwise."""
        accessors = self.doc.accessors or []
        if index is None or isinstance(index, bool) or not isinstance(index, (int, np.integer)):
            self.fail(f"{what}: accessor {short_repr(index, 40)} does not exist")
        index = int(index)
        what = f"{what} (accessor {index})"
        self.check_accessor(index, what)  # sizes first: nothing is allocated for a lying count
        acc = accessors[index]
        dtype, shape, count = self._accessor_type(acc, what)
        sparse_count = _count(get_field(get_field(acc, "sparse"), "count"), what, "sparse count", self.fail)
        self._count_decoded((count + sparse_count) * int(np.prod(shape)) * dtype.itemsize, what)
        view = get_field(acc, "bufferView")
        if view is None:
            out = np.zeros((count,) + shape, dtype=dtype)
        else:
            out = self._elements(int(view), int(get_field(acc, "byteOffset", 0) or 0), count, dtype, shape, what).copy()
        sparse = get_field(acc, "sparse")
        if sparse is not None and int(get_field(sparse, "count", 0) or 0) > 0:
            n = int(get_field(sparse, "count"))
            ind, val = get_field(sparse, "indices"), get_field(sparse, "values")
            itype = get_field(ind, "componentType")
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


def check_accessor_sizes(doc, reader: DocumentReader) -> None:
    """Check every accessor and buffer view of a document against the declared buffer sizes (no decoding)."""
    for i in range(len(doc.accessors or [])):
        reader.check_accessor(i, f"accessor {i}")
    for i in range(len(doc.bufferViews or [])):
        reader.view_range(i, f"bufferView {i}")


def check_resource_uris(doc, path: Path) -> None:
    """Refuse buffer and image URIs that would read outside the glTF file's folder (nothing is read)."""
    for key in ("buffers", "images"):
        for i, item in enumerate(get_field(doc, key) or []):
            uri = get_field(item, "uri")
            if uri is None or (isinstance(uri, str) and uri.startswith("data:")):
                continue
            try:
                confined_path(path.parent, uri, unquote=True)
            except (ValueError, TypeError) as exc:
                raise InputError(f"{key[:-1]} {i}: refusing external file {short_repr(uri)} ({exc})", path) from None


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
    next_suffix: dict[str, int] = {}
    for j, name in enumerate(raw):
        base = name if isinstance(name, str) and name else f"joint{j}"
        candidate, k = base, next_suffix.get(base, 2)
        while candidate in seen:
            candidate, k = f"{base}_{k}", k + 1
        next_suffix[base] = k
        seen.add(candidate)
        names.append(candidate)
    return names
