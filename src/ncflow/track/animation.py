"""A tracked sequence as one animation: the skeleton's motion over the frames, the skinned source with exact
per-frame corrections (``animation.glb``), the motion alone (``animation.bvh``) and the per-frame joint
positions and bone transforms (``skeleton_frames.json``).

The source at rest is the bind pose. Each tracked frame is a key (time = frame index / fps): its joint
rotations are recovered from the fitted skeleton of the frame with the twist that best explains the
registered vertices (:func:`ncflow.retarget.rig.joint_motion`, as ``ncflow rig`` does), the root joint
translates. Linear blend skinning of the source with the skeleton's weights (4 influences per vertex)
does not reproduce a flowed shape exactly, so each key has a morph target: the displacement d in the
bind pose with Σ_j w_j S_j (v + d) = registered(v), i.e. d = (Σ_j w_j A_j)⁻¹ (registered − LBS(v)),
S_j = [A_j | b_j] the glTF skinning matrix world_j · inverseBind_j of that key (computed here by the
same forward kinematics a glTF viewer runs). At key times the GLB's mesh is the registered shape up to
float32 rounding; between keys the skeleton's rotations slerp and two corrections blend.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from jaxtyping import Float, Int
from scipy.spatial.transform import Rotation

from ncflow.geometry.rigid import dense_weights, forward_kinematics, joint_local_transforms, skinning_matrices
from ncflow.retarget.rig import INFLUENCES, joint_motion
from ncflow.retarget.weights import limit_influences, skeleton_weights

__all__ = ["SequenceMotion", "morph_corrections", "sequence_motion", "skinning_transforms"]


@dataclasses.dataclass(frozen=True)
class SequenceMotion:
    """The skeleton's motion over the tracked frames.

    Attributes:
        rotations: (K, J, 4) local joint rotations (x, y, z, w) relative to the bind (rest) pose.
        root_positions: (K, 3) the root joint's position per frame.
        transforms: (K, J, 4, 4) per joint the rigid motion from the rest pose to the frame (what
            moves the points of every bone that joint drives): the glTF skinning matrices.
        joints: (V, 4) and ``weights`` (V, 4): the source's skin, 4 influences per vertex.
    """

    rotations: Float[np.ndarray, "K J 4"]
    root_positions: Float[np.ndarray, "K 3"]
    transforms: Float[np.ndarray, "K J 4 4"]
    joints: Int[np.ndarray, "V 4"]
    weights: Float[np.ndarray, "V 4"]


def skinning_transforms(
    rest_joints: Float[np.ndarray, "J 3"],
    parents: Int[np.ndarray, " J"],
    rotations: Float[np.ndarray, "K J 4"],
    root_positions: Float[np.ndarray, "K 3"],
) -> Float[np.ndarray, "K J 4 4"]:
    """Per key, world(joint) · inverseBind(joint) of a rig bound at ``rest_joints`` whose nodes have the
    local ``rotations`` (x, y, z, w) and the root at ``root_positions`` (the layout of
    :func:`ncflow.io.gltf.rig_writer.write_rig_glb`).
    """
    rest = np.asarray(rest_joints, np.float64)
    out = np.empty((rotations.shape[0], rest.shape[0], 4, 4))
    for k in range(rotations.shape[0]):
        r = Rotation.from_quat(np.asarray(rotations[k], np.float64)).as_matrix()
        local = joint_local_transforms(rest, parents, r, root_translation=root_positions[k] - rest[0])
        out[k] = skinning_matrices(forward_kinematics(local, parents), rest)
    return out


def sequence_motion(
    source_vertices: Float[np.ndarray, "V 3"],
    rest_joints: Float[np.ndarray, "J 3"],
    parents: Int[np.ndarray, " J"],
    registered: Float[np.ndarray, "K V 3"],
    frame_joints: Float[np.ndarray, "K J 3"],
    skinning_width: float,
    normals: Float[np.ndarray, "V C"] | None = None,
) -> SequenceMotion:
    """The skeleton's motion from its rest pose to every tracked frame (module docstring); ``normals``:
    the source's outward vertex normals and islands where the matches' bone weights saw the skin
    (:func:`ncflow.retarget.weights.skeleton_weights`).
    """
    rest = np.asarray(rest_joints, np.float64)
    src = np.asarray(source_vertices, np.float64)
    w_dense = skeleton_weights(src, rest, parents, skinning_width, normals)
    # joint_motion takes the bind pose as the last frame (the twist is measured against it)
    positions = np.concatenate([np.asarray(frame_joints, np.float64), rest[None]])
    meshes = np.concatenate([np.asarray(registered, np.float64), src[None]])
    quats, _ = joint_motion(rest, positions, parents, mesh_frames=meshes, vertex_weights=w_dense)
    quats, roots = quats[:-1], positions[:-1, 0]
    joints4, weights4 = limit_influences(w_dense, INFLUENCES)
    return SequenceMotion(quats, roots, skinning_transforms(rest, parents, quats, roots), joints4, weights4)


def morph_corrections(
    source_vertices: Float[np.ndarray, "V 3"], motion: SequenceMotion, registered: Float[np.ndarray, "K V 3"]
) -> Float[np.ndarray, "K V 3"]:
    """Per key, the bind-pose displacement that makes the skinned source the registered shape (module
    docstring); where the blended linear part is singular (rotations that cancel), its pseudo-inverse.
    """
    src = np.asarray(source_vertices, np.float64)
    w = dense_weights(motion.joints, motion.weights, motion.transforms.shape[1])
    out = np.empty_like(np.asarray(registered, np.float64))
    for k in range(out.shape[0]):
        blended = np.einsum("vj,jab->vab", w, motion.transforms[k, :, :3, :])  # (V, 3, 4)
        linear = blended[:, :, :3]
        skinned = np.einsum("vab,vb->va", linear, src) + blended[:, :, 3]
        residual = registered[k] - skinned
        out[k] = np.einsum("vab,vb->va", np.linalg.pinv(linear), residual)
    return out
