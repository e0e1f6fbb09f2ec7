"""Body tables of the procedural characters: the humanoid, the hand and the quadruped.

A :class:`CharacterSpec` holds a joint tree (topological order, root first; bone b ends at joint
b + 1), the solid primitives attached to its bones (:mod:`ncflow.synthetic.primitives`), the
smooth-union blend width, and the pose limits that
:func:`~ncflow.synthetic.characters.random_pose` draws from (natural flexion axis and range per
joint, twist, the joints eligible for the one large rotation and its direction).
:func:`character_spec` draws the proportions (size, limb lengths and thicknesses, torso width,
head size, splay angles) per seed within plausible ranges; limbs are kept a little chunkier than
life so that the default grid resolves them. :func:`character_sdf` is the implicit function whose
zero level set is the character's surface.

Coordinates: y up, the character faces +z (the hand's fingers point +z, palm towards −y),
metre-like units (humanoid ~1.6–1.9 tall, hand ~0.17–0.21 long, quadruped ~1.1–1.5 long).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError
from ncflow.synthetic.primitives import Ellipsoid, RoundCone, smooth_min

KINDS = ("humanoid", "hand", "quadruped")


#: grid cells along the largest extent, per kind (2.3–2.9k vertices over seeds 0–39)
DEFAULT_RESOLUTION = {"humanoid": 52, "hand": 48, "quadruped": 46}


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
    for side, _sx in (("l", 1.0), ("r", -1.0)):
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
    for side, _sx in (("l", 1.0), ("r", -1.0)):
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
    for f, _tip, rf in tips:
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
    for side, _sx in (("l", 1.0), ("r", -1.0)):
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


def primitive_distances(spec: CharacterSpec, points: Float[np.ndarray, "n 3"]) -> Float[np.ndarray, "P n"]:
    """Signed distance of every point to every primitive of ``spec``."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return np.stack([p.distance(points) for p in spec.primitives])


def character_sdf(spec: CharacterSpec, points: Float[np.ndarray, "n 3"], chunk: int = 65536) -> Float[np.ndarray, " n"]:
    """The implicit function of the character (negative inside, ~signed distance near the surface)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.empty(points.shape[0])
    for s in range(0, points.shape[0], chunk):
        out[s : s + chunk] = smooth_min(primitive_distances(spec, points[s : s + chunk]), spec.blend)
    return out
