"""Evaluation metrics (DESIGN.md "Evaluation definitions"; docs/evaluation.md).

All functions are pure NumPy on arrays. Conventions:

* Reporting scale ("unit cube"): both shapes of a pair are multiplied by
  s = 1 / (largest side of the source's axis-aligned bounding box), so the source fits a unit
  cube and the target keeps its size relative to the source. Chamfer distances are in these
  units; geodesic errors are divided by sqrt(source area) and do not depend on scale;
  conformal distortion is scale-free.
* Cumulative curves: PCK(τ) = fraction of errors ≤ τ; AUC = (1/τmax) ∫₀^τmax PCK(τ) dτ
  = mean(max(0, 1 − e/τmax)) (closed form; NaN errors are left out, +inf errors count as misses).
  τmax defaults: 0.20 geodesic, 0.10 Chamfer, 0.15 conformal (:data:`TAU_MAX`).
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Bool, Float, Int

from ncflow.errors import InputError
from ncflow.evaluate.geodesics import GeodesicInfo, pair_geodesic_distances
from ncflow.geometry.closest import closest_points_on_surface
from ncflow.geometry.cloud import PointCloud
from ncflow.geometry.mesh import Mesh, enclosed_volume, face_areas, repaired_mesh

TAU_MAX = {"geodesic": 0.20, "chamfer": 0.10, "conformal": 0.15}


# ----------------------------------------------------------------------------------------------
# Scale


def unit_cube_scale(vertices: Float[np.ndarray, "V 3"]) -> float:
    """S = 1 / (largest side of the axis-aligned bounding box); multiply coordinates by s."""
    v = np.asarray(vertices, dtype=np.float64)
    side = float(np.max(v.max(0) - v.min(0)))
    if not side > 0:
        raise InputError("cannot scale to a unit cube: all vertices coincide")
    return 1.0 / side


# ----------------------------------------------------------------------------------------------
# Geodesic error


def geodesic_errors(
    source: Mesh,
    pred_face: Int[np.ndarray, " n"],
    pred_bary: Float[np.ndarray, "n 3"],
    gt_face: Int[np.ndarray, " n"],
    gt_bary: Float[np.ndarray, "n 3"],
    method: str = "auto",
    exact_below: float = 0.25,
    return_info: bool = False,
) -> Float[np.ndarray, " n"] | tuple[Float[np.ndarray, " n"], GeodesicInfo]:
    """Geodesic error e_j = d_X(predicted point, true point) / sqrt(area(X)) on the source X.

    Args:
        source: the source mesh X (rest pose).
        pred_face: (n,) source face index of the predicted point of each evaluated target vertex.
        pred_bary: (n, 3) barycentric coordinates of that predicted point in its face.
        gt_face: (n,) source face index of the ground-truth point of the same target vertices.
        gt_bary: (n, 3) barycentric coordinates of that ground-truth point in its face.
        method: ``"auto"`` (exact polyhedral geodesics for errors up to ``exact_below``, heat
            method beyond), ``"exact"``, ``"heat"`` or ``"dijkstra"``; see
            :mod:`ncflow.evaluate.geodesics`.
        exact_below: in normalised units (fraction of sqrt(area)); only used by ``"auto"``.
        return_info: also return the :class:`~ncflow.evaluate.geodesics.GeodesicInfo`.

    Returns:
        (n,) errors (scale-free; +inf for points on different connected components).

    The distances are taken on the source after the intake step
    (:func:`~ncflow.geometry.mesh.repaired_mesh`: a triangle soup or a mesh split at its seams is one
    surface there; the points are carried over, :meth:`~ncflow.geometry.repair.Repair.points_from_input`);
    a clean source is used as it is.
    """
    clean, rep = repaired_mesh(source)
    if rep.changed:
        pred_face, pred_bary = rep.points_from_input(source.vertices, source.faces, pred_face, pred_bary)
        gt_face, gt_bary = rep.points_from_input(source.vertices, source.faces, gt_face, gt_bary)
        source = clean
    v, f = source.vertices, source.faces
    root_area = float(np.sqrt(face_areas(v, f).sum()))
    d, info = pair_geodesic_distances(
        v, f, pred_face, pred_bary, gt_face, gt_bary, method=method, exact_below=exact_below * root_area
    )
    e = d / root_area
    return (e, info) if return_info else e


# ----------------------------------------------------------------------------------------------
# Point-to-surface distance (exact)


def chamfer_distances(
    deformed_source: Float[np.ndarray, "V 3"],
    source_faces: Int[np.ndarray, "F 3"],
    target: Mesh | PointCloud,
    scale: float | None = None,
) -> tuple[Float[np.ndarray, " V"], Float[np.ndarray, " W"]]:
    """Per-vertex unsquared Chamfer distances (exact point-to-surface), both directions.

    Args:
        deformed_source: (V, 3) flowed source vertices, in the target's coordinates.
        source_faces: (F, 3) source connectivity.
        target: the target mesh (a point cloud, without faces: distances to its nearest points).
        scale: factor applied to the distances: pass :func:`unit_cube_scale` of the rest
            source for unit-cube units (as :func:`evaluate_correspondence` does); None keeps the
            input's own units.

    Returns:
        (distance of every flowed source vertex to the target surface (V,),
         distance of every target vertex to the flowed source surface (W,)).
    """
    s = 1.0 if scale is None else float(scale)
    x = np.asarray(deformed_source, dtype=np.float64)
    if target.faces.shape[0]:
        a = closest_points_on_surface(x, target.vertices, target.faces)[0]
    else:  # a point cloud: the nearest point
        from scipy.spatial import cKDTree

        a = cKDTree(target.vertices).query(x)[0]
    b = closest_points_on_surface(target.vertices, x, source_faces)[0]
    return a * s, b * s


# ----------------------------------------------------------------------------------------------
# Conformal distortion


def triangle_singular_values(
    rest: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], deformed: Float[np.ndarray, "*T V 3"]
) -> tuple[Float[np.ndarray, "*T F"], Float[np.ndarray, "*T F"]]:
    """Singular values s₁ ≥ s₂ ≥ 0 of the affine map from each rest triangle (in its own plane) to the deformed one.

    With rest edges e₁ = x_b − x_a, e₂ = x_c − x_a written in an orthonormal frame of the rest
    triangle as the columns of P (2×2), and deformed edges as the columns of Q (3×2), the
    Jacobian is J = Q P⁻¹ (3×2). From G = JᵀJ = [[a, b], [b, c]] (stable closed form):
    s₁s₂ = ‖J₁ × J₂‖ (area ratio), s₁ + s₂ = sqrt(a + c + 2 s₁s₂), s₁ − s₂ = sqrt((a − c)² + 4b²)/(s₁ + s₂).
    Degenerate rest triangles give NaN.
    """
    r = np.asarray(rest, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    x = np.asarray(deformed, dtype=np.float64)
    t = r[f]
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    l1 = np.linalg.norm(e1, axis=1)
    cr = np.linalg.norm(np.cross(e1, e2), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        # P = [[l1, p12], [0, p22]] in the frame (ê1, n × ê1)
        p12 = np.einsum("ij,ij->i", e1, e2) / l1
        p22 = cr / l1
        # P⁻¹ = [[1/l1, −p12/(l1 p22)], [0, 1/p22]]
        i11, i12, i22 = 1.0 / l1, -p12 / (l1 * p22), 1.0 / p22
        d = x[..., f, :]
        q1, q2 = d[..., 1, :] - d[..., 0, :], d[..., 2, :] - d[..., 0, :]
        j1 = q1 * i11[:, None]
        j2 = q1 * i12[:, None] + q2 * i22[:, None]
        a = np.sum(j1 * j1, -1)
        c = np.sum(j2 * j2, -1)
        b = np.sum(j1 * j2, -1)
        prod = np.linalg.norm(np.cross(j1, j2), axis=-1)
        ssum = np.sqrt(a + c + 2 * prod)
        sdiff = np.sqrt((a - c) ** 2 + 4 * b * b) / ssum
        s1 = 0.5 * (ssum + sdiff)
        s2 = np.where(s1 > 0, prod / s1, 0.0)
    bad = ~(cr > 0) | ~(l1 > 0)
    s1 = np.where(bad, np.nan, s1)
    s2 = np.where(bad, np.nan, s2)
    return s1, s2


def conformal_distortion(
    rest: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], frames: Float[np.ndarray, "*T V 3"]
) -> tuple[Float[np.ndarray, "*T F"], Float[np.ndarray, "*T F"]]:
    """Quasi-conformal distortion K − 1 = s₁/s₂ − 1 and MIPS s₁/s₂ + s₂/s₁ − 2 per triangle and frame.

    Both are 0 for similarities (rigid motion and uniform scaling), +inf for a triangle collapsed
    to a segment, NaN for a degenerate rest triangle. MIPS = (s₁ − s₂)²/(s₁s₂) is computed in
    that cancellation-free form.
    """
    s1, s2 = triangle_singular_values(rest, faces, frames)
    with np.errstate(divide="ignore", invalid="ignore"):
        diff = s1 - s2
        k1 = np.where(s2 > 0, diff / s2, np.where(np.isnan(s2), np.nan, np.inf))
        mips = np.where(s2 > 0, diff * diff / (s1 * s2), np.where(np.isnan(s2), np.nan, np.inf))
    return k1, mips


# ----------------------------------------------------------------------------------------------
# Cumulative curves


def _finite_or_inf(errors) -> np.ndarray:
    e = np.asarray(errors, dtype=np.float64).reshape(-1)
    return e[~np.isnan(e)]


def pck_curve(
    errors: Float[np.ndarray, ...], tau_max: float, n_thresholds: int = 1001
) -> tuple[Float[np.ndarray, " k"], Float[np.ndarray, " k"]]:
    """Cumulative curve PCK(τ) = fraction of errors ≤ τ on the grid τ = linspace(0, τmax, k).

    NaN errors are left out; +inf counts as never below any threshold.
    """
    e = np.sort(_finite_or_inf(errors))
    tau = np.linspace(0.0, float(tau_max), int(n_thresholds))
    if e.size == 0:
        return tau, np.full(tau.shape, np.nan)
    return tau, np.searchsorted(e, tau, side="right") / e.size


def auc(errors: Float[np.ndarray, ...], tau_max: float) -> float:
    """AUC = (1/τmax)∫₀^τmax PCK(τ) dτ = mean(max(0, 1 − e/τmax)) (NaN left out; NaN if none left)."""
    e = _finite_or_inf(errors)
    if e.size == 0:
        return float("nan")
    return float(np.mean(np.maximum(0.0, 1.0 - e / float(tau_max))))


def error_summary(errors: Float[np.ndarray, ...], tau_max: float) -> dict:
    """{'mean', 'median', 'max', 'auc', 'tau_max', 'n', 'n_nan'} of an error array (NaN left out)."""
    raw = np.asarray(errors, dtype=np.float64).reshape(-1)
    e = _finite_or_inf(raw)
    if e.size == 0:
        nan = float("nan")
        return {
            "mean": nan,
            "median": nan,
            "max": nan,
            "auc": nan,
            "tau_max": float(tau_max),
            "n": 0,
            "n_nan": int(raw.size),
        }
    return {
        "mean": float(np.mean(e)),
        "median": float(np.median(e)),
        "max": float(np.max(e)),
        "auc": auc(e, tau_max),
        "tau_max": float(tau_max),
        "n": int(e.size),
        "n_nan": int(raw.size - e.size),
    }


# ----------------------------------------------------------------------------------------------
# Plausibility


def bone_violation(
    samples: Float[np.ndarray, "*T B S 3"], reference: Float[np.ndarray, "*T B S 3"], scale: float = 1.0
) -> Float[np.ndarray, "*T B"]:
    """Per-bone constraint value g_k = mean over the bone's samples of ‖flowed − rigid reference‖².

    Coordinates are multiplied by ``scale`` first (so the value scales with scale²); the matcher
    reports it in its normalised units, evaluation in unit-cube units.
    """
    d = (np.asarray(samples, dtype=np.float64) - np.asarray(reference, dtype=np.float64)) * float(scale)
    return np.mean(np.sum(d * d, axis=-1), axis=-1)


def volume_change(frames: Float[np.ndarray, "T V 3"], faces: Int[np.ndarray, "F 3"]) -> Float[np.ndarray, " T"]:
    """Relative enclosed volume vol(frame_t)/vol(frame_0) − 1 per frame.

    Volumes from :func:`ncflow.mesh.enclosed_volume` (open surfaces are first closed by fans to
    their boundary-loop centroids). NaN everywhere if frame 0 encloses no volume (a flat sheet).
    """
    x = np.asarray(frames, dtype=np.float64)
    vols = np.array([enclosed_volume(x[t], faces) for t in range(x.shape[0])])
    if not vols[0] > 0:
        return np.full(vols.shape, np.nan)
    return vols / vols[0] - 1.0


def _unit_normals(x: np.ndarray, f: np.ndarray) -> np.ndarray:
    t = x[..., f, :]
    n = np.cross(t[..., 1, :] - t[..., 0, :], t[..., 2, :] - t[..., 0, :])
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300)


def inverted_triangles(
    rest: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    frames: Float[np.ndarray, "*T V 3"],
    mode: str = "local",
    rings: int = 2,
) -> Bool[np.ndarray, "*T F"]:
    """Triangles whose orientation flips relative to the source, per frame.

    ``mode="global"``: dot(n_frame, n_rest) < 0 — meaningful only when the frames are not rotated
    much relative to the rest pose (a limb bent by more than 90° "flips" under this test).
    ``mode="local"`` (default): dot(n_frame, R n_rest) < 0 where R is the best proper rotation
    (Kabsch) taking the rest positions of the triangle's neighbourhood to their frame positions.
    The neighbourhood is the faces within ``rings`` steps of face-to-face adjacency through shared
    vertices (each face's three corners counted once per face). This detects fold-overs
    independently of articulation; a mirror image of a planar sheet is a rotation in 3-D and is
    not a flip in this mode. Near a crease of a non-smooth map (a rigid elbow) the local rotation
    is ambiguous and the two modes can disagree on up to ~2 % of the triangles (docs/evaluation.md).

    Returns:
        (..., F) bool, True where inverted.
    """
    if mode not in ("local", "global"):
        raise ValueError(f"mode must be 'local' or 'global', got {mode!r}")
    r = np.asarray(rest, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    x = np.asarray(frames, dtype=np.float64)
    n_rest = _unit_normals(r, f)
    n_frame = _unit_normals(x, f)
    if mode == "global":
        return np.sum(n_frame * n_rest, -1) < 0
    from scipy.sparse import csr_matrix

    nf, nv = f.shape[0], r.shape[0]
    inc = csr_matrix((np.ones(3 * nf), (np.repeat(np.arange(nf), 3), f.reshape(-1))), shape=(nf, nv))
    step = ((inc @ inc.T) > 0).astype(np.float64)  # faces sharing at least one vertex (incl. itself)
    adj = step
    for _ in range(max(1, int(rings)) - 1):
        adj = ((adj @ step) > 0).astype(np.float64)
    adj = adj.tocsr()
    lead = x.shape[:-2]
    xf = x.reshape(-1, nv, 3)
    n_frame = n_frame.reshape(-1, nf, 3)
    out = np.empty((xf.shape[0], nf), dtype=bool)
    rp = r[f]  # (F, 3, 3)
    sum_p = adj @ rp.sum(1)  # (F, 3)
    cnt = 3.0 * np.asarray(adj.sum(1)).reshape(-1)
    for t in range(xf.shape[0]):
        q = xf[t][f]
        sum_q = adj @ q.sum(1)
        spq = adj @ np.einsum("fki,fkj->fij", rp, q).reshape(nf, 9)
        h = spq.reshape(nf, 3, 3) - np.einsum("fi,fj->fij", sum_p, sum_q) / cnt[:, None, None]
        u, _, vt = np.linalg.svd(h)  # h = U S Vᵀ; R = V diag(1, 1, det(V Uᵀ)) Uᵀ
        det = np.linalg.det(np.einsum("fji,fkj->fik", vt, u))
        dmat = np.ones((nf, 3))
        dmat[:, 2] = np.where(det < 0, -1.0, 1.0)
        rot = np.einsum("fji,fj,fkj->fik", vt, dmat, u)
        out[t] = np.einsum("fi,fij,fj->f", n_frame[t], rot, n_rest) < 0
    return out.reshape(*lead, nf)


# ----------------------------------------------------------------------------------------------
# Everything


def _check_map(face, bary, n: int, n_faces: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    face = np.asarray(face)
    bary = np.asarray(bary, dtype=np.float64)
    if face.shape != (n,) or bary.shape != (n, 3):
        raise InputError(f"{what}: expected face ({n},) and bary ({n}, 3), got {face.shape} and {bary.shape}")
    if not np.issubdtype(face.dtype, np.integer):
        raise InputError(f"{what}: face indices must be integers, got {face.dtype}")
    if n and (face.min() < 0 or face.max() >= n_faces):
        raise InputError(f"{what}: face index out of range [0, {n_faces})")
    if not np.all(np.isfinite(bary)):
        raise InputError(f"{what}: barycentric coordinates contain NaN or infinity")
    return face.astype(np.int64), bary


def evaluate_correspondence(
    source: Mesh,
    target: Mesh | PointCloud,
    pred_face: Int[np.ndarray, " W"],
    pred_bary: Float[np.ndarray, "W 3"],
    gt_face: Int[np.ndarray, " K"],
    gt_bary: Float[np.ndarray, "K 3"],
    deformed_vertices: Float[np.ndarray, "V 3"] | None = None,
    frames: Float[np.ndarray, "T V 3"] | None = None,
    *,
    gt_index: Int[np.ndarray, " K"] | None = None,
    geodesic_method: str = "auto",
    tau_max: dict | None = None,
    inverted_mode: str = "local",
) -> dict:
    """All metrics of one matched pair.

    Args:
        source: the source mesh (user coordinates, rest pose).
        target: the target mesh (user coordinates) with W vertices.
        pred_face: (W,) for every target vertex, the source face of its predicted source point
            (``map_tgt_to_src.npz``).
        pred_bary: (W, 3) barycentric coordinates of that predicted point in its face.
        gt_face: (K,) source face of the true source point of every target vertex (K = W), or of
            the target vertices ``gt_index`` (partial ground truth, e.g. template-based datasets).
        gt_bary: (K, 3) barycentric coordinates of that true point in its face.
        deformed_vertices: (V, 3) flowed source at t = 1 in target coordinates; enables Chamfer.
            Defaults to ``frames[-1]`` when frames are given.
        frames: (T, V, 3) interpolation frames (source connectivity); enables conformal
            distortion, inverted triangles and volume change. Defaults to ``deformed_vertices[None]``.
            Every given frame is scored (a frame identical to the source scores 0 distortion).
        gt_index: target vertices that have ground truth (default: all, in order).
        geodesic_method: see :func:`geodesic_errors`.
        tau_max: overrides of :data:`TAU_MAX`.
        inverted_mode: ``"local"`` or ``"global"``, see :func:`inverted_triangles`.

    Returns:
        ``{"summary": {...}, "arrays": {...}}``. ``summary`` holds Python scalars and lists
        (JSON-ready except possible ±inf/NaN): ``unit_cube_scale``, ``geodesic`` (+ ``geodesic_solver``),
        ``chamfer_src_to_tgt``, ``chamfer_tgt_to_src``, ``chamfer`` (mean of the two directions'
        means and AUCs), ``conformal`` (K − 1 over all frames × triangles), ``mips``,
        ``conformal_per_frame`` (mean K − 1 per frame), ``inverted_triangles`` (count per frame),
        ``volume_change`` (per frame); each error entry is :func:`error_summary`.
        ``arrays`` holds ``geodesic`` (W,) with NaN where no ground truth,
        ``chamfer_src_to_tgt`` (V,), ``chamfer_tgt_to_src`` (W,), ``conformal`` and ``mips``
        (T, F), ``inverted`` (T, F) bool, ``volume_change`` (T,).
    """
    taus = dict(TAU_MAX, **(tau_max or {}))
    nt, nfs = target.n_vertices, source.n_faces
    pred_face, pred_bary = _check_map(pred_face, pred_bary, nt, nfs, "predicted map")
    if gt_index is None:
        gt_index = np.arange(nt)
    gt_index = np.asarray(gt_index, dtype=np.int64)
    if gt_index.size and (gt_index.min() < 0 or gt_index.max() >= nt):
        raise InputError(f"ground truth: target vertex index out of range [0, {nt})")
    gt_face, gt_bary = _check_map(gt_face, gt_bary, gt_index.size, nfs, "ground truth")

    scale = unit_cube_scale(source.vertices)
    summary: dict = {"unit_cube_scale": scale}
    arrays: dict = {}

    geo = np.full(nt, np.nan)
    e, info = geodesic_errors(
        source, pred_face[gt_index], pred_bary[gt_index], gt_face, gt_bary, method=geodesic_method, return_info=True
    )
    geo[gt_index] = e
    arrays["geodesic"] = geo
    summary["geodesic"] = error_summary(e, taus["geodesic"])
    summary["geodesic_solver"] = info.to_dict()

    if frames is not None:
        frames = np.asarray(frames, dtype=np.float64)
        if frames.ndim != 3 or frames.shape[1:] != (source.n_vertices, 3):
            raise InputError(f"frames: expected shape (T, {source.n_vertices}, 3), got {frames.shape}")
    if deformed_vertices is None and frames is not None:
        deformed_vertices = frames[-1]
    if deformed_vertices is not None:
        deformed_vertices = np.asarray(deformed_vertices, dtype=np.float64)
        if deformed_vertices.shape != (source.n_vertices, 3):
            raise InputError(f"deformed source: expected shape ({source.n_vertices}, 3), got {deformed_vertices.shape}")
        if frames is None:
            frames = deformed_vertices[None]
        a, b = chamfer_distances(deformed_vertices, source.faces, target, scale=scale)
        arrays["chamfer_src_to_tgt"], arrays["chamfer_tgt_to_src"] = a, b
        sa, sb = error_summary(a, taus["chamfer"]), error_summary(b, taus["chamfer"])
        summary["chamfer_src_to_tgt"], summary["chamfer_tgt_to_src"] = sa, sb
        summary["chamfer"] = {
            "mean": 0.5 * (sa["mean"] + sb["mean"]),
            "auc": 0.5 * (sa["auc"] + sb["auc"]),
            "tau_max": float(taus["chamfer"]),
        }
    if frames is not None:
        k1, mips = conformal_distortion(source.vertices, source.faces, frames)
        inv = inverted_triangles(source.vertices, source.faces, frames, mode=inverted_mode)
        vol = volume_change(frames, source.faces)
        arrays.update(conformal=k1, mips=mips, inverted=inv, volume_change=vol)
        summary["conformal"] = error_summary(k1, taus["conformal"])
        summary["mips"] = error_summary(mips, taus["conformal"])
        with np.errstate(invalid="ignore"):
            summary["conformal_per_frame"] = [float(np.nanmean(row)) for row in k1]
        summary["inverted_triangles"] = [int(c) for c in inv.sum(1)]
        summary["inverted_mode"] = inverted_mode
        summary["volume_change"] = [float(x) for x in vol]
    return {"summary": summary, "arrays": arrays}


CURVE_METRICS = ("geodesic", "chamfer", "conformal")
