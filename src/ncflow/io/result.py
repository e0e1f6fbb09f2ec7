"""The output contract of ``ncflow match``: the result folder, written atomically and read back.

What :func:`write_result` writes into ``DIR`` (docs/architecture.md, "Outputs and evaluation"):

=========================  ==================================================================
``deformed_source.ply``    source connectivity, vertices flowed to t = 1 (user coordinates)
``p2p_src_to_tgt.txt``     one 0-based target vertex index per source vertex, one per line
``p2p_tgt_to_src.txt``     one 0-based source vertex index per target vertex, one per line
``map_tgt_to_src.npz``     arrays ``face`` (n_target,) int64 and ``bary`` (n_target, 3) float64
``frames/frame_XXXX.ply``  interpolation frames (source connectivity), t from 0 to 1
``animation.glb``          the same frames as one glTF 2.0 binary (morph-target animation)
``skeleton_target.tgf``    fitted target skeleton (libigl TGF, 1-based)
``skeleton_frames.json``   joint positions per frame, parents, names, times
``skeleton_source.tgf``    the source skeleton ncflow suggested, when none was given
``source_seen.txt``        per source vertex how much the target shows it, in [0, 1] (1: all; a scan's far side 0)
``metrics.json``           the caller's metrics dict, plus ``frame_times``
=========================  ==================================================================

The maps are computed by :mod:`ncflow.matcher.correspondence`: ``map_tgt_to_src`` is the foot point
of every target vertex on the flowed source surface as (source face, barycentric coordinates),
which names the same point of the rest source; the ``p2p`` files are vertex roundings (the corner
of the foot face with the largest barycentric weight).

Writing is **atomic**: everything is written into a hidden temporary folder next to ``DIR`` and
moved into place only when every file is complete; on any error the temporary folder is removed
and ``DIR`` is left as it was (absent, or with its previous contents). ``DIR`` is resolved first
(a symbolic link to a folder is followed; the link itself is never moved or replaced). The final
folder has the usual mode (``0o777`` minus the umask). An existing non-empty ``DIR`` is refused
unless ``overwrite=True``; then only the contract entries are replaced, one rename each inside
``DIR`` (``frames/`` as a whole, so stale frames of a longer earlier run disappear), and an error
part-way puts the earlier ones back. Every other entry of ``DIR`` (the user's own files, plots,
logs) stays where it is, untouched: ncflow never moves or deletes a file it did not write. A
contract name that ncflow would not have written (a symbolic link, a folder in place of a file,
``frames/`` holding other files than ``frame_XXXX.ply``) is refused before anything is written.
Nothing non-finite is ever written: all
arrays and the metrics (recursively) are checked first and a :class:`ResultError` names the first
offending value. :func:`read_result` loads a folder back and checks it (sizes, index ranges, the
two skeleton files together, optionally the animation), each problem one
:class:`~ncflow.errors.InputError` line. Both go through one :class:`ResultFolder`: what is written
is what is read back (:func:`ncflow.io.fallback.save_result` writes one and, when the disk fails,
keeps a copy under the system's temporary folder so that a finished match is never lost).

Over 500 lines: one file contract, with its writer and its reader kept together so that they
cannot drift apart.
"""

from __future__ import annotations

import dataclasses
import os
import re
import warnings
from pathlib import Path

import numpy as np
from jaxtyping import Float, Int

from ncflow.errors import InputError, ResultError, first_line
from ncflow.geometry.skeleton import Skeleton
from ncflow.io.arrays import (
    as_faces,
    as_frames,
    as_index,
    as_times,
    check_finite,
    check_finite_tree,
    dumps_strict,
    json_safe,
)
from ncflow.io.atomic import atomic_path, atomic_write_text, move_into_place, remove_tree, staging_dir
from ncflow.io.files import dtype_text, read_json_object, read_npz_arrays, short_repr
from ncflow.io.frames import read_skeleton_frames_json, write_frames, write_skeleton_frames_json
from ncflow.io.gltf.writer import write_animation_glb
from ncflow.io.ground_truth import read_index_file
from ncflow.io.meshes import load_mesh, save_mesh
from ncflow.io.points import is_point_cloud_file, load_points, load_target, save_target
from ncflow.io.skeletons import load_skeleton, save_skeleton
from ncflow.io.vertex_arrays import read_vertex_array

