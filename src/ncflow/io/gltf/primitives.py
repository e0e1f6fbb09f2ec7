"""Decoding a glTF mesh's primitives: triangle lists, strips and fans, and the skinned attributes
(``POSITION``, every ``JOINTS_n`` / ``WEIGHTS_n`` set present, ``indices``) of all primitives of a mesh
concatenated, each accessor read through the document's checked reader.
"""

from __future__ import annotations

import numpy as np

from ncflow.io.gltf.document import DocumentReader, get_field

TRIANGLE_MODES = {4: "triangles", 5: "strip", 6: "fan"}


def triangles(indices: np.ndarray, mode: int) -> np.ndarray:
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


def read_skinned_primitives(doc, reader: DocumentReader, mesh_index: int, n_joints: int):
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
        if mode not in TRIANGLE_MODES:
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
        faces = triangles(idx.astype(np.int64), mode)
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
