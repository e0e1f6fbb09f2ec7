"""glTF animations: clips, channels and samplers, evaluated at a time.

Reads ``translation`` / ``rotation`` / ``scale`` channels (``weights`` channels, i.e. morph
targets, are ignored) with ``LINEAR`` (slerp for rotations, :func:`ncflow.geometry.rigid.quat_slerp`), ``STEP`` and
``CUBICSPLINE`` samplers (:func:`interpolate_keyframes`). Quaternions are in glTF's order
``(x, y, z, w)``.

**Animation time** is in seconds on the file's own timeline (the keyframe times as stored; clips
conventionally start at 0, and then this is "seconds into the clip"). It is clamped to the clip's
range ``[start, end]`` (the smallest and largest keyframe time over the clip's channels); channels
shorter than the clip hold their end values. :func:`gltf_animations` lists the clips of a file
(index, name, start, end, duration, channel count).
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path

import numpy as np
from jaxtyping import Float

from ncflow.errors import InputError
from ncflow.geometry.rigid import quat_slerp
from ncflow.io.files import short_repr
from ncflow.io.gltf.document import DocumentReader, get_field, load_document, malformed

_INTERPOLATIONS = ("LINEAR", "STEP", "CUBICSPLINE")


_PATHS = ("translation", "rotation", "scale")


def interpolate_keyframes(
    times: Float[np.ndarray, " K"],
    values: Float[np.ndarray, "K C"] | Float[np.ndarray, "K 3 C"],
    t: float,
    interpolation: str = "LINEAR",
    rotation: bool = False,
) -> Float[np.ndarray, " C"]:
    """Value of one animation sampler at time ``t`` (clamped to the keyframe range).

    Args:
        times: (K,) increasing keyframe times.
        values: (K, C) keyframe values for LINEAR / STEP; (K, 3, C) for CUBICSPLINE, each key
            holding (in-tangent, value, out-tangent) as glTF stores them.
        t: the time.
        interpolation: ``"LINEAR"``, ``"STEP"`` or ``"CUBICSPLINE"``.
        rotation: the values are quaternions ``(x, y, z, w)``: LINEAR uses slerp and the
            CUBICSPLINE result is normalised.

    Returns:
        (C,) the interpolated value.
    """
    times = np.asarray(times, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    cubic = interpolation == "CUBICSPLINE"
    key = (lambda k: values[k, 1]) if cubic else (lambda k: values[k])
    n = times.shape[0]
    if n == 1 or t <= times[0]:
        out = key(0)
    elif t >= times[-1]:
        out = key(n - 1)
    else:
        k = int(np.searchsorted(times, t, side="right")) - 1
        td = times[k + 1] - times[k]
        u = (t - times[k]) / td if td > 0 else 1.0
        if interpolation == "STEP":
            out = key(k)
        elif interpolation == "LINEAR":
            if rotation:
                out = quat_slerp(values[k], values[k + 1], u, scalar_first=False)
            else:
                out = (1.0 - u) * values[k] + u * values[k + 1]
        elif cubic:
            u2, u3 = u * u, u * u * u
            out = (
                (2 * u3 - 3 * u2 + 1) * values[k, 1]
                + td * (u3 - 2 * u2 + u) * values[k, 2]
                + (-2 * u3 + 3 * u2) * values[k + 1, 1]
                + td * (u3 - u2) * values[k + 1, 0]
            )
        else:
            raise ValueError(f"unknown interpolation {interpolation!r}")
    out = np.array(out, dtype=np.float64)
    if rotation:
        out = out / np.linalg.norm(out)
    return out


@dataclasses.dataclass(frozen=True)
class Channel:
    """One animated transform channel of a clip, with its sampler's keyframes."""

    node: int
    path: str  # translation / rotation / scale
    interpolation: str
    times: np.ndarray  # (K,)
    values: np.ndarray  # (K, C) or (K, 3, C)


