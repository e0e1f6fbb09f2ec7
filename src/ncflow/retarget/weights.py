"""Skin weights carried from the source to the target, with the unreliable ones inpainted.

"Robust Skin Weights Transfer via Weight Inpainting" (Abdrashitov, Raichstat, Monsen, Hill;
SIGGRAPH Asia 2023 Technical Communications) in two stages:

1. **Carry.** Every target vertex reads the source weights at its point of the source surface,
   ``map_tgt_to_src`` (face + barycentric coordinates; :func:`ncflow.geometry.barycentric.surface_points`).
   The carried value is *reliable* when the target vertex lies close to that point on the flowed
   source (``deformed_source``, the source moved onto the target) — distance at most
   ``max_distance``, by default 0.05 × the target's bounding-box diagonal, the paper's setting —
   and the two surfaces face the same way there: the angle between the target's vertex normal and
   the flowed source's normal at the point (its vertex normals interpolated) is at most
   ``max_normal_angle``, by default 30° (the paper's). Opposite normals (a limb matched to the
   wrong side of a thin part, an inverted fold) are unreliable.
2. **Inpaint.** The unreliable rows are replaced by the minimiser of ``trace(Wᵀ Q W)`` with
   ``Q = −L + L M⁻¹ L`` (L the cotangent Laplacian, M the lumped mass of the *target*,
   :mod:`ncflow.geometry.laplacian`), the reliable rows held fixed (Dirichlet conditions):
   ``Q_UU W_U = −Q_UK W_K``, one sparse LU factorisation for all J columns. ``Q`` mixes a
   Dirichlet (−L) and a Laplacian-energy (L M⁻¹ L) term whose balance depends on the units, so it
   is built on the target scaled to unit bounding-box diagonal. Then weights are clamped at 0 and
   every row renormalised to sum 1.

Edge cases: a connected component of the target with no reliable vertex has nothing to inpaint
from and keeps its carried weights; degenerate triangles are handled by the mollified Laplacian.

The source's per-joint weights (what is carried) come from its glTF skin
(:func:`gltf_skin_weights`, joints matched by name) or from the skeleton
(:func:`skeleton_weights`, the skeleton-driven flow field's bone weights). In both, a vertex's
weight for joint p is the weight with which it follows p's frame, glTF's meaning; ncflow moves bone
(p → c) rigidly with the frame of joint p (:mod:`ncflow.skeleton.kinematics`), so the weight of
bone (p → c) is a weight for joint p.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from jaxtyping import Bool, Float, Int
from scipy.sparse.linalg import splu

from ncflow.errors import InputError
from ncflow.flow.bone_weights import skinning_weights, surface_skinning_weights
from ncflow.geometry.barycentric import surface_points
from ncflow.geometry.laplacian import cotangent_laplacian, lumped_mass
from ncflow.geometry.mesh import orientation, vertex_normals
from ncflow.geometry.rigid import dense_weights
from ncflow.geometry.topology import vertex_components
from ncflow.io.gltf.skins import GltfSkin

__all__ = [
    "DEFAULT_MAX_DISTANCE",
    "DEFAULT_MAX_NORMAL_ANGLE",
    "DEFAULT_SKINNING_WIDTH",
    "gltf_skin_weights",
    "inpaint_weights",
    "limit_influences",
    "skeleton_weights",
    "transfer_skin_weights",
]

DEFAULT_MAX_DISTANCE = 0.05
"""Reliability: largest distance to the flowed source, as a fraction of the target's bounding-box diagonal."""
DEFAULT_MAX_NORMAL_ANGLE = 30.0
"""Reliability: largest angle (degrees) between the target's normal and the flowed source's."""
DEFAULT_SKINNING_WIDTH = 0.05
"""τ of the skeleton-driven field's weights as a fraction of the median bone length (``flow.skinning_width``)."""


