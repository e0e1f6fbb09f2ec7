"""The output contract of ``ncflow match``: correspondence maps, frames, glTF animation, result folder.

What :func:`write_result` writes into ``DIR`` (DESIGN.md, "Output contract of ``ncflow match``"):

=========================  ==================================================================
``deformed_source.ply``    source connectivity, vertices flowed to t = 1 (user coordinates)
``p2p_src_to_tgt.txt``     one 0-based target vertex index per source vertex, one per line
``p2p_tgt_to_src.txt``     one 0-based source vertex index per target vertex, one per line
``map_tgt_to_src.npz``     arrays ``face`` (n_target,) int64 and ``bary`` (n_target, 3) float64
``frames/frame_XXXX.ply``  interpolation frames (source connectivity), t from 0 to 1
``animation.glb``          the same frames as one glTF 2.0 binary (morph-target animation)
``skeleton_target.tgf``    fitted target skeleton (libigl TGF, 1-based)
``skeleton_frames.json``   joint positions per frame, parents, names, times
``metrics.json``           the caller's metrics dict, plus ``frame_times``
=========================  ==================================================================

Correspondence (:func:`correspondence_maps`):

* ``map_tgt_to_src`` (the map that is scored): each target vertex y_j is projected onto the
  *flowed* source surface (exact closest point); the foot point is written as (source face,
  barycentric coordinates). The flow keeps the connectivity, so the same (face, bary) names a point
  of the *rest* source: Σ_k bary_k · rest[faces[face, k]].
* ``p2p_tgt_to_src``: the vertex-level rounding of that map — the corner of the foot face with the
  largest barycentric weight (ties: the first corner in the face's order). This is the vertex whose
  barycentric Voronoi cell of the triangle contains the foot point; it is intrinsic to the
  triangulation (the same on the rest and the flowed source) and differs from the Euclidean-nearest
  corner only in obtuse triangles, near their cell borders.
* ``p2p_src_to_tgt``: each flowed source vertex is projected onto the *target surface* (closest
  point) and rounded the same way (corner of the target foot face with the largest barycentric
  weight). Projecting onto the surface first, rather than taking the nearest target vertex
  directly, makes the rounding independent of how densely the target is sampled near the point.
  Without target faces the nearest target vertex is used.

Writing is **atomic**: everything is written into a hidden temporary folder next to ``DIR`` and
moved into place only when every file is complete; on any error the temporary folder is removed
and ``DIR`` is left as it was (absent, or with its previous contents). An existing non-empty
``DIR`` is refused unless ``overwrite=True``; then the contract entries are replaced as a whole
(``frames/`` included, so stale frames of a longer earlier run disappear) and every other entry
of ``DIR`` (the user's own files, plots, logs) is kept. Nothing non-finite is ever written: all
arrays and the metrics (recursively) are checked first and a :class:`ResultError` names the first
offending value.
"""

from __future__ import annotations

import json
import math
import numbers
import os
import re
import shutil
import tempfile
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError, NcflowError, first_line, read_json_object, read_npz_arrays

if TYPE_CHECKING:
    from ncflow.skeleton import Skeleton

__all__ = [
    "ResultError",
    "CONTRACT_FILES",
    "correspondence_maps",
    "round_to_vertex",
    "write_frames",
    "write_animation_glb",
    "write_skeleton_frames_json",
    "read_skeleton_frames_json",
    "write_result",
    "read_result",
]

CONTRACT_FILES = (
    "deformed_source.ply",
    "p2p_src_to_tgt.txt",
    "p2p_tgt_to_src.txt",
    "map_tgt_to_src.npz",
    "frames",
    "animation.glb",
    "skeleton_target.tgf",
    "skeleton_frames.json",
    "metrics.json",
)
_FRAME_RE = re.compile(r"^frame_(\d{4,})\.ply$")


class ResultError(NcflowError, ValueError):
    """A result that must not be written (non-finite values, inconsistent shapes, occupied folder).

    The message is one line naming the offending array or file.
    """

    def __init__(self, message: str, path: str | os.PathLike | None = None):
        self.path = None if path is None else os.fspath(path)
        message = " ".join(str(message).split())
        super().__init__(f"{self.path}: {message}" if self.path else message)


# ----------------------------------------------------------------------------------------------
# Correspondence


def round_to_vertex(
    faces: Int[np.ndarray, "F 3"], face: Int[np.ndarray, " n"], bary: Float[np.ndarray, "n 3"]
) -> Int[np.ndarray, " n"]:
    """Vertex-level rounding of surface points: the corner with the largest barycentric weight.

    Args:
        faces: (F, 3) triangles of the surface.
        face: (n,) face index of each point.
        bary: (n, 3) barycentric coordinates of each point in its face.

    Returns:
        (n,) vertex indices; ties go to the first corner of the face.
    """
    faces = np.asarray(faces, dtype=np.int64)
    face = np.asarray(face, dtype=np.int64)
    corner = np.argmax(np.asarray(bary), axis=1)
    return faces[face, corner]


