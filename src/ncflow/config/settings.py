"""The settings tree: frozen dataclasses whose fields carry their own range, choices and message.

Every field is declared with :func:`setting`, which keeps in the field's metadata what a valid value is
(bounds, choices, a check) and the message a user reads when a value is not; the one walker
(:func:`ncflow.config.checks.walk`) and the one validator (:func:`ncflow.config.checks.validate_config`)
read them, so a setting, its range and its message live in one place. Settings that never change a
result carry ``neutral=True`` (:data:`RESULT_NEUTRAL`).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from ncflow.config.quoting import quote
from ncflow.geometry.repair import MAX_WELD_TOLERANCE

METRICS = ("varifold", "normal-cycles", "auto")
#: largest seed + 1 (NumPy and JAX take 32-bit seeds)
SEED_LIMIT = 2**32


@dataclass(frozen=True)
class Rule:
    """What a valid value of one setting is, and what to say when it is not.

    Bounds apply to numbers: ``lo`` ≤ v ≤ ``hi``, ``above`` < v < ``below``; ``choices`` to words;
    ``check`` is any other test: it returns whether the value holds, or the message of what is wrong
    (None when nothing). ``message`` is said when the value is out of range (``{name}`` stands for the
    setting's dotted name, ``{table}`` for that of its table, e.g. ``phases[0]``, ``{value}`` for the
    value, quoted); without one an integer out of range says ``NAME must be at least LO`` / ``at most
    HI``. ``neutral``: the setting never changes a result (left out where configurations are compared).
    """

    lo: float | None = None
    hi: float | None = None
    above: float | None = None
    below: float | None = None
    choices: tuple[str, ...] | None = None
    check: Callable[[Any], bool] | None = None
    message: str | None = None
    neutral: bool = False

    def problem(self, value) -> str | None:
        """None when ``value`` (a number, a word, or each item of a tuple) is in range, else the message
        template of what is wrong (``{name}``, ``{table}``, ``{value}`` still to fill).
        """
        if self.check is not None:
            verdict = self.check(value)
            if isinstance(verdict, str) or verdict is False:
                return verdict or self.message
        return None if self.holds(value) else self.message or ""

    def holds(self, value) -> bool:
        """Whether ``value`` (a number, a word, or each item of a tuple) is within the bounds and choices."""
        if isinstance(value, tuple):
            return bool(value) and all(self.holds(v) for v in value)
        if self.choices is not None and value not in self.choices:
            return False
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return not (
                (self.lo is not None and value < self.lo)
                or (self.hi is not None and value > self.hi)
                or (self.above is not None and value <= self.above)
                or (self.below is not None and value >= self.below)
            )
        return True


def setting(default=dataclasses.MISSING, *, factory=dataclasses.MISSING, **rule) -> Any:
    """A dataclass field with its :class:`Rule` in the metadata (``setting(64, lo=1, message=...)``)."""
    return field(default=default, default_factory=factory, metadata={"rule": Rule(**rule)})


def rule_of(f: dataclasses.Field) -> Rule:
    """The :class:`Rule` of a field (an empty one for fields declared without :func:`setting`)."""
    return f.metadata.get("rule", Rule())


NON_NEGATIVE = "{name} must be non-negative"
POSITIVE = "{name} must be positive"
AT_LEAST_1 = "{name} must be at least 1"
PHASE_RATES = "{table}: learning rates and warm-up must be finite and non-negative"
PHASE_SCALES = "{table}: steps must be ≥ 0 and sigmas positive"
PHASE_COUNT = "{name} must be an integer in [0, 10**8] (got {value})"


@dataclass(frozen=True)
class FlowConfig:
    """Flow-Net F_θ(x, t) (paper §4.6): MLP width, hidden layers, divergence-free option, ODE grid size T.

    ``skinning`` adds the skeleton's blended rigid bone velocities to the Flow-Net, with the pose
    trained by the data term (:class:`ncflow.flow.SkinnedField`; not in the paper, on in ``fast``);
    ``skinning_width`` is the width τ of its bone weights as a fraction of the median bone length;
    ``skinning_weights`` is where a point's bone weights are taken: ``"current"`` (its current
    place: a flow of space, a diffeomorphism), ``"start"`` (its starting place: limbs can meet and
    pass through each other, as the fingertips and palm of captured fists do), ``"surface"`` (as
    ``"start"``, from the bones under the skin there: a bone in front of the skin is left out, so the
    palm under a fist's fingertips stays with the palm) or ``"auto"`` (``"surface"`` when the source's
    limbs touch, ``"start"`` when the target passes through itself over more of its area than the
    source does, :func:`ncflow.matcher.prepare.skinning_weight_mode`);
    ``pose_lr_scale`` multiplies the learning rate of that pose (its quaternions take sign-like
    steps of about lr each, too slow for a 100° joint in a few hundred steps at the flow's rate);
    ``hold_contact_pose`` holds that pose at the pose search's during the first phase when the source's
    limbs touch (weights ``"surface"``): at its coarse σ touching fingers merge in the data term
    (:func:`ncflow.matcher.train.held_phases`);
    ``rigid_core`` (with ``skinning``; 0: off) fades the Flow-Net out around every bone, so that the
    bone samples (within ``sampling.bone_radius`` of the bone's axis) move with the skeleton alone and
    the bones stay rigid by construction: the Flow-Net's velocity is scaled by a smoothstep from 0 at
    the samples' radius to 1 at (1 + ``rigid_core``) radii (:func:`ncflow.flow.bone_weights.core_gate`);
    ``clear_joints`` (with ``rigid_core``) keeps each bone's samples and core out of its parent's and
    children's cores where a bend brings them together (:func:`ncflow.skeleton.checks.clear_joint_ranges`;
    docs/tuning.md, "Cores that meet at a bend": a fist's finger bone at 1.62 ε held to rounding, at the
    same geodesic AUC over the benchmarks' changed pairs);
    ``leash`` (with ``skinning``; 0: off) weighs a term that holds the Flow-Net itself, before the cores
    fade it, near zero at the bone samples (:func:`ncflow.matcher.objective.leash_term`), so that the
    skin next to a bone moves with the bone's pose rather than with a Flow-Net turning against it (off by
    default: it costs MANO hands 0.01–0.03 of geodesic AUC; docs/tuning.md, "The Flow-Net on a leash");
    ``tissue_anchor`` gives each tissue sample's stencil the bone weights of its centre where the weights
    are those of the start, so that the skeleton moves it rigidly and the tissue term reads the Flow-Net's
    distortion alone: ``"on"``, ``"off"``, or ``"auto"`` (on where the weights see the skin, ``"surface"``:
    a stencil between touching limbs is otherwise torn by the articulated motion itself;
    :func:`ncflow.matcher.objective.tissue_anchored`, docs/tuning.md, "Tissue stencils anchored").
    """

    width: int = setting(64, lo=1, hi=1 << 16, message=AT_LEAST_1)
    depth: int = setting(3, lo=1, hi=1024, message=AT_LEAST_1)
    div_free: bool = setting(False)
    skinning: bool = setting(True)
    skinning_width: float = setting(0.05, above=0, message=POSITIVE)
    skinning_weights: str = setting(
        "auto",
        choices=("auto", "current", "start", "surface"),
        message="{name} must be 'auto', 'current', 'start' or 'surface'",
    )
    pose_lr_scale: float = setting(5.0, lo=0, message=NON_NEGATIVE)
    hold_contact_pose: bool = setting(True)
    rigid_core: float = setting(1.0, lo=0, message=NON_NEGATIVE)
    clear_joints: bool = setting(True)
    leash: float = setting(0.0, lo=0, message=NON_NEGATIVE)
    tissue_anchor: str = setting("auto", choices=("auto", "on", "off"), message="{name} must be 'auto', 'on' or 'off'")
    n_times: int = setting(10, lo=2, hi=100_000, message="{name} must be at least 2")
    gso_width: int = setting(32, lo=1, hi=1 << 16)
    gso_depth: int = setting(2, lo=0, hi=1024)


@dataclass(frozen=True)
class SamplingConfig:
    """Per-step samples (paper §4.6): points per bone, tissue centroids, surface edges for the ARAP term.

    ``surface_edges`` ≥ 0: edges drawn per step for the ARAP term; 0 means all edges (the ``paper``
    preset).
    """

    bone_samples: int = setting(16, lo=5, hi=10**7, message="{name} must be at least 5")
    bone_radius: float = setting(0.1, above=0, message=POSITIVE)
    tissue_samples: int = setting(256, lo=0, hi=10**8, message=NON_NEGATIVE)
    tissue_delta: float = setting(0.01, above=0, message=POSITIVE)
    surface_edges: int = setting(1024, lo=0, hi=10**9, message="{name} must be non-negative (0 means all edges)")


@dataclass(frozen=True)
class PhaseConfig:
    """One optimisation phase: its data term, steps, kernel widths and learning-rate schedule.

    ``sigmas`` are used in equal consecutive parts of the phase (coarse to fine). The learning rate
    warms up linearly from 0 to ``lr`` over ``warmup`` steps, then follows a cosine to ``lr_end``
    (constant if ``lr_end`` is None). ``trajectory`` adds the interior-time bone constraints;
    ``constraint_weight`` multiplies the constraint term in this phase (the release's fine-tuning
    phase uses 20× its main endpoint weight; no preset uses more than 1, docs/tuning.md).
    ``metric``: ``"varifold"``, ``"normal-cycles"`` or ``"auto"`` (per stage: Normal Cycles, or the Varifold
    at four points a face where σ is below the source's edge length; :func:`ncflow.matcher.stages.stage_metric`).
    ``quadrature`` (Varifold only): points a face is integrated at, 1 (its centroid, the paper's) or 4
    (the centroids of its midpoint subdivision: :mod:`ncflow.measures.varifold`).
    """

    metric: str = setting("normal-cycles", choices=METRICS, message="{name} must be one of " + ", ".join(METRICS))
    steps: int = setting(100, lo=0, hi=10**8, message=PHASE_COUNT)
    sigmas: tuple[float, ...] = setting((0.25,), above=0, message=PHASE_SCALES)
    sigma_normal: float = setting(0.5, above=0, message=PHASE_SCALES)
    lr: float = setting(3e-3, lo=0, message=PHASE_RATES)
    lr_end: float | None = setting(None, lo=0, message=PHASE_RATES)
    warmup: int = setting(10, lo=0, hi=10**8, message=PHASE_COUNT)
    trajectory: bool = setting(True)
    constraint_weight: float = setting(1.0, lo=0, message=NON_NEGATIVE)
    quadrature: int = setting(1, check=lambda q: q in (1, 4), message="{name} must be 1 or 4 (got {value})")
    name: str = setting("")


@dataclass(frozen=True)
class ConstraintConfig:
    """Bone constraints g_k ≤ ε (paper §4.5, DESIGN.md "Constraints (MDMM)").

    ``eps`` is the tolerance on the mean squared distance (normalised units: the source encloses
    the volume of the unit ball) between a bone's flowed samples and their rigid reference.
    ``mode`` "mdmm": Lagrangian w·mean_k(λ_k Γ_k + (δ/2)Γ_k²), Γ_k = max(g_k − ε, 0), with
    multipliers λ ≥ 0 updated every step by λ ← max(0, λ ± η_t) (up while the running mean of g, decay
    ``multiplier_average``, is above the aim, down once below; η_t ramps from 0 to 2·``multiplier_lr``
    over the run; :func:`ncflow.optim.mdmm.update_multipliers`) and damping δ = ``damping``;
    "soft": a fixed penalty ``soft_weight`` · mean_k g_k/ε (the ARC-Flow baseline).
    ``trajectory_weight`` scales the interior-time constraints.
    ``margin`` (0 < margin ≤ 1): the MDMM terms aim at g_k ≤ margin·ε. MDMM settles each active
    constraint *at* its target, fluctuating around it with the per-step sampling; aiming a
    margin below ε keeps the final values (estimated on fresh samples) under ε. The ``paper``
    preset aims at ε itself (margin 1), as the release.
    ``reach_stretch`` (> 1): a bone whose skin the match stretched along it by more than this factor, or
    squeezed below its inverse, is named in a warning and ``constraints.out_of_reach`` (the skeleton did
    not reach the target there; :func:`ncflow.skeleton.reach.skin_stretch`).
    """

    mode: str = setting("mdmm", choices=("mdmm", "soft"), message="{name} must be 'mdmm' or 'soft'")
    eps: float = setting(3e-4, above=0, message=POSITIVE)
    margin: float = setting(0.7, above=0, hi=1, message="{name} must be in (0, 1]")
    damping: float = setting(1.0, lo=0, message=NON_NEGATIVE)
    multiplier_lr: float = setting(1.0, lo=0, message=NON_NEGATIVE)
    multiplier_average: float = setting(0.9, lo=0, below=1, message="{name} must be in [0, 1)")
    weight: float = setting(1.0, lo=0, message=NON_NEGATIVE)
    soft_weight: float = setting(1.0, lo=0, message=NON_NEGATIVE)
    trajectory_weight: float = setting(1.0, lo=0, message=NON_NEGATIVE)
    reach_stretch: float = setting(2.0, above=1, message="{name} must be above 1")


@dataclass(frozen=True)
class WeightsConfig:
    """μ_surf (ARAP surface distortion) and μ_soft (tissue distortion), paper Eq. 22."""

    surface: float = setting(1.0, lo=0, message=NON_NEGATIVE)
    tissue: float = setting(0.1, lo=0, message=NON_NEGATIVE)


@dataclass(frozen=True)
class TissueConfig:
    """Tetrahedralisation of the source (fTetWild) and its refinement; ``file``: reuse the exact
    tissue of an earlier run (its cache entry, named in that run's ``metrics.json`` under
    ``tissue.cache_file``) instead of tetrahedralising.
    """

    edge_length_fac: float = setting(0.1, above=0, hi=1, message="{name} must be in (0, 1]")
    epsilon: float = setting(5e-3, above=0, message=POSITIVE)
    split_passes: int = setting(2, lo=0, hi=100)
    cache: bool = setting(True)
    file: str | None = setting(None)


@dataclass(frozen=True)
class RepairConfig:
    """The intake step every mesh passes before it is matched (:func:`ncflow.geometry.repair.repair_mesh`):
    exactly coincident vertices are welded, zero-area and duplicate faces dropped, non-manifold edges and
    vertices split. ``weld_tolerance``: weld vertices closer than this fraction of the mesh's
    bounding-box diagonal too (0: exactly coincident ones only; at most 0.01). ``min_component``: leave
    out of the data terms the connected components (after the split) with less than this share of a
    mesh's area: the fins the split tears off a surface, the debris of a scan (default 0.5 %; 0 keeps
    every component). The outputs keep one row per vertex of the files either way.
    """

    weld_tolerance: float = setting(
        0.0,
        lo=0,
        hi=MAX_WELD_TOLERANCE,
        message=f"{{name}} must be in [0, {MAX_WELD_TOLERANCE:g}] (a fraction of the mesh's size)",
    )
    min_component: float = setting(
        0.005, lo=0, below=1, message="{name} must be in [0, 1) (a share of the mesh's area)"
    )


OFF_WORDS = ("auto", "none", "off", "0", "false", "no")


def jit_cache_problem(value) -> str | None:
    """What is wrong with a ``jit_cache`` setting (None when nothing): it must be ``auto``, ``none`` or
    a folder that is not under a file.
    """
    if not isinstance(value, str) or not value.strip() or "\x00" in value or len(value) > 4096:
        return "{name} must be auto, none or a folder (got {value})"
    if value.lower() in OFF_WORDS:
        return None
    folder = os.path.realpath(os.path.expanduser(value))
    probe = folder
    while not os.path.exists(probe):
        parent = os.path.dirname(probe)
        if parent == probe:
            break
        probe = parent
    if os.path.exists(probe) and not os.path.isdir(probe):
        return f"{{name}}: {{value}} is not a folder ({quote(probe)} is a file)"
    return None


@dataclass(frozen=True)
class Config:
    """Everything :func:`ncflow.match` needs besides the inputs.

    ``divergence_guard`` (> 1, or 0 to disable): when the smoothed data term of a stage rises
    above this multiple of its best value in that stage (or, from the second stage on, the
    largest bone violation above 5× this multiple of its best and above 20 ε), the run is rolled
    back to its last healthy snapshot and continues with half the learning rate; a run whose
    last stage ends with the violation above 5× this multiple of an earlier stage end's keeps
    that earlier end (``match.guard.DivergenceGuard``).
    ``placement`` (``auto`` | ``none``): move the target rigidly onto the source before matching
    (any rotation; :mod:`ncflow.matcher.placement`), outputs moved back; ``none`` trusts the input
    placement. ``pose_search``: search the skeleton pose that best explains the target before the
    flow trains (:mod:`ncflow.matcher.pose_search`; with ``flow.skinning`` only). ``pose_chains``
    (``auto`` | ``on`` | ``off``): after that search, re-pose each finger or limb with the others held
    at a finer kernel scale (:func:`ncflow.matcher.pose_search.search_chains`); ``auto``: where the
    source's limbs touch (bone weights ``"surface"``, whose first phase holds the searched pose).
    ``pose_exchanges``: after that search, try the found pose's fingers (three or more alike limbs off one
    joint) exchanged in pairs at the fine kernel scale, the one-to-one assignment of fingers to the
    target's (:mod:`ncflow.matcher.pose_exchange`); off by default until measured on every benchmark pair.
    ``skeleton_bases`` (``auto`` | ``ring`` | ``inside`` | ``choose``): without a given skeleton, where the
    suggested skeleton puts a limb's base joint (:func:`ncflow.skeleton.suggest.suggest_skeleton`): ``ring``
    where the limb leaves the body, ``inside`` a limb's radius further in for limbs in pairs, ``auto`` (the
    default) inside for fingers and toes only (limbs in groups of four or more alike), ring elsewhere;
    ``choose``: ring and inside suggested, the second's pose searched at the first's placement, the one whose
    pose explains the target best kept (:func:`ncflow.matcher.place.place_suggested`; measured, not the
    default: docs/skeleton-suggest.md). ``ncflow track`` suggests one skeleton for all frames (``auto`` for
    ``choose``).
    ``partial`` (``off`` | ``auto`` | ``on``): match with the partial data terms (:mod:`ncflow.matcher.partial`):
    the source's parts the target does not show carry no mass, the target's cut borders are not read as
    the shape's boundary; ``auto``: when the target has open borders the posed source has not (a scan's
    view, holes). ``off`` (default: measured, the whole terms scored higher on every scan case,
    docs/scans.md) still reports what a partial target shows (``source_seen.txt``).
    ``working_vertices``: train on a decimated copy of a source larger than this (its vertices a
    subset of the source's, :func:`ncflow.geometry.decimate.decimate`); the outputs and the
    correspondence are computed at full resolution with the trained field. ``none``: train on the
    full source. ``jit_cache`` (``auto`` | ``none`` | a folder): JAX's persistent compilation cache
    (:mod:`ncflow.jit.cache`; ``$NCFLOW_JIT_CACHE`` wins); it never changes results.
    ``compile_ahead``: compile the training step and the output programs in a background thread
    while the target is placed and the pose searched (:mod:`ncflow.jit.ahead`); it never changes
    results. ``setup_cache``: keep the placement and the pose search of a pair in the cache folder
    (``setup/``), keyed by the normalised inputs, the settings they depend on and ncflow's code, so
    a run on the same pair with other training settings reads them back
    (:func:`ncflow.matcher.place.place_and_pose_cached`); it never changes results.
    """

    preset: str = setting("fast")
    seed: int = setting(0, lo=0, hi=SEED_LIMIT - 1)
    flow: FlowConfig = setting(factory=FlowConfig)
    sampling: SamplingConfig = setting(factory=SamplingConfig)
    phases: tuple[PhaseConfig, ...] = setting(())
    constraints: ConstraintConfig = setting(factory=ConstraintConfig)
    weights: WeightsConfig = setting(factory=WeightsConfig)
    tissue: TissueConfig = setting(factory=TissueConfig)
    repair: RepairConfig = setting(factory=RepairConfig)
    optimizer: str = setting(
        "adabelief", choices=("adabelief", "vectoradam"), message="{name} must be 'adabelief' or 'vectoradam'"
    )
    clip_norm: float = setting(0.5, above=0, message=POSITIVE)
    weight_decay: float = setting(1e-4, lo=0, message=NON_NEGATIVE)
    interp: str = setting("sclerp", choices=("sclerp", "slerp"), message="{name} must be 'sclerp' or 'slerp'")
    compress: int | None = setting(3000, lo=10, hi=10**9, message="{name} must be at least 10 (or none)")
    working_vertices: int | None = setting(
        3000, lo=100, hi=10**9, message="{name} must be at least 100 (or none: train on the full-resolution source)"
    )
    frames: int = setting(20, lo=2, hi=1_000_000, message="{name} must be at least 2")
    divergence_guard: float = setting(2.0, check=lambda v: v == 0 or v > 1, message="{name} must be 0 (off) or above 1")
    placement: str = setting("auto", choices=("auto", "none"), message="{name} must be 'auto' or 'none'")
    pose_search: bool = setting(True)
    pose_chains: str = setting("off", choices=("auto", "on", "off"), message="{name} must be 'auto', 'on' or 'off'")
    pose_exchanges: bool = setting(False)
    skeleton_bases: str = setting(
        "auto",
        choices=("ring", "inside", "auto", "choose"),
        message="{name} must be 'ring', 'inside', 'auto' or 'choose'",
    )
    partial: str = setting("off", choices=("auto", "on", "off"), message="{name} must be 'auto', 'on' or 'off'")
    jit_cache: str = setting("auto", check=jit_cache_problem, neutral=True)
    compile_ahead: bool = setting(True, neutral=True)
    setup_cache: bool = setting(True, neutral=True)

    @property
    def total_steps(self) -> int:
        return sum(p.steps for p in self.phases)


RESULT_NEUTRAL = tuple(f.name for f in dataclasses.fields(Config) if rule_of(f).neutral)
"""Settings of :class:`Config` that never change a result (left out where configurations are compared)."""
