"""Skinned glTF characters: a skin, its skinned mesh, its skeleton, and posing.

Animated characters give source/target pairs with exact ground truth: posing one skinned mesh at
two animation times moves the same vertices, so vertex ``i`` of both poses is the same body point.
:func:`load_gltf_skin` reads one skin (the first, or the one chosen by index): its joints in the
skin's order, its inverse bind matrices (identity when the skin has none), and the first node that
uses it with a mesh — all primitives of that mesh concatenated (``POSITION``, ``JOINTS_n`` /
``WEIGHTS_n`` for every set n present, ``indices``; triangle lists, strips and fans).
:func:`pose_gltf` and :meth:`GltfSkin.pose` pose it, :func:`gltf_skeleton` gives its joints.

Conventions:

* Coordinates are the scene's world coordinates. Skinning follows the glTF specification:
  vertex ``v`` of the mesh moves to ``Σ_k w_k · world(joint_k) · inverseBind_k · v``; the transform
  of the node holding the skinned mesh is ignored (the spec's "MUST be ignored"). Writing the
  result in the mesh node's coordinates and then applying that node's world transform, as some
  viewers do, gives the same points.
* The **bind pose** (``time=None`` and no ``joint_rotations``) is the pose the mesh is bound in:
  every skin matrix is the identity, the vertices are the file's ``POSITION`` values, and joint
  ``j`` sits at the translation of ``inverse(inverseBind_j)``.
* At an **animation time** (:mod:`ncflow.io.gltf.animation`), nodes that no channel of the clip
  targets keep their rest transform (the node's TRS or matrix).
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
  :func:`ncflow.geometry.mesh.weld_vertices` on the bind-pose positions; the posed positions are
  taken at the same first occurrences (``file_index``), so every pose has the same vertex order.
  Faces that become degenerate (a repeated vertex) are dropped.

Over 500 lines: one reader of skinned characters (skin, geometry, skeleton, posing), read end to
end.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError
from ncflow.geometry.mesh import Mesh, weld_vertices
from ncflow.geometry.rigid import forward_kinematics, sparse_linear_blend_skinning, trs_matrix
from ncflow.geometry.skeleton import MAX_JOINTS, Skeleton, _default_labels, merge_zero_length_bones
from ncflow.io.files import short_repr
from ncflow.io.gltf.animation import AnimationInfo, Channel, check_time, interpolate_keyframes, read_animations
from ncflow.io.gltf.document import (
    DocumentReader,
    get_field,
    load_document,
    malformed,
    node_hierarchy,
    node_rest,
    unique_names,
)


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
        """The surface as an :class:`ncflow.geometry.mesh.Mesh`."""
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
    channels: list[list[Channel]] = dataclasses.field(repr=False)
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
        but an integer selects by index.
        """
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
                    f"no animation named {short_repr(str(animation), 40)}; clips: {self._clip_list()}", self.path
                ) from None
        if not 0 <= index < len(self.animations):
            raise InputError(f"animation index {index} out of range (clips: {self._clip_list()})", self.path)
        return self.animations[index]

    def _clip_list(self, most: int = 5) -> str:
        """The first ``most`` clips as ``index:name`` (names cut short), for error messages."""
        shown = [f"{a.index}:{short_repr(a.name, 24) if a.name else '(unnamed)'}" for a in self.animations[:most]]
        return ", ".join(shown) + (f", ... ({len(self.animations)} clips)" if len(self.animations) > most else "")

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
            time = check_time(time, self.path)
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
        local[changed] = trs_matrix(t_[changed], r_[changed], s_[changed], scalar_first=False)
        return local

    def world_transforms(self, local: Float[np.ndarray, "N 4 4"]) -> Float[np.ndarray, "N 4 4"]:
        """World transform of every node from the local ones (:func:`ncflow.geometry.rigid.forward_kinematics`
        over the node hierarchy, parents first).
        """
        return forward_kinematics(local, self.node_parents, order=self.node_order)

    def joint_world(
        self,
        time: float | None = None,
        animation: str | int | None = None,
        joint_rotations: Float[np.ndarray, "J 4"] | None = None,
    ) -> Float[np.ndarray, "J 4 4"]:
        """World transforms of the joints: the bind pose (inverse of the inverse bind matrices)
        when neither a time nor rotations are given, else the animated / rotated node hierarchy.
        """
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
            skin_matrices = joint_world @ self.inverse_bind
            posed = sparse_linear_blend_skinning(self.positions, self.joints, self.weights, skin_matrices)
        faces = self.faces
        file_index = np.arange(self.positions.shape[0])
        if weld:
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


