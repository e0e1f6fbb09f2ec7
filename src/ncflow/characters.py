"""Procedural articulated characters: a humanoid, a hand and a quadruped, with skeletons and skinning.

Used by ``ncflow demo`` and the pair builders (:mod:`ncflow.pairs`) to make matching problems
with exact ground truth and no external data.

Construction
------------
A character is a *spec* (:class:`CharacterSpec`): a joint tree and, attached to its bones, a set
of solid primitives — round cones (capsules with different end radii) along limb bones and
ellipsoids for the torso, head and palm. Its surface is the zero level set of the smooth union
``f(x) = -k log Σ_p exp(-d_p(x) / k)`` of the primitives' signed distances ``d_p`` (``k``: the
blend width; a symmetric smooth minimum, so no primitive order matters). The mesh is extracted
by marching cubes (scikit-image, Lewiner) on a grid of ``resolution`` cells along the largest
extent (checked: one closed manifold component of genus 0 enclosing every joint, else the grid is
shifted and tried again), then improved: rounds of tangential, area-weighted centroid smoothing,
each followed by Newton projection of the vertices back onto ``f = 0``, and Delaunay edge flips.
The result is a closed, consistently outward-wound, single-component genus-0 surface with
near-uniform triangles whose vertices lie on the implicit surface to ~1e-12 (measured over seeds
0–39 of every kind: 2.3–2.9k vertices, smallest triangle angle ≥ 8°, over 99 % of triangles with
all angles above 25°). Proportions (size, limb lengths and
thicknesses, torso width, head size, splay angles) are drawn per seed within plausible ranges;
limbs are kept a little chunkier than life so that the default grid resolves them.

Coordinates: y up, the character faces +z (the hand's fingers point +z, palm towards -y),
metre-like units (humanoid ~1.6–1.9 tall, hand ~0.17–0.21 long, quadruped ~1.1–1.5 long).

Skeleton and skinning
---------------------
Joints are stored in topological order (root first), so :class:`~ncflow.skeleton.Skeleton`
keeps them as given. Every joint lies inside the surface (extremity joints such as finger tips,
the head top, toes and paws sit at the centre of the primitive's end sphere). Bone ``b`` ends at
joint ``b + 1`` and, as everywhere in ncflow (:mod:`ncflow.skeleton.kinematics`), moves rigidly
with the frame of its parent joint. Skinning weights (``(V, B)``, rows sum to 1) come from the
distances of a vertex to the primitives of every bone, through a compactly supported kernel
``(1 − (d_p / R_p)²)³`` with ``R_p`` the primitive's radius, summed per bone, normalised
and diffused one step along the mesh (smooth across joints, rigid in the middle of limbs,
no leaking across a gap to a neighbouring limb).

Posing
------
A pose is an :class:`ncflow.skeleton.Pose`: one unit quaternion ``(w, x, y, z)`` per joint
(internal order) rotating everything distal to the joint about it, in the parent's rest-aligned
frame, plus a root translation — exactly the convention of
:func:`ncflow.skeleton.forward_kinematics`. Forward kinematics is evaluated here in NumPy float64
(independent of JAX's x64 flag) and agrees with the JAX implementation. Skinning is dual-quaternion
skinning by default (``skinning="dqs"``: no candy-wrapper or elbow collapse at large angles) or
linear blend skinning (``"lbs"``). :func:`random_pose` draws small, anatomically signed flexions
(and a little twist) at every joint, one large flexion (60–100° by default) at an elbow, knee,
shoulder, finger, neck or tail joint, and a global rotation + translation.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError
from ncflow.mesh import Mesh
from ncflow.skeleton import Pose, Skeleton

__all__ = [
    "KINDS",
    "DEFAULT_RESOLUTION",
    "RoundCone",
    "Ellipsoid",
    "CharacterSpec",
    "Character",
    "PosedCharacter",
    "character_spec",
    "make_character",
    "character_sdf",
    "primitive_distances",
    "mesh_implicit",
    "relax_on_surface",
    "delaunay_flip",
    "skinning_weights",
    "random_pose",
    "pose_character",
    "pose_from_rotvecs",
    "forward_kinematics_np",
    "skin_lbs",
    "skin_dqs",
    "check_closed_surface",
]

KINDS = ("humanoid", "hand", "quadruped")
#: grid cells along the largest extent, per kind (2.3–2.9k vertices over seeds 0–39)
DEFAULT_RESOLUTION = {"humanoid": 52, "hand": 48, "quadruped": 46}


# ----------------------------------------------------------------------------------------------
# Primitives


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


Primitive = RoundCone | Ellipsoid


@dataclasses.dataclass(frozen=True, eq=False)
class CharacterSpec:
    """The implicit shape, skeleton and pose limits of one procedural character.

    Attributes:
        kind: ``"humanoid"``, ``"hand"`` or ``"quadruped"``.
        seed: the seed the proportions were drawn with.
        names: J joint names.
        positions: (J, 3) rest joint positions (topological order, root first).
        parents: (J,) parent joint, -1 for the root.
        primitives: the solids; each is attached to a bone (bone b ends at joint b + 1).
        blend: smooth-union width k.
        flex_axes: (J, 3) unit axis (rest frame) of the natural flexion of each joint (zero: none).
        flex_range: (J, 2) range in degrees of small random flexions about ``flex_axes``.
        twist: (J,) magnitude in degrees of the small random rotation about a random axis.
        large_joints: joints eligible for the large rotation (a hinge whose axis is perpendicular
            to both adjacent bones, which are collinear at rest).
        large_sign: (J,) +1 or -1: direction of the large flexion about ``flex_axes``.
        size: characteristic size (largest extent of the rest shape's primitives).
    """

    kind: str
    seed: int
    names: tuple[str, ...]
    positions: Float[np.ndarray, "J 3"]
    parents: Int[np.ndarray, " J"]
    primitives: tuple
    blend: float
    flex_axes: Float[np.ndarray, "J 3"]
    flex_range: Float[np.ndarray, "J 2"]
    twist: Float[np.ndarray, " J"]
    large_joints: tuple[int, ...]
    large_sign: Float[np.ndarray, " J"]
    size: float

    @property
    def n_joints(self) -> int:
        return int(self.parents.shape[0])

    @property
    def n_bones(self) -> int:
        return self.n_joints - 1

    def joint(self, name: str) -> int:
        """Index of the joint called ``name``."""
        try:
            return self.names.index(name)
        except ValueError:
            raise InputError(f"no joint named {name!r} in the {self.kind}; joints: {', '.join(self.names)}") from None

    def bounds(self) -> tuple[Float[np.ndarray, " 3"], Float[np.ndarray, " 3"]]:
        """(lower, upper) corners of a box containing every primitive."""
        lo, hi = [], []
        for p in self.primitives:
            if isinstance(p, RoundCone):
                lo.append(np.minimum(p.a - p.ra, p.b - p.rb))
                hi.append(np.maximum(p.a + p.ra, p.b + p.rb))
            else:
                lo.append(p.center - p.radii)
                hi.append(p.center + p.radii)
        return np.min(lo, axis=0), np.max(hi, axis=0)


def primitive_distances(spec: CharacterSpec, points: Float[np.ndarray, "n 3"]) -> Float[np.ndarray, "P n"]:
    """Signed distance of every point to every primitive of ``spec``."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return np.stack([p.distance(points) for p in spec.primitives])


def _smooth_min(d: np.ndarray, k: float) -> np.ndarray:
    m = d.min(axis=0)
    return m - k * np.log(np.exp(-(d - m) / k).sum(axis=0))


def character_sdf(spec: CharacterSpec, points: Float[np.ndarray, "n 3"], chunk: int = 65536) -> Float[np.ndarray, " n"]:
    """The implicit function of the character (negative inside, ~signed distance near the surface)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.empty(points.shape[0])
    for s in range(0, points.shape[0], chunk):
        out[s : s + chunk] = _smooth_min(primitive_distances(spec, points[s : s + chunk]), spec.blend)
    return out


# ----------------------------------------------------------------------------------------------
# Specs of the three kinds


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


class _Builder:
    """Collects joints (in topological order), primitives and pose limits."""

    def __init__(self):
        self.names: list[str] = []
        self.pos: list[np.ndarray] = []
        self.par: list[int] = []
        self.prims: list = []
        self.flex: dict[int, tuple[np.ndarray, float, float]] = {}
        self.twist: dict[int, float] = {}
        self.large: list[int] = []
        self.large_sign: dict[int, float] = {}

    def joint(self, name: str, position, parent: str | None) -> int:
        self.names.append(name)
        self.pos.append(np.asarray(position, dtype=np.float64))
        self.par.append(-1 if parent is None else self.names.index(parent))
        return len(self.names) - 1

    def P(self, name: str) -> np.ndarray:
        return self.pos[self.names.index(name)]

    def bone(self, child: str) -> int:
        return self.names.index(child) - 1

    def cone(self, child: str, a, b, ra: float, rb: float) -> None:
        self.prims.append(RoundCone(np.asarray(a, float), np.asarray(b, float), float(ra), float(rb), self.bone(child)))

    def bone_cone(self, child: str, ra: float, rb: float) -> None:
        j = self.names.index(child)
        self.cone(child, self.pos[self.par[j]], self.pos[j], ra, rb)

    def ellipsoid(self, child: str, center, radii) -> None:
        self.prims.append(Ellipsoid(np.asarray(center, float), np.asarray(radii, float), self.bone(child)))

    def hinge(
        self,
        joint: str,
        child: str,
        bend_towards,
        lo: float,
        hi: float,
        twist: float = 5.0,
        large: bool = False,
        sign: float = 1.0,
    ) -> None:
        """Flexion of ``joint``: positive angles turn the bone ``joint → child`` towards ``bend_towards``."""
        j = self.names.index(joint)
        d = _unit(self.P(child) - self.P(joint))
        axis = _unit(np.cross(d, bend_towards))
        self.flex[j] = (axis, float(lo), float(hi))
        self.twist[j] = float(twist)
        if large:
            self.large.append(j)
            self.large_sign[j] = float(sign)

    def build(self, kind: str, seed: int, blend: float) -> CharacterSpec:
        n = len(self.names)
        axes = np.zeros((n, 3))
        rng_ = np.zeros((n, 2))
        twist = np.zeros(n)
        sign = np.ones(n)
        for j, (a, lo, hi) in self.flex.items():
            axes[j], rng_[j] = a, (lo, hi)
        for j, t in self.twist.items():
            twist[j] = t
        for j, s in self.large_sign.items():
            sign[j] = s
        parents = np.asarray(self.par, dtype=np.int64)
        assert np.all(parents[1:] < np.arange(1, n)) and parents[0] == -1
        spec = CharacterSpec(
            kind=kind,
            seed=int(seed),
            names=tuple(self.names),
            positions=np.stack(self.pos),
            parents=parents,
            primitives=tuple(self.prims),
            blend=float(blend),
            flex_axes=axes,
            flex_range=rng_,
            twist=twist,
            large_joints=tuple(self.large),
            large_sign=sign,
            size=0.0,
        )
        lo, hi = spec.bounds()
        return dataclasses.replace(spec, size=float(np.max(hi - lo)))


def _humanoid(rng: np.random.Generator) -> _Builder:
    u = rng.uniform
    s = u(1.6, 1.9) / 1.75
    th = u(0.95, 1.15)  # limb thickness
    bw = u(0.9, 1.1)  # torso width
    lf, af, tf, hf = u(0.93, 1.07), u(0.93, 1.07), u(0.93, 1.07), u(0.92, 1.08)
    thigh, shin = 0.42 * s * lf * u(0.97, 1.03), 0.41 * s * lf * u(0.97, 1.03)
    splay = np.radians(u(3.0, 7.0))
    hip_half = 0.09 * s * bw
    ankle_h = 0.085 * s
    hip_y = ankle_h + (thigh + shin) * np.cos(splay)
    b = _Builder()
    up = np.array([0.0, 1.0, 0.0])
    b.joint("pelvis", [0, hip_y + 0.04 * s, 0], None)
    b.joint("spine", b.P("pelvis") + [0, 0.16 * s * tf, 0], "pelvis")
    b.joint("chest", b.P("spine") + [0, 0.16 * s * tf, 0], "spine")
    b.joint("neck", b.P("chest") + [0, 0.14 * s * tf, 0], "chest")
    b.joint("head", b.P("neck") + [0, 0.09 * s, 0], "neck")
    b.joint("head_end", b.P("head") + [0, 0.12 * s * hf, 0.01 * s], "head")
    arm_angle = np.radians(u(42.0, 55.0))
    upper, fore, hand = 0.29 * s * af, 0.26 * s * af, 0.12 * s
    for side, sx in (("l", 1.0), ("r", -1.0)):
        d = np.array([sx * np.sin(arm_angle), -np.cos(arm_angle), 0.0])
        sh = b.P("chest") + [sx * 0.17 * s * bw, 0.10 * s * tf, 0]
        b.joint(f"shoulder_{side}", sh, "chest")
        b.joint(f"elbow_{side}", sh + upper * d, f"shoulder_{side}")
        b.joint(f"wrist_{side}", sh + (upper + fore) * d, f"elbow_{side}")
        b.joint(f"hand_{side}", sh + (upper + fore + hand) * d, f"wrist_{side}")
    for side, sx in (("l", 1.0), ("r", -1.0)):
        d = np.array([sx * np.sin(splay), -np.cos(splay), 0.0])
        hip = b.P("pelvis") + [sx * hip_half, -0.04 * s, 0]
        b.joint(f"hip_{side}", hip, "pelvis")
        b.joint(f"knee_{side}", hip + thigh * d, f"hip_{side}")
        ankle = hip + (thigh + shin) * d
        b.joint(f"ankle_{side}", ankle, f"knee_{side}")
        b.joint(f"toe_{side}", ankle + [sx * 0.01 * s, -0.035 * s, 0.14 * s * u(0.95, 1.05)], f"ankle_{side}")
    # solids
    b.ellipsoid("spine", b.P("pelvis") + [0, -0.01 * s, 0], np.array([0.16 * bw, 0.11, 0.11]) * s)
    b.ellipsoid("chest", b.P("spine") + [0, 0.02 * s, 0], np.array([0.145 * bw, 0.13, 0.10]) * s)
    b.ellipsoid("neck", b.P("chest") + [0, 0.03 * s, 0.005 * s], np.array([0.165 * bw, 0.15, 0.11]) * s)
    b.cone("head", b.P("neck") - [0, 0.04 * s, 0], b.P("head"), 0.058 * s, 0.052 * s)
    b.ellipsoid("head_end", b.P("head") + [0, 0.075 * s * hf, 0.015 * s], np.array([0.09, 0.115, 0.10]) * s * hf)
    for side, sx in (("l", 1.0), ("r", -1.0)):
        b.cone(
            f"shoulder_{side}",
            b.P(f"shoulder_{side}") * [0.3, 1, 1],
            b.P(f"shoulder_{side}"),
            0.065 * s,
            0.058 * s * th,
        )
        b.bone_cone(f"elbow_{side}", 0.058 * s * th, 0.048 * s * th)
        b.bone_cone(f"wrist_{side}", 0.048 * s * th, 0.040 * s * th)
        b.bone_cone(f"hand_{side}", 0.042 * s * th, 0.038 * s * th)
        b.bone_cone(f"knee_{side}", 0.085 * s * th, 0.062 * s * th)
        b.bone_cone(f"ankle_{side}", 0.062 * s * th, 0.047 * s * th)
        b.bone_cone(f"toe_{side}", 0.05 * s * th, 0.04 * s * th)
    # pose limits (degrees); bend directions: elbows forward, knees backward, arms up. Large
    # rotations only at hinges whose two bones are collinear at rest (elbows, knees)
    fwd, back = np.array([0, 0, 1.0]), np.array([0, 0, -1.0])
    b.hinge("spine", "chest", fwd, -8, 15, 6)
    b.hinge("chest", "neck", fwd, -8, 12, 6)
    b.hinge("neck", "head", fwd, -15, 20, 8)
    b.hinge("head", "head_end", fwd, -15, 20, 10)
    for side, sx in (("l", 1.0), ("r", -1.0)):
        b.hinge(f"shoulder_{side}", f"elbow_{side}", up, -12, 20, 8)
        b.hinge(f"elbow_{side}", f"wrist_{side}", fwd, 0, 30, 5, large=True)
        b.hinge(f"wrist_{side}", f"hand_{side}", fwd, -20, 20, 8)
        b.hinge(f"hip_{side}", f"knee_{side}", fwd, -10, 25, 5)
        b.hinge(f"knee_{side}", f"ankle_{side}", back, 0, 25, 4, large=True)
        b.hinge(f"ankle_{side}", f"toe_{side}", up, -15, 15, 5)
    return b


# finger order as MANO: index, middle, little, ring, thumb
_FINGERS = ("index", "middle", "little", "ring")


def _hand(rng: np.random.Generator) -> _Builder:
    u = rng.uniform
    s = u(0.17, 0.21) / 0.19
    th = u(0.92, 1.08)
    ff = u(0.92, 1.08)  # finger length
    pw = u(0.93, 1.07)  # palm width
    # (MCP across, MCP along, phalanx lengths (prox, mid, distal to tip joint), radius factor); the
    # fingers fan out from a point 0.2 behind the knuckles, so the gaps between them open up
    table = {
        "index": (0.027, 0.090, (0.041, 0.025, 0.017), 0.97),
        "middle": (0.0, 0.094, (0.045, 0.029, 0.018), 1.0),
        "ring": (-0.026, 0.089, (0.042, 0.027, 0.017), 0.94),
        "little": (-0.049, 0.080, (0.033, 0.020, 0.015), 0.86),
    }
    b = _Builder()
    b.joint("wrist", [0.0, 0.0, 0.0], None)
    palm_down = np.array([0.0, -1.0, 0.0])
    tips = []
    for f in _FINGERS:
        across, along, lens, rf = table[f]
        mcp = np.array([across * pw, 0.0, along * u(0.97, 1.03)]) * s
        phi = np.arctan2(mcp[0], 0.2 * s) + np.radians(u(-1.5, 1.5))
        d = np.array([np.sin(phi), 0.0, np.cos(phi)])
        lens = np.asarray(lens) * s * ff * u(0.95, 1.05)
        b.joint(f"{f}1", mcp, "wrist")
        b.joint(f"{f}2", mcp + lens[0] * d, f"{f}1")
        b.joint(f"{f}3", mcp + (lens[0] + lens[1]) * d, f"{f}2")
        tips.append((f, mcp + lens.sum() * d, rf))
    # thumb: from the carpometacarpal joint on the radial side, pointing out and forward
    dt = _unit([0.78, -0.22, 0.58])
    cmc = np.array([0.022, -0.008, 0.018]) * s
    tl = np.array([0.040, 0.032, 0.024]) * s * ff * u(0.95, 1.05)
    b.joint("thumb1", cmc, "wrist")
    b.joint("thumb2", cmc + tl[0] * dt, "thumb1")
    b.joint("thumb3", cmc + (tl[0] + tl[1]) * dt, "thumb2")
    for f, tip, _ in tips:
        b.joint(f"{f}_tip", tip, f"{f}3")
    b.joint("thumb_tip", cmc + tl.sum() * dt, "thumb3")
    # solids: wrist stub and palm (root frame), metacarpals, phalanges
    r = 0.0088 * s * th  # middle finger radius at the MCP
    b.cone("middle1", [0, 0, -0.035 * s], [0, 0, 0.01 * s], 0.026 * s, 0.027 * s)
    b.ellipsoid("middle1", np.array([-0.004, -0.001, 0.048]) * s, np.array([0.044 * pw, 0.016 * th, 0.05]) * s)
    for f, tip, rf in tips:
        b.bone_cone(f"{f}1", 0.013 * s, r * rf * 1.03)
        b.bone_cone(f"{f}2", r * rf, r * rf * 0.96)
        b.bone_cone(f"{f}3", r * rf * 0.96, r * rf * 0.92)
        b.bone_cone(f"{f}_tip", r * rf * 0.92, r * rf * 0.9)
    b.bone_cone("thumb2", 0.016 * s * th, 0.0125 * s * th)
    b.bone_cone("thumb3", 0.0115 * s * th, 0.0105 * s * th)
    b.bone_cone("thumb_tip", 0.0105 * s * th, 0.0092 * s * th)
    # pose limits: fingers curl towards the palm (-y); MCP and PIP joints can take the large curl
    for f in _FINGERS:
        b.hinge(f"{f}1", f"{f}2", palm_down, -10, 25, 3)
        b.hinge(f"{f}2", f"{f}3", palm_down, 0, 30, 3, large=True)  # PIP: MCP-PIP-DIP is straight
        b.hinge(f"{f}3", f"{f}_tip", palm_down, 0, 25, 3)
    thumb_curl = _unit([-0.6, -0.8, 0.1])
    b.hinge("thumb1", "thumb2", thumb_curl, -10, 20, 5)
    b.hinge("thumb2", "thumb3", thumb_curl, 0, 25, 4)
    b.hinge("thumb3", "thumb_tip", thumb_curl, 0, 25, 4)
    return b


def _quadruped(rng: np.random.Generator) -> _Builder:
    u = rng.uniform
    s = u(0.9, 1.1)
    th = u(0.95, 1.15)  # limb thickness
    bl, bw, lf = u(0.9, 1.12), u(0.9, 1.1), u(0.88, 1.12)
    nf, hf, tf = u(0.9, 1.1), u(0.9, 1.1), u(0.85, 1.15)
    r_paw = 0.044 * s * th
    y_wrist, y_hock = 0.085 * s, 0.095 * s
    up1, lo1 = 0.18 * s * lf, 0.19 * s * lf  # front: shoulder-elbow, elbow-wrist
    up2, lo2 = 0.19 * s * lf, 0.18 * s * lf  # hind: hip-knee, knee-hock
    sh_y = y_wrist + up1 + lo1
    hip_y = y_hock + up2 + lo2
    b = _Builder()
    b.joint("pelvis", [0, hip_y + 0.04 * s, -0.28 * s * bl], None)
    b.joint("spine", [0, 0.5 * (hip_y + sh_y) + 0.05 * s, 0], "pelvis")
    b.joint("chest", [0, sh_y + 0.05 * s, 0.26 * s * bl], "spine")
    neck_dir = np.array([0.0, np.sin(np.radians(48.0)), np.cos(np.radians(48.0))])
    b.joint("neck", b.P("chest") + 0.12 * s * neck_dir, "chest")
    b.joint("head", b.P("neck") + 0.17 * s * nf * neck_dir, "neck")
    b.joint("nose", b.P("head") + np.array([0, -0.03, 0.15]) * s * hf, "head")
    tail_angle = np.radians(u(-10.0, 30.0))
    tail_dir = np.array([0.0, np.sin(tail_angle), -np.cos(tail_angle)])
    t1 = b.P("pelvis") + 0.12 * s * tail_dir  # collinear with the tail, so the base is a clean hinge
    b.joint("tail1", t1, "pelvis")
    b.joint("tail2", t1 + 0.13 * s * tf * tail_dir, "tail1")
    b.joint("tail3", t1 + 0.26 * s * tf * tail_dir, "tail2")
    for side, sx in (("l", 1.0), ("r", -1.0)):
        sh = np.array([sx * (0.05 * th + 0.04 * bw) * s, sh_y, b.P("chest")[2] + 0.02 * s])  # legs > 2 cells apart
        b.joint(f"shoulder_{side}", sh, "chest")
        b.joint(f"elbow_{side}", sh - [0, up1, 0], f"shoulder_{side}")
        b.joint(f"wrist_{side}", sh - [0, up1 + lo1, 0], f"elbow_{side}")
        b.joint(f"fpaw_{side}", [sh[0], r_paw, sh[2] + 0.05 * s], f"wrist_{side}")
    for side, sx in (("l", 1.0), ("r", -1.0)):
        hip = np.array([sx * (0.05 * th + 0.038 * bw) * s, hip_y, b.P("pelvis")[2]])
        b.joint(f"hip_{side}", hip, "pelvis")
        b.joint(f"knee_{side}", hip - [0, up2, 0], f"hip_{side}")
        b.joint(f"hock_{side}", hip - [0, up2 + lo2, 0], f"knee_{side}")
        b.joint(f"hpaw_{side}", [hip[0], r_paw, hip[2] + 0.05 * s], f"hock_{side}")
    # solids
    b.ellipsoid("spine", b.P("pelvis") + [0, 0, 0.02 * s], np.array([0.115 * bw, 0.125, 0.16]) * s)
    b.ellipsoid("chest", b.P("spine"), np.array([0.12 * bw, 0.13, 0.22 * bl]) * s)
    b.ellipsoid("neck", b.P("chest") + [0, -0.03 * s, 0], np.array([0.13 * bw, 0.155, 0.16]) * s)
    b.cone("head", b.P("chest") + 0.02 * s * neck_dir, b.P("head"), 0.085 * s, 0.065 * s)
    b.ellipsoid("nose", b.P("head") + np.array([0, 0.01, 0.01]) * s, np.array([0.075, 0.075, 0.09]) * s * hf)
    b.cone("nose", b.P("head") + np.array([0, -0.01, 0.04]) * s, b.P("nose"), 0.05 * s * hf, 0.036 * s * hf)
    b.bone_cone("tail1", 0.052 * s, 0.046 * s * th)
    b.bone_cone("tail2", 0.046 * s * th, 0.041 * s * th)
    b.bone_cone("tail3", 0.041 * s * th, 0.036 * s * th)
    for side, sx in (("l", 1.0), ("r", -1.0)):
        b.cone(f"shoulder_{side}", b.P("chest") - [0, 0.02 * s, 0], b.P(f"shoulder_{side}"), 0.08 * s, 0.065 * s * th)
        b.bone_cone(f"elbow_{side}", 0.065 * s * th, 0.046 * s * th)
        b.bone_cone(f"wrist_{side}", 0.048 * s * th, 0.04 * s * th)
        b.bone_cone(f"fpaw_{side}", 0.04 * s * th, r_paw)
        b.cone(f"hip_{side}", b.P("pelvis"), b.P(f"hip_{side}"), 0.085 * s, 0.075 * s * th)
        b.bone_cone(f"knee_{side}", 0.075 * s * th, 0.048 * s * th)
        b.bone_cone(f"hock_{side}", 0.05 * s * th, 0.04 * s * th)
        b.bone_cone(f"hpaw_{side}", 0.04 * s * th, r_paw)
    fwd, back, upv = np.array([0, 0, 1.0]), np.array([0, 0, -1.0]), np.array([0, 1.0, 0])
    b.hinge("spine", "chest", upv, -8, 8, 5)
    b.hinge("neck", "head", np.array([0, -1.0, 0]), -20, 20, 6, large=True)
    b.hinge("head", "nose", np.array([0, -1.0, 0]), -15, 20, 8)
    b.hinge("tail1", "tail2", upv, -20, 25, 10, large=True)
    b.hinge("tail2", "tail3", upv, -20, 25, 10)
    for side in ("l", "r"):
        b.hinge(f"shoulder_{side}", f"elbow_{side}", fwd, -15, 20, 4)
        b.hinge(f"elbow_{side}", f"wrist_{side}", back, 0, 25, 4, large=True)
        b.hinge(f"wrist_{side}", f"fpaw_{side}", back, -10, 25, 5)
        b.hinge(f"hip_{side}", f"knee_{side}", fwd, -15, 20, 4)
        b.hinge(f"knee_{side}", f"hock_{side}", back, 0, 25, 4, large=True)
        b.hinge(f"hock_{side}", f"hpaw_{side}", fwd, -10, 20, 5)
    return b


_BUILDERS = {"humanoid": (_humanoid, 0.02), "hand": (_hand, 0.0022), "quadruped": (_quadruped, 0.02)}


def _check_kind(kind: str) -> str:
    if kind not in KINDS:
        raise InputError(f"unknown character kind {kind!r}; use one of {', '.join(KINDS)}")
    return kind


def character_spec(kind: str, seed: int = 0) -> CharacterSpec:
    """The implicit shape, skeleton and pose limits of a character; proportions drawn from ``seed``."""
    build, blend = _BUILDERS[_check_kind(kind)]
    rng = np.random.default_rng([int(seed), KINDS.index(kind)])
    b = build(rng)
    spec = b.build(kind, seed, blend)
    return dataclasses.replace(spec, blend=blend * spec.size / _NOMINAL_SIZE[kind])


_NOMINAL_SIZE = {"humanoid": 1.75, "hand": 0.22, "quadruped": 1.3}


# ----------------------------------------------------------------------------------------------
# Meshing


def _faces_edges(faces: np.ndarray) -> np.ndarray:
    return np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])


def check_closed_surface(vertices: Float[np.ndarray, "V 3"], faces: Int[np.ndarray, "F 3"]) -> str | None:
    """None if the mesh is a closed, consistently wound, single-component 2-manifold surface;
    otherwise what is wrong.

    Checks: no face repeats a vertex; every directed edge occurs once and its reverse occurs
    (each edge in exactly two faces, wound oppositely); every vertex is used; the faces form one
    edge-connected component; the faces around every vertex form a single fan.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    faces = np.asarray(faces, dtype=np.int64)
    nv = int(np.asarray(vertices).shape[0])
    nf = faces.shape[0]
    if nf == 0:
        return "no faces"
    if np.any(faces[:, 0] == faces[:, 1]) or np.any(faces[:, 1] == faces[:, 2]) or np.any(faces[:, 2] == faces[:, 0]):
        return "a face repeats a vertex"
    directed = _faces_edges(faces)  # blocks: edges 0->1, 1->2, 2->0 of every face
    key = directed[:, 0] * nv + directed[:, 1]
    order = np.argsort(key)
    skey = key[order]
    if np.any(skey[1:] == skey[:-1]):
        return "a directed edge is used twice (inconsistent winding or a non-manifold edge)"
    rev = directed[:, 1] * nv + directed[:, 0]
    pos = np.minimum(np.searchsorted(skey, rev), skey.size - 1)
    if not np.all(skey[pos] == rev):
        return "open boundary (an edge has one face)"
    if np.unique(faces).size != nv:
        return "unreferenced vertices"
    twin = order[pos]  # index of the reversed edge
    face_of = np.arange(3 * nf) % nf
    adj = coo_matrix((np.ones(3 * nf), (face_of, face_of[twin])), shape=(nf, nf))
    n_comp, _ = connected_components(adj, directed=False)
    if n_comp != 1:
        return f"{n_comp} connected components"
    # around vertex a, the face with edge a->b is followed by the face with edge a->c, c the
    # third corner; in a manifold these successors form one cycle per vertex
    third = np.concatenate([faces[:, 2], faces[:, 0], faces[:, 1]])
    nxt_key = directed[:, 0] * nv + third
    succ = order[np.searchsorted(skey, nxt_key)]
    graph = coo_matrix((np.ones(3 * nf), (np.arange(3 * nf), succ)), shape=(3 * nf, 3 * nf))
    _, label = connected_components(graph, directed=True, connection="weak")
    cycles_per_vertex = np.bincount(directed[np.unique(label, return_index=True)[1], 0], minlength=nv)
    if np.any(cycles_per_vertex > 1):
        return f"{int(np.sum(cycles_per_vertex > 1))} non-manifold vertices"
    return None


def delaunay_flip(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    *,
    max_passes: int = 10,
    max_dihedral: float = 60.0,
) -> Int[np.ndarray, "F 3"]:
    """Flip edges of a closed, consistently wound mesh towards the (intrinsic-ish) Delaunay condition.

    An edge (a, b) with opposite corners c, d is flipped to (c, d) when the angles at c and d
    sum to more than π, the two faces meet at a dihedral angle below ``max_dihedral`` degrees,
    the edge (c, d) does not exist yet, both a and b keep at least three neighbours and neither
    new face turns against the old ones. Vertices do not move; winding is kept.

    Returns:
        (F, 3) the new faces.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).copy()
    nv, nf = v.shape[0], f.shape[0]
    cos_max = np.cos(np.radians(max_dihedral))

    def normal(tri):
        return np.cross(tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :])

    for _ in range(max_passes):
        directed = _faces_edges(f)
        key = directed[:, 0] * nv + directed[:, 1]
        order = np.argsort(key)
        skey = key[order]
        rev = directed[:, 1] * nv + directed[:, 0]
        twin = order[np.minimum(np.searchsorted(skey, rev), skey.size - 1)]
        e = np.flatnonzero(directed[:, 0] < directed[:, 1])
        a, b = directed[e, 0], directed[e, 1]
        f1, k1 = e % nf, e // nf
        f2, k2 = twin[e] % nf, twin[e] // nf
        c = f[f1, (k1 + 2) % 3]
        d = f[f2, (k2 + 2) % 3]

        def angle(at, p, q):
            u, w = v[p] - v[at], v[q] - v[at]
            cosv = np.einsum("ij,ij->i", u, w) / np.maximum(
                np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1), 1e-300
            )
            return np.arccos(np.clip(cosv, -1.0, 1.0))

        excess = angle(c, a, b) + angle(d, a, b) - np.pi
        n1, n2 = normal(v[f[f1]]), normal(v[f[f2]])
        n1 /= np.maximum(np.linalg.norm(n1, axis=1, keepdims=True), 1e-300)
        n2 /= np.maximum(np.linalg.norm(n2, axis=1, keepdims=True), 1e-300)
        cand = np.flatnonzero((excess > 1e-9) & (np.einsum("ij,ij->i", n1, n2) > cos_max))
        if cand.size == 0:
            break
        cand = cand[np.argsort(-excess[cand], kind="stable")]
        edges = set(np.minimum(directed[:, 0], directed[:, 1]) * nv + np.maximum(directed[:, 0], directed[:, 1]))
        valence = np.bincount(f.reshape(-1), minlength=nv)
        used = np.zeros(nf, dtype=bool)
        flipped = 0
        for i in cand.tolist():
            fa, fb = int(f1[i]), int(f2[i])
            if used[fa] or used[fb]:
                continue
            ai, bi, ci, di = int(a[i]), int(b[i]), int(c[i]), int(d[i])
            cd = min(ci, di) * nv + max(ci, di)
            if ci == di or cd in edges or valence[ai] <= 3 or valence[bi] <= 3:
                continue
            t1 = np.array([ai, di, ci])
            t2 = np.array([di, bi, ci])
            m1, m2 = normal(v[t1]), normal(v[t2])
            if m1 @ n1[i] <= 0 or m2 @ n1[i] <= 0 or m1 @ n2[i] <= 0 or m2 @ n2[i] <= 0:
                continue
            f[fa], f[fb] = t1, t2
            used[fa] = used[fb] = True
            edges.discard(min(ai, bi) * nv + max(ai, bi))
            edges.add(cd)
            valence[ai] -= 1  # valence counts faces; a closed mesh has as many faces as edges around a vertex
            valence[bi] -= 1
            valence[ci] += 1
            valence[di] += 1
            flipped += 1
        if flipped == 0:
            break
    return f


def _vertex_normals_from_gradient(fn, x: np.ndarray, eps: float) -> np.ndarray:
    g = np.empty_like(x)
    for i in range(3):
        e = np.zeros(3)
        e[i] = eps
        g[:, i] = (fn(x + e) - fn(x - e)) / (2 * eps)
    return g


def _project_to_level(fn, x: np.ndarray, eps: float, iterations: int = 3) -> np.ndarray:
    for _ in range(iterations):
        f = fn(x)
        g = _vertex_normals_from_gradient(fn, x, eps)
        x = x - (f / np.maximum(np.sum(g * g, axis=1), 1e-300))[:, None] * g
    return x


def _area_centroids(x: np.ndarray, faces: np.ndarray) -> np.ndarray:
    tri = x[faces]
    c = tri.mean(axis=1)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    num = np.zeros_like(x)
    den = np.zeros(x.shape[0])
    for k in range(3):
        np.add.at(num, faces[:, k], area[:, None] * c)
        np.add.at(den, faces[:, k], area)
    return num / np.maximum(den, 1e-300)[:, None]


def relax_on_surface(
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    project: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    iterations: int = 8,
    step: float = 0.8,
) -> Float[np.ndarray, "V 3"]:
    """Tangential area-weighted centroid relaxation with re-projection onto a surface.

    Args:
        vertices, faces: the mesh (connectivity is kept).
        project: maps points (n, 3) to (their projection onto the surface (n, 3), unit surface
            normals there (n, 3)).
        iterations: rounds of (move towards the area-weighted centroid of the incident faces,
            tangentially; project back).
        step: fraction of the tangential move taken per round.

    Returns:
        (V, 3) relaxed vertices, on the surface.
    """
    x, n = project(np.asarray(vertices, dtype=np.float64))
    faces = np.asarray(faces, dtype=np.int64)
    for _ in range(iterations):
        d = _area_centroids(x, faces) - x
        d -= np.sum(d * n, axis=1)[:, None] * n
        x, n = project(x + step * d)
    return x


def mesh_implicit(
    fn: Callable[[np.ndarray], np.ndarray],
    lower: Float[np.ndarray, " 3"],
    upper: Float[np.ndarray, " 3"],
    resolution: float,
    *,
    offset: Float[np.ndarray, " 3"] | None = None,
    relax_iterations: int = 8,
    euler: int | None = 2,
    inside: Float[np.ndarray, "n 3"] | None = None,
    max_attempts: int = 4,
) -> tuple[Float[np.ndarray, "V 3"], Int[np.ndarray, "F 3"]]:
    """Closed triangle mesh of the zero level set of ``fn`` (negative inside) inside a box.

    Marching cubes (scikit-image, Lewiner) on a grid of ``resolution`` cells along the box's
    largest side (cell size h, padded by two cells, shifted by ``offset`` · h), oriented outward,
    then :func:`relax_on_surface` with Newton projection onto ``fn = 0`` and
    :func:`delaunay_flip` (twice). If the extracted surface is not one closed manifold component
    with Euler characteristic ``euler`` (2: a sphere; None: any) enclosing all the ``inside``
    points (e.g. the joints of a skeleton: thin parts lost by a coarse grid leave them outside),
    the grid is shifted and tried again, ``max_attempts`` times in all.

    Raises:
        InputError: no attempt gave such a surface (the grid is too coarse for the thinnest part
            or the narrowest gap: raise ``resolution``).
    """
    from skimage.measure import marching_cubes

    lower = np.asarray(lower, dtype=np.float64)
    upper = np.asarray(upper, dtype=np.float64)
    h = float(np.max(upper - lower)) / float(resolution)
    off0 = np.zeros(3) if offset is None else np.asarray(offset, dtype=np.float64)
    problem = ""
    for attempt in range(max_attempts):
        # further attempts shift the grid along a low-discrepancy sequence
        off = np.mod(off0 + attempt * np.array([0.618034, 0.414214, 0.732051]), 1.0)
        origin = lower - 2.0 * h + off * h
        n = np.ceil((upper + 2.0 * h - origin) / h).astype(np.int64) + 1
        axes = [origin[i] + h * np.arange(n[i]) for i in range(3)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        values = fn(grid).reshape(tuple(n))
        tiny = 1e-9 * h
        values = np.where(np.abs(values) < tiny, tiny, values)  # no grid value exactly on the level set
        v, f, _, _ = marching_cubes(values, 0.0, spacing=(h, h, h), method="lewiner")
        v = v.astype(np.float64) + origin
        f = f.astype(np.int64)
        problem = check_closed_surface(v, f) or ""
        if not problem and euler is not None:
            chi = v.shape[0] - f.shape[0] // 2  # closed triangle mesh: E = 3F/2
            if chi != euler:
                problem = f"Euler characteristic {chi} instead of {euler}: parts fused or holes"
        if not problem and inside is not None:
            wn = np.abs(_winding_numbers(np.asarray(inside, dtype=np.float64).reshape(-1, 3), v[f]))
            if np.any(wn < 0.5):
                problem = f"{int(np.sum(wn < 0.5))} of the given inside points are outside: thin parts were lost"
        if not problem:
            break
    else:
        raise InputError(
            f"marching cubes at resolution {resolution:g} gave no single closed surface of the expected "
            f"topology ({problem}; {max_attempts} grid offsets tried); use a higher resolution"
        )
    if _signed_volume(v, f) < 0:
        f = f[:, ::-1].copy()
    eps = 1e-3 * h

    def project(p):
        p = _project_to_level(fn, p, eps)
        g = _vertex_normals_from_gradient(fn, p, eps)
        return p, g / np.linalg.norm(g, axis=1, keepdims=True)

    half = max(1, relax_iterations // 2)
    v = relax_on_surface(v, f, project, iterations=half)
    f = delaunay_flip(v, f)
    v = relax_on_surface(v, f, project, iterations=relax_iterations - half)
    f = delaunay_flip(v, f)
    return v, f


def _winding_numbers(points: np.ndarray, tri: np.ndarray, chunk: int = 4_000_000) -> np.ndarray:
    """Generalised winding numbers of points w.r.t. a triangle soup (1 inside a closed outward surface)."""
    out = np.zeros(points.shape[0])
    per = max(1, chunk // max(1, tri.shape[0]))
    for s in range(0, points.shape[0], per):
        abc = tri[None] - points[s : s + per, None, None, :]
        a, b, c = abc[:, :, 0], abc[:, :, 1], abc[:, :, 2]
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        num = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
        den = la * lb * lc + np.einsum("pfi,pfi->pf", a, b) * lc + np.einsum("pfi,pfi->pf", b, c) * la
        den += np.einsum("pfi,pfi->pf", c, a) * lb
        out[s : s + per] = np.arctan2(num, den).sum(axis=1) / (2.0 * np.pi)
    return out


def _signed_volume(v: np.ndarray, f: np.ndarray) -> float:
    t = v[f]
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0)


# ----------------------------------------------------------------------------------------------
# Characters


def skinning_weights(
    spec: CharacterSpec,
    vertices: Float[np.ndarray, "V 3"],
    faces: Int[np.ndarray, "F 3"],
    *,
    reach: float = 1.0,
    smooth_iterations: int = 1,
) -> Float[np.ndarray, "V B"]:
    """Per-vertex bone weights from the distances to the bones' primitives.

    ``w_p ∝ (1 − (d_p / R_p)²)³`` for ``0 ≤ d_p < R_p`` (else 0; ``d_p`` the distance to the
    primitive, clamped at 0), ``R_p = reach ·`` the primitive's scale (mean radius of a cone,
    half the smallest semi-axis of an ellipsoid); a vertex out of every support takes the nearest
    primitive. Summed per bone, then ``smooth_iterations`` steps of
    ``W ← ½ W + ½ mean over mesh neighbours``; weights below 1e-12 are dropped and rows
    normalised to sum 1. So weights blend smoothly across joints, the middle of a limb is
    rigidly attached to its bone, and nothing leaks across a gap to a neighbouring limb.

    Returns:
        (V, B) weights; bone b ends at joint b + 1.
    """
    from scipy.sparse import coo_matrix

    v = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    d = np.maximum(primitive_distances(spec, v), 0.0)
    radius = np.array([p.scale for p in spec.primitives])[:, None] * reach
    w = np.maximum(0.0, 1.0 - (d / radius) ** 2) ** 3  # compactly supported, C² (Wendland-like)
    none = w.sum(axis=0) <= 0.0
    if np.any(none):  # outside every support: the nearest primitive
        w[:, none] = 0.0
        w[np.argmin(d[:, none] / radius, axis=0), np.flatnonzero(none)] = 1.0
    w /= w.sum(axis=0)
    bone_of = np.array([p.bone for p in spec.primitives])
    weights = np.zeros((v.shape[0], spec.n_bones))
    np.add.at(weights.T, bone_of, w)
    e = _faces_edges(faces)
    adj = coo_matrix((np.ones(e.shape[0]), (e[:, 0], e[:, 1])), shape=(v.shape[0],) * 2).tocsr()
    adj = ((adj + adj.T) > 0).astype(np.float64)
    deg = np.asarray(adj.sum(axis=1)).reshape(-1, 1)
    for _ in range(smooth_iterations):
        weights = 0.5 * weights + 0.5 * (adj @ weights) / deg
    weights[weights < 1e-12] = 0.0
    return weights / weights.sum(axis=1, keepdims=True)


@dataclasses.dataclass(frozen=True, eq=False)
class Character:
    """A procedural character in its rest pose.

    Attributes:
        kind: ``"humanoid"``, ``"hand"`` or ``"quadruped"``.
        seed: the seed of its proportions.
        mesh: the closed rest surface (vertices (V, 3), faces (F, 3)).
        skeleton: the rest skeleton (joints in topological order, names set).
        weights: (V, B) skinning weights per bone (bone b ends at joint b + 1), rows sum to 1.
        spec: the implicit shape and pose limits (for :func:`character_sdf`, re-meshing, posing).
        resolution: the marching-cubes resolution used.
    """

    kind: str
    seed: int
    mesh: Mesh
    skeleton: Skeleton
    weights: Float[np.ndarray, "V B"]
    spec: CharacterSpec
    resolution: float

    @property
    def vertices(self) -> Float[np.ndarray, "V 3"]:
        return self.mesh.vertices

    @property
    def faces(self) -> Int[np.ndarray, "F 3"]:
        return self.mesh.faces

    def sdf(self, points: Float[np.ndarray, "n 3"]) -> Float[np.ndarray, " n"]:
        """The implicit function of the rest shape."""
        return character_sdf(self.spec, points)

    def remesh(self, resolution: float, offset: Float[np.ndarray, " 3"] | None = None):
        """Another triangulation (vertices, faces) of the same implicit rest surface (see :func:`mesh_implicit`)."""
        lo, hi = self.spec.bounds()
        return mesh_implicit(self.sdf, lo, hi, resolution, offset=offset, inside=self.spec.positions)


def make_character(kind: str, seed: int = 0, resolution: float | None = None) -> Character:
    """Build a procedural articulated character.

    Args:
        kind: ``"humanoid"``, ``"hand"`` or ``"quadruped"``.
        seed: proportions (size, limb lengths and thicknesses, …) are drawn from it; the same
            seed gives byte-identical arrays.
        resolution: marching-cubes cells along the largest extent (default
            :data:`DEFAULT_RESOLUTION`, 2.3–2.9k vertices).

    Returns:
        :class:`Character` with a closed single-component rest mesh, a skeleton (humanoid 21
        bones, hand 20, quadruped 24) and skinning weights.

    Raises:
        InputError: unknown kind, or a resolution too coarse for a closed surface.
    """
    spec = character_spec(kind, seed)
    res = float(DEFAULT_RESOLUTION[kind] if resolution is None else resolution)
    if not np.isfinite(res) or res < 8:
        raise InputError(f"resolution must be at least 8 cells (got {resolution})")
    lo, hi = spec.bounds()
    v, f = mesh_implicit(lambda p: character_sdf(spec, p), lo, hi, res, inside=spec.positions)
    mesh = Mesh(vertices=v, faces=f, name=f"{kind}-{seed}", file_index=np.arange(v.shape[0]))
    skeleton = Skeleton.from_arrays(spec.positions, spec.parents, list(spec.names), name=f"{kind}-{seed}")
    weights = skinning_weights(spec, v, f)
    return Character(
        kind=kind, seed=int(seed), mesh=mesh, skeleton=skeleton, weights=weights, spec=spec, resolution=res
    )


# ----------------------------------------------------------------------------------------------
# Quaternions, forward kinematics and skinning in NumPy float64 (quaternions (w, x, y, z))


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def _qmat(q: np.ndarray) -> np.ndarray:
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def _quat_from_rotvec(rv: np.ndarray) -> np.ndarray:
    rv = np.asarray(rv, dtype=np.float64)
    angle = np.linalg.norm(rv, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(θ/2)/θ, smooth at 0
    k = np.where(angle > 1e-12, np.sin(half) / np.where(angle > 1e-12, angle, 1.0), 0.5 - angle**2 / 48.0)
    return np.concatenate([np.cos(half), k * rv], axis=-1)


def pose_from_rotvecs(rotvecs: Float[np.ndarray, "J 3"], translation: Float[np.ndarray, " 3"] | None = None) -> Pose:
    """A :class:`~ncflow.skeleton.Pose` (NumPy float64) from per-joint rotation vectors (axis × angle, radians)."""
    rotvecs = np.asarray(rotvecs, dtype=np.float64)
    t = np.zeros(3) if translation is None else np.asarray(translation, dtype=np.float64).reshape(3)
    return Pose(_quat_from_rotvec(rotvecs), t)


def forward_kinematics_np(
    positions: Float[np.ndarray, "J 3"], parents: Int[np.ndarray, " J"], pose: Pose
) -> tuple[Float[np.ndarray, "J 4"], Float[np.ndarray, "J 3"]]:
    """World frames of the joints (NumPy float64; the convention of :func:`ncflow.skeleton.forward_kinematics`).

    Frame j maps joint-local coordinates to world: ``x ↦ R(q_j) x + t_j``; at rest ``q_j = 1``,
    ``t_j = P_j``. Root: ``q_0 = r_0``, ``t_0 = P_0 + s̃``; child: ``q_j = q_p r_j``,
    ``t_j = R(q_p)(P_j − P_p) + t_p``. Joints must be in topological order.

    Returns:
        (world rotations (J, 4) as unit quaternions (w, x, y, z), posed joint positions (J, 3)).
    """
    positions = np.asarray(positions, dtype=np.float64)
    parents = np.asarray(parents, dtype=np.int64)
    rot = np.asarray(pose.rotations, dtype=np.float64)
    norm = np.linalg.norm(rot, axis=1, keepdims=True)
    rot = np.where(norm > 0, rot / np.where(norm > 0, norm, 1.0), np.array([1.0, 0, 0, 0]))
    q = np.empty_like(rot)
    t = np.empty_like(positions)
    q[0] = rot[0]
    t[0] = positions[0] + np.asarray(pose.translation, dtype=np.float64)
    mats = np.empty((positions.shape[0], 3, 3))
    mats[0] = _qmat(q[0])
    for j in range(1, positions.shape[0]):
        p = parents[j]
        q[j] = _qmul(q[p], rot[j])
        mats[j] = _qmat(q[j])
        t[j] = mats[p] @ (positions[j] - positions[p]) + t[p]
    return q, t


def _joint_weights(weights: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """Bone weights (V, B) → weights of the joint frames (V, J) that move each bone."""
    n = parents.shape[0]
    s = np.zeros((n - 1, n))
    s[np.arange(n - 1), parents[1:]] = 1.0
    return np.asarray(weights, dtype=np.float64) @ s


def skin_lbs(
    vertices: Float[np.ndarray, "V 3"],
    weights: Float[np.ndarray, "V J"],
    rest_positions: Float[np.ndarray, "J 3"],
    world_q: Float[np.ndarray, "J 4"],
    world_t: Float[np.ndarray, "J 3"],
) -> Float[np.ndarray, "V 3"]:
    """Linear blend skinning ``x' = Σ_j w_j (R_j (x − P_j) + t_j)`` with per-frame weights (V, J)."""
    r = _qmat(world_q)  # (J, 3, 3)
    c = world_t - np.einsum("jab,jb->ja", r, rest_positions)
    m = np.einsum("vj,jab->vab", weights, r)
    return np.einsum("vab,vb->va", m, vertices) + weights @ c