def correspondence_maps(
    rest_source_vertices: Float[np.ndarray, "Vs 3"],
    source_faces: Int[np.ndarray, "Fs 3"],
    flowed_source_vertices: Float[np.ndarray, "Vs 3"],
    target_vertices: Float[np.ndarray, "Vt 3"],
    target_faces: Int[np.ndarray, "Ft 3"] | None = None,
) -> dict[str, np.ndarray]:
    """Dense correspondence between a flowed source and the target (see the module docstring).

    Args:
        rest_source_vertices: (Vs, 3) source vertices before the flow.
        source_faces: (Fs, 3) source triangles (shared by rest and flowed source).
        flowed_source_vertices: (Vs, 3) source vertices flowed to t = 1, in the target's frame.
        target_vertices: (Vt, 3) target vertices.
        target_faces: (Ft, 3) target triangles; when None, ``p2p_src_to_tgt`` is the nearest
            target vertex instead of the rounding of the surface projection.

    Returns:
        dict with
        ``map_face`` (Vt,) int64 and ``map_bary`` (Vt, 3) float64: the foot point of every target
        vertex on the flowed source, as (source face, barycentric coordinates);
        ``map_points`` (Vt, 3): that point on the rest source;
        ``dist_tgt_to_src`` (Vt,): distance of each target vertex to the flowed source surface;
        ``p2p_tgt_to_src`` (Vt,) int64: source vertex per target vertex;
        ``p2p_src_to_tgt`` (Vs,) int64: target vertex per source vertex;
        ``dist_src_to_tgt`` (Vs,): distance of each flowed source vertex to the target surface
        (to the nearest target vertex when ``target_faces`` is None).
    """
    from scipy.spatial import cKDTree

    from ncflow.evaluate.metrics import closest_points_on_surface

    rest = np.asarray(rest_source_vertices, dtype=np.float64)
    flowed = np.asarray(flowed_source_vertices, dtype=np.float64)
    sf = np.asarray(source_faces, dtype=np.int64)
    tv = np.asarray(target_vertices, dtype=np.float64)
    if rest.shape != flowed.shape or rest.ndim != 2 or rest.shape[1] != 3:
        raise ResultError(f"rest and flowed source vertices must both be (V, 3), got {rest.shape} and {flowed.shape}")
    _check_finite("flowed source vertices", flowed)
    _check_finite("target vertices", tv)
    dist_t, face, bary = closest_points_on_surface(tv, flowed, sf)
    out = {
        "map_face": face.astype(np.int64),
        "map_bary": bary,
        "map_points": np.einsum("nk,nkd->nd", bary, rest[sf[face]]),
        "dist_tgt_to_src": dist_t,
        "p2p_tgt_to_src": round_to_vertex(sf, face, bary),
    }
    if target_faces is None:
        dist_s, nearest = cKDTree(tv).query(flowed)
        out["p2p_src_to_tgt"] = np.asarray(nearest, dtype=np.int64)
    else:
        tf = np.asarray(target_faces, dtype=np.int64)
        dist_s, tface, tbary = closest_points_on_surface(flowed, tv, tf)
        out["p2p_src_to_tgt"] = round_to_vertex(tf, tface, tbary)
    out["dist_src_to_tgt"] = np.asarray(dist_s, dtype=np.float64)
    return out


# ----------------------------------------------------------------------------------------------
# Checks


def _check_finite(what: str, array: Any) -> None:
    arr = np.asarray(array)
    if arr.dtype.kind in "fc" and not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))
        where = tuple(int(i) for i in bad[0])
        raise ResultError(f"{what} has {bad.shape[0]} non-finite values (first at index {where}); refusing to write it")


def _check_finite_tree(value: Any, where: str = "metrics") -> None:
    """Raise :class:`ResultError` at the first NaN/inf in a nested dict/list/array structure."""
    if isinstance(value, dict):
        for k, v in value.items():
            _check_finite_tree(v, f"{where}[{k!r}]")
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            _check_finite_tree(v, f"{where}[{i}]")
    elif isinstance(value, (bool, np.bool_, str, bytes)) or value is None:
        return
    elif isinstance(value, numbers.Number):
        if isinstance(value, numbers.Real) and not math.isfinite(float(value)):
            raise ResultError(f"{where} is {value}; refusing to write non-finite metrics")
    elif hasattr(value, "__array__") or isinstance(value, np.generic):
        _check_finite(where, np.asarray(value))


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if hasattr(value, "__array__"):
        return np.asarray(value).tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot write {type(value).__name__} to JSON")