def _check_invertible(inverse_bind: np.ndarray, what: str, reader: DocumentReader) -> None:
    """InputError unless every inverse bind matrix is invertible (relative determinant, then a trial inverse)."""
    a = inverse_bind[:, :3, :3]
    with np.errstate(over="ignore", invalid="ignore"):
        scale = np.max(np.abs(a), axis=(1, 2))
        bad = ~(np.abs(np.linalg.det(a)) > 1e-12 * scale**3)  # also zero matrices, overflow to NaN
    if np.any(bad):
        reader.fail(f"{what}: singular inverse bind matrix (joint {int(np.argmax(bad))})")
    try:
        bind = np.linalg.inv(inverse_bind)
    except np.linalg.LinAlgError:
        reader.fail(f"{what}: singular inverse bind matrix")
    if not np.all(np.isfinite(bind)):
        reader.fail(f"{what}: inverse bind matrices whose inverse is not finite")


def _skeleton_parents(
    joint_nodes: np.ndarray, node_parents: np.ndarray, node_depth: np.ndarray, node_order: np.ndarray
) -> np.ndarray:
    """Parent joint of every joint: nearest joint ancestor node; extra roots attached to the top-most root.

    One pass over the nodes, parents first (linear in the number of nodes, however deep the hierarchy).
    """
    where = {int(node): j for j, node in enumerate(joint_nodes)}
    nearest = np.full(node_parents.shape[0], -1, dtype=np.int64)  # nearest joint among a node's ancestors
    for node in node_order.tolist():
        p = int(node_parents[node])
        if p >= 0:
            nearest[node] = where[p] if p in where else nearest[p]
    parents = nearest[joint_nodes]
    roots = np.flatnonzero(parents < 0)
    if roots.size > 1:
        root = int(roots[np.lexsort((roots, node_depth[joint_nodes[roots]]))[0]])
        parents[roots[roots != root]] = root
    return parents


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


def _read_geometry(doc, reader: DocumentReader, mesh_index: int, n_joints: int):
    """(positions (V,3), faces (F,3), joints (V,K), weights (V,K)) of all primitives of a mesh."""
    meshes = doc.meshes or []
    if not 0 <= mesh_index < len(meshes):
        reader.fail(f"mesh {mesh_index} does not exist")
    prims = get_field(meshes[mesh_index], "primitives") or []
    pos_all, face_all, jnt_all, wgt_all = [], [], [], []
    offset = 0
    n_sets = None
    for p, prim in enumerate(prims):
        what = f"mesh {mesh_index} primitive {p}"
        mode = get_field(prim, "mode")
        mode = 4 if mode is None else int(mode)
        if mode not in _MODES:
            reader.fail(f"{what} is not made of triangles (mode {mode})")
        attrs = get_field(prim, "attributes")
        pos = reader.accessor(get_field(attrs, "POSITION"), what + " POSITION").astype(np.float64)
        if pos.ndim != 2 or pos.shape[1] != 3:
            reader.fail(f"{what}: POSITION must be VEC3")
        sets = []
        k = 0
        while get_field(attrs, f"JOINTS_{k}") is not None and get_field(attrs, f"WEIGHTS_{k}") is not None:
            j = reader.accessor(get_field(attrs, f"JOINTS_{k}"), f"{what} JOINTS_{k}")
            w = reader.accessor(get_field(attrs, f"WEIGHTS_{k}"), f"{what} WEIGHTS_{k}").astype(np.float64)
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
        if get_field(prim, "indices") is not None:
            idx = reader.accessor(get_field(prim, "indices"), what + " indices").reshape(-1)
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
    with malformed(path):  # a JSON structure of unexpected types
        return _load_gltf_skin(path, skin, geometry)


