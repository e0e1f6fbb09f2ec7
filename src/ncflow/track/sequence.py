"""``ncflow track``: one source with its skeleton registered to every frame of a sequence.

:func:`track_sequence` matches the first frame as ``ncflow match`` does (placement, pose search, the
whole schedule). Every later frame starts from the previous good frame — its trained networks, pose
(every joint but the root turned on at its speed when that frame was warm-started from the one before:
:func:`~ncflow.track.warm.predicted_state`) and multipliers, and its placement followed onto the new frame
(:mod:`ncflow.track.warm`) — and trains
``warm_steps`` steps of the last phase; its map is still the map from the **source** to that frame, so
nothing accumulates. When the warm frame's final data term, or its fit (the mean distance from the
frame's vertices to the registered source, once above :data:`ncflow.track.warm.LOST_FIT` of the source's size), is more
than ``lost_ratio`` × the median of the last few good frames' (:func:`reference`), the warm start is
called lost and the frame is matched again from scratch (placement and pose search); likewise when the warm
frame leaves a bone beyond its tolerance ε that the previous good frame held (a warm start that lost the
bones). Of the two the one whose bones hold is kept when only one does, else the lower final data term
(``fell_back`` and ``fell_back_reason``, ``lost`` or ``bones``, in its record).

Each frame's outputs are written, atomically, as soon as it is done: ``maps/STEM.npz``
(``face``, ``bary``: the source point of every frame vertex, as ``map_tgt_to_src.npz``),
``registered/STEM.ply`` (the source's connectivity on the frame, user coordinates),
``records/STEM.json`` (seconds, data term, fit, largest bone violation, warm / fell back, placement,
joints) and ``state/STEM.eqx`` (the trained state, for a resumed run). A frame that fails (a broken
file, a diverged training) is recorded with its one-line error and the next frame starts from the last
good one. At the end, from the good frames: ``skeleton_frames.json``, ``animation.glb`` and
``animation.bvh`` (:mod:`ncflow.track.animation`) and ``metrics.json``. ``track.json`` records the
inputs (SHA-256) and the settings: a run with the same ones resumes — every frame whose record
matches (same file, same previous frame) is read back, not computed again.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ncflow import __version__
from ncflow.config import Config, preset, result_config, validate_config
from ncflow.errors import InputError, NcflowError
from ncflow.geometry.mesh import Mesh
from ncflow.geometry.normalize import fit_normalization
from ncflow.io.atomic import atomic_path, atomic_write_text, check_output_dir
from ncflow.io.files import file_sha256, read_json_object
from ncflow.io.meshes import load_mesh, save_mesh
from ncflow.io.points import load_target
from ncflow.matcher.inputs import intake, load_source
from ncflow.matcher.placement import Placement
from ncflow.matcher.prepare import suggested_skeleton
from ncflow.matcher.steps import Matcher, WarmStart
from ncflow.matcher.train import TrainState
from ncflow.skeleton import Skeleton, save_skeleton
from ncflow.track.frames import frame_files
from ncflow.track.outputs import write_sequence_outputs
from ncflow.track.warm import (
    WARM_LR,
    better_match,
    bones_held,
    final_data,
    fixed_weights,
    follow_placement,
    load_state,
    lost,
    predicted_state,
    reference,
    save_state,
)

__all__ = ["DEFAULT_FPS", "LOST_RATIO", "WARM_STEPS", "TrackReport", "track_sequence"]

WARM_STEPS = 50
"""Training steps of a warm frame (the first frame trains the whole schedule)."""
LOST_RATIO = 3.0
"""A warm frame whose final data term or fit exceeds this × the recent frames' (:func:`reference`) is matched
again from scratch."""
DEFAULT_FPS = 24.0
"""Frames per second of the animation."""
MANIFEST = "track.json"
FORMAT = "ncflow-track/1"
OWN_FILES = (
    "track.json",
    "metrics.json",
    "skeleton_frames.json",
    "animation.glb",
    "animation.bvh",
    "source.ply",
    "target.ply",
    "skeleton_source.tgf",
)
OWN_FOLDERS = ("maps", "registered", "records", "state")


@dataclasses.dataclass(frozen=True)
class TrackReport:
    """What :func:`track_sequence` did.

    Attributes:
        out_dir: the folder written.
        n_frames, n_ok, n_failed, n_fell_back, n_resumed: frame counts.
        seconds: wall time of this run.
        metrics: the ``metrics.json`` written.
    """

    out_dir: Path
    n_frames: int
    n_ok: int
    n_failed: int
    n_fell_back: int
    n_resumed: int
    seconds: float
    metrics: dict


@dataclasses.dataclass
class _Last:
    """The last good frame: what the next one starts from (``before``: the trained state of the good frame
    before it when the two are one warm run, for :func:`~ncflow.track.warm.predicted_state`).
    """

    start: WarmStart | None
    placed_target: np.ndarray | None
    reference: np.ndarray | None
    stem: str | None
    before: TrainState | None = None


def _check_options(warm_steps: int, lost_ratio: float, fps: float) -> None:
    if not (isinstance(warm_steps, int) and 1 <= warm_steps <= 100_000):
        raise InputError(f"warm steps must be an integer from 1 to 100000, got {warm_steps!r}")
    if not (math.isfinite(lost_ratio) and lost_ratio > 1.0):
        raise InputError(f"the lost ratio must be a number above 1, got {lost_ratio!r}")
    if not (math.isfinite(fps) and 0 < fps <= 1000):
        raise InputError(f"frames per second must be in (0, 1000], got {fps!r}")


def _manifest(source, skeleton, config: Config, options: dict) -> dict:
    return {
        "format": FORMAT,
        "ncflow_version": __version__,
        "source_sha256": file_sha256(source) if isinstance(source, (str, os.PathLike)) else None,
        "skeleton_sha256": file_sha256(skeleton) if isinstance(skeleton, (str, os.PathLike)) else None,
        "config": result_config(config),
        "options": options,
    }


def _open_folder(out_dir, manifest: dict, overwrite: bool) -> tuple[Path, bool]:
    """The output folder, checked; whether an earlier run with the same manifest may be resumed there."""
    out = check_output_dir(out_dir, overwrite=True)
    old_path = out / MANIFEST
    resumable = False
    if old_path.is_file():
        try:
            old = read_json_object(old_path)
        except InputError:
            old = {}
        resumable = old == manifest and manifest["source_sha256"] is not None and not overwrite
        if old != manifest and not overwrite:
            raise InputError(
                "holds a track of other inputs or settings (track.json); use --overwrite to start again", out_dir
            )
    elif out.is_dir() and any(os.scandir(out)) and not overwrite:
        raise InputError("exists and is not empty (use --overwrite to replace ncflow's files in it)", out_dir)
    if not resumable and old_path.is_file():  # a track ncflow wrote: its own files go, nothing else
        _remove_own(out)
    for name in OWN_FOLDERS:
        (out / name).mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / MANIFEST, json.dumps(manifest, indent=1))
    return out, resumable


def _remove_own(out: Path) -> None:
    """Remove the files an earlier track wrote in ``out`` (only names of its own layout)."""
    for name in OWN_FILES:
        (out / name).unlink(missing_ok=True)
    suffixes = {"maps": ".npz", "registered": ".ply", "records": ".json", "state": ".eqx"}
    for folder, suffix in suffixes.items():
        d = out / folder
        if d.is_dir() and not d.is_symlink():
            for entry in os.scandir(d):
                if entry.is_file(follow_symlinks=False) and entry.name.endswith(suffix):
                    os.unlink(entry.path)


def _message(quiet: bool, stream):
    def message(text: str) -> None:
        if not quiet:
            print(text, file=stream or sys.stderr, flush=True)

    return message


def _frame_record(stem, path, sha, previous, result, info, seconds) -> dict:
    m = result.metrics
    return {
        "stem": stem,
        "file": str(path),
        "sha256": sha,
        "previous": previous,
        "status": "ok",
        "warm": info["warm"],
        "fell_back": info["fell_back"],
        "fell_back_reason": info.get("fell_back_reason"),
        "kept": info["kept"],
        "seconds": seconds,
        "data": final_data(result),
        "data_ratio": info.get("data_ratio"),
        "fit_ratio": info.get("fit_ratio"),
        "fit": m["correspondence"]["mean_distance_target_to_flowed_source"],
        "max_violation_ratio": m["constraints"]["max_violation_ratio"],
        "all_bones_within_tolerance": m["constraints"]["all_satisfied"],
        "n_vertices": int(result.target.n_vertices),
        "placement": {
            "rotation": result.placement.rotation.tolist(),
            "translation": result.placement.translation.tolist(),
        },
        "weight_mode": m["skinning_weights"]["mode"],
        "joints": np.asarray(result.skeleton_target.positions).tolist(),
        "warnings": m["warnings"],
        "timings": m["timings"],
    }


def _write_frame(out: Path, stem: str, result, record: dict) -> None:
    with atomic_path(out / "maps" / f"{stem}.npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, face=result.maps["map_face"].astype(np.int64), bary=result.maps["map_bary"].astype(np.float64))
    with atomic_path(out / "registered" / f"{stem}.ply") as tmp:
        save_mesh(tmp, result.deformed_source, result.source.faces)
    with atomic_path(out / "state" / f"{stem}.eqx") as tmp:
        save_state(tmp, result.state)
    atomic_write_text(out / "records" / f"{stem}.json", json.dumps(record, indent=1))


@dataclasses.dataclass
class _Run:
    """The configuration of a run (``full``: with the bone-weight mode of the first frame once it is known),
    the normalisation every match of this source uses, and the compiled programs of the first match: every
    later frame, warm (the last phase alone, :class:`~ncflow.matcher.steps.WarmStart`'s ``steps``) or
    searched again, runs on them — they depend only on the source, the skeleton and the configuration.
    """

    config: Config
    warm_steps: int
    normalization: object
    full: Config | None = None
    mode: str | None = None
    programs: object = None

    def fix_mode(self, mode: str) -> None:
        if self.mode is None:
            self.mode = mode
            self.full = fixed_weights(self.config, mode)

    def matcher(self, src, frame, skel, quiet, stream, start=None) -> Matcher:
        """A :class:`~ncflow.matcher.steps.Matcher` of ``frame`` on the run's programs (built by the first)."""
        matcher = Matcher(
            src, frame, skel, self.full or self.config, quiet=quiet, stream=stream, start=start, programs=self.programs
        )
        self.programs = matcher.programs
        return matcher


def _match_frame(src, frame: Mesh, skel, run: _Run, last: _Last, lost_ratio, ref, held, quiet, stream):
    """(result, info) of one frame: a full match without a previous frame, else a warm one and, when it
    is lost or leaves a bone beyond ε that the previous frame (``held``: all its bones within ε) held, a full
    match too (:func:`better_match` kept).
    """
    if last.start is None:
        result = run.matcher(src, frame, skel, quiet, stream).run()
        return result, {"warm": False, "fell_back": False, "kept": "search"}
    placement = follow_placement(
        last.start.placement, last.placed_target, last.reference, run.normalization.apply(frame.vertices)
    )
    start = WarmStart(predicted_state(last.start.state, last.before), placement, run.warm_steps, WARM_LR)
    warm = run.matcher(src, frame, skel, quiet, stream, start).run()
    test = lost(warm, ref, lost_ratio, float(np.linalg.norm(np.ptp(src.vertices, axis=0))))
    torn = held and not bones_held(warm)
    info = {
        "warm": True,
        "fell_back": False,
        "kept": "warm",
        "data_ratio": test["data_ratio"],
        "fit_ratio": test["fit_ratio"],
    }
    if not (test["lost"] or torn):
        return warm, info
    if test["lost"]:
        why = (
            f"the warm start is lost (data term {test['data_ratio']:.3g}x, fit {test['fit_ratio']:.3g}x the recent "
            "frames')"
        )
    else:
        ratio = warm.metrics["constraints"]["max_violation_ratio"]
        why = f"the warm start left a bone beyond its tolerance ({ratio:.3g} eps) that the previous frame held"
    _message(quiet, stream)(f"{why}: searching again")
    full = run.matcher(src, frame, skel, quiet, stream).run()
    better = better_match(warm, full)
    reason = "lost" if test["lost"] else "bones"
    return better, dict(info, fell_back=True, fell_back_reason=reason, kept="search" if better is full else "warm")


def _hand_on(state, placement: Placement, norm, frame, registered, stem: str, last: _Last, kept: str) -> _Last:
    """What the next frame starts from: the frame's trained ``state`` and ``placement``, the frame's vertices
    and its registered source (user coordinates, as ``registered/STEM.ply`` holds it: float32) placed in
    training coordinates, and ``last``'s state when the frame was ``kept`` warm from it — the same for a frame
    just finished and one read back.
    """
    registered = np.asarray(registered, np.float32).astype(np.float64)
    placed = placement.apply(norm.apply(frame)), placement.apply(norm.apply(registered))
    before = last.start.state if kept == "warm" and last.start is not None else None
    return _Last(WarmStart(state, placement), *placed, stem, before)


def _resumed(out: Path, path: Path, sha: str, last: _Last, src: Mesh, skel: Skeleton, run: _Run):
    """(record, hand-on) of a good frame an earlier run finished, or None when it must be computed."""
    stem = path.stem
    try:
        rec = read_json_object(out / "records" / f"{stem}.json")
        if rec.get("sha256") != sha or rec.get("previous") != last.stem or rec.get("status") != "ok":
            return None
        mode = str(rec["weight_mode"])
        if run.mode not in (None, mode):
            return None
        run.fix_mode(mode)
        state = load_state(out / "state" / f"{stem}.eqx", skel, run.normalization, run.full, mode)
        reg = load_mesh(out / "registered" / f"{stem}.ply").vertices
        frame = load_target(path).vertices
        pl = Placement(
            np.asarray(rec["placement"]["rotation"], float), np.asarray(rec["placement"]["translation"], float)
        )
    except (NcflowError, OSError, ValueError, KeyError, TypeError, RuntimeError):
        return None
    if reg.shape != src.vertices.shape:
        return None
    return rec, _hand_on(state, pl, run.normalization, frame, reg, stem, last, str(rec.get("kept")))


SUGGEST_FRAMES = 3
"""Frames (first, middle, last) whose poses show the suggested skeleton where the source's limbs bend."""


def _inputs(source, skeleton, config, message, paths) -> tuple[Mesh, Skeleton, bool, object]:
    """The source, its skeleton (suggested when None, with up to :data:`SUGGEST_FRAMES` mesh frames as other
    poses; a frame that cannot be read or is a point cloud is left out), whether it was suggested, and the
    normalisation.
    """
    src, skel = load_source(source, skeleton)
    clean, _, _ = intake(src, "source", config)
    suggested = skel is None
    if suggested:
        others = []
        for k in sorted({0, (len(paths) - 1) // 2, len(paths) - 1})[:SUGGEST_FRAMES]:
            try:
                frame = load_target(paths[k])
                if isinstance(frame, Mesh):
                    others.append(intake(frame, "frame", config)[0])
            except NcflowError:
                continue
        bases = config.skeleton_bases if config.skeleton_bases != "choose" else "auto"  # one skeleton for all frames
        skel, _ = suggested_skeleton(clean, message, others, bases)
    return src, skel, suggested, fit_normalization(clean.vertices, clean.faces)


def _failed(out: Path, stem, path, sha, previous, exc, message) -> dict:
    rec = {"stem": stem, "file": str(path), "sha256": sha, "previous": previous, "status": "failed", "error": str(exc)}
    message(f"frame {stem} failed: {exc}")
    atomic_write_text(out / "records" / f"{stem}.json", json.dumps(rec, indent=1))
    return rec


def track_sequence(
    source,
    frames: str | os.PathLike | Sequence[str | os.PathLike],
    skeleton,
    out_dir: str | os.PathLike,
    config: Config | None = None,
    *,
    warm_steps: int = WARM_STEPS,
    lost_ratio: float = LOST_RATIO,
    fps: float = DEFAULT_FPS,
    overwrite: bool = False,
    quiet: bool = False,
    stream=None,
    on_frame: Callable[[int, dict], None] | None = None,
) -> TrackReport:
    """Register ``source`` (mesh or file) with its ``skeleton`` (file, :class:`Skeleton`, or None: one is
    suggested) to every frame of ``frames`` (a folder, a glob pattern or a list of files:
    :func:`ncflow.track.frames.frame_files`) and write the outputs into ``out_dir`` (module docstring).

    Args:
        source: the source mesh or its file.
        frames: the frames (folder, pattern or list of files).
        skeleton: the source's skeleton (file or :class:`~ncflow.skeleton.Skeleton`), or None.
        out_dir: the output folder.
        config: the matching configuration (default: the ``fast`` preset); the first frame and every
            fallback use it whole, warm frames its last phase alone, ``warm_steps`` steps at peak rate
            :data:`ncflow.track.warm.WARM_LR` (:func:`ncflow.matcher.stages.last_phase_stages`), on the
            first frame's compiled programs.
        warm_steps: training steps of a warm frame.
        lost_ratio: a warm frame whose final data term exceeds this × the recent good frames' is searched again.
        fps: frames per second of ``animation.glb`` / ``animation.bvh``.
        overwrite: start again in a folder holding another track (or other files of ncflow's layout).
        quiet: no progress display.
        stream: where the progress display goes (default stderr).
        on_frame: called after each frame with its index and record.

    Raises:
        InputError: bad inputs or options (one line naming the file), an occupied ``out_dir``; no frame
            matched at all.
    """
    t0 = time.perf_counter()
    _check_options(warm_steps, lost_ratio, fps)
    cfg = validate_config(config or preset("fast"))
    message = _message(quiet, stream)
    paths = frame_files(frames)
    src, skel, suggested, norm = _inputs(source, skeleton, cfg, message, paths)
    options = {"warm_steps": warm_steps, "lost_ratio": lost_ratio, "fps": fps}
    out, resumable = _open_folder(out_dir, _manifest(source, skeleton, cfg, options), overwrite)
    if suggested:
        with atomic_path(out / "skeleton_source.tgf") as tmp:
            save_skeleton(tmp, skel)
    run = _Run(cfg, warm_steps, norm)
    last = _Last(None, None, None, None)
    records: list[dict] = []
    n_resumed = 0
    for k, path in enumerate(paths):
        stem, sha = path.stem, file_sha256(path)
        got = _resumed(out, path, sha, last, src, skel, run) if resumable else None
        if got is not None:
            rec, last = got
            records.append(rec)
            n_resumed += 1
            message(f"frame {k + 1}/{len(paths)} {stem}: read back from an earlier run")
            continue
        resumable = False
        message(f"frame {k + 1}/{len(paths)} {stem}: " + ("matching" if last.start is None else "warm start"))
        t1 = time.perf_counter()
        try:
            frame = load_target(path)
            held = next(
                (r.get("all_bones_within_tolerance", True) for r in reversed(records) if r["status"] == "ok"), True
            )
            ref = reference(records)
            result, info = _match_frame(src, frame, skel, run, last, lost_ratio, ref, held, quiet, stream)
        except NcflowError as exc:
            records.append(_failed(out, stem, path, sha, last.stem, exc, message))
        else:
            run.fix_mode(result.metrics["skinning_weights"]["mode"])
            rec = _frame_record(stem, path, sha, last.stem, result, info, time.perf_counter() - t1)
            _write_frame(out, stem, result, rec)
            records.append(rec)
            last = _hand_on(
                result.state,
                result.placement,
                run.normalization,
                frame.vertices,
                result.deformed_source,
                stem,
                last,
                info["kept"],
            )
        if on_frame:
            on_frame(k, records[-1])
    ok = [r for r in records if r["status"] == "ok"]
    if not ok:
        raise InputError("no frame could be matched: " + records[0].get("error", "see records/"), paths[0])
    last_ok = next(p for p, r in zip(reversed(paths), reversed(records)) if r["status"] == "ok")
    seconds = time.perf_counter() - t0
    metrics = write_sequence_outputs(out, src, skel, records, cfg, options, seconds, n_resumed, load_target(last_ok))
    return TrackReport(
        out_dir=out,
        n_frames=len(records),
        n_ok=len(ok),
        n_failed=len(records) - len(ok),
        n_fell_back=sum(bool(r.get("fell_back")) for r in ok),
        n_resumed=n_resumed,
        seconds=time.perf_counter() - t0,
        metrics=metrics,
    )
