"""The skinned-character writer: a mesh, its skeleton, skin weights and a joint-rotation clip as one GLB.

:func:`write_rig_glb` writes a glTF 2.0 binary that Blender, three.js and every glTF viewer open
as a rigged character:

* **Nodes**: one per joint, in the given (topological) order, named, each with its local
  translation (the offset from its parent; the root's is its position) and the children it has,
  and no rotation or scale: the joints' frames are aligned with the world axes in the bind pose.
  One more node holds the mesh and the skin (``skin.skeleton`` is the root joint). The scene lists
  the root joint and the mesh node.
* **Skin**: ``inverseBindMatrices`` = the translation by −P_j for every joint (MAT4, float32,
  column-major as glTF stores matrices), so world(joint) · inverseBind is the identity in the bind
  pose and the mesh is bound exactly as written.
* **Mesh**: one triangle primitive with ``POSITION`` (float32), ``NORMAL`` (area-weighted unit
  normals), ``JOINTS_0`` (unsigned short) / ``WEIGHTS_0`` (float32, rows summing to 1 after
  rounding), ``indices`` (uint32) and one double-sided material, so it renders without a light
  setup of its own.
* **Animation** (optional): one clip with a LINEAR sampler per joint driving its node's
  ``rotation`` (quaternions x, y, z, w; consecutive keys on the same hemisphere) and one driving
  the root's ``translation``.
* **Morph targets** (optional, with the animation): one ``POSITION`` target per key, the correction in
  the bind pose that makes the skinned mesh at that key exact (``ncflow track``: the registered
  shape of each frame), and one LINEAR sampler driving the mesh node's ``weights``: target k has
  weight 1 at key k and 0 at the others (so between keys two neighbouring corrections blend).

Every accessor has ``min`` / ``max`` (required for ``POSITION`` and sampler inputs, optional
elsewhere) equal to the stored (rounded) data; buffer views are 4-byte aligned, vertex-attribute
views carry the ``ARRAY_BUFFER`` target and index views ``ELEMENT_ARRAY_BUFFER``. Arrays are checked
before anything is written and the file is written atomically. The binary buffer is assembled by
:class:`ncflow.io.gltf.writer.BinBuilder`, shared with the morph-target writer.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import ResultError
from ncflow.geometry.mesh import vertex_normals
from ncflow.io.arrays import as_faces, as_times
from ncflow.io.gltf.writer import new_document, save_document

__all__ = ["MAX_RIG_JOINTS", "write_rig_glb"]

MAX_RIG_JOINTS = 65535
"""Joints a rig may have: ``JOINTS_0`` is written as unsigned short."""


def _normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit vertex normals for the GLB; a vertex in no proper triangle gets +Z (glTF wants unit length)."""
    n = vertex_normals(vertices, faces)
    n[np.linalg.norm(n, axis=1) == 0] = (0.0, 0.0, 1.0)
    return n


