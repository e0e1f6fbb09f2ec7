"""The one similarity that normalises a matching problem (docs/architecture.md, "Normalisation").

:func:`fit_normalization` centres the source on its area-weighted surface centroid (independent of
the triangulation) and scales it to enclose the volume of the unit ball, 4π/3, as the authors'
release does; an open source is closed by fans first
(:func:`~ncflow.geometry.topology.close_boundary`), and a surface enclosing almost no volume is
scaled to area 4π instead. The same :class:`Normalization` is applied to the target and the
skeleton, and inverted on every output, so results are in the user's coordinates.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from jaxtyping import Float, Int

from ncflow.geometry.mesh import enclosed_volume, face_areas

UNIT_BALL_VOLUME = 4.0 * np.pi / 3.0


@dataclasses.dataclass(frozen=True)
class Normalization:
    """One similarity x ↦ (x − center) · scale, shared by source and target; reversible.

    Attributes:
        center: (3,) the source's area-weighted surface centroid (user coordinates).
        scale: positive factor making the source enclose the volume of the unit ball (4π/3).
    """

    center: Float[np.ndarray, " 3"]
    scale: float

    def apply(self, points: Float[np.ndarray, "... 3"]) -> Float[np.ndarray, "... 3"]:
        """User coordinates → normalised coordinates."""
        return (np.asarray(points, dtype=np.float64) - self.center) * self.scale

    def invert(self, points: Float[np.ndarray, "... 3"]) -> Float[np.ndarray, "... 3"]:
        """Normalised coordinates → user coordinates."""
        return np.asarray(points, dtype=np.float64) / self.scale + self.center

    def to_dict(self) -> dict:
        """``{"center": [x, y, z], "scale": s}`` as plain Python floats (JSON-serialisable)."""
        return {"center": [float(c) for c in self.center], "scale": float(self.scale)}


def fit_normalization(
    vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"], target_volume: float = UNIT_BALL_VOLUME
) -> Normalization:
    """The similarity that centres a (source) mesh and scales it to enclose ``target_volume``.

    Centre: area-weighted centroid of the surface (independent of the triangulation). Scale:
    (target_volume / V)^(1/3) with V the enclosed volume (:func:`enclosed_volume`; open meshes
    are closed by fans to their boundary-loop centroids). A surface enclosing almost no volume
    (a flat sheet) is instead scaled to the surface area of the unit sphere, 4π.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    areas = face_areas(vertices, faces)
    centres = vertices[np.asarray(faces)].mean(1)
    total = areas.sum()
    center = (centres * areas[:, None]).sum(0) / total if total > 0 else vertices.mean(0)
    volume = enclosed_volume(vertices, faces)
    diag = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    if volume > 1e-6 * diag**3:
        scale = (target_volume / volume) ** (1.0 / 3.0)
    else:
        scale = float(np.sqrt(4.0 * np.pi / total))
    return Normalization(center=center, scale=float(scale))
