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

Every setting is checked when a configuration is loaded or overridden (:func:`validate_config`):
numbers finite and in range, integers integral (``seed``: 0 ≤ seed < 2**32), choices among
their words; a file must be a mapping with string keys, at most 1 MiB, and a YAML file may not
use aliases (``*name``: a few hundred bytes of nested aliases expand to gigabytes). Error
messages quote at most :data:`QUOTE_LIMIT` characters of any value.

Over 500 lines: the settings, their presets, the file readers and the range checks are one
contract; a setting and its check are kept in one file so that they cannot drift apart.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import tomllib
import types
import typing
from dataclasses import dataclass, field

from ncflow.errors import InputError
from ncflow.geometry.repair import MAX_WELD_TOLERANCE

METRICS = ("varifold", "normal-cycles")
#: largest seed + 1 (NumPy and JAX take 32-bit seeds)
SEED_LIMIT = 2**32
#: characters of a user's value quoted in an error message
QUOTE_LIMIT = 80
#: largest configuration file read
MAX_CONFIG_BYTES = 1 << 20
#: most YAML nodes of a configuration file
MAX_YAML_NODES = 100_000


def quote(value, limit: int = QUOTE_LIMIT) -> str:
    """``repr(value)`` cut to ``limit`` characters (``…`` marks a cut), for one-line error messages."""
    try:
        text = repr(value)
    except Exception:  # noqa: BLE001 -- a broken or too deep __repr__ must not hide the real error
        text = f"<{type(value).__name__}>"
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 1] + "…"


@dataclass(frozen=True)
class FlowConfig:
    """Flow-Net F_θ(x, t) (paper §4.6): MLP width, hidden layers, divergence-free option, ODE grid size T.

    ``skinning`` adds the skeleton's blended rigid bone velocities to the Flow-Net, with the pose
    trained by the data term (:class:`ncflow.flow.SkinnedField`; not in the paper, on in ``fast``);
    ``skinning_width`` is the width τ of its bone weights as a fraction of the median bone length;
    ``skinning_weights`` is where a point's bone weights are taken: ``"current"`` (its current
    place: a flow of space, a diffeomorphism), ``"start"`` (its starting place: limbs can meet and
    pass through each other, as the fingertips and palm of captured fists do) or ``"auto"``
    (``"start"`` when the target passes through itself over more of its area than the source does,
    :func:`ncflow.match.prepare.skinning_weight_mode`);
    ``pose_lr_scale`` multiplies the learning rate of that pose (its quaternions take sign-like
    steps of about lr each, too slow for a 100° joint in a few hundred steps at the flow's rate).
    """

    width: int = 64
    depth: int = 3
    div_free: bool = False
    skinning: bool = True
    skinning_width: float = 0.05
    skinning_weights: str = "auto"
    pose_lr_scale: float = 5.0
    n_times: int = 10
    gso_width: int = 32
    gso_depth: int = 2


@dataclass(frozen=True)
class SamplingConfig:
    """Per-step samples (paper §4.6): points per bone, tissue centroids, surface edges for the ARAP term.

    ``surface_edges`` ≥ 0: edges drawn per step for the ARAP term; 0 means all edges (the ``paper``
    preset).
    """

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
    """Tetrahedralisation of the source (fTetWild) and its refinement; ``file``: reuse the exact
    tissue of an earlier run (its cache entry, named in that run's ``metrics.json`` under
    ``tissue.cache_file``) instead of tetrahedralising.
    """

    edge_length_fac: float = 0.1
    epsilon: float = 5e-3
    split_passes: int = 2
    cache: bool = True
    file: str | None = None


@dataclass(frozen=True)
class RepairConfig:
    """The intake step every mesh passes before it is matched (:func:`ncflow.geometry.repair.repair_mesh`):
    exactly coincident vertices are welded, zero-area and duplicate faces dropped, non-manifold edges and
    vertices split. ``weld_tolerance``: weld vertices closer than this fraction of the mesh's
    bounding-box diagonal too (0: exactly coincident ones only; at most 0.01). ``min_component``: leave
    out of the data terms the connected components with less than this share of a mesh's area (debris
    of a scan; 0 keeps every component). The outputs keep one row per vertex of the files either way.
    """

    weld_tolerance: float = 0.0
    min_component: float = 0.0


