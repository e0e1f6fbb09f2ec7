"""Matcher configuration: typed settings, presets, TOML/YAML files and overrides.

A :class:`Config` is a tree of frozen dataclasses. Presets:

* ``fast`` (default) — tuned for a 2-core CPU: a narrow flow net plus the skeleton-driven
  velocities (``flow.skinning``), few bone/tissue samples per step, a short Varifold phase then
  Normal Cycles coarse → fine, target compressed per length scale, MDMM aiming at 0.7 ε.
* ``paper`` — the paper/release settings (reference-notes §10): width-256 depth-6 flow net,
  50 samples per bone, 2000 tissue samples, 2000 Varifold steps (σ 0.5 → 0.25) then 2000 Normal
  Cycle steps (σ 0.25 → 0.1) and 1000 fine-tuning steps, AdaBelief-cautious with lr 3e-3.
  Hours on a CPU; meant for a GPU.

Files: a TOML or YAML mapping with the same nesting as :class:`Config`, e.g. ::

    preset = "fast"
    seed = 3
    [flow]
    width = 96
    [[phases]]
    metric = "varifold"
    steps = 100
    sigmas = [0.5]

``phases``, when given, replaces the preset's list. Dotted command-line overrides
(``flow.width=96``) are applied last.
"""

from __future__ import annotations

import dataclasses
import os
import tomllib
import typing
from dataclasses import dataclass, field

from ncflow.errors import InputError

METRICS = ("varifold", "normal-cycles")


@dataclass(frozen=True)
class FlowConfig:
    """Flow-Net F_θ(x, t) (paper §4.6): MLP width, hidden layers, divergence-free option, ODE grid size T.

    ``skinning`` adds the skeleton's blended rigid bone velocities to the Flow-Net, with the pose
    trained by the data term (:class:`ncflow.flow.SkinnedField`; not in the paper, on in ``fast``);
    ``skinning_width`` is the width τ of its bone weights as a fraction of the median bone length;
    ``pose_lr_scale`` multiplies the learning rate of that pose (its quaternions take sign-like
    steps of about lr each, too slow for a 100° joint in a few hundred steps at the flow's rate).
    """

    width: int = 64
    depth: int = 3
    div_free: bool = False
    skinning: bool = True
    skinning_width: float = 0.05
    pose_lr_scale: float = 5.0
    n_times: int = 10
    gso_width: int = 32
    gso_depth: int = 2


@dataclass(frozen=True)
class SamplingConfig:
    """Per-step samples (paper §4.6): points per bone, tissue centroids, surface edges for the ARAP term."""

    bone_samples: int = 16
    bone_radius: float = 0.1
    tissue_samples: int = 256
    tissue_delta: float = 0.01
    surface_edges: int = 1024


@dataclass(frozen=True)
class PhaseConfig:
    """One optimisation phase: its data term, steps, kernel widths and learning-rate schedule.

    ``sigmas`` are used in equal consecutive parts of the phase (coarse to fine). The learning rate
    warms up linearly from 0 to ``lr`` over ``warmup`` steps, then follows a cosine to ``lr_end``
    (constant if ``lr_end`` is None). ``trajectory`` adds the interior-time bone constraints;
    ``constraint_weight`` multiplies the constraint term in this phase (the release's fine-tuning
    phase uses 20× its main endpoint weight; with our multiplier schedule a 20× phase destabilised
    the fast preset on MANO, so no preset uses it).
    """

    metric: str = "normal-cycles"
    steps: int = 100
    sigmas: tuple[float, ...] = (0.25,)
    sigma_normal: float = 0.5
    lr: float = 3e-3
    lr_end: float | None = None
    warmup: int = 10
    trajectory: bool = True
    constraint_weight: float = 1.0
    name: str = ""


