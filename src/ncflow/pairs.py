"""Source/target pairs with exact ground truth: procedural characters, MANO hands, glTF animations.

A :class:`Pair` holds a source mesh, a target mesh, the source skeleton (joints in the source's
pose) and, for every target vertex, the source surface point it corresponds to (a
:class:`~ncflow.evaluate.GroundTruth`: source face + barycentric coordinates).

Exact ground truth by construction
----------------------------------
Both shapes are posed copies of one rest surface S (a triangle mesh). Posing moves the vertices
of S; a point of S given as (face, barycentrics) is moved to the same barycentric combination of
the posed corners. So:

* *same connectivity* (``retriangulate=False``): the target is S posed by pose B, vertex i ↔
  vertex i (identity ground truth, stored as one-hot barycentrics);
* *retriangulated* (``retriangulate=True``): a different triangulation T of the same shape is
  made (a marching-cubes mesh at another resolution and grid offset — of the character's implicit
  function, or of the signed distance to S for meshes without one), its vertices are projected
  onto S (:func:`ncflow.evaluate.closest_points_on_surface` → face, barycentrics), and the target
  vertices are ``Σ_k bary_k · posed_B(S vertex_k)``. Every target vertex is then exactly the image
  of its ground-truth source point under the generating deformation, up to float64 rounding
  (~1e-16), while the target has its own vertex count and connectivity.

The source is S in the rest pose or posed by pose A (same connectivity as S).
"""

from __future__ import annotations

import csv
import dataclasses
import os
import pickle
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ncflow.characters import (
    Character,
    _winding_numbers,
    check_closed_surface,
    delaunay_flip,
    make_character,
    pose_character,
    random_pose,
    relax_on_surface,
)
from ncflow.errors import InputError
from ncflow.evaluate import (
    GroundTruth,
    closest_points_on_surface,
    ground_truth_from_vertex_map,
    save_ground_truth,
    surface_points,
)
from ncflow.mesh import Mesh, close_boundary
from ncflow.skeleton import Skeleton, save_skeleton

__all__ = [
    "Pair",
    "make_pair",
    "retriangulate_mesh",
    "ManoModel",
    "MANO_TIP_VERTICES",
    "MANO_JOINT_NAMES",
    "load_mano",
    "mano_finger_pose",
    "mano_forward",
    "mano_pair",
    "gltf_pair",
    "write_pair",
    "write_pairs",
    "PAIRS_CSV_COLUMNS",
]

PAIRS_CSV_COLUMNS = ("name", "source", "target", "skeleton", "gt", "gt_format", "dataset")


@dataclasses.dataclass(frozen=True, eq=False)
class Pair:
    """A matching problem with exact ground truth.

    Attributes:
        name: a label (also the default folder name when written).
        source: the source mesh.
        target: the target mesh (its own connectivity when retriangulated).
        skeleton: the source skeleton, joints in the source's pose.
        ground_truth: for every target vertex, the source face and barycentric coordinates of
            the point it corresponds to.
        dataset: where it comes from (character kind, ``"mano"``, or the glTF file's stem).
        target_joints: (J, 3) the skeleton's joints in the target pose (internal joint order), or None.
        info: how it was made (seeds, poses, resolutions, vertex counts, …).
    """

    name: str
    source: Mesh
    target: Mesh
    skeleton: Skeleton
    ground_truth: GroundTruth
    dataset: str
    target_joints: Float[np.ndarray, "J 3"] | None = None
    info: dict = dataclasses.field(default_factory=dict)

    @property
    def target_skeleton(self) -> Skeleton | None:
        """The skeleton with its joints in the target pose (None when unknown)."""
        return None if self.target_joints is None else self.skeleton.with_positions(self.target_joints)

    def ground_truth_points(self, source_vertices: Float[np.ndarray, "V 3"] | None = None) -> Float[np.ndarray, "n 3"]:
        """The ground-truth points Σ bary · vertices of the source (or of other vertex positions
        with the source's connectivity), one per target vertex."""
        v = self.source.vertices if source_vertices is None else source_vertices
        return surface_points(v, self.source.faces, self.ground_truth.face, self.ground_truth.bary)


def _identity_ground_truth(source: Mesh, name: str) -> GroundTruth:
    return ground_truth_from_vertex_map(np.arange(source.n_vertices), source, source.n_vertices, name=name)


def _ground_truth(face: np.ndarray, bary: np.ndarray, name: str) -> GroundTruth:
    n = face.shape[0]
    return GroundTruth(
        face=np.asarray(face, dtype=np.int64),
        bary=np.asarray(bary, dtype=np.float64),
        target_index=np.arange(n),
        n_target=n,
        name=name,
    )


def _flipped_faces(before: np.ndarray, after: np.ndarray, faces: np.ndarray) -> int:
    """Faces whose normal turned by more than 90° between two placements of the same mesh."""

    def normals(v):
        t = v[faces]
        return np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])

    return int(np.sum(np.einsum("ij,ij->i", normals(before), normals(after)) <= 0))


def _project(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray):
    """(distance, face, bary) of the closest points, barycentrics clipped to the face and renormalised."""
    dist, face, bary = closest_points_on_surface(points, vertices, faces)
    bary = np.clip(bary, 0.0, None)
    bary /= bary.sum(axis=1, keepdims=True)
    return dist, face, bary


# ----------------------------------------------------------------------------------------------
# Procedural characters


def _pair_seed(seed: int, which: int) -> list[int]:
    return [int(seed), 0x5EED, int(which)]