RESULT_NEUTRAL = ("jit_cache", "compile_ahead", "setup_cache")
"""Settings of :class:`Config` that never change a result (left out where configurations are compared)."""


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
    (any rotation; :mod:`ncflow.match.placement`), outputs moved back; ``none`` trusts the input
    placement. ``pose_search``: search the skeleton pose that best explains the target before the
    flow trains (:mod:`ncflow.match.pose_search`; with ``flow.skinning`` only).
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
    (:func:`ncflow.match.prepare.place_and_pose_cached`); it never changes results.
    """

    preset: str = "fast"
    seed: int = 0
    flow: FlowConfig = field(default_factory=FlowConfig)
    sampling: SamplingConfig = field(default_factory=SamplingConfig)
    phases: tuple[PhaseConfig, ...] = ()
    constraints: ConstraintConfig = field(default_factory=ConstraintConfig)
    weights: WeightsConfig = field(default_factory=WeightsConfig)
    tissue: TissueConfig = field(default_factory=TissueConfig)
    repair: RepairConfig = field(default_factory=RepairConfig)
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
    compile_ahead: bool = True
    setup_cache: bool = True

    @property
    def total_steps(self) -> int:
        return sum(p.steps for p in self.phases)


def _fast() -> Config:
    return Config(
        preset="fast",
        phases=(
            PhaseConfig(name="varifold", metric="varifold", steps=150, sigmas=(0.25,), lr=3e-3, warmup=10),
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
        raise InputError(f"unknown preset {quote(name)}; choose from {', '.join(PRESETS)}")
    return PRESETS[name]()


def config_to_dict(config: Config) -> dict:
    """Plain nested dict (JSON/TOML-ready) of a configuration."""
    return dataclasses.asdict(config)


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _coerce(value, typ, where: str):
    origin = typing.get_origin(typ)
    args = typing.get_args(typ)
    if dataclasses.is_dataclass(typ):
        if not isinstance(value, dict):
            raise InputError(f"{where}: expected a table, got {quote(value)}")
        return _build(typ, value, where)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            value = [value]
        inner = args[0]
        return tuple(_coerce(v, inner, f"{where}[{i}]") for i, v in enumerate(value))
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(value, a, where)
            except InputError as exc:
                errors.append(exc)
        if len(errors) == 1:  # Optional[X]: X's own message
            raise errors[0]
        raise InputError(f"{where}: cannot use {quote(value)}")
    if typ is bool:
        if isinstance(value, str):
            if value.lower() in ("true", "1", "yes", "on"):
                return True
            if value.lower() in ("false", "0", "no", "off"):
                return False
        if isinstance(value, bool):
            return value
        raise InputError(f"{where}: expected true/false, got {quote(value)}")
    if typ is int:
        return _as_int(value, where)
    if typ is float:
        if isinstance(value, str):
            try:
                value = float(value.strip())
            except ValueError:
                raise InputError(f"{where}: expected a number, got {quote(value)}") from None
        if not _is_number(value):
            raise InputError(f"{where}: expected a number, got {quote(value)}")
        out = float(value)  # an int too large for a float raises OverflowError
        if not math.isfinite(out):
            raise InputError(f"{where} must be finite, got {quote(value)}")
        return out
    if typ is str:
        if value is None:
            return "none"  # ``key=none`` of a string setting is the word
        if not isinstance(value, (str, int, float)) or isinstance(value, bool):
            raise InputError(f"{where}: expected a word, got {quote(value)}")
        return str(value)
    return value


def _as_int(value, where: str) -> int:
    """An integer setting from an int, an integral finite float or a decimal string."""
    if isinstance(value, str):
        text = value.strip()
        try:
            value = int(text)
        except ValueError:
            try:
                value = float(text)
            except ValueError:
                raise InputError(f"{where}: expected an integer, got {quote(text)}") from None
    if not _is_number(value):
        raise InputError(f"{where}: expected an integer, got {quote(value)}")
    if isinstance(value, float):
        if not math.isfinite(value):
            raise InputError(f"{where} must be a finite integer, got {quote(value)}")
        if value != int(value):
            raise InputError(f"{where}: expected an integer, got {quote(value)}")
        value = int(value)
    return int(value)


def _check_keys(data: dict, where: str | None, prefix: str = "") -> None:
    for key in data:
        if not isinstance(key, str):
            name = f"{prefix}{quote(key)}"
            raise InputError(f"setting names must be words, got {name} ({type(key).__name__})", where)


def _names(keys, most: int = 10) -> str:
    """Setting names for a message: at most ``most``, each cut to 40 characters."""
    shown = [k if k.isidentifier() and len(k) <= 40 else quote(k, 40) for k in sorted(keys)[:most]]
    return ", ".join(shown) + (", …" if len(keys) > most else "")


def _unknown(unknown, names, prefix: str = "") -> str:
    """The message for unknown setting names: the closest known ones first, then the known ones."""
    close = sorted({m for u in unknown for m in difflib.get_close_matches(str(u)[:100], names, n=3, cutoff=0.7)})
    hint = f"; did you mean {', '.join(prefix + c for c in close)}?" if close else ""
    return f"unknown setting(s) {prefix}{_names(unknown)}{hint} (known: {_names(names, 12)})"


def _build(cls, data: dict, where: str):
    _check_keys(data, None, f"{where}." if where else "")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise InputError(f"{where}: {_unknown(unknown, names)}")
    base = cls()
    kwargs = {}
    for name, value in data.items():
        kwargs[name] = _coerce(value, hints[name], f"{where}.{name}" if where else name)
    return dataclasses.replace(base, **kwargs)


def _merge(config: Config, data: dict, where: str | None) -> Config:
    """Replace the fields given in ``data`` (nested tables merge into the current sub-config)."""
    _check_keys(data, where)
    hints = typing.get_type_hints(Config)
    names = {f.name for f in dataclasses.fields(Config)}
    unknown = set(data) - names
    if unknown:
        raise InputError(_unknown(unknown, names), where)
    updates = {}
    for name, value in data.items():
        current = getattr(config, name)
        if dataclasses.is_dataclass(current) and isinstance(value, dict):
            _check_keys(value, where, f"{name}.")
            sub_hints = typing.get_type_hints(type(current))
            sub_names = {f.name for f in dataclasses.fields(current)}
            bad = set(value) - sub_names
            if bad:
                raise InputError(_unknown(bad, sub_names, f"{name}."), where)
            updates[name] = dataclasses.replace(
                current, **{k: _coerce(v, sub_hints[k], f"{name}.{k}") for k, v in value.items()}
            )
        else:
            updates[name] = _coerce(value, hints[name], name)
    return dataclasses.replace(config, **updates)


def _yaml_loader():
    """A safe YAML loader that refuses aliases and caps the number of nodes."""
    import yaml

    class Loader(yaml.SafeLoader):
        nodes = 0

        def compose_node(self, parent, index):
            if self.check_event(yaml.AliasEvent):
                mark = self.peek_event().start_mark
                raise InputError(f"YAML aliases (*name) are not allowed (line {mark.line + 1})")
            self.nodes += 1
            if self.nodes > MAX_YAML_NODES:
                raise InputError(f"more than {MAX_YAML_NODES} YAML nodes")
            return super().compose_node(parent, index)

    return Loader


def _read_file(path: str) -> dict:
    try:
        size = os.path.getsize(path)
        if size > MAX_CONFIG_BYTES:
            raise InputError(f"configuration file is too large ({size} bytes; at most {MAX_CONFIG_BYTES})", path)
        if path.lower().endswith((".yaml", ".yml")):
            with open(path, encoding="utf-8") as fh:
                text = fh.read()
            loader = _yaml_loader()(text)
            try:
                data = loader.get_single_data()
            finally:
                loader.dispose()
            data = {} if data is None else data
        elif path.lower().endswith(".toml"):
            with open(path, "rb") as fh:
                data = tomllib.load(fh)
        else:
            raise InputError("configuration files must be .toml, .yaml or .yml", path)
    except InputError as exc:
        if exc.path is None:
            raise InputError(str(exc), path) from None
        raise
    except RecursionError:
        raise InputError("cannot parse configuration (nested too deeply)", path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read configuration ({_one_line(exc)})", path) from None
    except Exception as exc:  # noqa: BLE001 -- parse errors of either library
        if "yaml" in type(exc).__module__ and not isinstance(exc, (ValueError, TypeError)):
            text = getattr(exc, "problem", None) or _one_line(exc)
            mark = getattr(exc, "problem_mark", None)
            where = f" at line {mark.line + 1}" if mark is not None else ""
            raise InputError(f"cannot parse configuration ({_cut(str(text))}{where})", path) from None
        raise InputError(f"cannot parse configuration ({_one_line(exc)})", path) from None
    if not isinstance(data, dict):
        raise InputError(f"configuration must be a mapping of settings, got {type(data).__name__}", path)
    return data


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return _cut(text.splitlines()[0] if text else type(exc).__name__)


def _cut(text: str, limit: int = 2 * QUOTE_LIMIT) -> str:
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 1] + "…"


def load_config(path: str | os.PathLike | None = None, preset_name: str | None = None) -> Config:
    """Preset (``preset_name``, else the file's ``preset`` key, else ``fast``) updated by a TOML/YAML file.

    Raises:
        InputError: one line naming the file: unreadable, too large, not a mapping with string
            keys, YAML aliases, unknown settings, or a value out of range (:func:`validate_config`).
    """
    data: dict = {}
    if path is not None:
        path = os.fspath(path)
        if not os.path.exists(path):
            raise InputError("no such file", path)
        if not os.path.isfile(path):
            raise InputError("not a file", path)
        data = _read_file(path)
        _check_keys(data, path)
    name = preset_name or data.get("preset") or "fast"
    if not isinstance(name, str):
        raise InputError(f"preset must be a word, got {quote(name)}", path)
    config = preset(name)
    data = {k: v for k, v in data.items() if k != "preset"}
    try:
        return validate_config(_merge(config, data, path))
    except InputError as exc:
        if path and not str(exc).startswith(str(path)):
            raise InputError(str(exc), path) from None
        raise
    except (OverflowError, RecursionError, TypeError, ValueError) as exc:  # a value no setting can hold
        raise InputError(f"bad setting ({_one_line(exc)})", path) from None


def apply_overrides(config: Config, overrides: list[str]) -> Config:
    """Apply ``section.key=value`` strings (e.g. ``flow.width=96``, ``seed=3``)."""
    for item in overrides:
        if "=" not in item:
            raise InputError(f"override {quote(item)} must look like key=value (e.g. flow.width=96)")
        key, value = item.split("=", 1)
        parts = key.strip().split(".")
        if not all(p.isidentifier() for p in parts):
            raise InputError(f"override {quote(item)}: {quote(key.strip())} is not a setting name")
        parsed: typing.Any = value.strip()
        if parsed.startswith("[") and parsed.endswith("]"):
            parsed = [p.strip() for p in parsed[1:-1].split(",") if p.strip()]
        if parsed == "none" or parsed == "None":
            parsed = None
        nested: typing.Any = parsed
        for p in reversed(parts[1:]):
            nested = {p: nested}
        try:
            config = _merge(config, {parts[0]: nested}, None)
        except (OverflowError, TypeError, ValueError) as exc:
            if isinstance(exc, InputError):
                raise
            raise InputError(f"override {quote(item)}: {_one_line(exc)}") from None
    return validate_config(config)


# (setting, lowest, highest) of the integer settings; None: unbounded on that side
_INT_RANGES = {
    "seed": (0, SEED_LIMIT - 1),
    "flow.width": (1, 1 << 16),
    "flow.depth": (1, 1024),
    "flow.n_times": (2, 100_000),
    "flow.gso_width": (1, 1 << 16),
    "flow.gso_depth": (0, 1024),
    "sampling.bone_samples": (5, 10**7),
    "sampling.tissue_samples": (0, 10**8),
    "sampling.surface_edges": (0, 10**9),
    "tissue.split_passes": (0, 100),
    "compress": (10, 10**9),
    "working_vertices": (100, 10**9),
    "frames": (2, 1_000_000),
}
# messages kept word for word from earlier versions (users and tests match them)
_INT_MESSAGES = {
    "flow.width": "flow.width must be at least 1",
    "flow.depth": "flow.depth must be at least 1",
    "flow.n_times": "flow.n_times must be at least 2",
    "sampling.bone_samples": "sampling.bone_samples must be at least 5",
    "sampling.tissue_samples": "sampling.tissue_samples must be non-negative",
    "sampling.surface_edges": "sampling.surface_edges must be non-negative (0 means all edges)",
    "compress": "compress must be at least 10 (or none)",
    "working_vertices": "working_vertices must be at least 100 (or none: train on the full-resolution source)",
    "frames": "frames must be at least 2",
}


def _walk(obj, prefix: str = ""):
    """(dotted name, value) of every leaf setting of a configuration (phases as ``phases[i].name``)."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        name = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(value):
            yield from _walk(value, f"{name}.")
        elif f.name == "phases" and isinstance(value, tuple):
            for i, p in enumerate(value):
                if dataclasses.is_dataclass(p):
                    yield from _walk(p, f"{name}[{i}].")
                else:
                    yield f"{name}[{i}]", p
        else:
            yield name, value


def _check_types(config: Config) -> None:
    """Every leaf has its declared type; every number is finite (a Config built in Python is checked too)."""
    for name, value in _walk(config):
        if isinstance(value, tuple):
            items = list(enumerate(value))
        else:
            items = [(None, value)]
        for i, v in items:
            where = name if i is None else f"{name}[{i}]"
            if isinstance(v, float) and not math.isfinite(v):
                raise InputError(f"{where} must be finite, got {quote(v)}")
            if isinstance(v, (list, dict, set)):
                raise InputError(f"{where}: expected a single value, got {quote(v)}")
    for name, (lo, hi) in _INT_RANGES.items():
        value = config
        for part in name.split("."):
            value = getattr(value, part)
        if value is None and name in ("compress", "working_vertices"):
            continue
        if not (isinstance(value, int) and not isinstance(value, bool)):
            raise InputError(f"{name} must be an integer, got {quote(value)}")
        if value < lo:
            raise InputError(_INT_MESSAGES.get(name, f"{name} must be at least {lo}") + f" (got {value})")
        if hi is not None and value > hi:
            raise InputError(f"{name} must be at most {hi} (got {quote(value)})")
    if config.seed >= SEED_LIMIT or config.seed < 0:  # pragma: no cover - covered by _INT_RANGES
        raise InputError("seed must be in [0, 2**32)")


def _finite(x) -> bool:
    return _is_number(x) and math.isfinite(x)


def validate_config(config: Config) -> Config:
    """Check types, ranges and choices; raise :class:`InputError` with the setting's name.

    Every number must be finite; integers integral and in range (``seed`` in [0, 2**32));
    ``sampling.surface_edges`` ≥ 0, where 0 means all edges.
    """
    if not isinstance(config, Config):
        raise InputError(f"expected a Config, got {type(config).__name__}")
    _check_types(config)
    flow, sampling, cons, weights, tissue = (
        config.flow,
        config.sampling,
        config.constraints,
        config.weights,
        config.tissue,
    )
    checks = [
        (_finite(flow.skinning_width) and flow.skinning_width > 0, "flow.skinning_width must be positive"),
        (
            flow.skinning_weights in ("auto", "current", "start"),
            "flow.skinning_weights must be 'auto', 'current' or 'start'",
        ),
        (_finite(flow.pose_lr_scale) and flow.pose_lr_scale >= 0, "flow.pose_lr_scale must be non-negative"),
        (
            not (flow.skinning and flow.div_free),
            "flow.div_free needs flow.skinning=false (blended bone velocities are not divergence-free)",
        ),
        (_finite(sampling.bone_radius) and sampling.bone_radius > 0, "sampling.bone_radius must be positive"),
        (_finite(sampling.tissue_delta) and sampling.tissue_delta > 0, "sampling.tissue_delta must be positive"),
        (cons.mode in ("mdmm", "soft"), "constraints.mode must be 'mdmm' or 'soft'"),
        (_finite(cons.eps) and cons.eps > 0, "constraints.eps must be positive"),
        (_finite(cons.margin) and 0 < cons.margin <= 1, "constraints.margin must be in (0, 1]"),
        (_finite(cons.damping) and cons.damping >= 0, "constraints.damping must be non-negative"),
        (_finite(cons.multiplier_lr) and cons.multiplier_lr >= 0, "constraints.multiplier_lr must be non-negative"),
        (_finite(cons.weight) and cons.weight >= 0, "constraints.weight must be non-negative"),
        (_finite(cons.soft_weight) and cons.soft_weight >= 0, "constraints.soft_weight must be non-negative"),
        (
            _finite(cons.trajectory_weight) and cons.trajectory_weight >= 0,
            "constraints.trajectory_weight must be non-negative",
        ),
        (_finite(weights.surface) and weights.surface >= 0, "weights.surface must be non-negative"),
        (_finite(weights.tissue) and weights.tissue >= 0, "weights.tissue must be non-negative"),
        (
            _finite(tissue.edge_length_fac) and 0 < tissue.edge_length_fac <= 1,
            "tissue.edge_length_fac must be in (0, 1]",
        ),
        (_finite(tissue.epsilon) and tissue.epsilon > 0, "tissue.epsilon must be positive"),
        (
            _finite(config.repair.weld_tolerance) and 0 <= config.repair.weld_tolerance <= MAX_WELD_TOLERANCE,
            f"repair.weld_tolerance must be in [0, {MAX_WELD_TOLERANCE:g}] (a fraction of the mesh's size)",
        ),
        (
            _finite(config.repair.min_component) and 0 <= config.repair.min_component < 1,
            "repair.min_component must be in [0, 1) (a share of the mesh's area)",
        ),
        (config.optimizer in ("adabelief", "vectoradam"), "optimizer must be 'adabelief' or 'vectoradam'"),
        (_finite(config.clip_norm) and config.clip_norm > 0, "clip_norm must be positive"),
        (_finite(config.weight_decay) and config.weight_decay >= 0, "weight_decay must be non-negative"),
        (config.interp in ("sclerp", "slerp"), "interp must be 'sclerp' or 'slerp'"),
        (
            _finite(config.divergence_guard) and (config.divergence_guard == 0 or config.divergence_guard > 1),
            "divergence_guard must be 0 (off) or above 1",
        ),
        (len(config.phases) >= 1, "at least one phase is needed"),
        (config.placement in ("auto", "none"), "placement must be 'auto' or 'none'"),
        (isinstance(config.pose_search, bool), "pose_search must be true or false"),
        (isinstance(config.compile_ahead, bool), "compile_ahead must be true or false"),
        (isinstance(config.setup_cache, bool), "setup_cache must be true or false"),
    ]
    for ok, message in checks:
        if not ok:
            raise InputError(message)
    _check_jit_cache(config.jit_cache)
    for i, p in enumerate(config.phases):
        if not isinstance(p, PhaseConfig):
            raise InputError(f"phases[{i}] must be a phase table, got {quote(p)}")
        if p.metric not in METRICS:
            raise InputError(f"phases[{i}].metric must be one of {', '.join(METRICS)} (got {quote(p.metric)})")
        for key in ("steps", "warmup"):
            v = getattr(p, key)
            if not (isinstance(v, int) and not isinstance(v, bool)) or not 0 <= v <= 10**8:
                raise InputError(f"phases[{i}].{key} must be an integer in [0, 10**8] (got {quote(v)})")
        sigmas = p.sigmas if isinstance(p.sigmas, tuple) else ()
        if (
            not sigmas
            or not all(_finite(s) and s > 0 for s in sigmas)
            or not (_finite(p.sigma_normal) and p.sigma_normal > 0)
        ):
            raise InputError(f"phases[{i}]: steps must be ≥ 0 and sigmas positive")
        if (
            not (_finite(p.lr) and p.lr >= 0)
            or (p.lr_end is not None and not (_finite(p.lr_end) and p.lr_end >= 0))
            or p.warmup < 0
        ):
            raise InputError(f"phases[{i}]: learning rates and warm-up must be finite and non-negative")
        if not (_finite(p.constraint_weight) and p.constraint_weight >= 0):
            raise InputError(f"phases[{i}].constraint_weight must be non-negative")
        if not isinstance(p.trajectory, bool):
            raise InputError(f"phases[{i}].trajectory must be true or false")
    if config.total_steps < 1:
        raise InputError("the phases have no steps")
    return config


def _check_jit_cache(value) -> None:
    if not isinstance(value, str) or not value.strip() or "\x00" in value or len(value) > 4096:
        raise InputError(f"jit_cache must be auto, none or a folder (got {quote(value)})")
    if value.lower() in ("auto", "none", "off", "0", "false", "no"):
        return
    folder = os.path.realpath(os.path.expanduser(value))
    probe = folder
    while not os.path.exists(probe):
        parent = os.path.dirname(probe)
        if parent == probe:
            break
        probe = parent
    if os.path.exists(probe) and not os.path.isdir(probe):
        raise InputError(f"jit_cache: {quote(value)} is not a folder ({quote(probe)} is a file)")


def with_metric(config: Config, metric: str) -> Config:
    """Ablation switch ``--metric``: 'varifold', 'normal-cycles' or 'varifold+normal-cycles' (the default)."""
    if metric == "varifold+normal-cycles":
        return config
    if metric not in METRICS:
        raise InputError(f"--metric must be varifold, normal-cycles or varifold+normal-cycles (got {quote(metric)})")
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
