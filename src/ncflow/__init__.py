"""ncflow: correspondence-free matching and interpolation of articulated 3D shapes.

A small public surface (:data:`__all__`, pinned by ``tests/test_public_api.py``); everything else lives
in the submodules (``ncflow.measures``, ``ncflow.skeleton``, ``ncflow.flow``, ``ncflow.evaluate``, ...).
``ncflow.match`` is the matching function; its steps are the modules of the package of the same name
(``from ncflow.matcher.prepare import prepare``). Importing ncflow sets nothing in JAX: a match applies its
settings when it runs (:func:`ncflow.matcher.steps.apply_runtime_settings`).
"""

__version__ = "0.3.0"

from ncflow.config import Config, load_config, preset
from ncflow.errors import InputError, NcflowError
from ncflow.geometry.mesh import Mesh
from ncflow.geometry.normalize import fit_normalization
from ncflow.geometry.topology import mesh_topology
from ncflow.io.meshes import load_mesh, save_mesh
from ncflow.io.result import read_result
from ncflow.matcher import Matcher, MatchResult, TrainingError, match
from ncflow.measures import (
    compress_normal_cycle,
    compress_varifold,
    normal_cycle,
    normal_cycle_distance,
    varifold,
    varifold_distance,
)
from ncflow.skeleton import Skeleton, load_skeleton, save_skeleton
from ncflow.transfer import rig_result, transfer, transfer_skin_weights
from ncflow.view import write_view

__all__ = [
    "Config",
    "InputError",
    "Matcher",
    "MatchResult",
    "Mesh",
    "NcflowError",
    "Skeleton",
    "TrainingError",
    "__version__",
    "compress_normal_cycle",
    "compress_varifold",
    "fit_normalization",
    "load_config",
    "load_mesh",
    "load_skeleton",
    "match",
    "mesh_topology",
    "normal_cycle",
    "normal_cycle_distance",
    "preset",
    "read_result",
    "rig_result",
    "save_mesh",
    "save_skeleton",
    "transfer",
    "transfer_skin_weights",
    "varifold",
    "varifold_distance",
    "write_view",
]