def inpaint_weights(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    values: Float[np.ndarray, "V ..."],
    known: Bool[np.ndarray, " V"],
) -> Float[np.ndarray, "V ..."]:
    """The unknown rows of ``values`` replaced by the minimiser of ``trace(Xᵀ Q X)``, known rows fixed.

    ``Q = −L + L M⁻¹ L`` on the mesh scaled to unit bounding-box diagonal (module docstring). ``Q``
    annihilates constants, so a constant known field is inpainted by the same constant; it also
    annihilates linear functions at vertices two rings inside a flat region, where a linear known
    field is reproduced exactly. Rows of a connected component without a known vertex are returned
    as given. The result is the raw minimiser: not clamped, not normalised.

    Args:
        vertices: (V, 3) positions.
        faces: (F, 3) triangles.
        values: (V,) or (V, C) per-vertex values (weights); the unknown rows are only read where
            a component has no known vertex.
        known: (V,) True where the value is kept.

    Returns:
        (V,) or (V, C) float64, as ``values``.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    x = np.array(values, dtype=np.float64)
    squeeze = x.ndim == 1
    if squeeze:
        x = x[:, None]
    n = v.shape[0]
    known = np.asarray(known, dtype=bool).reshape(-1)
    if known.shape != (n,) or x.shape[0] != n:
        raise ValueError(f"values ({x.shape[0]} rows) and known ({known.shape[0]}) must have one row per vertex ({n})")
    # components without any known vertex keep the given rows
    label = vertex_components(f, n)
    has_known = np.zeros(label.max() + 1 if n else 0, dtype=bool)
    has_known[label[known]] = True
    fixed = known | ~has_known[label]
    unknown = np.flatnonzero(~fixed)
    if unknown.size == 0:
        return x[:, 0] if squeeze else x
    extent = np.ptp(v, axis=0) if n else np.zeros(3)
    diag = float(np.linalg.norm(extent)) or 1.0
    vs = (v - v.min(0)) / diag
    lap = cotangent_laplacian(vs, f)
    mass = lumped_mass(vs, f)
    inv_mass = np.divide(1.0, mass, out=np.zeros_like(mass), where=mass > 0)
    q = (-lap + lap @ sp.diags(inv_mass) @ lap).tocsr()
    kept = np.flatnonzero(fixed)
    q_uu = q[unknown][:, unknown].tocsc()
    rhs = -(q[unknown][:, kept] @ x[kept])
    solution = splu(q_uu).solve(np.asfortranarray(rhs))
    x[unknown] = solution
    return x[:, 0] if squeeze else x


def _check_rows(name: str, array: np.ndarray, rows: int, cols: int | None = None) -> np.ndarray:
    a = np.asarray(array)
    if a.ndim != 2 or a.shape[0] != rows or (cols is not None and a.shape[1] != cols):
        want = f"({rows}, {cols if cols is not None else 'J'})"
        raise InputError(f"{name} must have shape {want}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name} must be finite")
    return a


def transfer_skin_weights(
    weights: Float[np.ndarray, "Vs J"],
    source_vertices: Float[np.ndarray, "Vs 3"],
    source_faces: Int[np.ndarray, "Fs 3"],
    deformed_source: Float[np.ndarray, "Vs 3"],
    target_vertices: Float[np.ndarray, "Vt 3"],
    target_faces: Int[np.ndarray, "Ft 3"],
    face: Int[np.ndarray, " Vt"],
    bary: Float[np.ndarray, "Vt 3"],
    *,
    max_distance: float | None = None,
    max_normal_angle: float | None = None,
) -> tuple[Float[np.ndarray, "Vt J"], Bool[np.ndarray, " Vt"]]:
    """Carry per-vertex skin weights from the source to the target; inpaint where the map is unreliable.

    See the module docstring for the reliability test and the inpainting.

    Args:
        weights: (Vs, J) non-negative skin weights of the source vertices (rows are normalised).
        source_vertices: (Vs, 3) the rest source (frame 0 of the result); only its vertex count is
            used (the map names points of it by face and barycentric coordinates).
        source_faces: (Fs, 3) source triangles.
        deformed_source: (Vs, 3) the source flowed onto the target (``deformed_source.ply``).
        target_vertices: (Vt, 3) the target.
        target_faces: (Ft, 3) target triangles; when they wind the other way from the source's
            (:func:`~ncflow.geometry.mesh.orientation`), their normals are taken reversed, as the
            match reads such a target.
        face: (Vt,) ``map_tgt_to_src`` source face of every target vertex.
        bary: (Vt, 3) its barycentric coordinates.
        max_distance: largest reliable distance between a target vertex and its point on the flowed
            source, in the target's units (default 0.05 × the target's bounding-box diagonal).
        max_normal_angle: largest reliable angle between the normals, in degrees (default 30).

    Returns:
        ((Vt, J) weights, non-negative, rows summing to 1; (Vt,) True where the carried weights were
        kept, False where they were inpainted, or kept because the component had no reliable vertex).

    Raises:
        InputError: inconsistent shapes, non-finite or negative weights, a weight row summing to 0,
            bad thresholds.
    """
    sv = _check_rows("source vertices", source_vertices, np.shape(source_vertices)[0], 3)
    ns = sv.shape[0]
    w = _check_rows("source weights", weights, ns).astype(np.float64)
    if np.any(w < 0):
        raise InputError("source weights must be non-negative")
    total = w.sum(1, keepdims=True)
    if np.any(total <= 0):
        raise InputError(f"source vertex {int(np.argmax(total[:, 0] <= 0))} has no skin weight")
    w = w / total
    sf = np.asarray(source_faces, dtype=np.int64)
    ds = _check_rows("deformed source", deformed_source, ns, 3)
    tv = _check_rows("target vertices", target_vertices, np.shape(target_vertices)[0], 3).astype(np.float64)
    nt = tv.shape[0]
    tf = np.asarray(target_faces, dtype=np.int64)
    if tf.ndim != 2 or tf.shape[1] != 3 or (tf.size and (tf.min() < 0 or tf.max() >= nt)):
        raise InputError(f"target faces must be (F, 3) indices into {nt} vertices")
    if sf.ndim != 2 or sf.shape[1] != 3 or (sf.size and (sf.min() < 0 or sf.max() >= ns)):
        raise InputError(f"source faces must be (F, 3) indices into {ns} vertices")
    face = np.asarray(face, dtype=np.int64).reshape(-1)
    bary = _check_rows("map barycentric coordinates", bary, nt, 3)
    if face.shape != (nt,) or (nt and (face.min() < 0 or face.max() >= sf.shape[0])):
        raise InputError(f"map faces must be {nt} indices into {sf.shape[0]} source faces")
    diag = float(np.linalg.norm(np.ptp(tv, axis=0))) if nt else 0.0
    if max_distance is None:
        max_distance = DEFAULT_MAX_DISTANCE * diag
    if max_normal_angle is None:
        max_normal_angle = DEFAULT_MAX_NORMAL_ANGLE
    if not (math.isfinite(max_distance) and max_distance >= 0):
        raise InputError(f"max_distance must be a finite non-negative distance, got {max_distance}")
    if not (math.isfinite(max_normal_angle) and 0 <= max_normal_angle <= 180):
        raise InputError(f"max_normal_angle must be in [0, 180] degrees, got {max_normal_angle}")

    carried = surface_points(w, sf, face, bary)
    mapped = surface_points(ds, sf, face, bary)
    near = np.linalg.norm(tv - mapped, axis=1) <= max_distance
    if orientation(ds, sf) * orientation(tv, tf) < 0:  # wound the other way (the match turned it too)
        tf = tf[:, ::-1]
    n_target = vertex_normals(tv, tf)
    n_source = surface_points(vertex_normals(ds, sf), sf, face, bary)
    norm = np.linalg.norm(n_source, axis=1)
    cos = np.einsum("ij,ij->i", n_target, n_source) / np.where(norm > 0, norm, 1.0)
    facing = (norm > 0) & (np.linalg.norm(n_target, axis=1) > 0) & (cos >= math.cos(math.radians(max_normal_angle)))
    reliable = near & facing
    out = inpaint_weights(tv, tf, carried, reliable) if not reliable.all() else carried
    out = np.maximum(out, 0.0)
    total = out.sum(1, keepdims=True)
    empty = total[:, 0] <= 1e-12  # inpainted to all zeros (cannot happen with Σ = 1 data, kept safe)
    out[empty] = carried[empty]
    total[empty] = carried[empty].sum(1, keepdims=True)
    return out / total, reliable


def limit_influences(
    weights: Float[np.ndarray, "V J"], k: int = 4
) -> tuple[Int[np.ndarray, "V k"], Float[np.ndarray, "V k"]]:
    """The ``k`` largest influences of every vertex, renormalised to sum 1 (glTF's ``JOINTS_0`` / ``WEIGHTS_0``).

    Args:
        weights: (V, J) non-negative weights (every row with a positive sum).
        k: influences kept per vertex (fewer joints than k: zero-weight influences on joint 0 pad).

    Returns:
        ((V, k) joint indices, by decreasing weight; (V, k) weights summing to 1, zero for padding).
    """
    w = np.asarray(weights, dtype=np.float64)
    v, j = w.shape
    kk = min(k, j)
    top = np.argsort(-w, axis=1, kind="stable")[:, :kk]
    tw = np.take_along_axis(w, top, axis=1)
    total = tw.sum(1, keepdims=True)
    if np.any(total <= 0):
        raise InputError(f"vertex {int(np.argmax(total[:, 0] <= 0))} has no skin weight")
    tw = tw / total
    tw[tw <= 0] = 0.0
    joints = np.zeros((v, k), dtype=np.int64)
    out = np.zeros((v, k))
    joints[:, :kk] = np.where(tw > 0, top, 0)
    out[:, :kk] = tw
    return joints, out


# ----------------------------------------------------------------------------------------------
# The source's weights: from a glTF skin, or from the skeleton


def _joint_matrix(parents: np.ndarray) -> np.ndarray:
    """(B, J) 0/1 matrix sending bone b (ending at joint b + 1) to the joint that moves it, its parent."""
    n = parents.shape[0]
    s = np.zeros((n - 1, n))
    s[np.arange(n - 1), parents[1:]] = 1.0
    return s


def skeleton_weights(
    vertices: Float[np.ndarray, "V 3"],
    rest_positions: Float[np.ndarray, "J 3"],
    parents: Int[np.ndarray, " J"],
    width: float = DEFAULT_SKINNING_WIDTH,
    normals: Float[np.ndarray, "V C"] | None = None,
) -> Float[np.ndarray, "V J"]:
    """Per-joint skin weights of the skeleton-driven flow field at rest
    (:func:`ncflow.flow.bone_weights.skinning_weights`).

    Bone weights ``softmax_b(−d_b(x)/τ)`` (d_b the distance to bone b's segment, τ = ``width`` ×
    the median bone length), each bone's weight given to its parent joint (module docstring). With the
    vertices' outward ``normals``, the bones in front of the skin (and the islands' bones,
    :func:`ncflow.flow.islands.skin_islands`) are left out, as the field's weights of a match that saw
    the skin (``"surface"``, :func:`ncflow.flow.bone_weights.surface_skinning_weights`).

    Args:
        vertices: (V, 3) the rest source.
        rest_positions: (J, 3) the skeleton at rest, topological order.
        parents: (J,) parents (−1 for the root, ``parents[j] < j``).
        width: τ as a fraction of the median bone length.
        normals: (V, 3) the rest source's outward vertex normals, or (V, 3 + J − 1) with the bones each
            vertex may not take (:func:`ncflow.flow.islands.surface_skin`), or None (the plain weights).

    Returns:
        (V, J) weights, rows summing to 1; joints that start no bone (leaves) get 0.
    """
    p = np.asarray(rest_positions, dtype=np.float64)
    par = np.asarray(parents, dtype=np.int64)
    x = np.asarray(vertices, dtype=np.float64)
    if p.shape[0] == 1:
        return np.ones((x.shape[0], 1))
    lengths = np.linalg.norm(p[1:] - p[par[1:]], axis=1)
    scale = float(np.median(lengths))
    if not (scale > 0 and math.isfinite(scale)) or not (width > 0 and math.isfinite(width)):
        raise InputError("the skeleton's median bone length and the skinning width must be positive")
    centre = p.mean(0)  # float32 inside JAX: work in coordinates of unit median bone length
    xs, ps = (x - centre) / scale, (p - centre) / scale
    bones = jnp.asarray(ps[par[1:]], jnp.float32), jnp.asarray(ps[1:], jnp.float32)
    if normals is None:
        bone_w = skinning_weights(jnp.asarray(xs, jnp.float32), *bones, float(width))
    else:
        n = jnp.asarray(normals, jnp.float32)
        bone_w = surface_skinning_weights(jnp.asarray(xs, jnp.float32), n, *bones, float(width))
    bone_w = np.asarray(bone_w, dtype=np.float64)
    w = bone_w @ _joint_matrix(par)
    return w / w.sum(1, keepdims=True)


def gltf_skin_weights(
    skin: GltfSkin,
    source_vertices: Float[np.ndarray, "V 3"],
    names: list[str] | tuple[str, ...],
) -> Float[np.ndarray, "V J"]:
    """Per-joint weights of the result's source read from the source's glTF skin.

    The skin's mesh, in its bind pose and welded as :func:`ncflow.io.meshes.load_mesh` welds a GLB
    (the way ``ncflow match`` read the source), must be the result's source: same vertex count and
    positions equal to frame 0 within 1e-5 of the bounding-box diagonal (directly, or after the
    mesh node's world transform, which a mesh loader applies). Skin joints are matched to the
    skeleton's joints by name; a skin joint the skeleton does not name may only carry weight if it
    sits on its nearest named ancestor (a zero-length bone, merged into that ancestor when the
    skeleton was read from the glTF), and then its weight goes there.

    Args:
        skin: the skin (read with geometry, :func:`~ncflow.io.gltf.skins.load_gltf_skin`).
        source_vertices: (V, 3) the result's rest source (frame 0).
        names: J joint names of the result's skeleton.

    Returns:
        (V, J) weights, rows summing to 1.

    Raises:
        InputError: one line naming the skin's file: a different mesh, joints that cannot be matched.
    """
    path = skin.path
    src = np.asarray(source_vertices, dtype=np.float64)
    if skin.positions is None:
        raise InputError("no skinned mesh in the skin", path)
    bind = skin.pose(weld=True)
    if bind.vertices.shape[0] != src.shape[0]:
        raise InputError(
            f"the skinned mesh has {bind.vertices.shape[0]} vertices (seams welded) but the result's source has "
            f"{src.shape[0]}: not the source of this result",
            path,
        )
    tol = 1e-5 * max(float(np.linalg.norm(np.ptp(src, axis=0))), 1e-300)
    gap = float(np.max(np.linalg.norm(bind.vertices - src, axis=1)))
    if gap > tol and skin.mesh_node is not None:
        world = skin.world_transforms(skin.rest_local)[skin.mesh_node]
        moved = bind.vertices @ world[:3, :3].T + world[:3, 3]
        gap = min(gap, float(np.max(np.linalg.norm(moved - src, axis=1))))
    if gap > tol:
        raise InputError(
            f"the skinned mesh's bind pose is not the result's source (vertices up to {gap:.3g} apart, "
            f"tolerance {tol:.3g})",
            path,
        )
    fi = bind.file_index
    dense = dense_weights(skin.joints[fi], skin.weights[fi], skin.n_joints)  # (V, Js)
    if names is None or not len(names):
        raise InputError("the result's skeleton has no joint names to match the skin's joints with", path)
    index = {str(n): j for j, n in enumerate(names)}
    joint_pos = skin.joint_world()[:, :3, 3]
    size = float(np.linalg.norm(np.ptp(joint_pos, axis=0))) or 1.0
    to_result = np.full(skin.n_joints, -1)
    unknown = []
    carries = dense.sum(0) > 0
    for s in range(skin.n_joints):
        if skin.names[s] in index:
            to_result[s] = index[skin.names[s]]
            continue
        a = int(skin.parents[s])
        while a >= 0 and skin.names[a] not in index:
            a = int(skin.parents[a])
        stacked = a >= 0 and np.linalg.norm(joint_pos[s] - joint_pos[a]) <= 1e-6 * size
        if stacked:
            to_result[s] = index[skin.names[a]]
        elif carries[s]:
            unknown.append(skin.names[s])
    if not np.any(to_result >= 0):
        raise InputError(
            f"none of the skin's {skin.n_joints} joint names is a joint of the result's skeleton "
            f"(skin: {', '.join(skin.names[:4])}…; skeleton: {', '.join(map(str, names[:4]))}…)",
            path,
        )
    if unknown:
        shown = ", ".join(repr(n) for n in unknown[:5]) + (f" and {len(unknown) - 5} more" if len(unknown) > 5 else "")
        raise InputError(f"skin joints with weights are not joints of the result's skeleton: {shown}", path)
    m = np.zeros((skin.n_joints, len(names)))
    ok = to_result >= 0
    m[np.flatnonzero(ok), to_result[ok]] = 1.0
    w = dense @ m
    total = w.sum(1, keepdims=True)
    if np.any(total <= 0):
        raise InputError(f"source vertex {int(np.argmax(total[:, 0] <= 0))} has no weight on a matched joint", path)
    return w / total