CONTRACT_FILES = (
    "deformed_source.ply",
    "p2p_src_to_tgt.txt",
    "p2p_tgt_to_src.txt",
    "map_tgt_to_src.npz",
    "frames",
    "animation.glb",
    "skeleton_target.tgf",
    "skeleton_frames.json",
    "skeleton_source.tgf",
    "source_seen.txt",
    "metrics.json",
    "target.ply",
)
_FRAME_RE = re.compile(r"^frame_(\d{4,})\.ply$")
MAP_KEYS = ("map_face", "map_bary", "p2p_tgt_to_src", "p2p_src_to_tgt")


@dataclasses.dataclass
class ResultFolder:
    """The output contract of ``ncflow match`` as arrays: what :func:`write_result` writes and
    :func:`read_result` reads back.

    Attributes:
        deformed_source: (Vs, 3) source vertices flowed to t = 1, user coordinates.
        source_faces: (Fs, 3) source triangles.
        maps: the correspondence (:func:`~ncflow.matcher.correspondence.correspondence_maps`): ``map_face``
            (Vt,), ``map_bary`` (Vt, 3), ``p2p_tgt_to_src`` (Vt,), ``p2p_src_to_tgt`` (Vs,); also
            attributes of their own names.
        frames: (K, Vs, 3) interpolation frames, frame 0 the rest source.
        frame_times: (K,) strictly increasing times from 0 to 1 (scaled to the clip length in the GLB).
        metrics: JSON-ready dict (NumPy/JAX scalars and arrays are converted when written).
        skeleton_target: the fitted target skeleton (TGF, 1-based, internal joint order), or None for
            a run without a skeleton (neither skeleton file is written then).
        skeleton_frames: (K, J, 3) joint positions per frame, in the skeleton's internal order (with
            ``skeleton_target``).
        joint_names: joint names of ``skeleton_frames.json`` (default: the skeleton's, or null).
        target_vertices, target_faces: the target mesh as given, written as ``target.ply`` so that the
            folder alone serves ``ncflow view``, ``transfer`` and ``rig`` (None: no ``target.ply``).
        animation: the path of ``animation.glb`` of a folder read back (None before it is written).
        skeleton_source: the source skeleton ncflow suggested because none was given, written as
            ``skeleton_source.tgf`` (None: a skeleton was given, nothing written).
        source_seen: (Vs,) how much the target shows each source vertex, in [0, 1]
            (:mod:`ncflow.matcher.partial`), written as ``source_seen.txt`` (None: not written).
    """

    deformed_source: Float[np.ndarray, "Vs 3"]
    source_faces: Int[np.ndarray, "Fs 3"]
    maps: dict[str, np.ndarray]
    frames: Float[np.ndarray, "K Vs 3"]
    frame_times: Float[np.ndarray, " K"]
    metrics: dict = dataclasses.field(default_factory=dict)
    skeleton_target: Skeleton | None = None
    skeleton_frames: Float[np.ndarray, "K J 3"] | None = None
    joint_names: list[str] | tuple[str, ...] | None = None
    target_vertices: Float[np.ndarray, "Vt 3"] | None = None
    target_faces: Int[np.ndarray, "Ft 3"] | None = None
    animation: Path | None = None
    skeleton_source: Skeleton | None = None
    source_seen: Float[np.ndarray, " Vs"] | None = None

    @property
    def map_face(self) -> np.ndarray:
        return self.maps["map_face"]

    @property
    def map_bary(self) -> np.ndarray:
        return self.maps["map_bary"]

    @property
    def p2p_tgt_to_src(self) -> np.ndarray:
        return self.maps["p2p_tgt_to_src"]

    @property
    def p2p_src_to_tgt(self) -> np.ndarray:
        return self.maps["p2p_src_to_tgt"]

    @property
    def n_source(self) -> int:
        return int(np.shape(self.deformed_source)[0])

    @property
    def n_target(self) -> int:
        return int(np.shape(self.maps["map_face"])[0])

    @property
    def n_frames(self) -> int:
        return int(np.shape(self.frames)[0])

    def write(self, out_dir: str | os.PathLike, *, overwrite: bool = False, clip_seconds: float = 2.0) -> Path:
        """:func:`write_result` of this folder."""
        return write_result(out_dir, self, overwrite=overwrite, clip_seconds=clip_seconds)

    def __getitem__(self, key: str):
        """The dict of :func:`read_result` before version 0.3 (``result["map_face"]``), for one release."""
        warnings.warn(
            "read_result returns a ResultFolder: use its attributes (result.map_face) instead of result['map_face']",
            DeprecationWarning,
            stacklevel=2,
        )
        if key == "skeleton_frames" and self.skeleton_frames is not None:
            return {
                "positions": self.skeleton_frames,
                "parents": self.skeleton_target.parents,
                "names": None if self.joint_names is None else list(self.joint_names),
                "times": self.frame_times,
            }
        return getattr(self, key)


