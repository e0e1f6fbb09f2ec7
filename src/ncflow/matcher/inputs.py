"""The inputs of a match, loaded and checked before any work: what a user can get wrong with files
that are each valid on their own.

* a target of another scale than the source (other units): refused beyond 2× (:func:`check_sizes`);
* a target wound the other way from the source (one of the two inside out): its faces turned for the
  match (:func:`target_faces_like_source`);
* a mesh far from the origin for its size: a warning (:func:`check_precision`);
* a skeleton outside the source (:func:`check_skeleton_placement`).

Before them, every mesh passes the intake step (:func:`intake`): a triangle soup or a mesh split at its
seams is welded, zero-area and duplicate faces are dropped, non-manifold edges and vertices split
(:mod:`ncflow.geometry.repair`), with one warning; the checks and the match take the repaired meshes.
:func:`check_meshes` and :func:`check_skeleton_placement` run the checks; :func:`ncflow.matcher.prepare.prepare`
calls them all (the skeleton's once per skeleton suggested).
"""

from __future__ import annotations

import time

import numpy as np

from ncflow.errors import InputError
from ncflow.geometry.cloud import (
    PointCloud,
    cloud_outliers,
    file_normals,
    oriented_normals,
    point_spacing,
    validate_cloud,
)
from ncflow.geometry.mesh import Mesh, face_areas, orientation, repaired_mesh, validate_mesh
from ncflow.geometry.reconstruct import reconstruct_surface
from ncflow.geometry.repair import Repair
from ncflow.geometry.topology import mesh_topology
from ncflow.io.meshes import load_mesh
from ncflow.io.points import load_target
from ncflow.matcher.partial import CUT_SHARE, border_share
from ncflow.skeleton import Skeleton, load_skeleton
from ncflow.skeleton.checks import DEFAULT_TOLERANCES, check_inside_at


def _mesh(mesh) -> Mesh:
    if isinstance(mesh, Mesh):
        validate_mesh(mesh.vertices, mesh.faces, name=mesh.name)  # what load_mesh checks of a file
        return mesh
    return load_mesh(mesh)


def load_source(source, skeleton) -> tuple[Mesh, Skeleton | None]:
    """The source mesh and its skeleton from objects or file paths, as :func:`load_inputs` loads them (a
    sequence loads its source once for all frames).
    """
    skel = skeleton if skeleton is None or isinstance(skeleton, Skeleton) else load_skeleton(skeleton)
    return _mesh(source), skel


def _target(target) -> Mesh | PointCloud:
    if isinstance(target, PointCloud):
        validate_cloud(target.points, target.normals, name=target.name)
        return target
    return _mesh(target) if isinstance(target, Mesh) else load_target(target)


def load_inputs(source, target, skeleton) -> tuple[Mesh, Mesh | PointCloud, Skeleton | None]:
    """Meshes and skeleton from objects or file paths, validated (meshes given as objects too:
    :func:`~ncflow.geometry.mesh.validate_mesh`); the target may be a point cloud (a file without faces,
    :func:`ncflow.io.points.load_target`); a skeleton of None stays None (one is suggested later).
    """
    src, skel = load_source(source, skeleton)
    return src, _target(target), skel


SURFACE_POINTS = 200_000
"""Most points a cloud's surface is made of (:func:`cloud_surface`); a larger cloud is thinned for it (every
point is still mapped)."""


def cloud_surface(cloud: PointCloud) -> tuple[Mesh, dict]:
    """The surface a point-cloud target is matched through, and what was done to make it: outliers
    (:func:`~ncflow.geometry.cloud.cloud_outliers`) left out (and a cloud of more than :data:`SURFACE_POINTS`
    thinned), normals oriented outward (the file's or
    estimated: :func:`~ncflow.geometry.cloud.oriented_normals`), the implicit surface of the rest
    (:func:`~ncflow.geometry.reconstruct.reconstruct_surface`), open where the scan saw nothing.

    Returns:
        (the surface as a :class:`Mesh` named after the cloud, a summary: ``n_points``, ``n_outliers``,
        ``outliers`` ((N,) bool), ``normals`` ("file" or "estimated"), ``spacing``, ``surface_vertices``,
        ``surface_faces``, ``seconds``).
    """
    t0 = time.perf_counter()
    outliers = cloud_outliers(cloud.points)
    keep = ~outliers
    if keep.sum() > SURFACE_POINTS:  # an even share of the file's order (a scan's rows) is plenty for the surface
        chosen = np.flatnonzero(keep)
        keep = np.zeros_like(keep)
        keep[chosen[np.linspace(0, chosen.size - 1, SURFACE_POINTS).round().astype(np.int64)]] = True
    spacing = point_spacing(cloud.points[keep])
    normals = oriented_normals(cloud, keep, spacing)
    vertices, faces = reconstruct_surface(cloud.points[keep], normals[keep], spacing)
    if faces.shape[0] == 0:
        raise InputError("no surface could be made of the points (too sparse or too noisy?)", cloud.name)
    info = {
        "n_points": cloud.n_points,
        "n_outliers": int(outliers.sum()),
        "outliers": outliers,
        "normals": "file" if file_normals(cloud, keep) else "estimated",
        "spacing": spacing,
        "surface_vertices": int(vertices.shape[0]),
        "surface_faces": int(faces.shape[0]),
        "seconds": time.perf_counter() - t0,
    }
    return Mesh(vertices, faces, name=cloud.name), info