@dataclass(frozen=True)
class ConstraintConfig:
    """Bone constraints g_k ≤ ε (paper §4.5, DESIGN.md "Constraints (MDMM)").

    ``eps`` is the tolerance on the mean squared distance (normalised units: the source encloses
    the volume of the unit ball) between a bone's flowed samples and their rigid reference.
    ``mode`` "mdmm": Lagrangian w·mean_k(λ_k Γ_k + (δ/2)Γ_k²), Γ_k = max(g_k − ε, 0), with
    multipliers λ ≥ 0 updated every step by λ ← max(0, λ ± η_t) (up while violated, down once
    satisfied; η_t ramps from 0 to 2·``multiplier_lr`` over the run) and damping δ = ``damping``;
    "soft": a fixed penalty ``soft_weight`` · mean_k g_k/ε (the ARC-Flow baseline).
    ``trajectory_weight`` scales the interior-time constraints.
    ``margin`` (0 < margin ≤ 1): the MDMM terms aim at g_k ≤ margin·ε. MDMM settles each active
    constraint *at* its target, fluctuating around it with the per-step sampling; aiming a
    margin below ε keeps the final values (estimated on fresh samples) under ε. The ``paper``
    preset aims at ε itself (margin 1), as the release.
    """

    mode: str = "mdmm"
    eps: float = 3e-4
    margin: float = 0.7
    damping: float = 1.0
    multiplier_lr: float = 1.0
    weight: float = 1.0
    soft_weight: float = 1.0
    trajectory_weight: float = 1.0


@dataclass(frozen=True)
class WeightsConfig:
    """μ_surf (ARAP surface distortion) and μ_soft (tissue distortion), paper Eq. 22."""

    surface: float = 1.0
    tissue: float = 0.1


@dataclass(frozen=True)
class TissueConfig:
    """Tetrahedralisation of the source (fTetWild) and its refinement."""

    edge_length_fac: float = 0.1
    epsilon: float = 5e-3
    split_passes: int = 2
    cache: bool = True


@dataclass(frozen=True)
class Config:
    """Everything :func:`ncflow.match` needs besides the inputs.

    ``divergence_guard`` (> 1, or 0 to disable): when the smoothed data term of a stage rises
    above this multiple of its best value in that stage (or, from the second stage on, the
    largest bone violation above 5× this multiple of its best and above 20 ε), the run is rolled
    back to its last healthy snapshot and continues with half the learning rate
    (``matcher.DivergenceGuard``).
    ``placement`` (``auto`` | ``none``): move the target rigidly onto the source before matching
    (any rotation; :mod:`ncflow.match.placement`), outputs moved back; ``none`` trusts the input
    placement. ``pose_search``: search the skeleton pose that best explains the target before the
    flow trains (:mod:`ncflow.match.pose_search`; with ``flow.skinning`` only).
    ``working_vertices``: train on a decimated copy of a source larger than this (its vertices a
    subset of the source's, :func:`ncflow.geometry.decimate.decimate`); the outputs and the
    correspondence are computed at full resolution with the trained field. ``none``: train on the
    full source. ``jit_cache`` (``auto`` | ``none`` | a folder): JAX's persistent compilation cache
    (:mod:`ncflow.cache`; ``$NCFLOW_JIT_CACHE`` wins); it never changes results.
    """

    preset: str = "fast"
    seed: int = 0
    flow: FlowConfig = field(default_factory=FlowConfig)
    sampling: SamplingConfig = field(default_factory=SamplingConfig)
    phases: tuple[PhaseConfig, ...] = ()
    constraints: ConstraintConfig = field(default_factory=ConstraintConfig)
    weights: WeightsConfig = field(default_factory=WeightsConfig)
    tissue: TissueConfig = field(default_factory=TissueConfig)
    optimizer: str = "adabelief"
    clip_norm: float = 0.5
    weight_decay: float = 1e-4
    interp: str = "sclerp"
    compress: int | None = 3000
    working_vertices: int | None = 3000
    frames: int = 20
    divergence_guard: float = 2.0
    placement: str = "auto"
    pose_search: bool = True
    jit_cache: str = "auto"

    @property
    def total_steps(self) -> int:
        return sum(p.steps for p in self.phases)


