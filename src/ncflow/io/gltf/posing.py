"""Posing a skinned glTF character: the node hierarchy's transforms at an animation time and/or with
joint rotations replaced, the joints' world transforms, and the skinned mesh by linear blend skinning
(the conventions of :mod:`ncflow.io.gltf.skins`). The functions take a
:class:`~ncflow.io.gltf.skins.GltfSkin`, whose methods of the same names call them.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError
from ncflow.geometry.mesh import Mesh, weld_vertices
from ncflow.geometry.rigid import forward_kinematics, sparse_linear_blend_skinning, trs_matrix
from ncflow.io.gltf.animation import check_time, interpolate_keyframes


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


def local_transforms(
    skin,
    time: float | None = None,
    animation: str | int | None = None,
    joint_rotations: Float[np.ndarray, "J 4"] | None = None,
) -> Float[np.ndarray, "N 4 4"]:
    """Local transform of every node of ``skin`` at an animation time and/or with replaced joint rotations."""
    t_, r_, s_ = skin.rest_translations.copy(), skin.rest_rotations.copy(), skin.rest_scales.copy()
    changed = np.zeros(skin.node_parents.shape[0], dtype=bool)
    if time is not None:
        time = check_time(time, skin.path)
        info = skin.find_animation(animation)
        t = min(max(time, info.start), info.end)
        target = {"translation": t_, "rotation": r_, "scale": s_}
        for ch in skin.channels[info.index]:
            target[ch.path][ch.node] = interpolate_keyframes(
                ch.times, ch.values, t, ch.interpolation, rotation=ch.path == "rotation"
            )
            changed[ch.node] = True
    if joint_rotations is not None:
        q = np.asarray(joint_rotations, dtype=np.float64)
        if q.shape != (skin.n_joints, 4):
            raise InputError(f"joint rotations must have shape ({skin.n_joints}, 4), got {q.shape}")
        norm = np.linalg.norm(q, axis=1)
        if not np.all(np.isfinite(q)) or np.any(norm < 1e-12):
            raise InputError("joint rotations must be finite non-zero quaternions (x, y, z, w)")
        r_[skin.joint_nodes] = q / norm[:, None]
        changed[skin.joint_nodes] = True
    local = skin.rest_local.copy()
    local[changed] = trs_matrix(t_[changed], r_[changed], s_[changed], scalar_first=False)
    return local


def world_transforms(skin, local: Float[np.ndarray, "N 4 4"]) -> Float[np.ndarray, "N 4 4"]:
    """World transform of every node from the local ones (:func:`ncflow.geometry.rigid.forward_kinematics`
    over the node hierarchy, parents first).
    """
    return forward_kinematics(local, skin.node_parents, order=skin.node_order)


def joint_world(
    skin,
    time: float | None = None,
    animation: str | int | None = None,
    joint_rotations: Float[np.ndarray, "J 4"] | None = None,
) -> Float[np.ndarray, "J 4 4"]:
    """World transforms of the joints: the bind pose (inverse of the inverse bind matrices)
    when neither a time nor rotations are given, else the animated / rotated node hierarchy.
    """
    if time is None and joint_rotations is None:
        if animation is not None:
            skin.find_animation(animation)  # validate even though the bind pose ignores it
        return np.linalg.inv(skin.inverse_bind)
    world = world_transforms(skin, local_transforms(skin, time, animation, joint_rotations))
    return world[skin.joint_nodes]


def pose_skin(
    skin,
    time: float | None = None,
    animation: str | int | None = None,
    joint_rotations: Float[np.ndarray, "J 4"] | None = None,
    weld: bool = True,
) -> PosedMesh:
    """The skinned mesh of ``skin`` (a :class:`~ncflow.io.gltf.skins.GltfSkin`) posed by linear blend
    skinning; see :func:`ncflow.io.gltf.skins.pose_gltf`.
    """
    if skin.positions is None:
        raise InputError("no skinned mesh was read for this skin", skin.path)
    joints = joint_world(skin, time, animation, joint_rotations)
    if time is None and joint_rotations is None:
        posed = skin.positions.copy()  # every skin matrix is the identity
    else:
        skin_matrices = joints @ skin.inverse_bind
        posed = sparse_linear_blend_skinning(skin.positions, skin.joints, skin.weights, skin_matrices)
    faces = skin.faces
    file_index = np.arange(skin.positions.shape[0])
    if weld:
        _, faces, file_index = weld_vertices(skin.positions, skin.faces)
        posed = posed[file_index]
        keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])
        faces = faces[keep]
    clip = None
    used_time = None
    if time is not None:
        info = skin.find_animation(animation)
        clip = info.name
        used_time = min(max(float(time), info.start), info.end)
    return PosedMesh(
        vertices=posed,
        faces=np.asarray(faces, dtype=np.int64),
        joint_positions=joints[:, :3, 3].copy(),
        parents=skin.parents.copy(),
        names=list(skin.names),
        file_index=np.asarray(file_index, dtype=np.int64),
        time=used_time,
        animation=clip,
    )