def write_result(
    out_dir: str | os.PathLike, result: ResultFolder, *, overwrite: bool = False, clip_seconds: float = 2.0
) -> Path:
    """Write the ``ncflow match`` output contract of ``result`` into ``out_dir``, atomically.

    Args:
        out_dir: the result folder (created; its parent too).
        result: what to write (``frame_times`` also go to ``metrics.json`` under ``frame_times``).
        overwrite: allow an existing non-empty ``out_dir``: its contract entries are replaced
            (``frames/`` as a whole) and its other entries kept. Otherwise such a folder is refused.
        clip_seconds: length of the GLB animation clip.

    Returns:
        ``out_dir`` as a Path.

    Raises:
        ResultError: non-finite values, inconsistent shapes or index ranges, or an occupied
            ``out_dir`` without ``overwrite``; raised before anything is written. Any error while
            writing leaves ``out_dir`` as it was and no temporary files behind.
    """
    shown = Path(out_dir)
    out_dir = Path(os.path.realpath(os.path.expanduser(out_dir)))  # a symlinked folder: its target
    if shown.is_symlink() and not shown.exists():
        raise ResultError("is a broken symbolic link", shown)
    _check_target_dir(out_dir, overwrite, shown)
    checked = _checked(result)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = staging_dir(out_dir)  # os.mkdir: the umask's mode, unlike mkdtemp's 0700
    try:
        _write_files(tmp, checked, clip_seconds)
        _move_into_place(tmp, out_dir, overwrite, shown)
    except BaseException:
        remove_tree(tmp)
        raise
    return shown


def _checked(r: ResultFolder) -> ResultFolder:
    """``r`` with every array checked and converted (shapes, index ranges, finiteness) and the metrics
    made JSON-ready; :class:`ResultError` naming the first problem, before anything is written.
    """
    deformed = as_frames(np.asarray(r.deformed_source)[None], "deformed source")[0]
    nv = deformed.shape[0]
    faces = as_faces(r.source_faces, nv, "source faces")
    frames = as_frames(r.frames)
    if frames.shape[1] != nv:
        raise ResultError(f"frames have {frames.shape[1]} vertices but the deformed source has {nv}")
    times = as_times(r.frame_times, frames.shape[0])
    maps = _checked_maps(r.maps, nv, faces.shape[0])
    nt = maps["map_face"].shape[0]
    target = (None, None)
    if (r.target_vertices is None) != (r.target_faces is None):
        raise ResultError("target_vertices and target_faces must be given together")
    if r.target_vertices is not None:
        tv = as_frames(np.asarray(r.target_vertices)[None], "target vertices")[0]
        if tv.shape[0] != nt:
            raise ResultError(f"the target has {tv.shape[0]} vertices but the maps have {nt} target vertices")
        target = (tv, as_faces(r.target_faces, nt, "target faces", allow_empty=True))
    metrics = {} if r.metrics is None else r.metrics
    if not isinstance(metrics, dict):
        raise ResultError(f"metrics must be a dict, got {type(metrics).__name__}")
    check_finite_tree(metrics)
    metrics = json_safe({**metrics, "frame_times": [float(x) for x in times]})[0]
    sk_frames, names = None, r.joint_names
    if r.skeleton_target is not None or r.skeleton_frames is not None:
        if r.skeleton_target is None or r.skeleton_frames is None:
            raise ResultError("skeleton_target and skeleton_frames must be given together")
        sk_frames = as_frames(r.skeleton_frames, "skeleton frames")
        check_finite("target skeleton joints", r.skeleton_target.positions)
        if sk_frames.shape[:2] != (frames.shape[0], r.skeleton_target.n_joints):
            raise ResultError(
                f"skeleton frames must be ({frames.shape[0]}, {r.skeleton_target.n_joints}, 3) (frames, joints), "
                f"got {sk_frames.shape}"
            )
        names = r.skeleton_target.names if names is None else names
    seen = r.source_seen
    if seen is not None:
        seen = np.asarray(seen, np.float64).reshape(-1)
        check_finite("source_seen", seen)
        if seen.shape[0] != nv or np.any((seen < 0) | (seen > 1)):
            raise ResultError(f"source_seen must hold {nv} values in [0, 1]")
    return dataclasses.replace(
        r,
        deformed_source=deformed,
        source_faces=faces,
        maps=maps,
        frames=frames,
        frame_times=times,
        metrics=metrics,
        skeleton_frames=sk_frames,
        joint_names=names,
        target_vertices=target[0],
        target_faces=target[1],
        source_seen=seen,
    )