def _fast() -> Config:
    return Config(
        preset="fast",
        phases=(
            PhaseConfig(name="varifold", metric="varifold", steps=150, sigmas=(0.5, 0.25), lr=3e-3, warmup=10),
            PhaseConfig(
                name="normal-cycles",
                metric="normal-cycles",
                steps=250,
                sigmas=(0.25, 0.1),
                lr=3e-3,
                lr_end=3e-4,
                warmup=10,
            ),
        ),
    )


def _paper() -> Config:
    return Config(
        preset="paper",
        flow=FlowConfig(width=256, depth=6, n_times=10, gso_width=128, gso_depth=3, skinning=False),
        sampling=SamplingConfig(bone_samples=50, tissue_samples=2000, surface_edges=0),
        phases=(
            PhaseConfig(
                name="varifold",
                metric="varifold",
                steps=2000,
                sigmas=(0.5, 0.25),
                lr=3e-3,
                warmup=100,
                trajectory=False,
            ),
            PhaseConfig(
                name="normal-cycles",
                metric="normal-cycles",
                steps=2000,
                sigmas=(0.25, 0.1),
                lr=3e-3,
                lr_end=1e-4,
                warmup=100,
            ),
            PhaseConfig(name="fine-tune", metric="normal-cycles", steps=1000, sigmas=(0.1,), lr=1e-4, warmup=100),
        ),
        constraints=ConstraintConfig(eps=3e-4, margin=1.0),
        weights=WeightsConfig(surface=20.0, tissue=10.0),
        tissue=TissueConfig(edge_length_fac=0.05, epsilon=1e-3, split_passes=2),
        compress=6000,
        working_vertices=6000,
        frames=100,
    )


PRESETS: dict[str, typing.Callable[[], Config]] = {"fast": _fast, "paper": _paper}


def preset(name: str) -> Config:
    """A preset configuration by name (``fast`` or ``paper``)."""
    if name not in PRESETS:
        raise InputError(f"unknown preset {name!r}; choose from {', '.join(PRESETS)}")
    return PRESETS[name]()


def config_to_dict(config: Config) -> dict:
    """Plain nested dict (JSON/TOML-ready) of a configuration."""
    return dataclasses.asdict(config)


def _coerce(value, typ, where: str):
    origin = typing.get_origin(typ)
    args = typing.get_args(typ)
    if dataclasses.is_dataclass(typ):
        if not isinstance(value, dict):
            raise InputError(f"{where}: expected a table, got {value!r}")
        return _build(typ, value, where)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            value = [value]
        inner = args[0]
        return tuple(_coerce(v, inner, f"{where}[{i}]") for i, v in enumerate(value))
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        if value is None and type(None) in args:
            return None
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(value, a, where)
            except InputError:
                continue
        raise InputError(f"{where}: cannot use {value!r}")
    if typ is bool:
        if isinstance(value, str):
            if value.lower() in ("true", "1", "yes", "on"):
                return True
            if value.lower() in ("false", "0", "no", "off"):
                return False
        if isinstance(value, bool):
            return value
        raise InputError(f"{where}: expected true/false, got {value!r}")
    if typ in (int, float):
        try:
            out = typ(value)
        except (TypeError, ValueError):
            raise InputError(f"{where}: expected a number, got {value!r}") from None
        if typ is int and isinstance(value, float) and value != int(value):
            raise InputError(f"{where}: expected an integer, got {value!r}")
        return out
    if typ is str:
        return "none" if value is None else str(value)  # ``key=none`` of a string setting is the word
    return value


