"""Rigid motions of a target (turned and moved pairs).

They are drawn from the pair seed, applied to the target and its joints, and recorded with the
pair; the ground truth does not change under them.
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Float

from ncflow.errors import InputError
from ncflow.geometry.rigid import rotvec_to_matrix


def _range(value: float | tuple[float, float] | None, what: str) -> tuple[float, float]:
    """(lo, hi) of a number (exactly that value) or a (lo, hi) range; None is (0, 0)."""
    if value is None:
        return 0.0, 0.0
    lo, hi = (float(value), float(value)) if np.ndim(value) == 0 else (float(value[0]), float(value[1]))
    if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 <= lo <= hi):
        raise InputError(f"{what} must be a number >= 0 or a range lo <= hi of such numbers, got {value!r}")
    return lo, hi


def target_motion(
    seed: int,
    rotation_deg: float | tuple[float, float] | None,
    translation: float | tuple[float, float] | None,
    centre: Float[np.ndarray, " 3"],
    scale: float,
) -> dict | None:
    """Draw the rigid motion ``x ↦ R x + t`` that turns and moves a target (reproducible from ``seed``).

    The rotation turns by ``rotation_deg`` degrees (a number: exactly that angle; a pair
    ``(lo, hi)``: uniform in that range) about an axis uniform on the sphere through ``centre``;
    then ``centre`` is shifted by ``translation × scale`` (same number-or-range rule) in a uniform
    random direction. So ``t = centre − R centre + shift``. The stream is
    ``default_rng([seed, 0x5EED, 4])``, independent of every other draw of a pair.

    Args:
        seed: the pair's seed.
        rotation_deg: rotation angle (degrees, at most 180) or range; None or 0: no rotation.
        translation: shift as a fraction of ``scale``, or a range; None or 0: no shift.
        centre: (3,) the point the rotation turns about (the unmoved target's vertex mean).
        scale: the length ``translation`` is a fraction of (the source's bounding-box diagonal).

    Returns:
        None when both are zero; else a dict with ``rotation`` (3, 3), ``translation`` (3,) (the
        ``t`` of ``R x + t``), ``angle_deg``, ``axis`` (3,), ``centre`` (3,), ``shift`` (3,) as
        NumPy float64 arrays / floats.
    """
    r_lo, r_hi = _range(rotation_deg, "the target rotation")
    t_lo, t_hi = _range(translation, "the target translation")
    if r_hi > 180.0:
        raise InputError(f"the target rotation is at most 180 degrees, got {rotation_deg!r}")
    if r_hi == 0.0 and t_hi == 0.0:
        return None
    rng = np.random.default_rng(_pair_seed(seed, 4))
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = rng.uniform(r_lo, r_hi)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    shift = rng.uniform(t_lo, t_hi) * float(scale) * direction
    rot = rotvec_to_matrix(np.radians(angle) * axis)
    c = np.asarray(centre, dtype=np.float64).reshape(3)
    return {
        "rotation": rot,
        "translation": c - rot @ c + shift,
        "angle_deg": float(angle),
        "axis": axis,
        "centre": c,
        "shift": shift,
    }


def _bbox_diagonal(vertices: np.ndarray) -> float:
    return float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))


def move_target(
    target_vertices: Float[np.ndarray, "W 3"],
    target_joints: Float[np.ndarray, "J 3"] | None,
    source_vertices: Float[np.ndarray, "V 3"],
    seed: int,
    rotation_deg: float | tuple[float, float] | None = None,
    translation: float | tuple[float, float] | None = None,
) -> tuple[Float[np.ndarray, "W 3"], Float[np.ndarray, "J 3"] | None, dict | None]:
    """Turn and move a target (and its joints) by one rigid motion drawn by :func:`target_motion`.

    The rotation turns about the target's vertex mean; ``translation`` is a fraction of the
    source's bounding-box diagonal. A rigid motion of the target leaves the ground truth (source
    face + barycentrics per target vertex) unchanged.

    Returns:
        (``R x + t`` of the target vertices, of the joints (or None), the motion dict or None
        when there is none — then the inputs are returned as they are).
    """
    tv = np.asarray(target_vertices, dtype=np.float64)
    motion = target_motion(seed, rotation_deg, translation, tv.mean(axis=0), _bbox_diagonal(source_vertices))
    if motion is None:
        return target_vertices, target_joints, None
    rot, t = motion["rotation"], motion["translation"]
    moved_j = None if target_joints is None else np.asarray(target_joints, dtype=np.float64) @ rot.T + t
    return tv @ rot.T + t, moved_j, motion


def motion_record(motion: dict) -> dict:
    """The JSON form of a :func:`target_motion` dict (lists of floats)."""
    return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in motion.items()}


def _pair_seed(seed: int, which: int) -> list[int]:
    return [int(seed), 0x5EED, int(which)]