def make_pair(
    kind: str,
    seed: int = 0,
    *,
    retriangulate: bool = True,
    resolution: float | None = None,
    target_resolution: float | None = None,
    source_pose: str = "rest",
    skinning: str = "dqs",
    large_angle: tuple[float, float] = (60.0, 100.0),
    character: Character | None = None,
) -> Pair:
    """A procedural character in two poses, with exact ground truth.

    Args:
        kind: ``"humanoid"``, ``"hand"`` or ``"quadruped"``.
        seed: proportions and poses are drawn from it (deterministic).
        retriangulate: give the target its own triangulation (marching cubes of the same implicit
            surface at ``target_resolution``, on a grid shifted by a seeded sub-cell offset,
            projected onto the source surface); otherwise the target has the source's vertices and
            faces and the ground truth is the identity.
        resolution: the source's marching-cubes resolution (default: the kind's default).
        target_resolution: the target's resolution (default 0.8 × the source's: a coarser
            target); ignored without ``retriangulate``.
        source_pose: ``"rest"`` or ``"random"`` (a second random pose A, with small rotations only
            and the identity at the target's large joint).
        skinning: ``"dqs"`` or ``"lbs"`` (see :func:`ncflow.characters.pose_character`).
        large_angle: range (degrees) of the target pose's large joint flexion.
        character: reuse an already built character (must match ``kind`` and ``seed``).

    Returns:
        :class:`Pair`; ``info`` records the large joint and angle, the poses and vertex counts.
    """
    if source_pose not in ("rest", "random"):
        raise InputError(f"source_pose must be 'rest' or 'random', got {source_pose!r}")
    ch = make_character(kind, seed, resolution) if character is None else character
    if ch.kind != kind or ch.seed != int(seed):
        raise InputError(f"the given character is a {ch.kind} of seed {ch.seed}, not a {kind} of seed {seed}")
    name = f"{kind}_{int(seed):03d}"
    pose_b, info_b = random_pose(ch, _pair_seed(seed, 2), large_angle=large_angle)
    posed_b = pose_character(ch, pose_b, skinning=skinning)
    if source_pose == "random":
        rest_joints = [info_b["large_joint"]] if info_b["large_joint"] else []
        pose_a, _ = random_pose(ch, _pair_seed(seed, 1), large_joint=None, rest_joints=rest_joints)
        posed_a = pose_character(ch, pose_a, skinning=skinning)
        src_v, src_j = posed_a.vertices, posed_a.joints
    else:
        pose_a = None
        src_v, src_j = ch.vertices, ch.skeleton.positions
    source = Mesh(vertices=src_v, faces=ch.faces, name=f"{name}/source", file_index=np.arange(src_v.shape[0]))
    skeleton = ch.skeleton.with_positions(src_j)
    info = {
        "kind": kind,
        "seed": int(seed),
        "skinning": skinning,
        "source_pose": source_pose,
        "resolution": ch.resolution,
        "retriangulated": bool(retriangulate),
        "large_joint": info_b["large_joint"],
        "large_angle_deg": info_b["large_angle_deg"],
        "pose_a": pose_a,
        "pose_b": pose_b,
    }
    if retriangulate:
        t_res = 0.8 * ch.resolution if target_resolution is None else float(target_resolution)
        offset = np.random.default_rng(_pair_seed(seed, 3)).uniform(0.0, 1.0, size=3)
        tv, tf = ch.remesh(t_res, offset=offset)
        _, face, bary = _project(tv, ch.vertices, ch.faces)
        rest_points = surface_points(ch.vertices, ch.faces, face, bary)
        target_v = surface_points(posed_b.vertices, ch.faces, face, bary)
        gt = _ground_truth(face, bary, f"{name}/gt")
        info.update(
            target_resolution=t_res,
            target_projection_flips=_flipped_faces(tv, rest_points, tf),
        )
    else:
        tf = ch.faces
        target_v = posed_b.vertices
        gt = _identity_ground_truth(source, f"{name}/gt")
    target = Mesh(
        vertices=target_v,
        faces=np.asarray(tf, dtype=np.int64),
        name=f"{name}/target",
        file_index=np.arange(target_v.shape[0]),
    )
    info.update(n_source=source.n_vertices, n_target=target.n_vertices)
    return Pair(
        name=name,
        source=source,
        target=target,
        skeleton=skeleton,
        ground_truth=gt,
        dataset=kind,
        target_joints=posed_b.joints,
        info=info,
    )


# ----------------------------------------------------------------------------------------------
# Retriangulating an arbitrary surface


def _surface_samples(v: np.ndarray, f: np.ndarray, spacing: float) -> np.ndarray:
    """Points on every triangle on a barycentric lattice whose step is at most ``spacing``."""
    tri = v[f]
    longest = np.max(np.linalg.norm(tri[:, [1, 2, 0]] - tri, axis=2), axis=1)
    m = np.maximum(1, np.ceil(longest / spacing).astype(np.int64))
    out = [v]
    for k in np.unique(m):
        if k == 1:
            continue
        ii, jj = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
        keep = ii + jj <= k
        b = np.stack([ii[keep], jj[keep], k - ii[keep] - jj[keep]], axis=1) / k
        out.append(np.einsum("sk,tkd->tsd", b, tri[m == k]).reshape(-1, 3))
    return np.concatenate(out)