def _as_frames(frames: Any, what: str = "frames") -> np.ndarray:
    arr = np.asarray(frames, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] == 0:
        raise ResultError(f"{what} must have shape (K, V, 3) with K ≥ 1, got {arr.shape}")
    _check_finite(what, arr)
    return arr


def _as_faces(faces: Any, n_vertices: int, what: str = "faces") -> np.ndarray:
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0 or not np.issubdtype(f.dtype, np.integer):
        raise ResultError(f"{what} must be (F, 3) integers with F ≥ 1, got shape {f.shape} dtype {f.dtype}")
    if f.min() < 0 or f.max() >= n_vertices:
        raise ResultError(f"{what} indices span [{int(f.min())}, {int(f.max())}] but there are {n_vertices} vertices")
    return f.astype(np.int64)


def _as_times(times: Any, k: int, what: str = "frame times") -> np.ndarray:
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if t.shape != (k,):
        raise ResultError(f"{what} must have one value per frame ({k}), got shape {np.shape(times)}")
    _check_finite(what, t)
    if k > 1 and not np.all(np.diff(t) > 0):
        raise ResultError(f"{what} must be strictly increasing")
    return t


def _as_index(values: Any, n: int, upper: int, what: str) -> np.ndarray:
    arr = np.asarray(values)
    if arr.shape != (n,) or not np.issubdtype(arr.dtype, np.integer):
        raise ResultError(f"{what} must be ({n},) integers, got shape {arr.shape} dtype {arr.dtype}")
    if n and (arr.min() < 0 or arr.max() >= upper):
        raise ResultError(f"{what} indices span [{int(arr.min())}, {int(arr.max())}], expected 0-based in [0, {upper})")
    return arr.astype(np.int64)


# ----------------------------------------------------------------------------------------------
# Frames and glTF


def write_frames(
    directory: str | os.PathLike, frames: Float[np.ndarray, "K V 3"], faces: Int[np.ndarray, "F 3"]
) -> list[Path]:
    """Write ``frame_0000.ply`` … ``frame_{K-1:04d}.ply`` (all with ``faces``) into ``directory``.

    Returns:
        The K paths written.

    Raises:
        ResultError: bad shapes or non-finite coordinates (checked before anything is written).
    """
    from ncflow.mesh import save_mesh

    frames = _as_frames(frames)
    faces = _as_faces(faces, frames.shape[1])
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for k, v in enumerate(frames):
        path = directory / f"frame_{k:04d}.ply"
        save_mesh(path, v, faces)
        paths.append(path)
    return paths


