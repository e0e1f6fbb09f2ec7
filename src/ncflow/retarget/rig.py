"""The target of a match as a skinned glTF character (``ncflow rig``).

:func:`rig_result` reads a result folder (:func:`ncflow.io.result.read_result`) and writes one GLB
(:func:`ncflow.io.gltf.rig_writer.write_rig_glb`):

* **Joints**: the fitted target skeleton (``skeleton_target.tgf``, names from
  ``skeleton_frames.json``). Its pose is the **bind pose**: every joint frame is aligned with the
  world axes and sits at its target position, so the inverse bind matrices are translations and
  the bound mesh is the target exactly.
* **Mesh**: the target (``target.ply``, or the mesh given with ``target=`` / ``--target``).
* **Weights**: per-joint skin weights on the source, carried to the target through
  ``map_tgt_to_src`` and inpainted where the map is unreliable
  (:func:`ncflow.retarget.weights.transfer_skin_weights`), then cut to the 4 largest per vertex and
  renormalised. The source's weights come from its glTF skin when one is given
  (:func:`gltf_skin_weights`: its joints matched to the skeleton's by name), otherwise from the
  skeleton (:func:`skeleton_weights`: the skeleton-driven flow field's bone weights on the rest
  source).
* **Clip** (unless ``animation=False``): the interpolation as joint rotations, one key per result
  frame, times scaled to ``clip_seconds``: key 0 is the source pose, the last key the bind
  (target) pose. Rotations are recovered from the joint positions of ``skeleton_frames.json``
  (:func:`joint_motion`): a joint with two or more non-collinear child bones gets the best-fit
  (Kabsch) rotation of its child bones; a joint with one child bone gets the smallest rotation
  (swing) that turns the bone onto its new direction, plus the **twist** about the bone that best
  explains the motion of the source vertices it carries in the result's frames (the joint
  positions alone cannot show a twist). Leaves keep their parent's rotation; the root also
  translates.

Semantics (ncflow's and glTF's agree): ncflow moves bone (parent p → child c) rigidly with the frame
of joint p (:mod:`ncflow.skeleton.kinematics`); in glTF a vertex weighted to joint p moves with
node p. So a vertex's weight for bone (p → c) is its weight for joint p.

The GLB is written to a temporary file, read back with ncflow's own glTF reader
(:func:`ncflow.io.gltf.skins.load_gltf_skin`) and checked — its bind pose, skinned through the
node hierarchy and the inverse bind matrices, must reproduce the target — before it is moved into
place.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import time
import warnings
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int
from scipy.spatial.transform import Rotation

from ncflow.errors import InputError, ResultError
from ncflow.flow.islands import surface_skin
from ncflow.io.atomic import atomic_path, check_output_file
from ncflow.io.bvh import write_bvh
from ncflow.io.gltf.document import unique_names
from ncflow.io.gltf.rig_writer import write_rig_glb
from ncflow.io.gltf.skins import load_gltf_skin
from ncflow.io.result import read_result, result_target
from ncflow.retarget.weights import (
    DEFAULT_MAX_DISTANCE,
    DEFAULT_SKINNING_WIDTH,
    gltf_skin_weights,
    limit_influences,
    skeleton_weights,
    transfer_skin_weights,
)

__all__ = ["INFLUENCES", "RigReport", "joint_motion", "rig_result"]

INFLUENCES = 4
"""Influences kept per vertex (glTF's ``JOINTS_0`` / ``WEIGHTS_0``)."""
TWIST_MIN_WEIGHT = 0.05
"""Source vertices with at least this weight for a joint vote on its twist, each with its weight to the 4th
power (blended vertices near the next joint, which also move with the child bone, count little)."""


@dataclasses.dataclass(frozen=True)
class RigReport:
    """What :func:`rig_result` wrote.

    Attributes:
        path: the GLB.
        n_vertices, n_faces, n_joints: the rig's size.
        n_keys: keys of the clip (0 without animation).
        weights_from: ``"gltf skin"`` or ``"skeleton"``.
        n_unreliable: target vertices whose carried weights were unreliable (inpainted, or kept
            where their component had no reliable vertex).
        bind_error: largest distance between the GLB's bind pose, read back and skinned through
            its node hierarchy and inverse bind matrices, and the target.
        seconds: wall time.
    """

    path: Path
    n_vertices: int
    n_faces: int
    n_joints: int
    n_keys: int
    weights_from: str
    n_unreliable: int
    bind_error: float
    seconds: float


# ----------------------------------------------------------------------------------------------
# The clip


def _swing(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(K, 3, 3) smallest rotations turning direction ``a`` (3,) onto each of ``b`` (K, 3)."""
    u = a / np.linalg.norm(a)
    nb = np.linalg.norm(b, axis=1, keepdims=True)
    v = np.where(nb > 1e-300, b / np.where(nb > 0, nb, 1.0), u)  # a collapsed bone: no swing
    axis = np.cross(u, v)
    s = np.linalg.norm(axis, axis=1)
    c = v @ u
    angle = np.arctan2(s, c)
    perp = np.cross(u, np.eye(3)[np.argmin(np.abs(u))])
    perp /= np.linalg.norm(perp)
    unit = np.where(s[:, None] > 1e-12, axis / np.where(s > 0, s, 1.0)[:, None], perp)
    return Rotation.from_rotvec(unit * angle[:, None]).as_matrix()


def _twist(
    swing: np.ndarray, axis: np.ndarray, r_bind: np.ndarray, r_frames: np.ndarray, weight: np.ndarray
) -> np.ndarray:
    """(K, 3, 3) rotations about ``axis`` (K, 3) that best turn ``swing · r_bind`` onto ``r_frames``.

    ``r_bind`` (n, 3) and ``r_frames`` (K, n, 3) are vertices relative to the joint in the bind pose
    and in each frame; the angle is the weighted least-squares one of their components across the
    axis, atan2(Σ w (s⊥ × r⊥)·u, Σ w s⊥·r⊥).
    """
    s = np.einsum("kab,nb->kna", swing, r_bind)
    u = axis[:, None, :]
    s_perp = s - np.sum(s * u, -1, keepdims=True) * u
    r_perp = r_frames - np.sum(r_frames * u, -1, keepdims=True) * u
    sin = np.einsum("n,kn->k", weight, np.sum(np.cross(s_perp, r_perp) * u, -1))
    cos = np.einsum("n,kn->k", weight, np.sum(s_perp * r_perp, -1))
    angle = np.where(np.hypot(sin, cos) > 0, np.arctan2(sin, cos), 0.0)
    return Rotation.from_rotvec(axis * angle[:, None]).as_matrix()


def joint_motion(
    bind_positions: Float[np.ndarray, "J 3"],
    positions: Float[np.ndarray, "K J 3"],
    parents: Int[np.ndarray, " J"],
    *,
    mesh_frames: Float[np.ndarray, "K V 3"] | None = None,
    vertex_weights: Float[np.ndarray, "V J"] | None = None,
) -> tuple[Float[np.ndarray, "K J 4"], Float[np.ndarray, "K J 3 3"]]:
    """Joint rotations that move the skeleton from its bind pose to each frame's joint positions.

    Joint j's world rotation D_j(k) maps bind-pose directions to frame k: for two or more child
    bones spanning a plane, the best-fit rotation of the child bone vectors (Kabsch,
    :meth:`scipy.spatial.transform.Rotation.align_vectors`); for one child bone (or collinear
    ones), the smallest rotation (swing) turning the longest child bone onto its new direction,
    then, with ``mesh_frames`` and ``vertex_weights``, the twist about the new bone direction that
    best fits the vertices weighted to j (relative to the joint, bind = last frame; weights to the
    4th power); for a leaf, its parent's. The local rotation is D_parent(k)ᵀ D_j(k) (the root's: D_root(k)).

    Args:
        bind_positions: (J, 3) joint positions in the bind pose, topological order.
        positions: (K, J, 3) joint positions per frame.
        parents: (J,) parents.
        mesh_frames: (K, V, 3) mesh vertices per frame (the last frame in the bind pose), or None
            for swing-only single-child joints.
        vertex_weights: (V, J) per-joint weights of those vertices.

    Returns:
        ((K, J, 4) local rotations as quaternions (x, y, z, w), (K, J, 3, 3) world rotations D).
    """
    bind = np.asarray(bind_positions, dtype=np.float64)
    pos = np.asarray(positions, dtype=np.float64)
    par = np.asarray(parents, dtype=np.int64)
    k, nj = pos.shape[:2]
    children: list[list[int]] = [[] for _ in range(nj)]
    for j in range(1, nj):
        children[int(par[j])].append(j)
    use_mesh = mesh_frames is not None and vertex_weights is not None
    world = np.tile(np.eye(3), (k, nj, 1, 1))
    for j in range(nj):
        ch = children[j]
        if not ch:
            if par[j] >= 0:
                world[:, j] = world[:, par[j]]
            continue
        a = bind[ch] - bind[j]
        b = pos[:, ch] - pos[:, j : j + 1]
        sv = np.linalg.svd(a, compute_uv=False)
        if len(ch) >= 2 and sv[1] > 1e-6 * sv[0]:
            with warnings.catch_warnings():  # collapsed child bones in a frame: any rotation fits
                warnings.simplefilter("ignore", UserWarning)
                for i in range(k):
                    world[i, j] = Rotation.align_vectors(b[i], a)[0].as_matrix()
            continue
        longest = int(np.argmax(np.linalg.norm(a, axis=1)))
        swing = _swing(a[longest], b[:, longest])
        world[:, j] = swing
        if use_mesh:
            w = np.asarray(vertex_weights)[:, j]
            sel = np.flatnonzero(w >= TWIST_MIN_WEIGHT)
            if sel.size:
                axis = np.einsum("kab,b->ka", swing, a[longest] / np.linalg.norm(a[longest]))
                r_bind = mesh_frames[-1, sel] - pos[-1, j]
                r_frames = mesh_frames[:, sel] - pos[:, j : j + 1]
                world[:, j] = _twist(swing, axis, r_bind, r_frames, w[sel] ** 4) @ swing
    local = world.copy()
    local[:, 1:] = np.einsum("kjba,kjbc->kjac", world[:, par[1:]], world[:, 1:])
    quats = Rotation.from_matrix(local.reshape(-1, 3, 3)).as_quat().reshape(k, nj, 4)
    return quats, world


# ----------------------------------------------------------------------------------------------
# The command


def _skinning_width(metrics: dict) -> float:
    """``flow.skinning_width`` of the run's configuration when recorded and valid, else the default."""
    try:
        value = float(metrics["config"]["flow"]["skinning_width"])
    except (KeyError, TypeError, ValueError):
        return DEFAULT_SKINNING_WIDTH
    return value if math.isfinite(value) and value > 0 else DEFAULT_SKINNING_WIDTH


def rig_result(
    result_dir: str | os.PathLike,
    out_glb: str | os.PathLike,
    *,
    source_skin: str | os.PathLike | None = None,
    target: str | os.PathLike | None = None,
    animation: bool = True,
    overwrite: bool = False,
    clip_seconds: float = 2.0,
    max_distance: float = DEFAULT_MAX_DISTANCE,
    max_normal_angle: float | None = None,
    bvh: str | os.PathLike | None = None,
) -> RigReport:
    """Write the target of a result folder as a skinned GLB character (module docstring).

    Args:
        result_dir: a folder written by ``ncflow match`` (with a skeleton).
        out_glb: the ``.glb`` to write.
        source_skin: the source as a skinned ``.glb`` / ``.gltf`` whose weights to carry; None:
            weights from the skeleton.
        target: the target mesh file, for a result without ``target.ply`` (or to override it);
            it must have the result's number of target vertices.
        animation: include the interpolation as a joint-rotation clip.
        overwrite: replace an existing ``out_glb``.
        clip_seconds: length of the clip.
        max_distance: reliability of the carried weights: largest distance to the flowed source,
            as a fraction of the target's bounding-box diagonal.
        max_normal_angle: reliability: largest angle between the normals, degrees (default 30).
        bvh: also write the clip's skeleton motion as this ``.bvh`` (:func:`ncflow.io.bvh.write_bvh`:
            the same joints, bind pose and key rotations as the GLB; frame time = clip / (keys − 1)).

    Returns:
        :class:`RigReport`.

    Raises:
        InputError: bad or missing inputs (one line naming the file), an existing ``out_glb``
            without ``overwrite``; nothing is written then.
    """
    start = time.perf_counter()
    out = Path(out_glb)
    real = _output_file(out, ".glb", "the rig is written as a binary glTF", "--out", overwrite)
    bvh_real = None
    if bvh is not None:
        if not animation:
            raise InputError("a BVH holds the motion: it cannot be written without the animation", bvh)
        bvh_real = _output_file(
            bvh, ".bvh", "the skeleton motion is written as Biovision Hierarchy", "--bvh", overwrite
        )
        if bvh_real == real:
            raise InputError("the BVH and the GLB must be two files", bvh)
    if not (math.isfinite(clip_seconds) and clip_seconds > 0):
        raise InputError(f"the clip length must be a positive number of seconds, got {clip_seconds}")
    if not (math.isfinite(max_distance) and max_distance >= 0):
        raise InputError(f"the largest reliable distance must be a non-negative fraction, got {max_distance}")

    res = read_result(result_dir, check_animation=False)
    skeleton, sk_frames = res.skeleton_target, res.skeleton_frames
    if skeleton is None:
        raise InputError(
            "the result has no skeleton (skeleton_target.tgf, skeleton_frames.json): rig needs a match run "
            "with --skeleton",
            result_dir,
        )
    tv, tf = result_target(res, target, result_dir)
    parents = skeleton.parents
    names = unique_names(list(res.joint_names or skeleton.names or [None] * skeleton.n_joints))
    frames = res.frames
    source = frames[0]
    if source_skin is not None:
        if res.joint_names is None and skeleton.names is None:
            raise InputError(
                "the result's skeleton has no joint names (a TGF skeleton): the skin's joints cannot be matched",
                Path(result_dir) / "skeleton_frames.json",
            )
        w_source = gltf_skin_weights(load_gltf_skin(source_skin), source, names)
        weights_from = "gltf skin"
    else:
        width = _skinning_width(res.metrics)
        seen = (res.metrics.get("skinning_weights") or {}).get("mode") == "surface"  # as the match's field
        normals = surface_skin(source, res.source_faces, sk_frames[0], parents) if seen else None
        w_source = skeleton_weights(source, sk_frames[0], parents, width, normals)
        weights_from = "skeleton"
    diag = float(np.linalg.norm(np.ptp(tv, axis=0)))
    w_target, reliable = transfer_skin_weights(
        w_source,
        source,
        res.source_faces,
        res.deformed_source,
        tv,
        tf,
        res.map_face,
        res.map_bary,
        max_distance=max_distance * diag,
        max_normal_angle=max_normal_angle,
    )
    joints4, weights4 = limit_influences(w_target, INFLUENCES)
    bind = skeleton.positions
    clip = {}
    if animation:
        quats, _ = joint_motion(bind, sk_frames, parents, mesh_frames=frames, vertex_weights=w_source)
        t = np.asarray(res.frame_times, dtype=np.float64)
        span = t[-1] - t[0]
        keys = (t - t[0]) * (clip_seconds / span) if span > 0 else t - t[0]
        clip = {"key_times": keys, "rotations": quats, "root_translations": sk_frames[:, 0]}
    with atomic_path(real) as tmp, contextlib.ExitStack() as more:
        if bvh_real is not None:
            keys = clip["key_times"]
            frame_time = float(keys[-1] / (len(keys) - 1)) if len(keys) > 1 and keys[-1] > 0 else clip_seconds
            bvh_tmp = more.enter_context(atomic_path(bvh_real))
            write_bvh(bvh_tmp, bind, parents, names, clip["rotations"], clip["root_translations"], frame_time)
        write_rig_glb(
            tmp,
            vertices=tv,
            faces=tf,
            joint_positions=bind,
            parents=parents,
            names=names,
            joints=joints4,
            weights=weights4,
            name="ncflow rig",
            **clip,
        )
        bind_error = _check_bind(tmp, tv, diag)
    return RigReport(
        path=out,
        n_vertices=int(tv.shape[0]),
        n_faces=int(tf.shape[0]),
        n_joints=int(skeleton.n_joints),
        n_keys=int(len(clip["key_times"])) if clip else 0,
        weights_from=weights_from,
        n_unreliable=int(np.sum(~reliable)),
        bind_error=bind_error,
        seconds=time.perf_counter() - start,
    )


def _output_file(path: str | os.PathLike, suffix: str, written_as: str, option: str, overwrite: bool) -> Path:
    """An output file checked before any work: its suffix, an existing file without ``overwrite``, and
    :func:`~ncflow.io.atomic.check_output_file`; returned resolved.
    """
    if Path(path).suffix.lower() != suffix:
        raise InputError(f"{written_as}: the output must end with {suffix}", path)
    if (Path(path).exists() or Path(path).is_symlink()) and not overwrite:
        raise InputError("exists (pass overwrite=True / --overwrite to replace it)", path)
    return check_output_file(path, option=option)


def _check_bind(path: Path, target: np.ndarray, diag: float) -> float:
    """Read the written GLB back; its bind pose skinned through nodes and inverse bind matrices must be the target."""
    rig = load_gltf_skin(path)
    posed = rig.pose(joint_rotations=rig.rest_rotations[rig.joint_nodes], weld=False)
    if posed.vertices.shape != target.shape:
        raise ResultError(f"the written rig has {posed.vertices.shape[0]} vertices, expected {target.shape[0]}", path)
    error = float(np.max(np.linalg.norm(posed.vertices - target, axis=1)))
    tol = 1e-5 * diag + 8 * float(np.finfo(np.float32).eps) * float(np.max(np.abs(target)))
    if not error <= tol:
        raise ResultError(f"the written rig does not reproduce the target in its bind pose (error {error:.3g})", path)
    return error
