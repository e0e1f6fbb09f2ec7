"""Large articulations of synthetic characters' poses, for harder pairs.

:func:`articulate` adds to a pose (e.g. from :func:`ncflow.synthetic.characters.random_pose`)
further large hinge flexions drawn from the spec's large joints and/or a named whole-body
articulation from :data:`ARTICULATIONS` (humanoid cross, stride and crouch; hand curl; quadruped
gallop), each built from joint rotations about the spec's natural flexion axes and drawn from its
own seed, so the same seed always gives the same pose.
"""

from __future__ import annotations

import numpy as np

from ncflow.errors import InputError
from ncflow.geometry.rigid import matrix_to_quat, rotvec_to_matrix
from ncflow.skeleton import Pose
from ncflow.synthetic.bodies import CharacterSpec


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _flex(spec: CharacterSpec, name: str, degrees: float) -> np.ndarray:
    """Rotation matrix of a flexion of ``degrees`` about the joint's natural axis."""
    return rotvec_to_matrix(np.radians(degrees) * spec.flex_axes[spec.joint(name)])


def _frame_rotation(a0: np.ndarray, b0: np.ndarray, a1: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """The rotation taking the orthonormal pair (a0, b0) to (a1, b1)."""
    f0 = np.stack([a0, b0, np.cross(a0, b0)], axis=1)
    f1 = np.stack([a1, b1, np.cross(a1, b1)], axis=1)
    return f1 @ f0.T


def _arm_towards(spec: CharacterSpec, side: str, upper: np.ndarray, fore: np.ndarray) -> dict[str, np.ndarray]:
    """Shoulder and elbow rotations pointing the upper arm along ``upper``, the forearm along ``fore``.

    Both are rest-frame unit vectors; the elbow bends about its own hinge axis only.
    """
    sh, el = spec.joint(f"shoulder_{side}"), spec.joint(f"elbow_{side}")
    d0 = _unit(spec.positions[el] - spec.positions[sh])
    hinge = spec.flex_axes[el]
    n = _unit(np.cross(upper, fore))
    bend = np.degrees(np.arccos(np.clip(upper @ fore, -1.0, 1.0)))
    return {
        f"shoulder_{side}": _frame_rotation(d0, hinge, upper, n),
        f"elbow_{side}": _flex(spec, f"elbow_{side}", bend),
    }


def _jitter(rng: np.random.Generator, v, amount: float = 0.08) -> np.ndarray:
    return _unit(np.asarray(v, dtype=np.float64) + amount * rng.normal(size=3))


def _humanoid_cross(spec: CharacterSpec, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Arms crossed in front of the chest.

    Each forearm points across the body, one above and in front of the other (which one: drawn).
    """
    top = ("l", "r")[int(rng.integers(2))]
    out = {}
    for side in ("l", "r"):
        sx = 1.0 if side == "l" else -1.0
        if side == top:
            upper, fore = [sx * 0.30, -0.35, 0.90], [-sx * 0.80, 0.12, 0.40]
        else:
            upper, fore = [sx * 0.35, -0.75, 0.60], [-sx * 0.85, 0.0, 0.35]
        out.update(_arm_towards(spec, side, _jitter(rng, upper, 0.05), _jitter(rng, fore, 0.05)))
    return out


def _humanoid_stride(spec: CharacterSpec, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """A long stride.

    One hip flexed forward 35–55°, the other extended 25–40° with its knee bent 60–90°; the arms
    swing the other way (20–35° about the body's left–right axis).
    """
    front = ("l", "r")[int(rng.integers(2))]
    back = "r" if front == "l" else "l"
    swing = np.array([1.0, 0.0, 0.0])  # a negative angle about +x swings a hanging arm forward
    return {
        f"hip_{front}": _flex(spec, f"hip_{front}", rng.uniform(35.0, 55.0)),
        f"knee_{front}": _flex(spec, f"knee_{front}", rng.uniform(5.0, 25.0)),
        f"hip_{back}": _flex(spec, f"hip_{back}", -rng.uniform(25.0, 40.0)),
        f"knee_{back}": _flex(spec, f"knee_{back}", rng.uniform(60.0, 90.0)),
        f"shoulder_{front}": rotvec_to_matrix(np.radians(rng.uniform(20.0, 35.0)) * swing),
        f"shoulder_{back}": rotvec_to_matrix(-np.radians(rng.uniform(20.0, 35.0)) * swing),
        f"elbow_{front}": _flex(spec, f"elbow_{front}", rng.uniform(10.0, 30.0)),
        f"elbow_{back}": _flex(spec, f"elbow_{back}", rng.uniform(40.0, 70.0)),
    }


def _humanoid_crouch(spec: CharacterSpec, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """A crouch: both hips flexed 55–80°, both knees bent 85–110°, arms raised forward 40–70°."""
    swing = np.array([1.0, 0.0, 0.0])
    out = {}
    for side in ("l", "r"):
        out[f"hip_{side}"] = _flex(spec, f"hip_{side}", rng.uniform(55.0, 80.0))
        out[f"knee_{side}"] = _flex(spec, f"knee_{side}", rng.uniform(85.0, 110.0))
        out[f"shoulder_{side}"] = rotvec_to_matrix(-np.radians(rng.uniform(40.0, 70.0)) * swing)
    return out


def _hand_curl(spec: CharacterSpec, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Every finger curled.

    Knuckle (MCP) 60–85°, middle (PIP) 70–100°, end (DIP) 45–70° towards the palm; the thumb
    10–25°, 30–50°, 30–55° about its own curl axis.
    """
    out = {}
    for name in spec.names:
        if name[-1:] in "123" and not name.startswith("thumb"):
            lo, hi = {"1": (60.0, 85.0), "2": (70.0, 100.0), "3": (45.0, 70.0)}[name[-1]]
        elif name in ("thumb1", "thumb2", "thumb3"):
            lo, hi = {"1": (10.0, 25.0), "2": (30.0, 50.0), "3": (30.0, 55.0)}[name[-1]]
        else:
            continue
        out[name] = _flex(spec, name, rng.uniform(lo, hi))
    return out


def _quadruped_gallop(spec: CharacterSpec, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """A gallop's extension.

    Forelegs swung forward 45–70° at the shoulder, hind legs back 35–60° at the hip, elbows and
    knees bent 15–45°, the tail raised.
    """
    out = {}
    for side in ("l", "r"):
        out[f"shoulder_{side}"] = _flex(spec, f"shoulder_{side}", rng.uniform(45.0, 70.0))
        out[f"elbow_{side}"] = _flex(spec, f"elbow_{side}", rng.uniform(15.0, 45.0))
        out[f"hip_{side}"] = _flex(spec, f"hip_{side}", -rng.uniform(35.0, 60.0))
        out[f"knee_{side}"] = _flex(spec, f"knee_{side}", rng.uniform(15.0, 45.0))
    out["tail1"] = _flex(spec, "tail1", rng.uniform(10.0, 35.0))
    return out


#: named whole-body articulations per kind (see :func:`articulate`)
ARTICULATIONS = {
    "humanoid": {"cross": _humanoid_cross, "stride": _humanoid_stride, "crouch": _humanoid_crouch},
    "hand": {"curl": _hand_curl},
    "quadruped": {"gallop": _quadruped_gallop},
}


def articulate(
    spec: CharacterSpec,
    pose: Pose,
    seed: int | list[int],
    *,
    large_joints: int = 1,
    large_angle: tuple[float, float] = (60.0, 100.0),
    articulation: str | None = None,
    exclude: tuple[str, ...] = (),
) -> tuple[Pose, dict]:
    """Add large rotations to a pose: more large hinge flexions and/or a named whole-body articulation.

    Args:
        spec: the character's spec.
        pose: the pose to change (e.g. from :func:`random_pose`, which already flexes one large joint).
        seed: seed (or seed sequence) of the draws, independent of the pose's own.
        large_joints: number of joints with a large flexion, counting the pose's own one:
            ``large_joints − 1`` further joints are drawn without replacement from
            ``spec.large_joints`` (humanoid: elbows and knees; hand: the fingers' middle joints;
            quadruped: neck, tail base, elbows and knees) less ``exclude``, each flexed by an
            angle uniform in ``large_angle`` in its large direction.
        large_angle: degrees.
        articulation: a name of :data:`ARTICULATIONS` for the spec's kind, applied last: humanoid
            ``"cross"`` (arms crossed in front of the chest), ``"stride"`` (a long stride, arms
            swinging the other way), ``"crouch"`` (hips and knees bent 55–110°, arms forward);
            hand ``"curl"`` (every finger joint flexed 45–100°, the thumb curled); quadruped
            ``"gallop"`` (forelegs swung 45–70° forward, hind legs 35–60° back).
        exclude: joint names that already have their large rotation (not drawn again).

    Returns:
        (the new pose: the chosen joints' rotations replaced, everything else as given; info with
        ``extra_large_joints`` (names of the added large flexions), ``extra_large_angles_deg`` and
        ``articulation_joints`` (the joints the articulation set)).
    """
    if large_joints < 1:
        raise InputError(f"large_joints must be at least 1, got {large_joints}")
    presets = ARTICULATIONS.get(spec.kind, {})
    if articulation is not None and articulation not in presets:
        choices = ", ".join(sorted(presets)) or "none"
        raise InputError(f"no articulation {articulation!r} for the {spec.kind}; choose one of {choices}")
    seq = [int(s) for s in (seed if isinstance(seed, (list, tuple)) else [seed])]
    pool = [j for j in spec.large_joints if spec.names[j] not in exclude]
    n_more = large_joints - 1
    if n_more > len(pool):
        raise InputError(
            f"the {spec.kind} has {len(spec.large_joints)} joints for large rotations, {large_joints} asked for"
        )
    rots: dict[str, np.ndarray] = {}
    names, angles = [], []
    rng = np.random.default_rng(seq + [1])
    for j in rng.permutation(np.asarray(pool, dtype=np.int64))[:n_more]:
        angle = float(rng.uniform(*large_angle))
        rots[spec.names[j]] = rotvec_to_matrix(spec.large_sign[j] * np.radians(angle) * spec.flex_axes[j])
        names.append(spec.names[j])
        angles.append(angle)
    preset = presets[articulation](spec, np.random.default_rng(seq + [2])) if articulation is not None else {}
    rots.update(preset)
    q = np.array(pose.rotations, dtype=np.float64)
    for name, rot in rots.items():
        q[spec.joint(name)] = matrix_to_quat(rot, scalar_first=True)
    info = {"extra_large_joints": names, "extra_large_angles_deg": angles, "articulation_joints": sorted(preset)}
    return Pose(q, np.array(pose.translation, dtype=np.float64)), info