def cloud_warning(cloud: PointCloud, info: dict) -> str:
    """What a user hears of a point-cloud target (:func:`cloud_surface`)."""
    left = f", {info['n_outliers']} outliers left out" if info["n_outliers"] else ""
    return (
        f"{cloud.name or 'target'}: a point cloud of {info['n_points']} points, matched through a surface made of it "
        f"({info['surface_faces']} triangles, normals {'from the file' if info['normals'] == 'file' else 'estimated'}"
        f"{left}); every point is mapped"
    )


SIZE_RATIO_LIMIT = 2.0
"""The most the target's size may differ from the source's, either way (:func:`check_sizes`)."""

SIZE_RATIO_WARNING = 1.25
"""Beyond this size ratio, either way, a run goes on with a warning (:func:`check_sizes`)."""

PARTIAL_SPAN = 0.3
"""A target cut open where the source is not (a scan) is a partial view when it spans at least this share of
the source's diameter (:func:`check_sizes`)."""


def size_ratio(src: Mesh, tgt: Mesh) -> float:
    """The target's size relative to the source's: √(target area / source area), in the files' units.
    Articulation keeps a surface's area (skin stretches by some percent), and so do triangulation
    and resolution, so one character in two poses has a ratio near 1.
    """
    return float(np.sqrt(face_areas(tgt.vertices, tgt.faces).sum() / face_areas(src.vertices, src.faces).sum()))


def diameter(vertices: np.ndarray) -> float:
    """The largest distance between two vertices (over the convex hull's; placement-free)."""
    from scipy.spatial import ConvexHull, QhullError

    v = np.asarray(vertices, np.float64)
    try:
        v = v[ConvexHull(v).vertices]
    except (QhullError, ValueError):  # flat or too few points: all of them
        pass
    v = v[:4000]
    return float(max(np.max(np.linalg.norm(v - p, axis=1)) for p in v)) if len(v) else 0.0


def check_sizes(src: Mesh, tgt: Mesh) -> list[str]:
    """A warning when the target's :func:`size_ratio` to the source is beyond
    :data:`SIZE_RATIO_WARNING` either way; an :class:`InputError` naming the target beyond
    :data:`SIZE_RATIO_LIMIT`. ncflow normalises both meshes by one similarity (DESIGN.md
    "Normalisation") and matches one character at one scale: a target in other units (millimetres
    against metres, inches against centimetres) would otherwise give a meaningless result without
    a word.

    A partial target (a scan seen from one side, with holes) shows less surface but spans the body:
    when the target's area is the smaller while its :func:`diameter` is within
    :data:`SIZE_RATIO_WARNING` of the source's, it is taken for a partial view of one size (a note
    saying how much it shows), not for another scale. A target cut open where the source is not (its
    open borders longer than the source's by :data:`ncflow.matcher.partial.CUT_SHARE` × √area: a view of a
    quarter of the body) may span less: down to :data:`PARTIAL_SPAN` of the diameter. A target in other
    units (1000×, 25.4×, 2.54×) of a whole character is closed and is refused as before.
    """
    ratio = size_ratio(src, tgt)
    across = diameter(tgt.vertices) / max(diameter(src.vertices), 1e-300)
    cut_open = open_share(tgt) - open_share(src) > CUT_SHARE
    lowest = PARTIAL_SPAN if cut_open else 1.0 / SIZE_RATIO_WARNING
    if np.isfinite(ratio) and ratio < 1.0 / SIZE_RATIO_WARNING and lowest <= across <= SIZE_RATIO_WARNING:
        return [
            f"the target shows about {ratio**2:.0%} of the source's surface area while spanning {across:.2f}x its "
            "diameter: taken for a partial view (a scan from one side, with holes) of the same size"
        ]
    if not np.isfinite(ratio) or max(ratio, 1.0 / ratio) > SIZE_RATIO_LIMIT:
        raise InputError(
            f"the target is {ratio:.3g}x the size of the source {src.name or ''} (the square root of their "
            f"surface areas' ratio; at most {SIZE_RATIO_LIMIT:g}x either way): ncflow matches one character "
            "in two poses at one scale; are the files in different units (millimetres and metres: 1000x)? "
            "Scale one of them",
            tgt.name,
        )
    if max(ratio, 1.0 / ratio) > SIZE_RATIO_WARNING:
        return [
            f"the target is {ratio:.3g}x the size of the source (the square root of their surface areas' "
            "ratio): ncflow matches one character at one scale"
        ]
    return []