def _checked_maps(maps: dict, nv: int, n_faces: int) -> dict[str, np.ndarray]:
    for key in MAP_KEYS:
        if key not in maps:
            raise ResultError(f"maps lack {key!r} (expected the output of correspondence_maps)")
    map_face = np.asarray(maps["map_face"]).reshape(-1)
    nt = map_face.shape[0]
    map_face = as_index(map_face, nt, n_faces, "map_tgt_to_src face")
    bary = np.asarray(maps["map_bary"], dtype=np.float64)
    if bary.shape != (nt, 3):
        raise ResultError(f"map_tgt_to_src bary must be ({nt}, 3), got {bary.shape}")
    check_finite("map_tgt_to_src bary", bary)
    p2p_ts = as_index(maps["p2p_tgt_to_src"], nt, nv, "p2p_tgt_to_src")
    if nt == 0:
        raise ResultError("the correspondence maps are empty (no target vertices)")
    p2p_st = as_index(maps["p2p_src_to_tgt"], nv, nt, "p2p_src_to_tgt")
    return {"map_face": map_face, "map_bary": bary, "p2p_tgt_to_src": p2p_ts, "p2p_src_to_tgt": p2p_st}


def _write_files(tmp: Path, r: ResultFolder, clip_seconds: float) -> None:
    """Every file of the contract of a checked folder into ``tmp``."""
    save_mesh(tmp / "deformed_source.ply", r.deformed_source, r.source_faces)
    if r.target_vertices is not None:
        save_target(tmp / "target.ply", r.target_vertices, r.target_faces)
    _write_indices(tmp / "p2p_src_to_tgt.txt", r.p2p_src_to_tgt)
    _write_indices(tmp / "p2p_tgt_to_src.txt", r.p2p_tgt_to_src)
    with atomic_path(tmp / "map_tgt_to_src.npz") as part:
        np.savez(part, face=r.map_face, bary=r.map_bary)
    write_frames(tmp / "frames", r.frames, r.source_faces)
    parents = None if r.skeleton_target is None else r.skeleton_target.parents
    times = r.frame_times
    write_animation_glb(
        tmp / "animation.glb", r.frames, r.source_faces, times, r.skeleton_frames, parents, duration=clip_seconds
    )
    if r.skeleton_target is not None:
        save_skeleton(tmp / "skeleton_target.tgf", r.skeleton_target)
        write_skeleton_frames_json(tmp / "skeleton_frames.json", r.skeleton_frames, parents, r.joint_names, times)
    if r.skeleton_source is not None:
        save_skeleton(tmp / "skeleton_source.tgf", r.skeleton_source)
    if r.source_seen is not None:
        atomic_write_text(tmp / "source_seen.txt", "".join(f"{v:.4f}\n" for v in r.source_seen))
    atomic_write_text(tmp / "metrics.json", dumps_strict(r.metrics))  # finite: checked


def _write_indices(path: Path, values: np.ndarray) -> None:
    """Write one integer per line (atomically)."""
    atomic_write_text(path, "".join(f"{int(v)}\n" for v in values))


