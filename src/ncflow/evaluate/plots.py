"""Figures of an evaluation and of a benchmark, drawn headless with matplotlib.

Figures use matplotlib's Agg canvas (``matplotlib.figure.Figure``, no pyplot, no global backend
change), imported only when a figure is drawn. For one result (:data:`EVALUATION_PLOTS`):

* ``eval_cumulative.png`` — cumulative curves: geodesic (τ 0–0.20), Chamfer (0–0.10, the mean of
  both directions' curves, so its AUC is the reported Chamfer AUC), conformal K − 1 (0–0.15), AUC in
  the legends (:func:`plot_cumulative_curves`);
* ``eval_geodesic_error.png`` — the target coloured by its per-vertex geodesic error (0 to 0.20,
  two views; grey: no ground truth; :func:`render_error_map`);
* ``eval_color_transfer.png`` — a smooth colour function of the source (its normalised
  coordinates as RGB) on the source, transferred to the target through the predicted map and
  through the ground truth (:func:`render_color_transfer`).

For a benchmark, :func:`plot_benchmark_curves` draws the mean cumulative curve per method with a
95 % bootstrap confidence band of the mean across pairs
(:func:`~ncflow.evaluate.aggregate.mean_curve_band`).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ncflow.evaluate.aggregate import mean_curve_band, mean_std
from ncflow.evaluate.formatting import format_number
from ncflow.evaluate.metrics import CURVE_METRICS, TAU_MAX
from ncflow.geometry.barycentric import surface_points
from ncflow.geometry.mesh import Mesh
from ncflow.io.ground_truth import GroundTruth

EVALUATION_PLOTS = {
    "cumulative": "eval_cumulative.png",
    "geodesic_error": "eval_geodesic_error.png",
    "color_transfer": "eval_color_transfer.png",
}


_CURVE_TITLES = {
    "geodesic": "geodesic error / sqrt(area)",
    "chamfer": "Chamfer distance (unit cube)",
    "conformal": "conformal distortion K - 1",
}


_NO_DATA_RGB = np.array([0.72, 0.72, 0.72])


def _plot_writers(ev) -> dict:
    rec = ev.record
    aucs = {m: rec["headline"][f"{m}_auc"] for m in CURVE_METRICS}
    title = Path(rec["inputs"]["result_dir"]).name
    writers = {
        "cumulative": lambda p: plot_cumulative_curves(rec["curves"], aucs, p, title=title),
        "geodesic_error": lambda p: render_error_map(
            ev.target.vertices,
            ev.target.faces,
            ev.arrays["geodesic"],
            p,
            vmax=TAU_MAX["geodesic"],
            title=f"{title}: geodesic error on the target",
        ),
        "color_transfer": lambda p: render_color_transfer(
            ev.source, ev.target, ev.pred_face, ev.pred_bary, ev.ground_truth, p, title=title
        ),
    }
    if not ev.target.faces.shape[0]:  # a point cloud: no surface to colour (the viewer shows its points)
        del writers["geodesic_error"], writers["color_transfer"]
    return writers


def _figure(width: float, height: float):
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), dpi=100, layout="constrained")


def plot_cumulative_curves(curves: dict, aucs: dict, path: str | os.PathLike, title: str | None = None) -> None:
    """Cumulative curves (one panel per metric of :func:`cumulative_curves`), AUC in the legend; a PNG."""
    names = [m for m in CURVE_METRICS if m in curves]
    fig = _figure(4.0 * max(1, len(names)), 3.6)
    axes = fig.subplots(1, max(1, len(names)), squeeze=False)[0]
    for ax, name in zip(axes, names):
        c = curves[name]
        ax.plot(c["tau"], c["pck"], lw=2, color="C0", label=f"AUC {format_number(aucs.get(name), '.3f')}")
        _curve_axes(ax, name, c["tau_max"])
        ax.legend(loc="lower right")
    if title:
        fig.suptitle(title)
    fig.savefig(path, format="png")


def _curve_axes(ax, name: str, tau_max: float) -> None:
    ax.set_xlim(0.0, tau_max)
    ax.set_ylim(0.0, 1.01)
    ax.set_xlabel(_CURVE_TITLES[name])
    ax.set_ylabel("fraction below threshold")
    ax.grid(alpha=0.3)


def _view_coordinates(vertices: np.ndarray) -> np.ndarray:
    """Model y-up coordinates to matplotlib's z-up frame by a proper rotation (x, -z, y)."""
    v = np.asarray(vertices, dtype=np.float64)
    return np.stack([v[:, 0], -v[:, 2], v[:, 1]], axis=1)


def _draw_mesh(ax, vertices: np.ndarray, faces: np.ndarray, face_rgb: np.ndarray, azim: float) -> None:
    """Lambert-shaded triangles (painter's order), equal aspect, no axes."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    p = _view_coordinates(vertices)
    tri = p[np.asarray(faces, dtype=np.int64)]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    el, az = np.radians(20.0), np.radians(azim)
    light = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    shade = 0.35 + 0.65 * np.abs(n @ light)
    ax.add_collection3d(Poly3DCollection(tri, facecolors=np.clip(face_rgb * shade[:, None], 0, 1), edgecolors="none"))
    lo, hi = p.min(0), p.max(0)
    side = np.maximum(hi - lo, 1e-3 * float(np.max(hi - lo)))  # flat shapes keep a visible box
    ax.set_xlim(lo[0], lo[0] + side[0])
    ax.set_ylim(lo[1], lo[1] + side[1])
    ax.set_zlim(lo[2], lo[2] + side[2])
    ax.set_box_aspect(tuple(side), zoom=1.3)  # equal scale on every axis
    ax.view_init(elev=20.0, azim=azim)
    ax.set_axis_off()


def _face_values(faces: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Per-face mean of per-vertex values (NaN if any corner is NaN)."""
    return np.asarray(values, dtype=np.float64)[np.asarray(faces, dtype=np.int64)].mean(axis=1)