def _load_gltf_skin(path: Path, skin: int | None, geometry: bool) -> GltfSkin:
    doc = load_document(path)
    reader = DocumentReader(doc, path)
    skins = doc.skins or []
    if not skins:
        raise InputError("has no skin (not a rigged character)", path)
    skin_index = 0 if skin is None else int(skin)
    if not 0 <= skin_index < len(skins):
        raise InputError(f"skin {skin_index} does not exist (the file has {len(skins)})", path)
    nodes = doc.nodes or []
    node_parents, node_order, node_depth = node_hierarchy(doc, reader)
    rest_local, trans, rots, scales, has_matrix = node_rest(doc, reader)
    joint_nodes = np.asarray(get_field(skins[skin_index], "joints") or [], dtype=np.int64)
    if joint_nodes.size == 0:
        reader.fail(f"skin {skin_index} has no joints")
    if joint_nodes.min() < 0 or joint_nodes.max() >= len(nodes):
        reader.fail(f"skin {skin_index} refers to a joint node that does not exist")
    if np.unique(joint_nodes).size != joint_nodes.size:
        reader.fail(f"skin {skin_index} lists a joint node twice")
    if joint_nodes.size > MAX_JOINTS:
        reader.fail(f"skin {skin_index} has {joint_nodes.size} joints, more than the {MAX_JOINTS} a skeleton may have")
    n_joints = joint_nodes.size
    ibm_index = get_field(skins[skin_index], "inverseBindMatrices")
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
        _check_invertible(inverse_bind, f"skin {skin_index}", reader)
    names = unique_names([get_field(nodes[int(n)], "name") for n in joint_nodes])
    parents = _skeleton_parents(joint_nodes, node_parents, node_depth, node_order)
    infos, channels = read_animations(doc, reader, len(nodes))
    positions = faces = joints = weights = None
    mesh_node = None
    if geometry:
        for i, node in enumerate(nodes):
            if (
                get_field(node, "skin") is not None
                and int(get_field(node, "skin")) == skin_index
                and get_field(node, "mesh") is not None
            ):
                mesh_node = i
                break
        if mesh_node is None:
            reader.fail(f"no node uses skin {skin_index} with a mesh (nothing to pose)")
        positions, faces, joints, weights = _read_geometry(
            doc, reader, int(get_field(nodes[mesh_node], "mesh")), n_joints
        )
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


def gltf_skeleton(
    source: str | os.PathLike | GltfSkin,
    time: float | None = None,
    animation: str | int | None = None,
    *,
    skin: int | None = None,
    merge: bool = True,
    name: str | os.PathLike | None = None,
) -> tuple[Skeleton, Int[np.ndarray, " K"]]:
    """The skeleton of a skin of a glTF file, posed at an animation time, stacked joints merged.

    The one function behind :func:`ncflow.skeleton.load_skeleton`, ``ncflow pose --skeleton-out``
    and :func:`ncflow.synthetic.gltf.gltf_pair`.

    Args:
        source: a ``.glb`` / ``.gltf`` file (read without its mesh), or a skin already read by
            :func:`load_gltf_skin`.
        time: seconds on the clip's timeline (clamped to the clip); None: the bind pose, taken
            from the inverse bind matrices (the pose the mesh is bound in).
        animation: clip name or index (None: the first clip); only used with ``time`` (checked
            to exist either way).
        skin: which skin of a file (None: the first); ignored when ``source`` is a skin.
        merge: merge joints stacked on their parent (zero-length bones, which rigs often have)
            into it, with :func:`ncflow.geometry.skeleton.merge_zero_length_bones` decided in the
            bind pose, so that every time of one file gives the same joints.
        name: the skeleton's name in messages (default: the file).

    Returns:
        (the skeleton of the K kept joints — names from the nodes, parents as in the module
        docstring (nearest joint ancestor; several joint roots joined under the top-most one),
        ``file_index`` into the kept list —, the kept joints' indices (K,) into the skin's joint
        list, increasing).

    Raises:
        InputError: not a glTF file, no skin, unknown animation, time not finite, a zero-length
            bone left (``merge=False``).
    """
    rig = source if isinstance(source, GltfSkin) else load_gltf_skin(source, skin, geometry=False)
    positions = rig.joint_world(time, animation)[:, :3, 3]
    if merge:
        keep, parents = merge_zero_length_bones(rig.joint_world()[:, :3, 3], rig.parents)
    else:
        keep, parents = np.arange(rig.n_joints), rig.parents.copy()
    names = [rig.names[j] for j in keep]
    skeleton = Skeleton.from_arrays(
        positions[keep],
        parents,
        names,
        name=rig.path if name is None else name,
        labels=_default_labels(keep.size, names),
    )
    return skeleton, keep


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
    exist. ``joint_rotations`` without ``time`` rotate the nodes' rest transforms. For several
    poses of one file, read it once with :func:`load_gltf_skin` and call :meth:`GltfSkin.pose`: all
    poses share vertex order and faces, so vertex ``i`` is the same body point in every pose.

    Returns:
        :class:`PosedMesh` in world coordinates.

    Raises:
        InputError: not a glTF file, no skin or skinned mesh, unknown animation, bad time or rotations.
    """
    return load_gltf_skin(path, skin).pose(time, animation, joint_rotations, weld)