class _BinBuilder:
    """Accumulates glTF bufferViews/accessors over one binary buffer (4-byte aligned)."""

    def __init__(self, gltf):
        self.gltf = gltf
        self.chunks: list[bytes] = []
        self.size = 0

    def add(
        self, array: np.ndarray, *, component: int, type_: str, target: int | None = None, minmax: bool = False
    ) -> int:
        import pygltflib

        data = np.ascontiguousarray(array).tobytes()
        pad = (-self.size) % 4
        if pad:
            self.chunks.append(b"\x00" * pad)
            self.size += pad
        view = pygltflib.BufferView(buffer=0, byteOffset=self.size, byteLength=len(data))
        if target is not None:
            view.target = target
        self.gltf.bufferViews.append(view)
        self.chunks.append(data)
        self.size += len(data)
        width = {"SCALAR": 1, "VEC3": 3}[type_]
        acc = pygltflib.Accessor(
            bufferView=len(self.gltf.bufferViews) - 1,
            byteOffset=0,
            componentType=component,
            count=int(array.size // width),
            type=type_,
        )
        if minmax:
            a = np.asarray(array).reshape(-1, width)
            acc.min = [float(x) for x in a.min(0)]
            acc.max = [float(x) for x in a.max(0)]
        self.gltf.accessors.append(acc)
        return len(self.gltf.accessors) - 1

    def blob(self) -> bytes:
        pad = (-self.size) % 4
        return b"".join(self.chunks) + b"\x00" * pad


def _morph_primitive(builder: _BinBuilder, frames32: np.ndarray, indices: np.ndarray, mode: int, material: int | None):
    import pygltflib

    base = frames32[0]
    pos = builder.add(base, component=pygltflib.FLOAT, type_="VEC3", target=pygltflib.ARRAY_BUFFER, minmax=True)
    idx = builder.add(
        indices.astype(np.uint32).reshape(-1),
        component=pygltflib.UNSIGNED_INT,
        type_="SCALAR",
        target=pygltflib.ELEMENT_ARRAY_BUFFER,
    )
    targets = []
    for k in range(frames32.shape[0]):
        delta = (frames32[k] - base).astype(np.float32)
        acc = builder.add(delta, component=pygltflib.FLOAT, type_="VEC3", target=pygltflib.ARRAY_BUFFER, minmax=True)
        targets.append({"POSITION": acc})
    prim = pygltflib.Primitive(attributes=pygltflib.Attributes(POSITION=pos), indices=idx, mode=mode, targets=targets)
    if material is not None:
        prim.material = material
    return prim


def write_animation_glb(
    path: str | os.PathLike,
    frames: Float[np.ndarray, "K V 3"],
    faces: Int[np.ndarray, "F 3"],
    times: Float[np.ndarray, " K"],
    skeleton_frames: Float[np.ndarray, "K J 3"] | None = None,
    parents: Int[np.ndarray, " J"] | None = None,
    *,
    duration: float | None = 2.0,
    name: str = "ncflow",
) -> Path:
    """Write the frames as one glTF 2.0 binary with a morph-target animation.

    Layout: one mesh ``name`` whose triangle primitive has the frame-0 positions as ``POSITION``
    (float32) and ``indices`` (uint32), and K morph targets, target k holding the ``POSITION``
    deltas frame_k − frame_0 (float32; accessor min/max set as the specification requires; target
    0 is all zeros). One animation drives the mesh's ``weights`` with a LINEAR sampler: at key time
    s_k the weight vector is one-hot on target k, so playback interpolates linearly between
    consecutive frames. With ``skeleton_frames``, a second node ``skeleton`` holds the bones as a
    LINES primitive (vertices = joints, one segment per (parent, child)) morphed and animated the
    same way. No normals are written (viewers compute them).

    Args:
        path: output ``.glb`` file.
        frames: (K, V, 3) vertex positions per frame.
        faces: (F, 3) triangles (shared by all frames).
        times: (K,) strictly increasing frame times (e.g. t from 0 to 1).
        skeleton_frames: optional (K, J, 3) joint positions per frame.
        parents: (J,) parent of each joint (−1 for roots); required with ``skeleton_frames``.
        duration: the clip length in seconds: key times are ``duration · (t − t_0)/(t_{K−1} − t_0)``;
            None keeps ``times`` as seconds.
        name: name of the mesh, node and animation.

    Returns:
        The path written.
    """
    import pygltflib

    frames = _as_frames(frames)
    k, nv, _ = frames.shape
    faces = _as_faces(faces, nv)
    t = _as_times(times, k)
    if duration is not None:
        if not (duration > 0 and math.isfinite(duration)):
            raise ResultError(f"clip duration must be a positive number of seconds, got {duration}")
        span = t[-1] - t[0]
        t = (t - t[0]) * (duration / span) if span > 0 else t - t[0]
    gltf = pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0", generator="ncflow"))
    gltf.buffers = [pygltflib.Buffer(byteLength=0)]
    builder = _BinBuilder(gltf)
    gltf.materials = [
        pygltflib.Material(
            name="surface",
            doubleSided=True,
            pbrMetallicRoughness=pygltflib.PbrMetallicRoughness(
                baseColorFactor=[0.8, 0.8, 0.8, 1.0], metallicFactor=0.0, roughnessFactor=0.8
            ),
        )
    ]
    prim = _morph_primitive(builder, frames.astype(np.float32), faces, pygltflib.TRIANGLES, material=0)
    gltf.meshes = [pygltflib.Mesh(name=name, primitives=[prim], weights=[0.0] * k)]
    gltf.nodes = [pygltflib.Node(name=name, mesh=0)]
    if skeleton_frames is not None:
        sk = _as_frames(skeleton_frames, "skeleton frames")
        if sk.shape[0] != k:
            raise ResultError(f"skeleton frames have {sk.shape[0]} frames but there are {k} mesh frames")
        if parents is None:
            raise ResultError("parents are required with skeleton frames")
        par = np.asarray(parents).reshape(-1)
        if par.shape != (sk.shape[1],):
            raise ResultError(f"expected {sk.shape[1]} parents (one per joint), got shape {np.shape(parents)}")
        child = np.flatnonzero(par >= 0)
        if child.size == 0:
            raise ResultError("a skeleton needs at least one bone (a joint with a parent)")
        bones = np.stack([par[child], child], axis=1)
        sprim = _morph_primitive(builder, sk.astype(np.float32), bones, pygltflib.LINES, material=None)
        gltf.meshes.append(pygltflib.Mesh(name="skeleton", primitives=[sprim], weights=[0.0] * k))
        gltf.nodes.append(pygltflib.Node(name="skeleton", mesh=1))
    gltf.scenes = [pygltflib.Scene(name=name, nodes=list(range(len(gltf.nodes))))]
    gltf.scene = 0
    key_in = builder.add(t.astype(np.float32), component=pygltflib.FLOAT, type_="SCALAR", minmax=True)
    key_out = builder.add(np.eye(k, dtype=np.float32).reshape(-1), component=pygltflib.FLOAT, type_="SCALAR")
    sampler = pygltflib.AnimationSampler(input=key_in, output=key_out, interpolation=pygltflib.ANIM_LINEAR)
    channels = [
        pygltflib.AnimationChannel(sampler=0, target=pygltflib.AnimationChannelTarget(node=n, path="weights"))
        for n in range(len(gltf.nodes))
    ]
    gltf.animations = [pygltflib.Animation(name=name, samplers=[sampler], channels=channels)]
    blob = builder.blob()
    gltf.buffers[0].byteLength = len(blob)
    gltf.set_binary_blob(blob)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    gltf.save_binary(str(path))
    return path


# ----------------------------------------------------------------------------------------------
# Skeleton frames


def write_skeleton_frames_json(
    path: str | os.PathLike,
    positions: Float[np.ndarray, "K J 3"],
    parents: Int[np.ndarray, " J"],
    names: list[str] | tuple[str, ...] | None,
    times: Float[np.ndarray, " K"],
) -> Path:
    """Write ``{"names", "parents", "times", "positions"}``: joint positions (K, J, 3) per frame.

    ``parents`` are 0-based indices into the joint list (−1 for the root), in the same joint
    order as the positions (for :func:`write_result`: the skeleton's internal topological order,
    which is also the node order of ``skeleton_target.tgf``). ``names`` may be None (written as
    null).
    """
    pos = _as_frames(positions, "skeleton frames")
    k, j, _ = pos.shape
    par = np.asarray(parents).reshape(-1)
    if par.shape != (j,) or not np.issubdtype(par.dtype, np.integer):
        raise ResultError(f"expected {j} integer parents (one per joint), got shape {par.shape}")
    if par.min() < -1 or par.max() >= j:
        raise ResultError(f"parents must be in [-1, {j}), got [{int(par.min())}, {int(par.max())}]")
    if names is not None and len(names) != j:
        raise ResultError(f"expected {j} joint names, got {len(names)}")
    t = _as_times(times, k)
    rows = ",\n  ".join(json.dumps([[float(x) for x in p] for p in frame]) for frame in pos)
    parts = [
        f' "names": {json.dumps(None if names is None else [str(s) for s in names])}',
        f' "parents": {json.dumps([int(p) for p in par])}',
        f' "times": {json.dumps([float(x) for x in t])}',
        f' "positions": [\n  {rows}\n ]',
    ]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("{\n" + ",\n".join(parts) + "\n}\n")
    return path


def read_skeleton_frames_json(path: str | os.PathLike) -> dict[str, Any]:
    """Read :func:`write_skeleton_frames_json` output: positions (K, J, 3), parents (J,), names, times (K,).

    Raises:
        InputError: one line naming the file and the problem.
    """
    path = Path(path)
    data = _read_json(path)
    for key in ("parents", "times", "positions"):
        if key not in data:
            raise InputError(f"missing key {key!r}", path)
    try:
        pos = np.asarray(data["positions"], dtype=np.float64)
        times = np.asarray(data["times"], dtype=np.float64)
        parents = np.asarray(data["parents"])
    except (TypeError, ValueError):
        raise InputError("'positions', 'times' and 'parents' must be numeric lists", path) from None
    if pos.ndim != 3 or pos.shape[2] != 3:
        raise InputError(f"'positions' must be (K, J, 3), got shape {pos.shape}", path)
    k, j, _ = pos.shape
    if times.shape != (k,):
        raise InputError(f"'times' has shape {times.shape}, expected ({k},)", path)
    if parents.shape != (j,) or (j and not np.issubdtype(parents.dtype, np.integer)):
        raise InputError(f"'parents' must be {j} integers, got shape {parents.shape}", path)
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(times))):
        raise InputError("non-finite joint positions or times", path)
    names = data.get("names")
    if names is not None and (not isinstance(names, list) or len(names) != j):
        raise InputError(f"'names' must be null or a list of {j} strings", path)
    return {"positions": pos, "parents": parents.astype(np.int64), "names": names, "times": times}