def _check_target_dir(out_dir: Path, overwrite: bool, shown: Path | None = None) -> None:
    """Refuse a file, an occupied folder without ``overwrite``, and contract names ncflow did not write."""
    shown = out_dir if shown is None else shown
    if out_dir.exists() and not out_dir.is_dir():
        raise ResultError("exists and is not a folder", shown)
    probe = out_dir.parent
    while not probe.exists() and probe.parent != probe:
        probe = probe.parent
    if not probe.is_dir():
        raise ResultError(f"is under {probe}, which is not a folder", shown)
    if not out_dir.is_dir():
        return
    if any(out_dir.iterdir()) and not overwrite:
        raise ResultError(
            "output folder exists and is not empty (pass overwrite=True / --overwrite to replace the result)", shown
        )
    check_contract_entries(out_dir, shown)


def check_contract_entries(out_dir: str | os.PathLike, shown: str | os.PathLike | None = None) -> None:
    """Refuse a folder whose contract names hold something ncflow would not have written there.

    A symbolic link, a folder where the contract has a file (or a file for ``frames/``), or
    ``frames/`` holding anything but ``frame_XXXX.ply`` files: replacing it would delete the
    user's data, so :func:`write_result` refuses it before anything is written.

    Raises:
        ResultError: one line naming the entry.
    """
    out_dir = Path(out_dir)
    for name in CONTRACT_FILES:
        entry = out_dir / name
        if entry.is_symlink():
            raise ResultError("is a symbolic link; ncflow replaces only files it wrote (remove it first)", entry)
        if not entry.exists():
            continue
        if name == "frames":
            if not entry.is_dir():
                raise ResultError("is not a folder; ncflow replaces only files it wrote (remove it first)", entry)
            for sub in entry.iterdir():
                if sub.is_symlink() or not sub.is_file() or not _FRAME_RE.match(sub.name):
                    raise ResultError(
                        "was not written by ncflow (frames/ holds only frame_XXXX.ply); move it away first", sub
                    )
        elif not entry.is_file():
            raise ResultError("is not a file; ncflow replaces only files it wrote (remove it first)", entry)


def _move_into_place(tmp: Path, out_dir: Path, overwrite: bool, shown: Path | None = None) -> None:
    """Move the finished temporary folder to ``out_dir``: only contract entries are replaced or removed.

    See the module docstring and :func:`ncflow.io.atomic.move_into_place`.
    """
    _check_target_dir(out_dir, overwrite, shown)
    move_into_place(tmp, out_dir, lambda name: name in CONTRACT_FILES)


# ----------------------------------------------------------------------------------------------
# Reading back


def _read_json(path: Path) -> dict:
    if not path.is_file():
        raise InputError("missing result file", path)
    return read_json_object(path)


def _read_ply(path: Path, cloud_ok: bool = False):
    if not path.is_file():
        raise InputError("missing result file", path)
    if cloud_ok and is_point_cloud_file(path):  # the target of a match against a point cloud
        return load_points(path)
    mesh = load_mesh(path, weld=False, validate=False)
    if not np.all(np.isfinite(mesh.vertices)):
        raise InputError("non-finite vertex coordinates", path)
    return mesh