def skin_dqs(
    vertices: Float[np.ndarray, "V 3"],
    weights: Float[np.ndarray, "V J"],
    rest_positions: Float[np.ndarray, "J 3"],
    world_q: Float[np.ndarray, "J 4"],
    world_t: Float[np.ndarray, "J 3"],
) -> Float[np.ndarray, "V 3"]:
    """Dual-quaternion skinning (Kavan et al. 2008) with per-frame weights (V, J).

    Frame j's motion ``x ↦ R_j (x − P_j) + t_j`` as a unit DQ; per vertex the DQs are blended with
    signs aligned to the vertex's heaviest frame, normalised, and applied.
    """
    r = world_q / np.linalg.norm(world_q, axis=1, keepdims=True)
    c = world_t - np.einsum("jab,jb->ja", _qmat(r), rest_positions)
    dual = 0.5 * _qmul(np.concatenate([np.zeros((c.shape[0], 1)), c], axis=1), r)
    pivot = r[np.argmax(weights, axis=1)]  # (V, 4)
    sign = np.sign(pivot @ r.T)  # (V, J)
    sign[sign == 0] = 1.0
    ws = weights * sign
    b0 = ws @ r
    be = ws @ dual
    n0 = np.linalg.norm(b0, axis=1, keepdims=True)
    b0, be = b0 / n0, be / n0
    w0, v0 = b0[:, :1], b0[:, 1:]
    we, ve = be[:, :1], be[:, 1:]
    x = np.asarray(vertices, dtype=np.float64)
    x = x + 2.0 * np.cross(v0, np.cross(v0, x) + w0 * x)
    return x + 2.0 * (w0 * ve - we * v0 + np.cross(v0, ve))