def open_share(mesh: Mesh) -> float:
    """The length of a mesh's open borders over the square root of its area (0 for a closed surface)."""
    return border_share(mesh.vertices, mesh_topology(mesh.faces, mesh.n_vertices))


PRECISION_WARNING = 1e-4
"""A mesh narrower than this fraction of its largest coordinate gets a warning (:func:`check_precision`)."""


def check_precision(mesh: Mesh, role: str) -> list[str]:
    """A warning when the mesh is small next to its distance from the origin (a scan in survey
    coordinates): the outputs are written in the input's coordinates at float32, seven digits, so
    below :data:`PRECISION_WARNING` they keep fewer than three digits of the mesh's own size.
    """
    size = float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
    far = float(np.abs(mesh.vertices).max())
    if size < PRECISION_WARNING * far:
        return [
            f"{mesh.name or role}: the {role} is {size:.3g} across but lies {far:.3g} from the origin; the outputs, "
            "written in its coordinates at float32, keep only about "
            f"{max(0.0, 7 + np.log10(size / far)):.0f} digits of its shape: move it near the origin"
        ]
    return []


def intake(mesh: Mesh, role: str, config) -> tuple[Mesh, Repair, list[str]]:
    """The intake step of a match (:func:`~ncflow.geometry.mesh.repaired_mesh` with the ``repair``
    settings): the mesh the match computes on, the repair with its maps back to ``mesh`` (the outputs
    keep one row per vertex of the file), and a warning saying what was repaired and how much.
    """
    clean, r = repaired_mesh(
        mesh, weld_tolerance=config.repair.weld_tolerance, min_component=config.repair.min_component
    )
    summary = r.summary()
    note = f"{mesh.name or role}: repaired for the match (the outputs keep its vertices): {summary}"
    return clean, r, [note] if summary else []


def target_faces_like_source(src: Mesh, tgt: Mesh) -> tuple[np.ndarray, list[str]]:
    """The target's faces wound as the source's, and a warning when they had to be turned.

    The data terms are oriented (DESIGN.md "Varifold", "Normal Cycles"): a target wound the other
    way from the source (one of the two inside out, as some exporters write) reads as a surface
    facing away, and the match fails without a word (on the shared MANO pair with the target's
    faces reversed, a 3-step run's geodesic AUC fell from 0.90 to 0.27). Turned only when both
    orientations are clear (:func:`~ncflow.geometry.mesh.orientation`); the target written with a
    result is the one given.
    """
    if orientation(src.vertices, src.faces) * orientation(tgt.vertices, tgt.faces) < 0:
        warning = (
            "the target's faces wind the other way from the source's (one of the two is inside out): "
            "the target's were turned to agree for the match"
        )
        return np.ascontiguousarray(tgt.faces[:, ::-1]), [warning]
    return tgt.faces, []


def check_skeleton_placement(skel: Skeleton, src: Mesh) -> list[str]:
    """Warnings for joints slightly outside; an :class:`InputError` for joints far outside the source."""
    far, near = check_inside_at(skel, src.vertices, src.faces, [(0.15, 0.15), DEFAULT_TOLERANCES])
    if far:
        raise InputError(
            f"skeleton does not fit the source mesh {src.name or ''}: {far[0]}"
            + (f" (and {len(far) - 1} more)" if len(far) > 1 else "")
            + "; is it in the same coordinates as the source?",
            skel.name,
        )
    return near


def check_meshes(src: Mesh, tgt: Mesh) -> tuple[np.ndarray, list[str]]:
    """The checks of the two meshes: the target's faces wound as the source's, and the warnings (what the
    mesh readers changed first), in the order a user should read them.

    Raises:
        InputError: a target of another scale.
    """
    tgt_f, turned = target_faces_like_source(src, tgt)
    meshes = ((src, "source"), (tgt, "target"))
    notes = [f"{m.name or role}: {n}" for m, role in meshes for n in m.notes]
    notes += [w for m, role in meshes for w in check_precision(m, role)]
    return tgt_f, notes + check_sizes(src, tgt) + turned