def render_error_map(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    errors: Float[np.ndarray, " V"],
    path: str | os.PathLike,
    vmax: float = TAU_MAX["geodesic"],
    title: str | None = None,
) -> None:
    """Render a mesh coloured by a per-vertex error (0 to ``vmax``, clipped; NaN grey), two views; a PNG."""
    import matplotlib

    cmap = matplotlib.colormaps["turbo"]
    fe = _face_values(faces, errors)
    rgb = cmap(np.clip(np.nan_to_num(fe, nan=0.0, posinf=vmax) / vmax, 0.0, 1.0))[:, :3]
    rgb[np.isnan(fe)] = _NO_DATA_RGB
    fig = _figure(10.0, 5.0)
    for k, azim in enumerate((-60.0, 120.0)):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        _draw_mesh(ax, vertices, faces, rgb, azim)
    mappable = matplotlib.cm.ScalarMappable(norm=matplotlib.colors.Normalize(0.0, vmax), cmap=cmap)
    fig.colorbar(mappable, ax=fig.axes, shrink=0.7, label="error (grey: no ground truth)")
    if title:
        fig.suptitle(title)
    fig.savefig(path, format="png")


def source_colors(vertices: Float[np.ndarray, "V 3"]) -> Float[np.ndarray, "V 3"]:
    """A smooth colour per vertex: the coordinates normalised to [0, 1] on the bounding box, as RGB."""
    v = np.asarray(vertices, dtype=np.float64)
    lo, hi = v.min(0), v.max(0)
    return (v - lo) / np.where(hi > lo, hi - lo, 1.0)


def render_color_transfer(
    source: Mesh,
    target: Mesh,
    pred_face: Int[np.ndarray, " Vt"],
    pred_bary: Float[np.ndarray, "Vt 3"],
    ground_truth: GroundTruth,
    path: str | os.PathLike,
    title: str | None = None,
) -> None:
    """Source coloured by :func:`source_colors`, and the target coloured through the predicted map
    and through the ground truth (grey where there is none), side by side; a PNG.
    """
    cs = source_colors(source.vertices)
    pred = surface_points(cs, source.faces, pred_face, pred_bary)
    truth = np.tile(_NO_DATA_RGB, (target.n_vertices, 1))
    truth[ground_truth.target_index] = surface_points(cs, source.faces, ground_truth.face, ground_truth.bary)
    panels = [
        ("source", source, cs),
        ("target through the predicted map", target, pred),
        ("target through the ground truth", target, truth),
    ]
    fig = _figure(13.5, 4.8)
    for k, (label, mesh, vc) in enumerate(panels):
        ax = fig.add_subplot(1, 3, k + 1, projection="3d")
        _draw_mesh(ax, mesh.vertices, mesh.faces, np.asarray(vc)[mesh.faces].mean(axis=1), -60.0)
        ax.set_title(label)
    if title:
        fig.suptitle(f"{title}: colour transfer through the correspondence")
    fig.savefig(path, format="png")


def plot_benchmark_curves(
    groups: dict[str, list[dict]], path: str | os.PathLike, title: str | None = None, labels: dict | None = None
) -> None:
    """Mean cumulative curve per method with a 95 % bootstrap band of the mean (Figs. 21–23 style).

    Args:
        groups: ``{method: [run rows]}`` (rows of :func:`run_row` with ``curves`` and ``tau_max``).
        path: the PNG.
        title: figure title.
        labels: display names of the methods.
    """
    fig = _figure(4.2 * len(CURVE_METRICS), 3.8)
    axes = fig.subplots(1, len(CURVE_METRICS), squeeze=False)[0]
    for ax, name in zip(axes, CURVE_METRICS):
        tau_max = TAU_MAX[name]
        for k, (method, rows) in enumerate(groups.items()):
            curves = [r["curves"][name] for r in rows if name in r["curves"] and np.all(np.isfinite(r["curves"][name]))]
            if not curves:
                continue
            tau_max = rows[0]["tau_max"].get(name, tau_max)
            tau = np.linspace(0.0, tau_max, len(curves[0]))
            mean, lo, hi = mean_curve_band(np.stack(curves))
            aucs = mean_std([r[f"{name}_auc"] for r in rows])
            label = (labels or {}).get(method, method)
            std = "" if not np.isfinite(aucs["std"]) else f" ± {aucs['std']:.3f}"
            ax.plot(tau, mean, lw=2, color=f"C{k}", label=f"{label} ({aucs['mean']:.3f}{std}, n={len(curves)})")
            ax.fill_between(tau, lo, hi, color=f"C{k}", alpha=0.2, lw=0)
        _curve_axes(ax, name, tau_max)
        ax.legend(loc="lower right", fontsize=7, title="AUC mean ± std", title_fontsize=7)
    if title:
        fig.suptitle(title)
    fig.savefig(path, format="png")