def read_result(out_dir: str | os.PathLike, *, check_animation: bool = True) -> ResultFolder:
    """Load and validate a result folder written by :func:`write_result`.

    Args:
        out_dir: the folder.
        check_animation: also parse ``animation.glb`` and check its morph-target count (K).

    Returns:
        the :class:`ResultFolder` (``animation``: the path of the GLB; ``target_vertices`` and
        ``target_faces`` None for a result written without ``target.ply``). The two skeleton files are
        optional but must come together.

    Raises:
        InputError: one line naming the missing or bad file.
    """
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise InputError("no such result folder", out_dir)
    deformed = _read_ply(out_dir / "deformed_source.ply")
    nv, faces = deformed.n_vertices, deformed.faces
    maps = _read_maps(out_dir, nv, faces.shape[0])
    nt = maps["map_face"].shape[0]
    frames = _read_frames(out_dir / "frames", nv, faces)
    k = frames.shape[0]
    metrics_path = out_dir / "metrics.json"
    metrics = _read_json(metrics_path)
    if "frame_times" in metrics:
        times = np.asarray(metrics["frame_times"], dtype=np.float64)
        if times.shape != (k,):
            raise InputError(f"'frame_times' has {times.size} entries but there are {k} frames", metrics_path)
    else:
        times = np.linspace(0.0, 1.0, k)
    glb = out_dir / "animation.glb"
    if not glb.is_file():
        raise InputError("missing result file", glb)
    if check_animation:
        _check_glb(glb, k, nv)
    skeleton, sk_frames = _read_skeleton(out_dir, k)
    target_vertices = target_faces = None
    target_path = out_dir / "target.ply"
    if target_path.exists():
        tm = _read_ply(target_path, cloud_ok=True)
        if tm.n_vertices != nt:
            raise InputError(f"the target has {tm.n_vertices} vertices but the maps have {nt}", target_path)
        target_vertices, target_faces = tm.vertices, tm.faces
    return ResultFolder(
        deformed_source=deformed.vertices,
        source_faces=faces,
        maps=maps,
        frames=frames,
        frame_times=times,
        metrics=metrics,
        skeleton_target=skeleton,
        skeleton_frames=None if sk_frames is None else sk_frames["positions"],
        joint_names=None if sk_frames is None else sk_frames["names"],
        target_vertices=target_vertices,
        target_faces=target_faces,
        animation=glb,
        skeleton_source=load_skeleton(out_dir / "skeleton_source.tgf")
        if (out_dir / "skeleton_source.tgf").exists()
        else None,
        source_seen=_read_seen(out_dir / "source_seen.txt", nv),
    )


def _read_seen(path: Path, nv: int) -> np.ndarray | None:
    """``source_seen.txt`` (None when absent): ``nv`` numbers in [0, 1]."""
    if not path.exists():
        return None
    seen = np.asarray(read_vertex_array(path, nv, max_columns=1), np.float64).reshape(-1)
    if np.any((seen < 0) | (seen > 1)):
        raise InputError("values outside [0, 1]", path)
    return seen


def _read_maps(out_dir: Path, nv: int, n_faces: int) -> dict[str, np.ndarray]:
    """``map_tgt_to_src.npz`` and the two ``p2p`` files, checked against the source's size."""
    npz_path = out_dir / "map_tgt_to_src.npz"
    if not npz_path.is_file():
        raise InputError("missing result file", npz_path)
    arrays = read_npz_arrays(npz_path, ("face", "bary"), ())
    face, bary = arrays["face"], arrays["bary"]
    if face.ndim != 1 or not np.issubdtype(face.dtype, np.integer):
        got = f"shape {short_repr(face.shape, 40)} dtype {dtype_text(face.dtype)}"
        raise InputError(f"'face' must be a 1-D integer array, got {got}", npz_path)
    nt = face.shape[0]
    if not np.issubdtype(bary.dtype, np.floating):
        raise InputError(f"'bary' must be a float array, got dtype {dtype_text(bary.dtype)}", npz_path)
    if bary.shape != (nt, 3):
        raise InputError(f"'bary' must have shape ({nt}, 3), got {short_repr(bary.shape, 40)}", npz_path)
    bad = ~np.all(np.isfinite(bary), axis=1)
    if np.any(bad):
        raise InputError(
            f"'bary' has NaN or infinite values in {int(bad.sum())} rows (first: row {int(np.argmax(bad))})", npz_path
        )
    if nt and (face.min() < 0 or face.max() >= n_faces):
        raise InputError(f"'face' indices outside [0, {n_faces}) (source faces)", npz_path)
    maps = {"map_face": face.astype(np.int64), "map_bary": bary.astype(np.float64)}
    for name, n, upper in (("p2p_src_to_tgt", nv, nt), ("p2p_tgt_to_src", nt, nv)):
        path = out_dir / f"{name}.txt"
        if not path.is_file():
            raise InputError("missing result file", path)
        idx = read_index_file(path)
        if idx.shape != (n,):
            raise InputError(f"expected {n} indices (one per line), got {idx.shape[0]}", path)
        if n and (idx.min() < 0 or idx.max() >= upper):
            raise InputError(
                f"indices span [{int(idx.min())}, {int(idx.max())}], expected 0-based in [0, {upper})", path
            )
        maps[name] = idx.astype(np.int64)
    return {key: maps[key] for key in MAP_KEYS}