@dataclasses.dataclass(frozen=True)
class PosedCharacter:
    """A character in a pose.

    Attributes:
        vertices: (V, 3) posed vertices (same order and faces as the rest mesh).
        faces: (F, 3) the rest mesh's faces.
        joints: (J, 3) posed joint positions.
        pose: the pose (NumPy :class:`~ncflow.skeleton.Pose`, quaternions (w, x, y, z)).
        info: how a random pose was drawn (large joint and angle), else empty.
    """

    vertices: Float[np.ndarray, "V 3"]
    faces: Int[np.ndarray, "F 3"]
    joints: Float[np.ndarray, "J 3"]
    pose: Pose
    info: dict

    @property
    def mesh(self) -> Mesh:
        return Mesh(vertices=self.vertices, faces=self.faces, file_index=np.arange(self.vertices.shape[0]))


def random_pose(
    character: Character | CharacterSpec,
    seed: int | Sequence[int] = 0,
    *,
    large_joint: str | None = "random",
    large_angle: tuple[float, float] = (60.0, 100.0),
    small_scale: float = 1.0,
    global_angle: float = 30.0,
    global_translation: float = 0.1,
    rest_joints: Sequence[str] = (),
) -> tuple[Pose, dict]:
    """Draw a plausible random pose.

    Every joint with a flexion axis gets a flexion uniform in its range (degrees, ×
    ``small_scale``) plus a rotation of up to its ``twist`` about a random axis; one joint
    (``large_joint``: a name, ``"random"`` for one of the kind's hinge joints, or None for none)
    instead gets a pure flexion uniform in ``large_angle`` degrees; the root gets a rotation of
    up to ``global_angle`` degrees about a random axis and a translation of up to
    ``global_translation`` × size in each coordinate. Joints named in ``rest_joints`` keep the
    identity.

    Returns:
        (pose with NumPy float64 arrays, info: ``large_joint`` name or None, ``large_angle_deg``).
    """
    spec = character.spec if isinstance(character, Character) else character
    seq = [int(s) for s in (seed if isinstance(seed, (list, tuple)) else [seed])]
    rng = np.random.default_rng(seq + [7919])
    n = spec.n_joints
    rotvec = np.zeros((n, 3))
    for j in range(1, n):
        axis = spec.flex_axes[j]
        lo, hi = spec.flex_range[j] * small_scale
        flex = np.radians(rng.uniform(lo, hi)) if np.any(axis) else 0.0
        tw_axis = rng.normal(size=3)
        tw_axis /= np.linalg.norm(tw_axis)
        tw = np.radians(rng.uniform(0.0, spec.twist[j] * small_scale))
        rotvec[j] = _compose_rotvec(flex * axis, tw * tw_axis)
    info: dict = {"large_joint": None, "large_angle_deg": 0.0}
    if large_joint is not None and spec.large_joints:
        if large_joint == "random":
            j = int(spec.large_joints[rng.integers(len(spec.large_joints))])
        else:
            j = spec.joint(large_joint)
            if not np.any(spec.flex_axes[j]):
                raise InputError(f"joint {large_joint!r} of the {spec.kind} has no flexion axis")
        angle = rng.uniform(*large_angle)
        rotvec[j] = spec.large_sign[j] * np.radians(angle) * spec.flex_axes[j]
        info = {"large_joint": spec.names[j], "large_angle_deg": float(angle)}
    g_axis = rng.normal(size=3)
    g_axis /= np.linalg.norm(g_axis)
    rotvec[0] = np.radians(rng.uniform(0.0, global_angle)) * g_axis
    translation = rng.uniform(-1.0, 1.0, size=3) * global_translation * spec.size
    for name in rest_joints:
        rotvec[spec.joint(name)] = 0.0
    return pose_from_rotvecs(rotvec, translation), info