def _pseudo_normal_sign(
    points: np.ndarray, v: np.ndarray, f: np.ndarray, face: np.ndarray, bary: np.ndarray, tol: float = 1e-9
) -> np.ndarray:
    """+1 outside / -1 inside a closed, consistently wound mesh, from the angle-weighted pseudo-normal
    of the closest feature (face, edge or vertex; Bærentzen & Aanæs 2005)."""
    from ncflow.mesh import mesh_topology

    tri = v[f]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
    # angle-weighted vertex normals
    vn = np.zeros_like(v)
    for k in range(3):
        a, b, c = tri[:, k], tri[:, (k + 1) % 3], tri[:, (k + 2) % 3]
        e1, e2 = b - a, c - a
        cosang = np.einsum("ij,ij->i", e1, e2) / np.maximum(
            np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1), 1e-300
        )
        np.add.at(vn, f[:, k], np.arccos(np.clip(cosang, -1.0, 1.0))[:, None] * fn)
    topo = mesh_topology(f, v.shape[0])
    en = fn[topo.edge_faces[:, 0]] + np.where(
        topo.edge_faces[:, 1:2] >= 0, fn[np.maximum(topo.edge_faces[:, 1], 0)], 0.0
    )
    zero = bary <= tol
    nz = zero.sum(axis=1)
    normal = fn[face].copy()
    at_vertex = nz == 2
    if np.any(at_vertex):
        corner = np.argmax(~zero[at_vertex], axis=1)
        normal[at_vertex] = vn[f[face[at_vertex], corner]]
    on_edge = nz == 1
    if np.any(on_edge):
        opp = np.argmax(zero[on_edge], axis=1)
        fe = f[face[on_edge]]
        a = fe[np.arange(fe.shape[0]), (opp + 1) % 3]
        b = fe[np.arange(fe.shape[0]), (opp + 2) % 3]
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        key = topo.edges[:, 0] * v.shape[0] + topo.edges[:, 1]
        idx = np.searchsorted(key, lo * v.shape[0] + hi)
        normal[on_edge] = en[idx]
    foot = surface_points(v, f, face, bary)
    return np.where(np.einsum("ij,ij->i", points - foot, normal) < 0, -1.0, 1.0)


