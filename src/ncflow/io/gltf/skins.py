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

Posing is :mod:`ncflow.io.gltf.posing`, the decoding of the mesh's primitives
:mod:`ncflow.io.gltf.primitives`.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError
from ncflow.geometry.skeleton import MAX_JOINTS, Skeleton, _default_labels, merge_zero_length_bones
from ncflow.io.files import short_repr
from ncflow.io.gltf.animation import AnimationInfo, Channel, read_animations
from ncflow.io.gltf.document import (
    DocumentReader,
    get_field,
    load_document,
    malformed,
    node_hierarchy,
    node_rest,
    unique_names,
)
from ncflow.io.gltf.posing import PosedMesh, joint_world, local_transforms, pose_skin, world_transforms
from ncflow.io.gltf.primitives import read_skinned_primitives


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

    # -- posing (ncflow.io.gltf.posing) --------------------------------------------------------

    def local_transforms(self, time=None, animation=None, joint_rotations=None) -> Float[np.ndarray, "N 4 4"]:
        """:func:`~ncflow.io.gltf.posing.local_transforms` of this skin."""
        return local_transforms(self, time, animation, joint_rotations)

    def world_transforms(self, local: Float[np.ndarray, "N 4 4"]) -> Float[np.ndarray, "N 4 4"]:
        """:func:`~ncflow.io.gltf.posing.world_transforms` of this skin."""
        return world_transforms(self, local)

    def joint_world(self, time=None, animation=None, joint_rotations=None) -> Float[np.ndarray, "J 4 4"]:
        """:func:`~ncflow.io.gltf.posing.joint_world` of this skin."""
        return joint_world(self, time, animation, joint_rotations)

    def pose(self, time=None, animation=None, joint_rotations=None, weld: bool = True) -> PosedMesh:
        """The skinned mesh posed by linear blend skinning (:func:`~ncflow.io.gltf.posing.pose_skin`; see
        :func:`pose_gltf`).
        """
        return pose_skin(self, time, animation, joint_rotations, weld)


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
        positions, faces, joints, weights = read_skinned_primitives(
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
