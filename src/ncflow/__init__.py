"""ncflow: correspondence-free matching and interpolation of articulated 3D shapes.

A small public surface; everything else lives in the submodules (``ncflow.measures``,
``ncflow.skeleton``, ``ncflow.flow``, ``ncflow.evaluate``, ...).
"""

__version__ = "0.1.0"

from ncflow.jit.cache import share_executables

share_executables()  # before anything imports JAX: compiled programs take their arrays as arguments

from ncflow import match
from ncflow.config import Config, load_config, preset
from ncflow.errors import InputError, NcflowError
from ncflow.geometry.mesh import Mesh
from ncflow.geometry.normalize import fit_normalization
from ncflow.geometry.topology import mesh_topology
from ncflow.io.meshes import load_mesh, save_mesh
from ncflow.io.result import read_result
from ncflow.match import Matcher, MatchResult, TrainingError
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
