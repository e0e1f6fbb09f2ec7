"""Source/target pairs with exact ground truth: the :class:`Pair` type, procedural pairs, writing pairs.

A :class:`Pair` holds a source mesh, a target mesh, the source skeleton (joints in the source's
pose) and, for every target vertex, the source surface point it corresponds to (a
:class:`~ncflow.io.ground_truth.GroundTruth`: source face + barycentric coordinates).
:func:`make_pair` builds one from a procedural character; pairs from a MANO model and from an
animated glTF character are built in :mod:`ncflow.synthetic.mano` and :mod:`ncflow.synthetic.gltf`
with the same construction. :func:`write_pair` and :func:`write_pairs` write them at full float64
precision, with a ``pairs.csv`` for ``ncflow benchmark``.

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
  onto S (:func:`ncflow.geometry.closest.closest_points_on_surface` → face, barycentrics), and the
  target vertices are ``Σ_k bary_k · posed_B(S vertex_k)``. Every target vertex is then exactly
  the image of its ground-truth source point under the generating deformation, up to float64
  rounding (~1e-16), while the target has its own vertex count and connectivity.

The source is S in the rest pose or posed by pose A (same connectivity as S).

Harder pairs
------------
:func:`articulate` adds large rotations to a procedural target pose (more large hinge flexions,
or a named whole-body articulation: arms crossed, a stride, a crouch, curled fingers, a gallop),
and every builder (:func:`make_pair`, :func:`ncflow.synthetic.mano.mano_pair`,
:func:`ncflow.synthetic.gltf.gltf_pair`) can turn and move its target by one rigid motion drawn
from the pair's seed (:func:`move_target`). A rigid motion of the target does not change which
source point a target vertex is, so the ground truth stays the same arrays; the motion is kept in
``Pair.info["target_motion"]`` and written to ``target_motion.json``. Each has its own random
stream, so pairs made without them are the same arrays as before they existed.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import os
import re
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError
from ncflow.geometry.barycentric import surface_points
from ncflow.geometry.closest import _project
from ncflow.geometry.mesh import Mesh
from ncflow.geometry.remesh import retriangulate_mesh
from ncflow.io.atomic import (
    atomic_path,
    atomic_write_text,
    check_output_dir,
    move_into_place,
    remove_tree,
    staging_dir,
)
from ncflow.io.ground_truth import GroundTruth, ground_truth_from_vertex_map, save_ground_truth
from ncflow.io.meshes import save_mesh
from ncflow.skeleton import Skeleton, save_skeleton
from ncflow.synthetic.articulations import articulate
from ncflow.synthetic.characters import Character, make_character, pose_character, random_pose
from ncflow.synthetic.motion import _pair_seed, motion_record, move_target

PAIRS_CSV_COLUMNS = ("name", "source", "target", "skeleton", "gt", "gt_format", "dataset")
#: extra columns of a pairs.csv in which some target was turned and moved
MOTION_CSV_COLUMNS = ("target_rotation_deg", "target_motion")


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
        """The ground-truth points Σ bary · vertices of the source, one per target vertex.

        ``source_vertices`` (V, 3): other vertex positions with the source's connectivity (default
        the source's own).
        """
        v = self.source.vertices if source_vertices is None else source_vertices
        return surface_points(v, self.source.faces, self.ground_truth.face, self.ground_truth.bary)


def identity_ground_truth(source: Mesh, name: str) -> GroundTruth:
    """Ground truth of a target with the source's vertices: target vertex i is source vertex i."""
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


# ----------------------------------------------------------------------------------------------
# Procedural characters


# ----------------------------------------------------------------------------------------------
# Turning and moving the target


# ----------------------------------------------------------------------------------------------
# Large articulations beyond random_pose's one large joint