def _read_frames(frames_dir: Path, nv: int, faces: np.ndarray) -> np.ndarray:
    """(K, Vs, 3): ``frame_0000.ply`` … in order, each with the source's connectivity."""
    if not frames_dir.is_dir():
        raise InputError("missing result folder", frames_dir)
    numbered = sorted((int(m.group(1)), p) for p in frames_dir.iterdir() if (m := _FRAME_RE.match(p.name)))
    if not numbered:
        raise InputError("no frame_XXXX.ply files", frames_dir)
    expected = list(range(len(numbered)))
    if [i for i, _ in numbered] != expected:
        missing = sorted(set(expected) - {i for i, _ in numbered})
        what = f"missing frame_{missing[0]:04d}.ply" if missing else "duplicate numbers"
        raise InputError(f"frame numbers are not 0..{len(numbered) - 1} ({what})", frames_dir)
    frames = []
    for _, path in numbered:
        m = _read_ply(path)
        if m.n_vertices != nv or not np.array_equal(m.faces, faces):
            raise InputError(
                f"frame does not have the source connectivity ({m.n_vertices} vertices, expected {nv})", path
            )
        frames.append(m.vertices)
    return np.stack(frames)


def _read_skeleton(out_dir: Path, k: int):
    """(the target skeleton, its frames) of the two skeleton files, or (None, None) without them."""
    tgf, sfj = out_dir / "skeleton_target.tgf", out_dir / "skeleton_frames.json"
    if tgf.exists() != sfj.exists():
        raise InputError("missing result file (the skeleton files come together)", sfj if tgf.exists() else tgf)
    if not tgf.exists():
        return None, None
    skeleton = load_skeleton(tgf)
    sk_frames = read_skeleton_frames_json(sfj)
    if sk_frames["positions"].shape[:2] != (k, skeleton.n_joints):
        raise InputError(
            f"positions have shape {sk_frames['positions'].shape}, expected ({k}, {skeleton.n_joints}, 3)", sfj
        )
    if not np.array_equal(sk_frames["parents"], skeleton.parents):
        raise InputError("parents differ from skeleton_target.tgf", sfj)
    return skeleton, sk_frames


def result_target(
    result: ResultFolder, target: str | os.PathLike | None, result_dir: str | os.PathLike, *, replace: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of a result's target: the mesh file ``target`` when given, else ``target.ply``.

    Args:
        result: a folder read back (:func:`read_result`).
        target: a target mesh file (for results written without ``target.ply``), or None.
        result_dir: the folder (named in the error when no target is available).
        replace: whether ``target`` may replace an existing ``target.ply`` (else that is an error).

    Raises:
        InputError: no target at all, ``target`` given beside ``target.ply`` without ``replace``, or a
            ``target`` whose vertex count is not the result's n_target.
    """
    if target is None:
        if result.target_vertices is None:
            raise InputError(
                "the result has no target.ply (an older result); give the target mesh with --target", result_dir
            )
        return result.target_vertices, result.target_faces
    if not replace and result.target_vertices is not None:
        raise InputError("--target is only for results without target.ply; this result has one", target)
    mesh = load_target(target)
    if mesh.n_vertices != result.n_target:
        raise InputError(
            f"has {mesh.n_vertices} vertices but the result maps {result.n_target} target vertices "
            "(not the target of this result)",
            target,
        )
    return mesh.vertices, mesh.faces


def _check_glb(path: Path, k: int, nv: int) -> None:
    import pygltflib

    try:
        gltf = pygltflib.GLTF2().load_binary(str(path))
    except Exception as exc:
        raise InputError(f"cannot read glTF binary ({first_line(exc)[:80]})", path) from None
    if gltf is None or not gltf.meshes or not gltf.meshes[0].primitives:
        raise InputError("no mesh in the glTF file", path)
    prim = gltf.meshes[0].primitives[0]
    n_targets = len(prim.targets or [])
    count = gltf.accessors[prim.attributes.POSITION].count if prim.attributes.POSITION is not None else -1
    if n_targets != k or count != nv:
        raise InputError(f"mesh has {count} vertices and {n_targets} morph targets, expected {nv} and {k}", path)