def _build(cls, data: dict, where: str):
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise InputError(f"{where}: unknown setting(s) {', '.join(sorted(unknown))}; known: {', '.join(sorted(names))}")
    base = cls()
    kwargs = {}
    for name, value in data.items():
        kwargs[name] = _coerce(value, hints[name], f"{where}.{name}" if where else name)
    return dataclasses.replace(base, **kwargs)


def _merge(config: Config, data: dict, where: str | None) -> Config:
    """Replace the fields given in ``data`` (nested tables merge into the current sub-config)."""
    hints = typing.get_type_hints(Config)
    names = {f.name for f in dataclasses.fields(Config)}
    unknown = set(data) - names
    if unknown:
        raise InputError(f"unknown setting(s) {', '.join(sorted(unknown))}; known: {', '.join(sorted(names))}", where)
    updates = {}
    for name, value in data.items():
        current = getattr(config, name)
        if dataclasses.is_dataclass(current) and isinstance(value, dict):
            sub_hints = typing.get_type_hints(type(current))
            sub_names = {f.name for f in dataclasses.fields(current)}
            bad = set(value) - sub_names
            if bad:
                raise InputError(f"unknown setting(s) {name}.{', '.join(sorted(bad))}", where)
            updates[name] = dataclasses.replace(
                current, **{k: _coerce(v, sub_hints[k], f"{name}.{k}") for k, v in value.items()}
            )
        else:
            updates[name] = _coerce(value, hints[name], name)
    return dataclasses.replace(config, **updates)


def load_config(path: str | os.PathLike | None = None, preset_name: str | None = None) -> Config:
    """Preset (``preset_name``, else the file's ``preset`` key, else ``fast``) updated by a TOML/YAML file."""
    data: dict = {}
    if path is not None:
        path = os.fspath(path)
        if not os.path.exists(path):
            raise InputError("no such file", path)
        try:
            if path.lower().endswith((".yaml", ".yml")):
                import yaml

                with open(path) as fh:
                    data = yaml.safe_load(fh) or {}
            elif path.lower().endswith(".toml"):
                with open(path, "rb") as fh:
                    data = tomllib.load(fh)
            else:
                raise InputError("configuration files must be .toml, .yaml or .yml", path)
        except InputError:
            raise
        except Exception as exc:  # parse errors of either library
            raise InputError(f"cannot parse configuration ({str(exc).splitlines()[0]})", path) from None
        if not isinstance(data, dict):
            raise InputError("configuration must be a mapping of settings", path)
    name = preset_name or data.get("preset") or "fast"
    config = preset(str(name))
    data = {k: v for k, v in data.items() if k != "preset"}
    try:
        return validate_config(_merge(config, data, path))
    except InputError as exc:
        if path and not str(exc).startswith(str(path)):
            raise InputError(str(exc), path) from None
        raise


def apply_overrides(config: Config, overrides: list[str]) -> Config:
    """Apply ``section.key=value`` strings (e.g. ``flow.width=96``, ``seed=3``)."""
    for item in overrides:
        if "=" not in item:
            raise InputError(f"override {item!r} must look like key=value (e.g. flow.width=96)")
        key, value = item.split("=", 1)
        parts = key.strip().split(".")
        parsed: typing.Any = value.strip()
        if parsed.startswith("[") and parsed.endswith("]"):
            parsed = [p.strip() for p in parsed[1:-1].split(",") if p.strip()]
        if parsed == "none" or parsed == "None":
            parsed = None
        nested: typing.Any = parsed
        for p in reversed(parts[1:]):
            nested = {p: nested}
        config = _merge(config, {parts[0]: nested}, None)
    return validate_config(config)