# ----------------------------------------------------------------------------------------------
# Procedural pairs


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
    large_joints: int = 1,
    articulation: str | None = None,
    target_rotation: float | tuple[float, float] | None = None,
    target_translation: float | tuple[float, float] | None = None,
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
        skinning: ``"dqs"`` or ``"lbs"`` (see :func:`ncflow.synthetic.characters.pose_character`).
        large_angle: range (degrees) of the target pose's large joint flexions.
        character: reuse an already built character (must match ``kind`` and ``seed``).
        large_joints: number of joints of the target pose flexed by ``large_angle`` (default 1:
            the one :func:`random_pose` draws; more are drawn by :func:`articulate`).
        articulation: a named whole-body articulation of the target pose (:data:`ARTICULATIONS`:
            humanoid ``"cross"``, ``"stride"``, ``"crouch"``; hand ``"curl"``; quadruped
            ``"gallop"``), applied on top of the random pose (see :func:`articulate`).
        target_rotation: turn the target by this many degrees (a number: exactly; a pair: uniform
            in the range) about a random axis through its vertex mean (:func:`move_target`).
        target_translation: then move it by this fraction of the source's bounding-box diagonal
            (number or range) in a random direction.

    Extra large joints, the articulation and the target motion have their own random streams:
    without them every array is the same as before they existed. The target motion (also applied
    to the target joints) leaves the ground truth unchanged.

    Returns:
        :class:`Pair`; ``info`` records the large joint(s) and angle(s), the articulation, the poses,
        the target motion (``target_motion``: rotation, translation, …, when there is one) and
        the vertex counts.
    """
    if source_pose not in ("rest", "random"):
        raise InputError(f"source_pose must be 'rest' or 'random', got {source_pose!r}")
    ch = make_character(kind, seed, resolution) if character is None else character
    if ch.kind != kind or ch.seed != int(seed):
        raise InputError(f"the given character is a {ch.kind} of seed {ch.seed}, not a {kind} of seed {seed}")
    name = f"{kind}_{int(seed):03d}"
    pose_b, info_b = random_pose(ch, _pair_seed(seed, 2), large_angle=large_angle)
    extra: dict | None = None
    if large_joints != 1 or articulation is not None:
        done = (info_b["large_joint"],) if info_b["large_joint"] else ()
        pose_b, extra = articulate(
            ch.spec,
            pose_b,
            _pair_seed(seed, 5),
            large_joints=large_joints,
            large_angle=large_angle,
            articulation=articulation,
            exclude=done,
        )
    posed_b = pose_character(ch, pose_b, skinning=skinning)
    if source_pose == "random":
        rest_joints = [info_b["large_joint"]] if info_b["large_joint"] else []
        if extra is not None:
            rest_joints += extra["extra_large_joints"] + extra["articulation_joints"]
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
    if extra is not None:
        info.update(articulation=articulation, **extra)
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
        gt = identity_ground_truth(source, f"{name}/gt")
    target_v, target_j, motion = move_target(
        target_v, posed_b.joints, source.vertices, seed, target_rotation, target_translation
    )
    if motion is not None:
        info["target_motion"] = motion
    return assemble_pair(name, source, skeleton, target_v, tf, gt, dataset=kind, target_joints=target_j, info=info)


def assemble_pair(
    name: str,
    source: Mesh,
    skeleton: Skeleton,
    target_vertices: Float[np.ndarray, "W 3"],
    target_faces: Int[np.ndarray, "G 3"],
    ground_truth: GroundTruth,
    *,
    dataset: str,
    target_joints: Float[np.ndarray, "J 3"] | None,
    info: dict,
) -> Pair:
    """The :class:`Pair` of a source, a target given as arrays and their ground truth.

    The target mesh is named ``NAME/target`` and keeps its own vertex order; ``info`` gets the
    vertex counts ``n_source`` and ``n_target``.
    """
    target = Mesh(
        vertices=target_vertices,
        faces=np.asarray(target_faces, dtype=np.int64),
        name=f"{name}/target",
        file_index=np.arange(target_vertices.shape[0]),
    )
    info.update(n_source=source.n_vertices, n_target=target.n_vertices)
    return Pair(
        name=name,
        source=source,
        target=target,
        skeleton=skeleton,
        ground_truth=ground_truth,
        dataset=dataset,
        target_joints=target_joints,
        info=info,
    )


# ----------------------------------------------------------------------------------------------
# Retriangulating an arbitrary surface


def retriangulated_target(
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


# ----------------------------------------------------------------------------------------------
# glTF


# ----------------------------------------------------------------------------------------------
# Writing


def write_pair(pair: Pair, directory: str | os.PathLike, fmt: str = "ply") -> dict[str, str]:
    """Write one pair into ``directory``: ``source.FMT``, ``target.FMT`` (full float64 precision:
    binary PLY with double coordinates, or OBJ with 17 digits), ``source_skeleton.tgf``,
    ``target_skeleton.tgf`` (when the target pose is known), ``gt.npz`` (``face``, ``bary``) and,
    when the target was turned and moved, ``target_motion.json`` (``rotation`` R (3×3 rows),
    ``translation`` t: target = R · unmoved target + t; ``angle_deg``, ``axis``, ``centre``, ``shift``).

    Returns:
        the file names written, by role (``source``, ``target``, ``skeleton``, ``gt``, and
        ``target_motion`` when written).
    """
    if fmt not in ("ply", "obj"):
        raise InputError(f"format must be 'ply' or 'obj', got {fmt!r}")
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    files = {"source": f"source.{fmt}", "target": f"target.{fmt}", "skeleton": "source_skeleton.tgf", "gt": "gt.npz"}
    save_mesh(d / files["source"], pair.source.vertices, pair.source.faces, precision="float64")
    save_mesh(d / files["target"], pair.target.vertices, pair.target.faces, precision="float64")
    save_skeleton(d / files["skeleton"], pair.skeleton)
    if pair.target_skeleton is not None:
        save_skeleton(d / "target_skeleton.tgf", pair.target_skeleton)
    save_ground_truth(d / files["gt"], pair.ground_truth)
    motion = pair.info.get("target_motion")
    if motion is not None:
        files["target_motion"] = "target_motion.json"
        atomic_write_text(d / files["target_motion"], json.dumps(motion_record(motion), indent=1) + "\n")
    return files


#: files :func:`write_pair` may write into a pair folder
_PAIR_NAMES = "source.ply source.obj target.ply target.obj source_skeleton.tgf target_skeleton.tgf gt.npz"
PAIR_FILES = frozenset(_PAIR_NAMES.split() + ["target_motion.json"])
_PAIR_DIR_RE = re.compile(r"^pair_\d{3,}$")


def _owned_by_write_pairs(csv_name: str):
    return lambda name: name == csv_name or bool(_PAIR_DIR_RE.match(name))


def check_pairs_dir(out_dir: str | os.PathLike, overwrite: bool = False, csv_name: str = "pairs.csv") -> Path:
    """Check the folder :func:`write_pairs` will write (before any pair is built); return it resolved.

    An existing non-empty folder is refused unless ``overwrite``; then its ``pair_XXX`` folders
    and ``csv_name`` are replaced as a set and must hold only what :func:`write_pairs` writes
    (anything else: refused, never deleted). Other entries are left untouched.

    Raises:
        InputError: one line naming the folder or the offending entry.
    """
    shown = Path(out_dir)
    out = check_output_dir(out_dir, overwrite=True, allow_cwd=True, option="output folder")
    if not out.is_dir() or not any(out.iterdir()):
        return out
    if not overwrite:
        raise InputError("output folder exists and is not empty (use --overwrite to replace its pairs)", shown)
    owned = _owned_by_write_pairs(csv_name)
    for entry in out.iterdir():
        if not owned(entry.name):
            continue
        if entry.is_symlink():
            raise InputError("is a symbolic link; ncflow replaces only files it wrote (remove it first)", entry)
        if entry.name == csv_name:
            if not entry.is_file():
                raise InputError("is not a file; ncflow replaces only files it wrote (remove it first)", entry)
            continue
        if not entry.is_dir():
            raise InputError("is not a folder; ncflow replaces only pair folders it wrote (remove it first)", entry)
        for sub in entry.iterdir():
            if sub.is_symlink() or not sub.is_file() or sub.name not in PAIR_FILES:
                raise InputError("was not written by ncflow make-pairs; move it away first", sub)
    return out


def write_pairs(
    pairs,
    out_dir: str | os.PathLike,
    fmt: str = "ply",
    csv_name: str = "pairs.csv",
    start: int = 0,
    verbose: bool = False,
    overwrite: bool = False,
) -> Path:
    """Write pairs to ``out_dir/pair_XXX/`` (see :func:`write_pair`) and list them in ``out_dir/pairs.csv``.

    The csv has columns ``name, source, target, skeleton, gt, gt_format, dataset`` (paths relative
    to the csv; ``gt_format`` is ``npz``), plus ``target_rotation_deg`` and ``target_motion`` (the
    ``target_motion.json`` file, empty for a pair without one) when some target was turned and
    moved. ``pairs`` may be any iterable (pairs are built as they come).

    The whole set is written **atomically**: into a hidden folder beside ``out_dir``, moved into
    place when the csv is complete (:func:`ncflow.io.atomic.move_into_place`), so an interrupted
    run never leaves new pairs beside an old csv. An existing non-empty ``out_dir`` is refused
    unless ``overwrite``; then its ``pair_XXX`` folders and csv are replaced as a set (stale pairs
    of a longer earlier run removed) and its other entries kept (:func:`check_pairs_dir`).

    Returns:
        the csv path.
    """
    shown = Path(out_dir)
    out = check_pairs_dir(out_dir, overwrite, csv_name)
    if os.sep in csv_name or not csv_name or csv_name.startswith("."):
        raise InputError(f"csv_name must be a plain file name, got {csv_name!r}")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = staging_dir(out)
    try:
        rows = []
        for k, pair in enumerate(pairs, start=start):
            sub = f"pair_{k:03d}"
            files = write_pair(pair, tmp / sub, fmt)
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
            if "target_motion" in files:
                rows[-1]["target_rotation_deg"] = f"{pair.info['target_motion']['angle_deg']:.6g}"
                rows[-1]["target_motion"] = f"{sub}/{files['target_motion']}"
            if verbose:
                motion = pair.info.get("target_motion")
                moved = ""
                if motion is not None:
                    moved = (
                        f", target turned {motion['angle_deg']:.4g}° and moved {np.linalg.norm(motion['shift']):.4g}"
                    )
                print(
                    f"{sub}: {pair.name} ({pair.dataset}) source {pair.source.n_vertices} vertices, "
                    f"target {pair.target.n_vertices} vertices, {pair.skeleton.n_bones} bones{moved}",
                    flush=True,
                )
        text = io.StringIO(newline="")
        moved_any = any("target_motion" in r for r in rows)
        columns = PAIRS_CSV_COLUMNS + (MOTION_CSV_COLUMNS if moved_any else ())
        writer = csv.DictWriter(text, fieldnames=list(columns), restval="")
        writer.writeheader()
        writer.writerows(rows)
        with atomic_path(tmp / csv_name) as part:
            with open(part, "w", newline="") as fh:
                fh.write(text.getvalue())
        check_pairs_dir(out_dir, overwrite, csv_name)  # again: the folder may have changed meanwhile
        move_into_place(tmp, out, _owned_by_write_pairs(csv_name))
    except BaseException:
        remove_tree(tmp)
        raise
    return shown / csv_name