# ----------------------------------------------------------------------------------------------
# The result folder


def write_result(
    out_dir: str | os.PathLike,
    *,
    deformed_source: Float[np.ndarray, "Vs 3"],
    source_faces: Int[np.ndarray, "Fs 3"],
    maps: dict[str, np.ndarray],
    frames: Float[np.ndarray, "K Vs 3"],
    frame_times: Float[np.ndarray, " K"],
    skeleton_target: "Skeleton | None" = None,
    skeleton_frames: Float[np.ndarray, "K J 3"] | None = None,
    parents: Int[np.ndarray, " J"] | None = None,
    joint_names: list[str] | tuple[str, ...] | None = None,
    metrics: dict | None = None,
    overwrite: bool = False,
    clip_seconds: float = 2.0,
) -> Path:
    """Write the ``ncflow match`` output contract into ``out_dir``, atomically.

    Args:
        out_dir: the result folder (created; its parent too).
        deformed_source: (Vs, 3) source vertices flowed to t = 1, user coordinates.
        source_faces: (Fs, 3) source triangles.
        maps: :func:`correspondence_maps` output; uses ``map_face`` (Vt,), ``map_bary`` (Vt, 3),
            ``p2p_tgt_to_src`` (Vt,) and ``p2p_src_to_tgt`` (Vs,). n_target is ``len(map_face)``.
        frames: (K, Vs, 3) interpolation frames, frame 0 the rest source.
        frame_times: (K,) strictly increasing times (t from 0 to 1); written to ``metrics.json``
            (key ``frame_times``) and ``skeleton_frames.json``; scaled to ``clip_seconds`` in the GLB.
        skeleton_target: fitted target skeleton (written as TGF, 1-based, internal joint order),
            or None for a run without skeleton (then neither skeleton file is written).
        skeleton_frames: (K, J, 3) joint positions per frame, in the skeleton's internal order;
            required with ``skeleton_target``.
        parents: (J,) parents of the joints of ``skeleton_frames`` (default: the skeleton's; when
            given they must equal the skeleton's).
        joint_names: joint names (default: the skeleton's, or null).
        metrics: JSON-serialisable dict (numpy/JAX scalars and arrays are converted).
        overwrite: allow an existing non-empty ``out_dir``: its contract entries are replaced
            (``frames/`` as a whole) and its other entries kept. Otherwise such a folder is refused.
        clip_seconds: length of the GLB animation clip.

    Returns:
        ``out_dir`` as a Path.

    Raises:
        ResultError: non-finite values, inconsistent shapes or index ranges, or an occupied
            ``out_dir`` without ``overwrite``; raised before anything is written. Any error while
            writing leaves ``out_dir`` as it was and no temporary files behind.
    """
    from ncflow.mesh import save_mesh
    from ncflow.skeleton import save_skeleton

    out_dir = Path(out_dir)
    _check_target_dir(out_dir, overwrite)
    # --- validate everything first --------------------------------------------------------
    deformed = _as_frames(np.asarray(deformed_source)[None], "deformed source")[0]
    nv = deformed.shape[0]
    faces = _as_faces(source_faces, nv, "source faces")
    frames = _as_frames(frames)
    if frames.shape[1] != nv:
        raise ResultError(f"frames have {frames.shape[1]} vertices but the deformed source has {nv}")
    k = frames.shape[0]
    times = _as_times(frame_times, k)
    for key in ("map_face", "map_bary", "p2p_tgt_to_src", "p2p_src_to_tgt"):
        if key not in maps:
            raise ResultError(f"maps lack {key!r} (expected the output of correspondence_maps)")
    map_face = np.asarray(maps["map_face"]).reshape(-1)
    nt = map_face.shape[0]
    map_face = _as_index(map_face, nt, faces.shape[0], "map_tgt_to_src face")
    bary = np.asarray(maps["map_bary"], dtype=np.float64)
    if bary.shape != (nt, 3):
        raise ResultError(f"map_tgt_to_src bary must be ({nt}, 3), got {bary.shape}")
    _check_finite("map_tgt_to_src bary", bary)
    p2p_ts = _as_index(maps["p2p_tgt_to_src"], nt, nv, "p2p_tgt_to_src")
    if nt == 0:
        raise ResultError("the correspondence maps are empty (no target vertices)")
    p2p_st = _as_index(maps["p2p_src_to_tgt"], nv, nt, "p2p_src_to_tgt")
    metrics = {} if metrics is None else metrics
    if not isinstance(metrics, dict):
        raise ResultError(f"metrics must be a dict, got {type(metrics).__name__}")
    _check_finite_tree(metrics)
    metrics = dict(metrics)
    metrics["frame_times"] = [float(x) for x in times]
    metrics_text = json.dumps(metrics, indent=1, default=_json_default, allow_nan=False, sort_keys=False)
    sk_frames = sk_parents = None
    if skeleton_target is not None or skeleton_frames is not None:
        if skeleton_target is None or skeleton_frames is None:
            raise ResultError("skeleton_target and skeleton_frames must be given together")
        sk_frames = _as_frames(skeleton_frames, "skeleton frames")
        _check_finite("target skeleton joints", skeleton_target.positions)
        if sk_frames.shape[:2] != (k, skeleton_target.n_joints):
            raise ResultError(
                f"skeleton frames must be ({k}, {skeleton_target.n_joints}, 3) (frames, joints), got {sk_frames.shape}"
            )
        sk_parents = np.asarray(skeleton_target.parents if parents is None else parents)
        if not np.array_equal(sk_parents, skeleton_target.parents):
            raise ResultError("parents differ from the target skeleton's (use the skeleton's internal joint order)")
        if joint_names is None:
            joint_names = skeleton_target.names
    # --- write into a temporary folder, then move it into place ---------------------------
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.tmp-", dir=out_dir.parent))
    try:
        save_mesh(tmp / "deformed_source.ply", deformed, faces)
        _write_indices(tmp / "p2p_src_to_tgt.txt", p2p_st)
        _write_indices(tmp / "p2p_tgt_to_src.txt", p2p_ts)
        np.savez(tmp / "map_tgt_to_src.npz", face=map_face, bary=bary)
        write_frames(tmp / "frames", frames, faces)
        write_animation_glb(tmp / "animation.glb", frames, faces, times, sk_frames, sk_parents, duration=clip_seconds)
        if skeleton_target is not None:
            save_skeleton(tmp / "skeleton_target.tgf", skeleton_target)
            write_skeleton_frames_json(tmp / "skeleton_frames.json", sk_frames, sk_parents, joint_names, times)
        (tmp / "metrics.json").write_text(metrics_text + "\n")
        _move_into_place(tmp, out_dir, overwrite)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out_dir