def validate_config(config: Config) -> Config:
    """Check ranges and choices; raise :class:`InputError` with the setting's name."""
    checks = [
        (config.flow.width >= 1, "flow.width must be at least 1"),
        (config.flow.depth >= 1, "flow.depth must be at least 1"),
        (config.flow.n_times >= 2, "flow.n_times must be at least 2"),
        (config.flow.skinning_width > 0, "flow.skinning_width must be positive"),
        (config.flow.pose_lr_scale >= 0, "flow.pose_lr_scale must be non-negative"),
        (
            not (config.flow.skinning and config.flow.div_free),
            "flow.div_free needs flow.skinning=false (blended bone velocities are not divergence-free)",
        ),
        (config.sampling.bone_samples >= 5, "sampling.bone_samples must be at least 5"),
        (config.sampling.bone_radius > 0, "sampling.bone_radius must be positive"),
        (config.sampling.tissue_samples >= 0, "sampling.tissue_samples must be non-negative"),
        (config.sampling.tissue_delta > 0, "sampling.tissue_delta must be positive"),
        (config.constraints.mode in ("mdmm", "soft"), "constraints.mode must be 'mdmm' or 'soft'"),
        (config.constraints.eps > 0, "constraints.eps must be positive"),
        (0 < config.constraints.margin <= 1, "constraints.margin must be in (0, 1]"),
        (config.optimizer in ("adabelief", "vectoradam"), "optimizer must be 'adabelief' or 'vectoradam'"),
        (config.interp in ("sclerp", "slerp"), "interp must be 'sclerp' or 'slerp'"),
        (config.compress is None or config.compress >= 10, "compress must be at least 10 (or none)"),
        (
            config.working_vertices is None or config.working_vertices >= 100,
            "working_vertices must be at least 100 (or none: train on the full-resolution source)",
        ),
        (config.frames >= 2, "frames must be at least 2"),
        (config.divergence_guard == 0 or config.divergence_guard > 1, "divergence_guard must be 0 (off) or above 1"),
        (len(config.phases) >= 1, "at least one phase is needed"),
        (config.placement in ("auto", "none"), "placement must be 'auto' or 'none'"),
    ]
    for ok, message in checks:
        if not ok:
            raise InputError(message)
    for i, p in enumerate(config.phases):
        if p.metric not in METRICS:
            raise InputError(f"phases[{i}].metric must be one of {', '.join(METRICS)} (got {p.metric!r})")
        if p.steps < 0 or not p.sigmas or any(s <= 0 for s in p.sigmas) or p.sigma_normal <= 0:
            raise InputError(f"phases[{i}]: steps must be ≥ 0 and sigmas positive")
        if p.lr < 0 or (p.lr_end is not None and p.lr_end < 0) or p.warmup < 0:
            raise InputError(f"phases[{i}]: learning rates and warm-up must be non-negative")
        if p.constraint_weight < 0:
            raise InputError(f"phases[{i}].constraint_weight must be non-negative")
    if config.total_steps < 1:
        raise InputError("the phases have no steps")
    return config


def with_metric(config: Config, metric: str) -> Config:
    """Ablation switch ``--metric``: 'varifold', 'normal-cycles' or 'varifold+normal-cycles' (the default)."""
    if metric == "varifold+normal-cycles":
        return config
    if metric not in METRICS:
        raise InputError(f"--metric must be varifold, normal-cycles or varifold+normal-cycles (got {metric!r})")
    phases = tuple(dataclasses.replace(p, metric=metric) for p in config.phases)
    return dataclasses.replace(config, phases=phases)


def scale_steps(cfg: Config, total: int) -> Config:
    """Rescale the phases' step counts (and warm-ups) to ``total`` steps, keeping proportions."""
    old = cfg.total_steps
    steps = [max(1, round(p.steps * total / old)) if p.steps else 0 for p in cfg.phases]
    steps[-1] = max(1, total - sum(steps[:-1])) if total > sum(steps[:-1]) else steps[-1]
    phases = tuple(
        dataclasses.replace(p, steps=n, warmup=min(p.warmup, max(0, n // 5))) for p, n in zip(cfg.phases, steps)
    )
    return dataclasses.replace(cfg, phases=phases)
