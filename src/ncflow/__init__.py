"""ncflow: correspondence-free matching and interpolation of articulated 3D shapes.

A small public surface (:data:`__all__`, pinned by ``tests/test_public_api.py``); everything else lives
in the submodules (``ncflow.measures``, ``ncflow.skeleton``, ``ncflow.flow``, ``ncflow.evaluate``, ...).
``ncflow.match`` is the matching function; its steps are the modules of :mod:`ncflow.matcher`
(``from ncflow.matcher.prepare import prepare``); ``ncflow.transfer`` and the rig are in
:mod:`ncflow.retarget`.

Importing ncflow imports nothing heavy (no JAX) and does one thing: when JAX has not started yet, it puts
the two JAX options that let pairs of similar size share compiled programs in the environment
(:func:`ncflow.jit.cache.prepare_jax`; JAX reads them once, when it starts, and takes them from nowhere
else; a user's own values stay). Each public name is loaded when it is first used; a match applies the
rest of its settings (the compilation cache) when it runs.
"""

from __future__ import annotations

import importlib

from ncflow.jit.cache import prepare_jax

__version__ = "0.3.0"

prepare_jax()
del prepare_jax

_PUBLIC = {
    "Config": "ncflow.config",
    "InputError": "ncflow.errors",
    "MatchResult": "ncflow.matcher",
    "Matcher": "ncflow.matcher",
    "Mesh": "ncflow.geometry.mesh",
    "NcflowError": "ncflow.errors",
    "PointCloud": "ncflow.geometry.cloud",
    "Skeleton": "ncflow.skeleton",
    "TrainingError": "ncflow.matcher",
    "compress_normal_cycle": "ncflow.measures",
    "compress_varifold": "ncflow.measures",
    "fit_normalization": "ncflow.geometry.normalize",
    "load_config": "ncflow.config",
    "load_mesh": "ncflow.io.meshes",
    "load_skeleton": "ncflow.skeleton",
    "load_target": "ncflow.io.points",
    "match": "ncflow.matcher",
    "mesh_topology": "ncflow.geometry.topology",
    "normal_cycle": "ncflow.measures",
    "normal_cycle_distance": "ncflow.measures",
    "preset": "ncflow.config",
    "read_result": "ncflow.io.result",
    "rig_result": "ncflow.retarget",
    "save_mesh": "ncflow.io.meshes",
    "save_skeleton": "ncflow.skeleton",
    "track_sequence": "ncflow.track",
    "transfer": "ncflow.retarget",
    "transfer_skin_weights": "ncflow.retarget",
    "varifold": "ncflow.measures",
    "varifold_distance": "ncflow.measures",
    "write_view": "ncflow.view",
}

__all__ = ["__version__", *sorted(_PUBLIC)]


def __getattr__(name: str):
    """A public name, loaded at its first use (PEP 562)."""
    if name not in _PUBLIC:
        raise AttributeError(f"module 'ncflow' has no attribute {name!r}")
    value = getattr(importlib.import_module(_PUBLIC[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))