def _write_indices(path: Path, values: np.ndarray) -> None:
    path.write_text("".join(f"{int(v)}\n" for v in values))


def _check_target_dir(out_dir: Path, overwrite: bool) -> None:
    if out_dir.exists() and not out_dir.is_dir():
        raise ResultError("exists and is not a folder", out_dir)
    if out_dir.is_dir() and any(out_dir.iterdir()) and not overwrite:
        raise ResultError(
            "output folder exists and is not empty (pass overwrite=True / --overwrite to replace the result)", out_dir
        )


def _move_into_place(tmp: Path, out_dir: Path, overwrite: bool) -> None:
    """Rename the finished temporary folder to ``out_dir`` (see the module docstring)."""
    _check_target_dir(out_dir, overwrite)
    if not out_dir.exists():
        os.rename(tmp, out_dir)
        return
    if not any(out_dir.iterdir()):
        out_dir.rmdir()
        os.rename(tmp, out_dir)
        return
    # overwrite: swap the folders, then carry the user's non-contract entries over
    backup = out_dir.parent / f".{out_dir.name}.old-{uuid.uuid4().hex[:8]}"
    os.rename(out_dir, backup)
    try:
        os.rename(tmp, out_dir)
    except BaseException:
        os.rename(backup, out_dir)
        raise
    for entry in backup.iterdir():
        if entry.name not in CONTRACT_FILES:
            os.rename(entry, out_dir / entry.name)
    shutil.rmtree(backup, ignore_errors=True)