@dataclasses.dataclass(frozen=True)
class AnimationInfo:
    """One animation clip.

    Attributes:
        index: position in the file's animation list.
        name: the clip's name ("" when the file gives none).
        start: first keyframe time (seconds, file timeline).
        end: last keyframe time.
        n_channels: number of transform channels (translation / rotation / scale).
    """

    index: int
    name: str
    start: float
    end: float
    n_channels: int

    @property
    def duration(self) -> float:
        """``end - start`` in seconds."""
        return self.end - self.start


def check_time(time, path) -> float:
    """The animation time as a finite float; InputError (naming ``path``) otherwise."""
    try:
        t = float(time)
    except (TypeError, ValueError):
        raise InputError(f"animation time must be a number (got {time!r})", path) from None
    if not math.isfinite(t):
        raise InputError(f"animation time must be finite (got {t})", path)
    return t


def read_animations(doc, reader: DocumentReader, n_nodes: int) -> tuple[list[AnimationInfo], list[list[Channel]]]:
    """Summaries and validated channels of every clip of a document (morph-target channels skipped)."""
    infos, all_channels = [], []
    for a, anim in enumerate(doc.animations or []):
        samplers = get_field(anim, "samplers") or []
        channels = []
        for c, channel in enumerate(get_field(anim, "channels") or []):
            target = get_field(channel, "target")
            path = get_field(target, "path")
            node = get_field(target, "node")
            if path not in _PATHS or node is None:
                continue  # morph-target weights, or a channel of an extension (KHR_animation_pointer)
            node = int(node)
            if not 0 <= node < n_nodes:
                reader.fail(f"animation {a} channel {c} targets node {node}, which does not exist")
            s = get_field(channel, "sampler")
            if s is None or not 0 <= int(s) < len(samplers):
                reader.fail(f"animation {a} channel {c} uses sampler {s}, which does not exist")
            sampler = samplers[int(s)]
            interpolation = get_field(sampler, "interpolation") or "LINEAR"
            if interpolation not in _INTERPOLATIONS:
                reader.fail(f"animation {a} sampler {s}: unknown interpolation {short_repr(interpolation, 40)}")
            what = f"animation {a} sampler {s}"
            times = reader.accessor(get_field(sampler, "input"), what + " input").reshape(-1).astype(np.float64)
            values = reader.accessor(get_field(sampler, "output"), what + " output").astype(np.float64)
            width = 4 if path == "rotation" else 3
            if values.ndim != 2 or values.shape[1] != width:
                reader.fail(f"{what}: {path} output must have {width} components, got shape {values.shape}")
            if times.size == 0:
                reader.fail(f"{what} has no keyframes")
            if not np.all(np.isfinite(times)) or np.any(np.diff(times) < 0):
                reader.fail(f"{what}: keyframe times are not finite and increasing")
            if not np.all(np.isfinite(values)):
                reader.fail(f"{what}: non-finite keyframe values")
            per_key = 3 if interpolation == "CUBICSPLINE" else 1
            if values.shape[0] != per_key * times.size:
                reader.fail(
                    f"{what}: {values.shape[0]} output values for {times.size} keyframes "
                    f"({interpolation} needs {per_key} per keyframe)"
                )
            if per_key == 3:
                values = values.reshape(times.size, 3, width)
            if path == "rotation" and interpolation != "CUBICSPLINE":
                if np.any(np.linalg.norm(values, axis=-1) < 1e-12):
                    reader.fail(f"{what}: zero rotation quaternion")
            channels.append(Channel(node, path, interpolation, times, values))
        if channels:
            start = float(min(ch.times[0] for ch in channels))
            end = float(max(ch.times[-1] for ch in channels))
        else:
            start = end = 0.0
        infos.append(AnimationInfo(a, get_field(anim, "name") or "", start, end, len(channels)))
        all_channels.append(channels)
    return infos, all_channels


def gltf_animations(path: str | os.PathLike) -> list[AnimationInfo]:
    """The animation clips of a glTF file (index, name, start, end, duration, channel count)."""
    path = Path(path)
    doc = load_document(path)
    reader = DocumentReader(doc, path)
    with malformed(path, "glTF animations"):
        infos, _ = read_animations(doc, reader, len(doc.nodes or []))
    return infos