def _compose_rotvec(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation vector of R(a) R(b)."""
    q = _qmul(_quat_from_rotvec(a), _quat_from_rotvec(b))
    if q[0] < 0:
        q = -q
    s = np.linalg.norm(q[1:])
    if s < 1e-15:
        return np.zeros(3)
    return 2.0 * np.arctan2(s, q[0]) * q[1:] / s


def _as_pose(spec: CharacterSpec, pose) -> Pose:
    if isinstance(pose, Pose):
        rot = np.asarray(pose.rotations, dtype=np.float64)
        if rot.shape != (spec.n_joints, 4):
            raise InputError(f"pose rotations must have shape ({spec.n_joints}, 4), got {rot.shape}")
        return Pose(rot, np.asarray(pose.translation, dtype=np.float64).reshape(3))
    if isinstance(pose, Mapping):
        rv = np.zeros((spec.n_joints, 3))
        translation = None
        for key, value in pose.items():
            if key == "translation":
                translation = np.asarray(value, dtype=np.float64)
                continue
            j = spec.joint(key) if isinstance(key, str) else int(key)
            rv[j] = np.asarray(value, dtype=np.float64).reshape(3)
        return pose_from_rotvecs(rv, translation)
    arr = np.asarray(pose, dtype=np.float64)
    if arr.shape == (spec.n_joints, 3):
        return pose_from_rotvecs(arr)
    if arr.shape == (spec.n_joints, 4):
        return Pose(arr, np.zeros(3))
    raise InputError(
        f"a pose must be a Pose, a mapping joint name -> rotation vector, or ({spec.n_joints}, 3) rotation vectors; "
        f"got shape {arr.shape}"
    )


def pose_character(
    character: Character,
    pose: Pose | Mapping | np.ndarray | None = None,
    *,
    seed: int | Sequence[int] | None = None,
    skinning: str = "dqs",
    **random_options,
) -> PosedCharacter:
    """Pose a character by forward kinematics and skinning.

    Args:
        character: the character.
        pose: a :class:`~ncflow.skeleton.Pose` (quaternions (w, x, y, z) per joint + root
            translation), a mapping ``joint name -> rotation vector`` (radians; the key
            ``"translation"`` sets the root translation), a (J, 3) array of rotation vectors, or
            None to draw one with :func:`random_pose` from ``seed``.
        seed: seed of the random pose (when ``pose`` is None).
        skinning: ``"dqs"`` (dual-quaternion, default) or ``"lbs"`` (linear blend).
        **random_options: passed to :func:`random_pose`.

    Returns:
        :class:`PosedCharacter`.
    """
    spec = character.spec
    info: dict = {}
    if pose is None:
        pose, info = random_pose(character, 0 if seed is None else seed, **random_options)
    else:
        pose = _as_pose(spec, pose)
    if skinning not in ("dqs", "lbs"):
        raise InputError(f"skinning must be 'dqs' or 'lbs', got {skinning!r}")
    q, t = forward_kinematics_np(spec.positions, spec.parents, pose)
    w = _joint_weights(character.weights, spec.parents)
    skin = skin_dqs if skinning == "dqs" else skin_lbs
    v = skin(character.vertices, w, spec.positions, q, t)
    return PosedCharacter(vertices=v, faces=character.faces, joints=t, pose=pose, info=info)