def _check_points(name: str, array, rows: int | None = None) -> np.ndarray:
    a = np.asarray(array, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3 or (rows is not None and a.shape[0] != rows):
        raise ResultError(f"{name} must have shape ({rows if rows is not None else 'N'}, 3), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ResultError(f"{name} must be finite")
    return a


def _check_skeleton(positions, parents, names) -> tuple[np.ndarray, np.ndarray, list[str]]:
    pos = _check_points("joint positions", positions)
    j = pos.shape[0]
    if not 1 <= j <= MAX_RIG_JOINTS:
        raise ResultError(f"a rig needs 1 to {MAX_RIG_JOINTS} joints, got {j}")
    par = np.asarray(parents)
    if par.shape != (j,) or not np.issubdtype(par.dtype, np.integer):
        raise ResultError(f"expected {j} integer parents, got shape {par.shape}")
    par = par.astype(np.int64)
    if par[0] != -1 or np.any(par[1:] < 0) or np.any(par[1:] >= np.arange(1, j)):
        raise ResultError("joints must be in topological order with one root first (parents[0] = -1, parents[j] < j)")
    names = [str(s) for s in names]
    if len(names) != j or len(set(names)) != j:
        raise ResultError(f"expected {j} distinct joint names, got {len(names)} ({len(set(names))} distinct)")
    return pos, par, names


def write_rig_glb(
    path: str | os.PathLike,
    *,
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    joint_positions: Float[np.ndarray, "J 3"],
    parents: Int[np.ndarray, " J"],
    names: list[str] | tuple[str, ...],
    joints: Int[np.ndarray, "V 4"],
    weights: Float[np.ndarray, "V 4"],
    key_times: Float[np.ndarray, " K"] | None = None,
    rotations: Float[np.ndarray, "K J 4"] | None = None,
    root_translations: Float[np.ndarray, "K 3"] | None = None,
    morph_targets: Float[np.ndarray, "K V 3"] | None = None,
    name: str = "ncflow",
) -> Path:
    """Write a skinned character as a GLB (layout in the module docstring).

    Args:
        path: output ``.glb``.
        vertices: (V, 3) the mesh in the bind pose.
        faces: (F, 3) triangles.
        joint_positions: (J, 3) joint positions in the bind pose, topological order (root first).
        parents: (J,) parent of each joint, −1 for the root (``parents[j] < j``).
        names: J distinct joint names.
        joints: (V, 4) joint index of each influence.
        weights: (V, 4) influence weights, non-negative, rows summing to 1 (within 1e-6).
        key_times: (K,) strictly increasing seconds of the clip; None: no animation.
        rotations: (K, J, 4) local joint rotations (x, y, z, w) at the key times, relative to the
            bind pose (whose local rotations are the identity).
        root_translations: (K, 3) the root node's translation at the key times (its position).
        morph_targets: (K, V, 3) per key, vertex displacements in the bind pose (applied before
            skinning, glTF's order), at full weight at their key only; None: no morph targets.
        name: name of the mesh node, mesh, skin and clip.

    Returns:
        The path written.

    Raises:
        ResultError: bad shapes, non-finite values, joints out of range, weights not summing to 1;
            raised before anything is written.
    """
    import pygltflib

    v = _check_points("vertices", vertices)
    nv = v.shape[0]
    f = as_faces(faces, nv)
    pos, par, names = _check_skeleton(joint_positions, parents, names)
    nj = pos.shape[0]
    jt = np.asarray(joints)
    wt = np.asarray(weights, dtype=np.float64)
    if jt.shape != (nv, 4) or wt.shape != (nv, 4) or not np.issubdtype(jt.dtype, np.integer):
        raise ResultError(f"joints (integers) and weights must have shape ({nv}, 4), got {jt.shape} and {wt.shape}")
    if jt.size and (jt.min() < 0 or jt.max() >= nj):
        raise ResultError(f"skin joint indices must be in [0, {nj}), got [{int(jt.min())}, {int(jt.max())}]")
    if not np.all(np.isfinite(wt)) or np.any(wt < 0) or np.any(np.abs(wt.sum(1) - 1.0) > 1e-6):
        raise ResultError("skin weights must be finite, non-negative and sum to 1 per vertex")
    animated = key_times is not None
    if animated:
        if rotations is None or root_translations is None:
            raise ResultError("an animation needs key times, rotations and root translations together")
        t = as_times(key_times, int(np.size(key_times)), "key times")
        k = t.shape[0]
        rot = np.asarray(rotations, dtype=np.float64)
        if rot.shape != (k, nj, 4) or not np.all(np.isfinite(rot)):
            raise ResultError(f"rotations must be finite with shape ({k}, {nj}, 4), got {rot.shape}")
        norm = np.linalg.norm(rot, axis=2, keepdims=True)
        if np.any(norm < 1e-12):
            raise ResultError("rotations must be non-zero quaternions")
        rot = rot / norm
        for i in range(1, k):  # consecutive keys on one hemisphere (sequential: each depends on the last)
            flip = np.sum(rot[i] * rot[i - 1], axis=1) < 0
            rot[i, flip] *= -1.0
        root = _check_points("root translations", root_translations, k)
    if morph_targets is not None:
        if not animated:
            raise ResultError("morph targets are keyed to the animation: give key times too")
        morphs = np.asarray(morph_targets, dtype=np.float64)
        if morphs.shape != (k, nv, 3) or not np.all(np.isfinite(morphs)):
            raise ResultError(f"morph targets must be finite with shape ({k}, {nv}, 3), got {morphs.shape}")

    f32 = np.float32
    v32 = v.astype(f32)
    w32 = wt.astype(f32)
    # float32 rounding can move a row sum off 1 by a few ulps: give the rest to the largest weight
    big = np.argmax(w32, axis=1)
    rows = np.arange(nv)
    w32[rows, big] = 0.0
    w32[rows, big] = np.maximum(f32(1.0) - w32.sum(1, dtype=f32), f32(0.0))

    gltf, builder = new_document("ncflow rig", "skin")
    attrs = pygltflib.Attributes(
        POSITION=builder.add(v32, component=pygltflib.FLOAT, type_="VEC3", target=pygltflib.ARRAY_BUFFER, minmax=True),
        NORMAL=builder.add(
            _normals(v, f).astype(f32),
            component=pygltflib.FLOAT,
            type_="VEC3",
            target=pygltflib.ARRAY_BUFFER,
            minmax=True,
        ),
        JOINTS_0=builder.add(
            jt.astype(np.uint16),
            component=pygltflib.UNSIGNED_SHORT,
            type_="VEC4",
            target=pygltflib.ARRAY_BUFFER,
            minmax=True,
        ),
        WEIGHTS_0=builder.add(w32, component=pygltflib.FLOAT, type_="VEC4", target=pygltflib.ARRAY_BUFFER, minmax=True),
    )
    indices = builder.add(
        f.astype(np.uint32).reshape(-1), component=pygltflib.UNSIGNED_INT, type_="SCALAR", target=34963, minmax=True
    )
    prim = pygltflib.Primitive(attributes=attrs, indices=indices, mode=pygltflib.TRIANGLES, material=0)
    gltf.meshes = [pygltflib.Mesh(name=name, primitives=[prim])]
    if morph_targets is not None:
        prim.targets = [
            {
                "POSITION": builder.add(
                    m.astype(f32), component=pygltflib.FLOAT, type_="VEC3", target=pygltflib.ARRAY_BUFFER, minmax=True
                )
            }
            for m in morphs
        ]
        gltf.meshes[0].weights = [0.0] * k

    offsets = pos - np.where(par[:, None] >= 0, pos[np.maximum(par, 0)], 0.0)
    children: list[list[int]] = [[] for _ in range(nj)]
    for j in range(1, nj):
        children[int(par[j])].append(j)
    gltf.nodes = []
    for j in range(nj):
        node = pygltflib.Node(name=names[j], translation=[float(x) for x in offsets[j]])
        if children[j]:
            node.children = children[j]
        gltf.nodes.append(node)
    mesh_node = nj
    gltf.nodes.append(pygltflib.Node(name=name, mesh=0, skin=0))
    ibm = np.tile(np.eye(4), (nj, 1, 1))
    ibm[:, :3, 3] = -pos
    ibm_acc = builder.add(
        np.transpose(ibm, (0, 2, 1)).astype(f32), component=pygltflib.FLOAT, type_="MAT4", minmax=True
    )  # column-major
    gltf.skins = [pygltflib.Skin(name=name, joints=list(range(nj)), inverseBindMatrices=ibm_acc, skeleton=0)]
    gltf.scenes = [pygltflib.Scene(name=name, nodes=[0, mesh_node])]
    gltf.scene = 0

    if animated:
        key_in = builder.add(t.astype(f32), component=pygltflib.FLOAT, type_="SCALAR", minmax=True)
        samplers, channels = [], []
        for j in range(nj):
            out = builder.add(rot[:, j].astype(f32), component=pygltflib.FLOAT, type_="VEC4", minmax=True)
            samplers.append(pygltflib.AnimationSampler(input=key_in, output=out, interpolation=pygltflib.ANIM_LINEAR))
            channels.append(
                pygltflib.AnimationChannel(
                    sampler=len(samplers) - 1, target=pygltflib.AnimationChannelTarget(node=j, path="rotation")
                )
            )
        out = builder.add(root.astype(f32), component=pygltflib.FLOAT, type_="VEC3", minmax=True)
        samplers.append(pygltflib.AnimationSampler(input=key_in, output=out, interpolation=pygltflib.ANIM_LINEAR))
        channels.append(
            pygltflib.AnimationChannel(
                sampler=len(samplers) - 1, target=pygltflib.AnimationChannelTarget(node=0, path="translation")
            )
        )
        if morph_targets is not None:
            out = builder.add(np.eye(k, dtype=f32).reshape(-1), component=pygltflib.FLOAT, type_="SCALAR", minmax=True)
            samplers.append(pygltflib.AnimationSampler(input=key_in, output=out, interpolation=pygltflib.ANIM_LINEAR))
            channels.append(
                pygltflib.AnimationChannel(
                    sampler=len(samplers) - 1, target=pygltflib.AnimationChannelTarget(node=mesh_node, path="weights")
                )
            )
        gltf.animations = [pygltflib.Animation(name=name, samplers=samplers, channels=channels)]

    return save_document(gltf, builder, path)
