"""Solid primitives with signed distances, and their smooth union: the parts of the procedural characters.

A :class:`RoundCone` (a swept sphere whose radius varies linearly from one end to the other; Quilez's
exact signed distance) models limbs, fingers and tails; an :class:`Ellipsoid` (a signed-distance
bound, exact on the surface) models the torso, head and palm. Each is attached to a bone. The
smooth union f = −k log Σ_p exp(−d_p/k) of their distances (computed stably around the minimum;
k is the blend width) is symmetric, so no primitive order matters.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from jaxtyping import Float


@dataclasses.dataclass(frozen=True)
class RoundCone:
    """Solid swept sphere from ``a`` (radius ``ra``) to ``b`` (radius ``rb``), attached to ``bone``."""

    a: Float[np.ndarray, " 3"]
    b: Float[np.ndarray, " 3"]
    ra: float
    rb: float
    bone: int

    @property
    def scale(self) -> float:
        return 0.5 * (self.ra + self.rb)

    def distance(self, p: Float[np.ndarray, "n 3"]) -> Float[np.ndarray, " n"]:
        """Exact signed distance (Quilez's round cone), negative inside."""
        a, b, r1, r2 = self.a, self.b, self.ra, self.rb
        ba = b - a
        l2 = float(ba @ ba)
        rr = r1 - r2
        a2 = l2 - rr * rr
        il2 = 1.0 / l2
        pa = p - a
        y = pa @ ba
        z = y - l2
        x2 = np.sum((pa * l2 - y[:, None] * ba) ** 2, axis=1)
        y2 = y * y * l2
        z2 = z * z * l2
        k = np.sign(rr) * rr * rr * x2
        d_b = np.sqrt(x2 + z2) * il2 - r2
        d_a = np.sqrt(x2 + y2) * il2 - r1
        d_side = (np.sqrt(np.maximum(x2 * a2 * il2, 0.0)) + y * rr) * il2 - r1
        return np.where(np.sign(z) * a2 * z2 > k, d_b, np.where(np.sign(y) * a2 * y2 < k, d_a, d_side))


@dataclasses.dataclass(frozen=True)
class Ellipsoid:
    """Solid axis-aligned ellipsoid (``center``, semi-axes ``radii``) attached to ``bone``."""

    center: Float[np.ndarray, " 3"]
    radii: Float[np.ndarray, " 3"]
    bone: int

    @property
    def scale(self) -> float:
        """Half the smallest semi-axis: the reach of its skinning influence (see :func:`skinning_weights`)."""
        return 0.5 * float(np.min(self.radii))

    def distance(self, p: Float[np.ndarray, "n 3"]) -> Float[np.ndarray, " n"]:
        """Signed distance bound ``k0 (k0 - 1) / k1`` (exact on the surface, negative inside)."""
        q = p - self.center
        k0 = np.linalg.norm(q / self.radii, axis=1)
        k1 = np.linalg.norm(q / (self.radii * self.radii), axis=1)
        return k0 * (k0 - 1.0) / np.maximum(k1, 1e-300)


def smooth_min(d: np.ndarray, k: float) -> np.ndarray:
    """Smooth minimum over axis 0: ``−k log Σ_p exp(−d_p / k)``, evaluated stably (shifted by the minimum)."""
    m = d.min(axis=0)
    return m - k * np.log(np.exp(-(d - m) / k).sum(axis=0))