# ----------------------------------------------------------------------------------------------
# Reading back


def _read_json(path: Path) -> dict:
    if not path.is_file():
        raise InputError("missing result file", path)
    return read_json_object(path)


def _read_ply(path: Path):
    from ncflow.mesh import load_mesh

    if not path.is_file():
        raise InputError("missing result file", path)
    mesh = load_mesh(path, weld=False, validate=False)
    if not np.all(np.isfinite(mesh.vertices)):
        raise InputError("non-finite vertex coordinates", path)
    return mesh


def read_result(out_dir: str | os.PathLike, *, check_animation: bool = True) -> dict[str, Any]:
    """Load and validate a result folder written by :func:`write_result`.

    Args:
        out_dir: the folder.
        check_animation: also parse ``animation.glb`` and check its morph-target count (K).

    Returns:
        dict with ``deformed_source`` (Vs, 3), ``source_faces`` (Fs, 3), ``p2p_src_to_tgt`` (Vs,),
        ``p2p_tgt_to_src`` (Vt,), ``map_face`` (Vt,), ``map_bary`` (Vt, 3), ``frames`` (K, Vs, 3),
        ``frame_times`` (K,), ``metrics`` (dict), ``skeleton_target`` (Skeleton or None),
        ``skeleton_frames`` (dict of ``positions`` (K, J, 3), ``parents``, ``names``, ``times``, or
        None), ``animation`` (path of the GLB), ``n_source``, ``n_target``, ``n_frames``.
        The two skeleton files are optional but must come together.

    Raises:
        InputError: one line naming the missing or bad file.
    """
    from ncflow.evaluate.ground_truth import read_index_file

    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise InputError("no such result folder", out_dir)
    deformed = _read_ply(out_dir / "deformed_source.ply")
    nv, faces = deformed.n_vertices, deformed.faces
    npz_path = out_dir / "map_tgt_to_src.npz"
    if not npz_path.is_file():
        raise InputError("missing result file", npz_path)
    arrays = read_npz_arrays(npz_path, ("face", "bary"))
    face, bary = arrays["face"], arrays["bary"]
    if face.ndim != 1 or not np.issubdtype(face.dtype, np.integer):
        raise InputError(f"'face' must be a 1-D integer array, got shape {face.shape} dtype {face.dtype}", npz_path)
    nt = face.shape[0]
    if bary.shape != (nt, 3) or not np.all(np.isfinite(bary)):
        raise InputError(f"'bary' must be finite with shape ({nt}, 3), got {bary.shape}", npz_path)
    if nt and (face.min() < 0 or face.max() >= faces.shape[0]):
        raise InputError(f"'face' indices outside [0, {faces.shape[0]}) (source faces)", npz_path)
    p2p = {}
    for name, n, upper in (("p2p_src_to_tgt", nv, nt), ("p2p_tgt_to_src", nt, nv)):
        path = out_dir / f"{name}.txt"
        if not path.is_file():
            raise InputError("missing result file", path)
        idx = read_index_file(path)
        if idx.shape != (n,):
            raise InputError(f"expected {n} indices (one per line), got {idx.shape[0]}", path)
        if n and (idx.min() < 0 or idx.max() >= upper):
            raise InputError(
                f"indices span [{int(idx.min())}, {int(idx.max())}], expected 0-based in [0, {upper})", path
            )
        p2p[name] = idx.astype(np.int64)
    frames_dir = out_dir / "frames"
    if not frames_dir.is_dir():
        raise InputError("missing result folder", frames_dir)
    numbered = sorted((int(m.group(1)), p) for p in frames_dir.iterdir() if (m := _FRAME_RE.match(p.name)))
    if not numbered:
        raise InputError("no frame_XXXX.ply files", frames_dir)
    expected = list(range(len(numbered)))
    if [i for i, _ in numbered] != expected:
        missing = sorted(set(expected) - {i for i, _ in numbered})
        what = f"missing frame_{missing[0]:04d}.ply" if missing else "duplicate numbers"
        raise InputError(f"frame numbers are not 0..{len(numbered) - 1} ({what})", frames_dir)
    frames = []
    for _, path in numbered:
        m = _read_ply(path)
        if m.n_vertices != nv or not np.array_equal(m.faces, faces):
            raise InputError(
                f"frame does not have the source connectivity ({m.n_vertices} vertices, expected {nv})", path
            )
        frames.append(m.vertices)
    frames = np.stack(frames)
    k = frames.shape[0]
    metrics_path = out_dir / "metrics.json"
    metrics = _read_json(metrics_path)
    if "frame_times" in metrics:
        times = np.asarray(metrics["frame_times"], dtype=np.float64)
        if times.shape != (k,):
            raise InputError(f"'frame_times' has {times.size} entries but there are {k} frames", metrics_path)
    else:
        times = np.linspace(0.0, 1.0, k)
    glb = out_dir / "animation.glb"
    if not glb.is_file():
        raise InputError("missing result file", glb)
    if check_animation:
        _check_glb(glb, k, nv)
    tgf, sfj = out_dir / "skeleton_target.tgf", out_dir / "skeleton_frames.json"
    skeleton = sk_frames = None
    if tgf.exists() != sfj.exists():
        raise InputError("missing result file (the skeleton files come together)", sfj if tgf.exists() else tgf)
    if tgf.exists():
        from ncflow.skeleton import load_skeleton

        skeleton = load_skeleton(tgf)
        sk_frames = read_skeleton_frames_json(sfj)
        if sk_frames["positions"].shape[:2] != (k, skeleton.n_joints):
            raise InputError(
                f"positions have shape {sk_frames['positions'].shape}, expected ({k}, {skeleton.n_joints}, 3)", sfj
            )
        if not np.array_equal(sk_frames["parents"], skeleton.parents):
            raise InputError("parents differ from skeleton_target.tgf", sfj)
    return {
        "deformed_source": deformed.vertices,
        "source_faces": faces,
        "p2p_src_to_tgt": p2p["p2p_src_to_tgt"],
        "p2p_tgt_to_src": p2p["p2p_tgt_to_src"],
        "map_face": face.astype(np.int64),
        "map_bary": bary.astype(np.float64),
        "frames": frames,
        "frame_times": times,
        "metrics": metrics,
        "skeleton_target": skeleton,
        "skeleton_frames": sk_frames,
        "animation": glb,
        "n_source": nv,
        "n_target": nt,
        "n_frames": k,
    }


def _check_glb(path: Path, k: int, nv: int) -> None:
    import pygltflib

    try:
        gltf = pygltflib.GLTF2().load_binary(str(path))
    except Exception as exc:
        raise InputError(f"cannot read glTF binary ({first_line(exc)})", path) from None
    if gltf is None or not gltf.meshes or not gltf.meshes[0].primitives:
        raise InputError("no mesh in the glTF file", path)
    prim = gltf.meshes[0].primitives[0]
    n_targets = len(prim.targets or [])
    count = gltf.accessors[prim.attributes.POSITION].count if prim.attributes.POSITION is not None else -1
    if n_targets != k or count != nv:
        raise InputError(f"mesh has {count} vertices and {n_targets} morph targets, expected {nv} and {k}", path)