def _signed_distance_grid(v: np.ndarray, f: np.ndarray, origin: np.ndarray, shape: tuple, h: float) -> np.ndarray:
    """Signed distance (negative inside) to a closed mesh on a grid, exact within a band of ~2 cells
    (sign from pseudo-normals), clamped to ±band outside it (one sign per connected region of
    the grid outside the band, by winding number)."""
    from scipy import ndimage
    from scipy.spatial import cKDTree

    axes = [origin[i] + h * np.arange(shape[i]) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    spacing = 0.5 * h
    samples = _surface_samples(v, f, spacing)
    band = 2.0 * h
    near, _ = cKDTree(samples).query(grid, distance_upper_bound=band + spacing)
    in_band = np.isfinite(near)
    values = np.full(grid.shape[0], band)
    idx = np.flatnonzero(in_band)
    dist, face, bary = closest_points_on_surface(grid[idx], v, f)
    values[idx] = _pseudo_normal_sign(grid[idx], v, f, face, bary) * dist
    labels, n = ndimage.label(~in_band.reshape(shape))
    labels = labels.reshape(-1)
    if n:
        first = np.unique(labels, return_index=True)[1][1:]  # first grid point of regions 1..n
        sign = np.where(_winding_numbers(grid[first], v[f]) > 0.5, -1.0, 1.0)
        out = ~in_band
        values[out] = band * sign[labels[out] - 1]
    return values.reshape(shape)


def _euler_characteristic(v: np.ndarray, f: np.ndarray) -> int:
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    n_edges = np.unique(e[:, 0] * v.shape[0] + e[:, 1]).size
    return int(np.unique(f).size - n_edges + f.shape[0])


def _largest_component_faces(faces: np.ndarray, nv: int) -> np.ndarray:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if faces.shape[0] == 0:
        return faces
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    g = coo_matrix((np.ones(e.shape[0]), (e[:, 0], e[:, 1])), shape=(nv, nv))
    _, label = connected_components(g, directed=False)
    big = np.argmax(np.bincount(label[faces[:, 0]]))
    return faces[label[faces[:, 0]] == big]


def _remove_fins(faces: np.ndarray, nv: int) -> np.ndarray:
    """Repeatedly drop faces with two or more boundary edges and the faces at vertices where
    several boundary loops meet, until the open surface is a manifold with boundary."""
    for _ in range(50):
        e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
        key = e[:, 0] * nv + e[:, 1]
        _, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
        per_face = (cnt[inv] == 1).reshape(3, -1).sum(axis=0)
        boundary = e[cnt[inv] == 1]
        deg = np.bincount(boundary.reshape(-1), minlength=nv)
        pinch = deg > 2
        bad = (per_face >= 2) | np.any(pinch[faces], axis=1)
        if not np.any(bad):
            return faces
        faces = faces[~bad]
    return faces


def retriangulate_mesh(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    resolution: float = 48,
    *,
    seed: int = 0,
    relax_iterations: int = 8,
    max_attempts: int = 4,
) -> tuple[Float[np.ndarray, "W 3"], Int[np.ndarray, "G 3"], Int[np.ndarray, " W"], Float[np.ndarray, "W 3"]]:
    """A different triangulation of a surface, with every new vertex on the surface.

    The surface is closed first if it has holes (:func:`ncflow.mesh.close_boundary`); its signed
    distance is sampled on a grid of ``resolution`` cells along the largest extent (shifted by a
    seeded sub-cell offset), marching cubes extracts a closed mesh (of the input's topology: if
    it is not one closed manifold component with the input's Euler characteristic, other seeded
    offsets are tried, ``max_attempts`` in all), which is relaxed
    tangentially with re-projection onto the surface. Every vertex is finally projected onto
    the surface (face + barycentrics). For an open input, the vertices that land on the caps
    added to close it are removed (with their faces, and any fins or pinched vertices left on
    the new boundary), so the result is open where the input is.

    Returns:
        (new vertices (W, 3) on the surface, new faces (G, 3), for every new vertex the face of
        the input it lies on (W,) and its barycentric coordinates (W, 3)).

    Raises:
        InputError: the grid is too coarse for the surface's thinnest part.
    """
    from skimage.measure import marching_cubes

    v0 = np.asarray(vertices, dtype=np.float64)
    f0 = np.asarray(faces, dtype=np.int64)
    v, f = close_boundary(v0, f0)
    n_open_faces = f0.shape[0]
    euler = _euler_characteristic(v, f)
    lo, hi = v.min(axis=0), v.max(axis=0)
    h = float(np.max(hi - lo)) / float(resolution)
    problem = ""
    for attempt in range(max_attempts):
        offset = np.random.default_rng([int(seed), 0xE7, attempt]).uniform(0.0, 1.0, size=3)
        origin = lo - 2.0 * h + offset * h
        shape = tuple(int(x) for x in np.ceil((hi + 2.0 * h - origin) / h).astype(np.int64) + 1)
        values = _signed_distance_grid(v, f, origin, shape, h)
        tiny = 1e-9 * h
        values = np.where(np.abs(values) < tiny, tiny, values)
        mv, mf, _, _ = marching_cubes(values, 0.0, spacing=(h, h, h), method="lewiner")
        mv = mv.astype(np.float64) + origin
        mf = mf.astype(np.int64)
        problem = check_closed_surface(mv, mf) or ""
        if not problem and _euler_characteristic(mv, mf) != euler:
            problem = f"Euler characteristic {_euler_characteristic(mv, mf)} instead of {euler}: parts fused"
        if not problem:
            break
    else:
        raise InputError(
            f"retriangulation at resolution {resolution:g} failed ({problem}, {max_attempts} grid offsets tried); "
            "the surface has parts or gaps thinner than the grid: use a higher target resolution"
        )
    tri0 = v[f]
    if float(np.einsum("ij,ij->i", mv[mf[:, 0]], np.cross(mv[mf[:, 1]], mv[mf[:, 2]])).sum()) < 0:
        mf = mf[:, ::-1].copy()
    normals = np.cross(tri0[:, 1] - tri0[:, 0], tri0[:, 2] - tri0[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)

    def project(p):
        _, face, bary = _project(p, v, f)
        return surface_points(v, f, face, bary), normals[face]

    half = max(1, relax_iterations // 2)
    mv = relax_on_surface(mv, mf, project, iterations=half)
    mf = delaunay_flip(mv, mf)
    mv = relax_on_surface(mv, mf, project, iterations=relax_iterations - half)
    mf = delaunay_flip(mv, mf)
    _, face, bary = _project(mv, v, f)
    keep_v = face < n_open_faces
    if not np.all(keep_v):
        mf = mf[np.all(keep_v[mf], axis=1)]
        mf = _remove_fins(mf, mv.shape[0])
        mf = _largest_component_faces(mf, mv.shape[0])
    used = np.unique(mf)
    remap = np.full(mv.shape[0], -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    face, bary = face[used], bary[used]
    return surface_points(v0, f0, face, bary), remap[mf], face, bary


def _retriangulated_target(
    rest_vertices: np.ndarray, faces: np.ndarray, posed_vertices: np.ndarray, resolution: float, seed: int, name: str
):
    """(posed target vertices, target faces, ground truth) from a retriangulation of the rest surface.

    The rest surface has the source's connectivity, so the (face, barycentric) coordinates found
    on it are coordinates on the source too, and the target vertices are the same barycentric
    combinations of the posed vertices.
    """
    _, tf, face, bary = retriangulate_mesh(rest_vertices, faces, resolution, seed=seed)
    target_v = surface_points(posed_vertices, faces, face, bary)
    return target_v, tf, _ground_truth(face, bary, name)


# ----------------------------------------------------------------------------------------------
# MANO

#: finger-tip vertices of the MANO right hand: index, middle, little, ring, thumb
MANO_TIP_VERTICES = (320, 443, 672, 555, 744)
MANO_JOINT_NAMES = (
    "wrist",
    "index1",
    "index2",
    "index3",
    "middle1",
    "middle2",
    "middle3",
    "little1",
    "little2",
    "little3",
    "ring1",
    "ring2",
    "ring3",
    "thumb1",
    "thumb2",
    "thumb3",
)
_TIP_NAMES = ("index_tip", "middle_tip", "little_tip", "ring_tip", "thumb_tip")


@dataclasses.dataclass(frozen=True, eq=False)
class ManoModel:
    """A MANO hand model as plain arrays (see ``load_mano``).

    Attributes:
        v_template: (V, 3) rest vertices.
        faces: (F, 3) triangles.
        weights: (V, J) skinning weights (J = 16).
        J_regressor: (J, V) joint regressor (dense).
        parents: (J,) parent joint, -1 for the root.
        posedirs: (V, 3, 9 (J − 1)) pose blend shapes driven by vec(R_j − I), j = 1..J−1.
        shapedirs: (V, 3, S) identity blend shapes, or None.
        hands_components: (45, 45) PCA basis of the finger pose (rows), or None.
        hands_mean: (45,) mean finger pose, or None.
        hands_coeffs: (N, 45) PCA coefficients of captured poses, or None.
        name: the file.
    """

    v_template: np.ndarray
    faces: np.ndarray
    weights: np.ndarray
    J_regressor: np.ndarray
    parents: np.ndarray
    posedirs: np.ndarray
    shapedirs: np.ndarray | None = None
    hands_components: np.ndarray | None = None
    hands_mean: np.ndarray | None = None
    hands_coeffs: np.ndarray | None = None
    name: str | None = None

    @property
    def n_joints(self) -> int:
        return int(self.parents.shape[0])


class _ChumpyStub:
    """Stands in for chumpy objects when unpickling a MANO ``.pkl`` (keeps their state)."""

    def __init__(self, *args, **kwargs):
        pass

    def __setstate__(self, state):
        if isinstance(state, dict):
            self.__dict__.update(state)
        else:
            self.__dict__["_state"] = state


class _ManoUnpickler(pickle.Unpickler):
    def find_class(self, module, name):
        if module.split(".")[0] == "chumpy":
            return _ChumpyStub
        if module.startswith("scipy.sparse"):
            import scipy.sparse

            return getattr(scipy.sparse, name)
        if module == "numpy.core" or module.startswith("numpy.core."):
            import importlib.util

            if importlib.util.find_spec("numpy._core") is not None:  # NumPy 2 (numpy.core is a deprecated alias)
                module = "numpy._core" + module[len("numpy.core") :]
        return super().find_class(module, name)


def _plain(value, key: str, path):
    """A NumPy array from an ndarray, a scipy sparse matrix or a chumpy stub."""
    if value is None:
        return None
    if isinstance(value, _ChumpyStub):
        for attr in ("x", "r", "_x"):
            if attr in value.__dict__:
                return _plain(value.__dict__[attr], key, path)
        raise InputError(f"MANO key {key!r} is a chumpy object without stored values", path)
    if hasattr(value, "toarray"):
        return np.asarray(value.toarray())
    return np.asarray(value)


def load_mano(path: str | os.PathLike) -> ManoModel:
    """Read a MANO model: a ``.npz`` of plain arrays (keys as in MANO: ``v_template``, ``faces`` or
    ``f``, ``weights``, ``J_regressor``, ``kintree_table``, ``posedirs``, optional ``shapedirs``,
    ``hands_components``, ``hands_mean``, ``hands_coeffs``) or the ``.pkl`` as MANO distributes it
    (a Python-2 pickle with chumpy objects and a sparse regressor; read without chumpy).

    Raises:
        InputError: unreadable file, missing keys or inconsistent shapes.
    """
    path = Path(path)
    if not path.exists():
        raise InputError("no such file", path)
    suffix = path.suffix.lower()
    try:
        if suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                data = {k: np.asarray(z[k]) for k in z.files}
        elif suffix == ".pkl":
            with open(path, "rb") as fh:
                data = _ManoUnpickler(fh, encoding="latin1").load()
            if not isinstance(data, dict):
                raise InputError("expected a pickled dict of MANO arrays", path)
        else:
            raise InputError(f"unsupported MANO model format {suffix or '(none)'!r}; use .npz or .pkl", path)
    except InputError:
        raise
    except Exception as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"cannot read MANO model ({msg})", path) from None
    if "faces" not in data and "f" in data:
        data["faces"] = data["f"]
    missing = [
        k for k in ("v_template", "faces", "weights", "J_regressor", "kintree_table", "posedirs") if k not in data
    ]
    if missing:
        raise InputError(f"MANO model lacks {', '.join(missing)}", path)
    arr = {
        k: _plain(data.get(k), k, path)
        for k in (
            "v_template",
            "faces",
            "weights",
            "J_regressor",
            "kintree_table",
            "posedirs",
            "shapedirs",
            "hands_components",
            "hands_mean",
            "hands_coeffs",
        )
    }
    v = arr["v_template"].astype(np.float64)
    nv = v.shape[0]
    kt = arr["kintree_table"].astype(np.int64)
    nj = kt.shape[1]
    parents = np.full(nj, -1, dtype=np.int64)
    id_to_col = {int(i): c for c, i in enumerate(kt[1])}
    for c in range(nj):
        p = int(kt[0, c])
        parents[c] = id_to_col.get(p, -1) if 0 <= p < 2**31 else -1
    model = ManoModel(
        v_template=v,
        faces=arr["faces"].astype(np.int64),
        weights=arr["weights"].astype(np.float64),
        J_regressor=arr["J_regressor"].astype(np.float64),
        parents=parents,
        posedirs=arr["posedirs"].astype(np.float64),
        shapedirs=None if arr["shapedirs"] is None else arr["shapedirs"].astype(np.float64),
        hands_components=None if arr["hands_components"] is None else arr["hands_components"].astype(np.float64),
        hands_mean=None if arr["hands_mean"] is None else arr["hands_mean"].astype(np.float64).reshape(-1),
        hands_coeffs=None if arr["hands_coeffs"] is None else arr["hands_coeffs"].astype(np.float64),
        name=str(path),
    )
    checks = [
        (model.faces.ndim == 2 and model.faces.shape[1] == 3, f"faces must be (F, 3), got {model.faces.shape}"),
        (model.weights.shape == (nv, nj), f"weights must be ({nv}, {nj}), got {model.weights.shape}"),
        (model.J_regressor.shape == (nj, nv), f"J_regressor must be ({nj}, {nv}), got {model.J_regressor.shape}"),
        (
            model.posedirs.shape == (nv, 3, 9 * (nj - 1)),
            f"posedirs must be ({nv}, 3, {9 * (nj - 1)}), got {model.posedirs.shape}",
        ),
        (int(np.sum(parents < 0)) == 1, "kintree_table must have exactly one root"),
    ]
    for ok, msg in checks:
        if not ok:
            raise InputError(f"MANO model: {msg}", path)
    return model


def _rodrigues(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) of rotation vectors (n, 3)."""
    rotvec = np.asarray(rotvec, dtype=np.float64).reshape(-1, 3)
    theta = np.linalg.norm(rotvec, axis=1)
    safe = np.where(theta > 1e-12, theta, 1.0)
    k = rotvec / safe[:, None]
    kx = np.zeros((rotvec.shape[0], 3, 3))
    kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    kx = kx - np.swapaxes(kx, 1, 2)
    s = np.where(theta > 1e-12, np.sin(theta), 0.0)[:, None, None]
    c = np.where(theta > 1e-12, 1.0 - np.cos(theta), 0.0)[:, None, None]
    return np.eye(3)[None] + s * kx + c * kx @ kx


def mano_finger_pose(
    model: ManoModel, pose: int | Sequence[float] | np.ndarray, *, space: str = "pca", flat_hand_mean: bool = False
) -> Float[np.ndarray, " 45"]:
    """The 15 × 3 axis-angle finger pose (flattened) of a pose argument.

    Args:
        pose: an int selects row ``pose`` of ``hands_coeffs``; an array is PCA coefficients
            (``space="pca"``; n ≤ 45 of them, using the first n components) or the 45 axis-angle
            values themselves (``space="axis_angle"``).
        space: ``"pca"`` or ``"axis_angle"``.
        flat_hand_mean: do not add ``hands_mean`` (PCA space only).

    Returns:
        θ = hands_mean + coeffs @ hands_components[:n] (PCA), or the given axis-angle values.
    """
    if space not in ("pca", "axis_angle"):
        raise InputError(f"pose space must be 'pca' or 'axis_angle', got {space!r}")
    n_f = 3 * (model.n_joints - 1)
    if isinstance(pose, (int, np.integer)) and not isinstance(pose, bool):
        if model.hands_coeffs is None:
            raise InputError(
                "the MANO model has no hands_coeffs: give pose coefficients instead of an index", model.name
            )
        if not 0 <= int(pose) < model.hands_coeffs.shape[0]:
            raise InputError(f"pose index {int(pose)} out of range [0, {model.hands_coeffs.shape[0] - 1}]", model.name)
        coeffs = model.hands_coeffs[int(pose)]
        space = "pca"
    else:
        coeffs = np.asarray(pose, dtype=np.float64).reshape(-1)
        if not np.all(np.isfinite(coeffs)):
            raise InputError("pose values must be finite")
    if space == "axis_angle":
        if coeffs.size != n_f:
            raise InputError(f"an axis-angle finger pose needs {n_f} values, got {coeffs.size}")
        return coeffs.copy()
    if model.hands_components is None:
        raise InputError(
            "the MANO model has no hands_components: give an axis-angle pose (space='axis_angle')", model.name
        )
    n = coeffs.size
    if n > model.hands_components.shape[0]:
        raise InputError(f"at most {model.hands_components.shape[0]} PCA coefficients, got {n}")
    theta = coeffs @ model.hands_components[:n]
    if not flat_hand_mean and model.hands_mean is not None:
        theta = theta + model.hands_mean
    return theta


def mano_forward(
    model: ManoModel,
    finger_pose: Float[np.ndarray, " 45"],
    global_rotation: Float[np.ndarray, " 3"] | None = None,
    betas: Float[np.ndarray, " S"] | None = None,
    translation: Float[np.ndarray, " 3"] | None = None,
) -> tuple[Float[np.ndarray, "V 3"], Float[np.ndarray, "J 3"]]:
    """Pose MANO: pose blend shapes, forward kinematics down the kinematic tree, linear blend skinning.

    v_shaped = v_template + shapedirs · betas; J = J_regressor v_shaped; R_j = Rodrigues(θ_j) with
    θ_0 the global rotation; v_posed = v_shaped + posedirs · vec(R_1..J−1 − I); G_0 = [R_0 | J_0],
    G_j = G_parent [R_j | J_j − J_parent]; vertex = Σ_j w_j G_j [I | −J_j] v_posed (+ translation).

    Returns:
        (posed vertices (V, 3), posed joint positions (J, 3)).
    """
    nj = model.n_joints
    v = model.v_template
    if betas is not None:
        if model.shapedirs is None:
            raise InputError("the MANO model has no shapedirs: betas cannot be used", model.name)
        b = np.asarray(betas, dtype=np.float64).reshape(-1)
        v = v + model.shapedirs[:, :, : b.size] @ b
    joints = model.J_regressor @ v
    fp = np.asarray(finger_pose, dtype=np.float64).reshape(-1)
    if fp.size != 3 * (nj - 1):
        raise InputError(f"finger pose needs {3 * (nj - 1)} axis-angle values, got {fp.size}")
    g = np.zeros(3) if global_rotation is None else np.asarray(global_rotation, dtype=np.float64).reshape(3)
    rot = _rodrigues(np.concatenate([g, fp]).reshape(nj, 3))
    pose_map = (rot[1:] - np.eye(3)).reshape(-1)
    v_posed = v + model.posedirs @ pose_map
    world_r = np.empty((nj, 3, 3))
    world_t = np.empty((nj, 3))
    for j in range(nj):  # MANO lists parents before children
        p = model.parents[j]
        if p < 0:
            world_r[j], world_t[j] = rot[j], joints[j]
        else:
            world_r[j] = world_r[p] @ rot[j]
            world_t[j] = world_r[p] @ (joints[j] - joints[p]) + world_t[p]
    shift = world_t - np.einsum("jab,jb->ja", world_r, joints)
    m = np.einsum("vj,jab->vab", model.weights, world_r)
    verts = np.einsum("vab,vb->va", m, v_posed) + model.weights @ shift
    if translation is not None:
        t = np.asarray(translation, dtype=np.float64).reshape(3)
        verts, world_t = verts + t, world_t + t
    return verts, world_t


def _mano_skeleton(model: ManoModel, joints: np.ndarray, verts: np.ndarray, tips: Sequence[int], name: str) -> Skeleton:
    nj = model.n_joints
    tips = [int(t) for t in tips]
    if any(not 0 <= t < verts.shape[0] for t in tips):
        raise InputError(f"tip vertices must be in [0, {verts.shape[0] - 1}], got {tips}")
    names = list(MANO_JOINT_NAMES) if nj == 16 else [f"joint{j}" for j in range(nj)]
    if len(tips) == 5 and nj == 16:
        tip_parents = [3, 6, 9, 12, 15]
        names += list(_TIP_NAMES)
    else:  # one tip per leaf joint, in joint order
        leaves = [j for j in range(nj) if j not in set(model.parents.tolist())]
        if len(tips) != len(leaves):
            raise InputError(f"need one tip vertex per finger ({len(leaves)}), got {len(tips)}")
        tip_parents = leaves
        names += [f"tip{k}" for k in range(len(tips))]
    positions = np.concatenate([joints, verts[tips]])
    parents = np.concatenate([model.parents, np.asarray(tip_parents, dtype=np.int64)])
    return Skeleton.from_arrays(positions, parents, names, name=name)


def mano_pair(
    model_path: str | os.PathLike | ManoModel,
    pose_a: int | Sequence[float] | np.ndarray,
    pose_b: int | Sequence[float] | np.ndarray,
    *,
    global_rotation_a: Sequence[float] | None = None,
    global_rotation_b: Sequence[float] | None = None,
    betas: Sequence[float] | None = None,
    pose_space: str = "pca",
    flat_hand_mean: bool = False,
    tip_vertices: Sequence[int] = MANO_TIP_VERTICES,
    skeleton_joints: str = "fk",
    retriangulate: bool = False,
    target_resolution: float | None = None,
    seed: int = 0,
    name: str | None = None,
) -> Pair:
    """A MANO hand in two poses (source = pose A, target = pose B) with exact ground truth.

    Args:
        model_path: the user's MANO model (``.npz`` or ``.pkl``, see :func:`load_mano`) or a loaded model.
        pose_a, pose_b: an index into ``hands_coeffs`` or explicit coefficients (see
            :func:`mano_finger_pose`).
        global_rotation_a, global_rotation_b: axis-angle rotation of the wrist (default none).
        betas: identity shape coefficients (default: the template).
        pose_space, flat_hand_mean: how explicit poses are read (:func:`mano_finger_pose`).
        tip_vertices: one vertex per finger for the tip bones (index, middle, little, ring, thumb).
        skeleton_joints: ``"fk"`` (default): the 16 joints moved by forward kinematics, i.e. the
            centres the generating rigid transforms turn about; ``"regressor"``: J_regressor
            applied to the posed vertices (the convention of registered MANO datasets; in bent
            poses it is off the kinematic joints by a few millimetres). Target joints follow the
            same convention.
        retriangulate: give the target its own triangulation (:func:`retriangulate_mesh` of the
            rest surface — flat hand, no finger pose — at ``target_resolution`` cells along its
            largest extent, default 36, about 1.9k vertices for MANO's right hand; mapped to the
            posed target by its barycentric coordinates); default: same vertices, identity
            ground truth.
        seed: seed of the retriangulation grid offset.
        name: pair name (default ``mano_A_B``).

    The skeleton is the 16 posed MANO joints (see ``skeleton_joints``; in the rest pose both
    conventions are J_regressor · vertices) plus one tip bone per finger ending at the tip
    vertex, in pose A.
    """
    if skeleton_joints not in ("fk", "regressor"):
        raise InputError(f"skeleton_joints must be 'fk' or 'regressor', got {skeleton_joints!r}")
    model = model_path if isinstance(model_path, ManoModel) else load_mano(model_path)
    fa = mano_finger_pose(model, pose_a, space=pose_space, flat_hand_mean=flat_hand_mean)
    fb = mano_finger_pose(model, pose_b, space=pose_space, flat_hand_mean=flat_hand_mean)
    va, ja = mano_forward(model, fa, global_rotation_a, betas)
    vb, jb = mano_forward(model, fb, global_rotation_b, betas)
    if skeleton_joints == "regressor":
        ja, jb = model.J_regressor @ va, model.J_regressor @ vb
    label = lambda p: str(int(p)) if isinstance(p, (int, np.integer)) else "custom"  # noqa: E731
    name = name or f"mano_{label(pose_a)}_{label(pose_b)}"
    source = Mesh(vertices=va, faces=model.faces, name=f"{name}/source", file_index=np.arange(va.shape[0]))
    skeleton = _mano_skeleton(model, ja, va, tip_vertices, name)
    target_joints = np.concatenate([jb, vb[[int(t) for t in tip_vertices]]])[skeleton.file_index]
    info = {
        "model": model.name,
        "pose_a": pose_a if isinstance(pose_a, (int, np.integer)) else "custom",
        "pose_b": pose_b if isinstance(pose_b, (int, np.integer)) else "custom",
        "retriangulated": bool(retriangulate),
    }
    if retriangulate:
        rest_v, _ = mano_forward(model, np.zeros(3 * (model.n_joints - 1)), None, betas)
        tres = 36.0 if target_resolution is None else float(target_resolution)
        target_v, tf, gt = _retriangulated_target(rest_v, model.faces, vb, tres, seed, f"{name}/gt")
        info["target_resolution"] = tres
    else:
        target_v, tf, gt = vb, model.faces, _identity_ground_truth(source, f"{name}/gt")
    target = Mesh(vertices=target_v, faces=tf, name=f"{name}/target", file_index=np.arange(target_v.shape[0]))
    info.update(n_source=source.n_vertices, n_target=target.n_vertices)
    return Pair(
        name=name,
        source=source,
        target=target,
        skeleton=skeleton,
        ground_truth=gt,
        dataset="mano",
        target_joints=target_joints,
        info=info,
    )


# ----------------------------------------------------------------------------------------------
# glTF


def gltf_pair(
    path: str | os.PathLike,
    time_a: float,
    time_b: float,
    animation: str | int | None = None,
    *,
    retriangulate: bool = False,
    target_resolution: float | None = None,
    seed: int = 0,
    skin: int | None = None,
    name: str | None = None,
) -> Pair:
    """A skinned glTF character posed at two animation times (source at ``time_a``, target at ``time_b``).

    Posing, welding of seam duplicates and animation sampling are those of :mod:`ncflow.gltf`.
    The skeleton is the skin's joints at ``time_a`` with joints stacked on their parent merged
    (:func:`ncflow.gltf.merge_zero_length_bones`, chosen in the bind pose, as ``ncflow pose``
    does). Ground truth: identity (same welded vertices), or, with ``retriangulate``, a
    retriangulation of the bind-pose surface (same connectivity as every pose; ``target_resolution``
    cells along its largest extent, default 48) mapped to the target by its barycentric
    coordinates.
    """
    from ncflow.gltf import load_gltf_skin, merge_zero_length_bones

    rig = load_gltf_skin(path, skin)
    a = rig.pose(float(time_a), animation)
    b = rig.pose(float(time_b), animation)
    stem = Path(path).stem
    name = name or f"{stem}_{float(time_a):g}_{float(time_b):g}"
    keep, parents = merge_zero_length_bones(rig.joint_world()[:, :3, 3], a.parents)
    skeleton = Skeleton.from_arrays(a.joint_positions[keep], parents, [a.names[j] for j in keep], name=str(path))
    target_joints = b.joint_positions[keep][skeleton.file_index]
    source = Mesh(vertices=a.vertices, faces=a.faces, name=f"{name}/source", file_index=a.file_index)
    info = {
        "file": str(path),
        "animation": a.animation,
        "time_a": a.time,
        "time_b": b.time,
        "retriangulated": bool(retriangulate),
        "merged_joints": int(len(a.names) - keep.size),
    }
    if retriangulate:
        bind = rig.pose(None)  # same welded vertices and faces as every pose
        tres = 48.0 if target_resolution is None else float(target_resolution)
        target_v, tf, gt = _retriangulated_target(bind.vertices, bind.faces, b.vertices, tres, seed, f"{name}/gt")
        info["target_resolution"] = tres
    else:
        target_v, tf, gt = b.vertices, b.faces, _identity_ground_truth(source, f"{name}/gt")
    target = Mesh(vertices=target_v, faces=tf, name=f"{name}/target", file_index=np.arange(target_v.shape[0]))
    info.update(n_source=source.n_vertices, n_target=target.n_vertices)
    return Pair(
        name=name,
        source=source,
        target=target,
        skeleton=skeleton,
        ground_truth=gt,
        dataset=stem,
        target_joints=target_joints,
        info=info,
    )


# ----------------------------------------------------------------------------------------------
# Writing


def _write_mesh_exact(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Write a mesh without losing precision: binary PLY with float64 coordinates, or OBJ with 17
    significant digits (``ncflow.mesh.save_mesh`` goes through trimesh, whose PLY is float32)."""
    v = np.ascontiguousarray(vertices, dtype="<f8")
    f = np.asarray(faces, dtype=np.int64)
    if not np.all(np.isfinite(v)):
        raise InputError("refusing to write non-finite vertex coordinates", path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".ply":
        header = (
            "ply\nformat binary_little_endian 1.0\ncomment ncflow pair (float64 vertices)\n"
            f"element vertex {v.shape[0]}\nproperty double x\nproperty double y\nproperty double z\n"
            f"element face {f.shape[0]}\nproperty list uchar int vertex_indices\nend_header\n"
        )
        rec = np.zeros(f.shape[0], dtype=[("n", "u1"), ("idx", "<i4", (3,))])
        rec["n"] = 3
        rec["idx"] = f
        with open(path, "wb") as fh:
            fh.write(header.encode("ascii"))
            fh.write(v.tobytes())
            fh.write(rec.tobytes())
    else:
        lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in v.tolist()]
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f.tolist()]
        path.write_text("\n".join(lines) + "\n")


def write_pair(pair: Pair, directory: str | os.PathLike, fmt: str = "ply") -> dict[str, str]:
    """Write one pair into ``directory``: ``source.FMT``, ``target.FMT`` (full float64 precision:
    binary PLY with double coordinates, or OBJ with 17 digits), ``source_skeleton.tgf``,
    ``target_skeleton.tgf`` (when the target pose is known) and ``gt.npz`` (``face``, ``bary``).

    Returns:
        the file names written, by role (``source``, ``target``, ``skeleton``, ``gt``).
    """
    if fmt not in ("ply", "obj"):
        raise InputError(f"format must be 'ply' or 'obj', got {fmt!r}")
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    files = {"source": f"source.{fmt}", "target": f"target.{fmt}", "skeleton": "source_skeleton.tgf", "gt": "gt.npz"}
    _write_mesh_exact(d / files["source"], pair.source.vertices, pair.source.faces)
    _write_mesh_exact(d / files["target"], pair.target.vertices, pair.target.faces)
    save_skeleton(d / files["skeleton"], pair.skeleton)
    if pair.target_skeleton is not None:
        save_skeleton(d / "target_skeleton.tgf", pair.target_skeleton)
    save_ground_truth(d / files["gt"], pair.ground_truth)
    return files


def write_pairs(
    pairs,
    out_dir: str | os.PathLike,
    fmt: str = "ply",
    csv_name: str = "pairs.csv",
    start: int = 0,
    verbose: bool = False,
) -> Path:
    """Write pairs to ``out_dir/pair_XXX/`` (see :func:`write_pair`) and list them in
    ``out_dir/pairs.csv`` with columns ``name, source, target, skeleton, gt, gt_format, dataset``
    (paths relative to the csv; ``gt_format`` is ``npz``). ``pairs`` may be any iterable (pairs
    are written as they come). Returns the csv path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for k, pair in enumerate(pairs, start=start):
        sub = f"pair_{k:03d}"
        files = write_pair(pair, out / sub, fmt)
        rows.append(
            {
                "name": pair.name,
                "source": f"{sub}/{files['source']}",
                "target": f"{sub}/{files['target']}",
                "skeleton": f"{sub}/{files['skeleton']}",
                "gt": f"{sub}/{files['gt']}",
                "gt_format": "npz",
                "dataset": pair.dataset,
            }
        )
        if verbose:
            print(
                f"{sub}: {pair.name} ({pair.dataset}) source {pair.source.n_vertices} vertices, "
                f"target {pair.target.n_vertices} vertices, {pair.skeleton.n_bones} bones",
                flush=True,
            )
    path = out / csv_name
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(PAIRS_CSV_COLUMNS))
        writer.writeheader()
        writer.writerows(rows)
    return path
