"""Single-view scans with exact ground truth: the part of a mesh one depth camera sees.

A scanner looking along a direction d records the surface nearest to it along each ray: the far side
and whatever a nearer part hides (an arm in front of the chest) are missing, and the border of what it
saw is a hole's rim. :func:`single_view` keeps the faces that face the camera and are not hidden, by a
z-buffer of dense surface samples on a pixel grid across d (an orthographic camera; trimesh's ray
casting does the same one ray at a time, ~100× slower here without Embree). :func:`scanned_sequence`
makes every frame of a :class:`~ncflow.synthetic.sequences.Sequence` such a view, the camera fixed while
the body turns in front of it, the ground truth restricted to the vertices kept.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from jaxtyping import Bool, Float, Int

from ncflow.errors import InputError
from ncflow.geometry.mesh import Mesh
from ncflow.io.ground_truth import GroundTruth

__all__ = ["scanned_sequence", "single_view"]

MAX_LATTICE = 16
"""At most this many sample intervals along a face's edge in the z-buffer (faces of over 16 pixels across)."""


def _lattice(m: int) -> np.ndarray:
    """(S, 3) barycentric coordinates (i, j, m − i − j) / m of a triangle's lattice, corners pulled a little in."""
    ij = np.array([(i, j) for i in range(m + 1) for j in range(m + 1 - i)], float)
    bary = np.column_stack([ij, m - ij.sum(1)]) / m
    return 0.98 * bary + 0.02 / 3.0


def _frame(direction: np.ndarray) -> np.ndarray:
    """(3, 3) rows u, w, d: an orthonormal frame whose third axis is the unit ``direction``."""
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    helper = np.eye(3)[int(np.argmin(np.abs(d)))]
    u = np.cross(d, helper)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(d, u), d])


def single_view(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    direction: Float[np.ndarray, " 3"],
    pixels: int = 160,
) -> Bool[np.ndarray, " F"]:
    """Which faces a camera looking along ``direction`` sees (orthographic, ``pixels`` across the mesh's
    largest extent seen from it): every face is sampled on a barycentric lattice of at most a pixel's
    spacing (its longest edges up to :data:`MAX_LATTICE` pixels), the samples' nearest depth kept per
    pixel, and a face is seen when it faces the camera and one of its samples lies within two pixels of
    that depth.
    """
    v, f = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    if f.size == 0:
        raise InputError("a single view needs faces")
    frame = _frame(direction)
    local = v @ frame.T
    lo = local[:, :2].min(0)
    h = float(np.ptp(local[:, :2], axis=0).max()) / pixels
    edges = np.linalg.norm(local[f[:, [1, 2, 0]], :2] - local[f, :2], axis=-1).max(1)
    m = int(np.clip(np.ceil(np.percentile(edges, 99) / h), 1, MAX_LATTICE))
    pts = np.einsum("sk,fkc->fsc", _lattice(m), local[f])  # (F, S, 3)
    ij = np.floor((pts[..., :2] - lo) / h).astype(np.int64)
    key = ij[..., 0] * (pixels + 2) + ij[..., 1]
    depth = np.full((pixels + 2) ** 2, np.inf)
    np.minimum.at(depth, key.ravel(), pts[..., 2].ravel())
    near = pts[..., 2] <= depth[key] + 2.0 * h
    corners = v[f]
    facing = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]) @ frame[2] < 0.0
    return facing & near.any(axis=1)


def _kept(mesh: Mesh, gt: GroundTruth, keep_faces: np.ndarray, stem: str) -> tuple[Mesh, GroundTruth]:
    """The sub-mesh of the faces kept (its vertices renumbered in order) and the ground truth of its vertices."""
    faces = mesh.faces[keep_faces]
    used = np.unique(faces)
    renumber = np.full(mesh.n_vertices, -1, np.int64)
    renumber[used] = np.arange(used.size)
    part = Mesh(mesh.vertices[used], renumber[faces], stem, np.arange(used.size))
    truth = dict(zip(gt.target_index.tolist(), range(gt.target_index.size)))
    rows = np.array([truth.get(int(i), -1) for i in used])
    has = rows >= 0
    out = GroundTruth(gt.face[rows[has]], gt.bary[rows[has]], np.flatnonzero(has), int(used.size), stem)
    return part, out


def scanned_sequence(seq, seed: int = 0, pixels: int = 160, min_share: float = 0.2):
    """``seq`` with every frame replaced by what one camera sees of it (:func:`single_view`): the camera's
    direction drawn from ``seed`` across the first frame's longest axis (a scanner in front of the body,
    not above its head), fixed for the whole sequence. A frame of which less than ``min_share`` of the
    faces would be seen is refused (InputError). ``info["scan"]`` records the direction and the share
    of faces kept per frame.
    """
    first = np.asarray(seq.frames[0].vertices)
    axes = np.linalg.svd(first - first.mean(0), full_matrices=False)[2]
    rng = np.random.default_rng(seed)
    angle = rng.uniform(0.0, 2.0 * np.pi)
    direction = np.cos(angle) * axes[1] + np.sin(angle) * axes[2]
    frames, truths, shares = [], [], []
    for stem, mesh, gt in zip(seq.stems, seq.frames, seq.ground_truth):
        keep = single_view(mesh.vertices, mesh.faces, direction, pixels)
        if keep.mean() < min_share:
            raise InputError(f"frame {stem}: the camera sees {keep.mean():.0%} of its faces")
        part, truth = _kept(mesh, gt, keep, stem)
        frames.append(part)
        truths.append(truth)
        shares.append(float(keep.mean()))
    info = dict(seq.info, scan={"direction": direction.tolist(), "pixels": int(pixels), "face_share": shares})
    return dataclasses.replace(seq, name=seq.name, frames=tuple(frames), ground_truth=tuple(truths), info=info)
