"""The morph-target animation writer: the interpolation frames as one glTF 2.0 binary (``animation.glb``).

:func:`write_animation_glb` stores frame 0 as the mesh and every frame as a morph target (the
position deltas from frame 0); one animation drives the morph weights so that playback
interpolates linearly between consecutive frames, and an optional second node carries the
skeleton's bones as lines, animated the same way. A morph-target clip needs no rig in the viewer
and shows exactly the computed frames. Arrays are checked
(:mod:`ncflow.io.arrays`) before anything is written; pygltflib assembles the file.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import ResultError
from ncflow.io.arrays import as_faces, as_frames, as_times
from ncflow.io.atomic import atomic_path

if TYPE_CHECKING:
    pass


_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


class BinBuilder:
    """Accumulates glTF bufferViews/accessors over one binary buffer (4-byte aligned); shared by the
    morph-target writer and the rig writer.
    """

    def __init__(self, gltf):
        self.gltf = gltf
        self.chunks: list[bytes] = []
        self.size = 0

    def add(
        self, array: np.ndarray, *, component: int, type_: str, target: int | None = None, minmax: bool = False
    ) -> int:
        """Append ``array`` (its bytes, 4-byte aligned) as one bufferView and accessor of ``type_``
        (SCALAR, VEC2/3/4, MAT4); ``minmax`` records the per-component bounds of the stored values.
        Returns the accessor's index.
        """
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
        width = _WIDTH[type_]
        acc = pygltflib.Accessor(
            bufferView=len(self.gltf.bufferViews) - 1,
            byteOffset=0,
            componentType=component,
            count=int(array.size // width),
            type=type_,
        )
        if minmax:
            a = np.asarray(array).reshape(-1, width)
            cast = int if a.dtype.kind in "iu" else float
            acc.min = [cast(x) for x in a.min(0)]
            acc.max = [cast(x) for x in a.max(0)]
        self.gltf.accessors.append(acc)
        return len(self.gltf.accessors) - 1

    def blob(self) -> bytes:
        """The binary buffer, padded to a multiple of 4 bytes."""
        pad = (-self.size) % 4
        return b"".join(self.chunks) + b"\x00" * pad


def new_document(generator: str, material: str):
    """An empty glTF 2.0 document with one buffer and one grey double-sided material (index 0),
    and the :class:`BinBuilder` that fills its buffer; returns ``(gltf, builder)``.
    """
    import pygltflib

    gltf = pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0", generator=generator))
    gltf.buffers = [pygltflib.Buffer(byteLength=0)]
    gltf.materials = [
        pygltflib.Material(
            name=material,
            doubleSided=True,
            pbrMetallicRoughness=pygltflib.PbrMetallicRoughness(
                baseColorFactor=[0.8, 0.8, 0.8, 1.0], metallicFactor=0.0, roughnessFactor=0.8
            ),
        )
    ]
    return gltf, BinBuilder(gltf)


def save_document(gltf, builder: BinBuilder, path: str | os.PathLike) -> Path:
    """Write ``gltf`` with the builder's buffer as one GLB file, atomically; returns the path."""
    blob = builder.blob()
    gltf.buffers[0].byteLength = len(blob)
    gltf.set_binary_blob(blob)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        gltf.save_binary(str(tmp))
    return path


def _morph_primitive(builder: BinBuilder, frames32: np.ndarray, indices: np.ndarray, mode: int, material: int | None):
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

    frames = as_frames(frames)
    k, nv, _ = frames.shape
    faces = as_faces(faces, nv)
    t = as_times(times, k)
    if duration is not None:
        if not (duration > 0 and math.isfinite(duration)):
            raise ResultError(f"clip duration must be a positive number of seconds, got {duration}")
        span = t[-1] - t[0]
        t = (t - t[0]) * (duration / span) if span > 0 else t - t[0]
    gltf, builder = new_document("ncflow", "surface")
    prim = _morph_primitive(builder, frames.astype(np.float32), faces, pygltflib.TRIANGLES, material=0)
    gltf.meshes = [pygltflib.Mesh(name=name, primitives=[prim], weights=[0.0] * k)]
    gltf.nodes = [pygltflib.Node(name=name, mesh=0)]
    if skeleton_frames is not None:
        sk = as_frames(skeleton_frames, "skeleton frames")
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
    return save_document(gltf, builder, path)
