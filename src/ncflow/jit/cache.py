"""ncflow's cache folder and JAX's persistent compilation cache in it.

Everything ncflow caches lives under one folder: ``$NCFLOW_CACHE_DIR``, default
``$XDG_CACHE_HOME/ncflow`` (``~/.cache/ncflow``): the tetrahedralisations (``tissue/``), each
pair's placement and pose search (``setup/``, :func:`ncflow.matcher.prepare.place_and_pose_cached`)
and JAX's compiled executables (``jax/``). The compilation cache makes a second run of a pair skip most of
its compilation (the ``jit`` executables of the first run are read back from disk).

``$NCFLOW_JIT_CACHE`` or the ``jit_cache`` setting move or disable the compilation cache: ``auto``
(the default: ``<cache folder>/jax``, unless JAX's own ``jax_compilation_cache_dir`` is already
set, which is then respected), ``none`` (off) or a folder. The environment variable wins over the
setting, so a cluster job can turn it off without editing configurations. On the CPU a cache folder
can be copied or mounted at another path and still serve (JAX writes the path of XLA's GPU
autotuning cache, which sits in the folder, into every key; ncflow turns that cache off on the CPU,
where it tunes nothing), so a cluster's nodes or a container image can share one warm folder.

A cached executable is found by the text of the program it compiles. JAX writes the arrays a
jitted function closes over (the source, the skeleton, the tissue centroids) into that text by
default, so every pair had its own programs. :func:`prepare_jax` (run by ``import ncflow``, before JAX
starts) makes them arguments of the program instead (JAX's ``jax_use_simplified_jaxpr_constants``, with
no size limit; :func:`share_executables` tells whether it took effect), and the
matcher pads the tissue centroids, whose count varies with each tetrahedralisation, to a power of
two (:func:`bucket`). Pairs whose sources have the same numbers of vertices and edges and whose
skeletons have the same joint tree (the same character in another pose, two MANO hands) then share
every compiled program of the training, the pose search and the outputs; the source's own arrays
are not padded, so sources of other sizes still compile their own.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

OFF = ("none", "off", "0", "false", "no")


def cache_root() -> Path:
    """``$NCFLOW_CACHE_DIR``, default ``$XDG_CACHE_HOME/ncflow`` (``~/.cache/ncflow``)."""
    base = os.environ.get("NCFLOW_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "ncflow"
    )
    return Path(base)


def compilation_cache_dir(setting: str = "auto") -> Path | None:
    """The folder the compilation cache uses for ``setting`` (``auto`` | ``none`` | a folder), after
    ``$NCFLOW_JIT_CACHE``; None when it is off or left to JAX's own configuration.
    """
    import jax

    choice = os.environ.get("NCFLOW_JIT_CACHE") or setting or "auto"
    if choice.lower() in OFF:
        return None
    if choice.lower() == "auto":
        if jax.config.jax_compilation_cache_dir:
            return Path(jax.config.jax_compilation_cache_dir)
        return cache_root() / "jax"
    return Path(choice).expanduser()


SHARE_SETTINGS = {"JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS": True, "JAX_EMBEDDED_CONSTANTS_MAX_BYTES": 0}
"""JAX's settings (their environment variables and values) that make closed-over arrays arguments of the
executable."""


def prepare_jax() -> bool:
    """Put the JAX options of :data:`SHARE_SETTINGS` in the environment, before JAX is imported, so that
    JAX starts with them: it reads them once, when imported (set later through its configuration, they
    do not take effect: :func:`share_executables`). A user's own settings stay; an already imported JAX
    is left alone. Called by ``import ncflow`` (the one thing importing ncflow does), so before any of
    its modules, the ``ncflow`` command's included. Returns whether it set them.
    """
    import sys

    if "jax" in sys.modules:
        return False
    for name, value in SHARE_SETTINGS.items():
        os.environ.setdefault(name, str(value).lower())
    return True


def share_executables() -> bool:
    """Whether one compiled program serves every array value of the same shape (see the module
    docstring): closed-over arrays are arguments of the executable. That holds when JAX started with
    the options of :data:`SHARE_SETTINGS` (:func:`prepare_jax`: ncflow imported before JAX, or the
    variables set by the user); JAX started without them ignores them when set later, and every pair
    then compiles its own programs (the results are the same up to rounding). Found by lowering a small
    program that closes over an array.
    """
    import jax
    import numpy as np

    values = np.zeros(3, np.float32)
    text = jax.jit(lambda x: x + values).lower(np.zeros(3, np.float32)).as_text()
    return "dense<" not in text


def configure_compilation_cache(setting: str = "auto") -> Path | None:
    """Turn JAX's persistent compilation cache on in :func:`compilation_cache_dir` (or off); returns
    the folder in use. Every executable is kept (most of a small run is compilation).
    """
    import jax

    folder = compilation_cache_dir(setting)
    if folder is None:
        jax.config.update("jax_enable_compilation_cache", False)
        return None
    folder.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_enable_compilation_cache", True)
    if (
        hasattr(jax.config, "jax_persistent_cache_enable_xla_caches")  # JAX ≥ 0.4.3x; before it, no path
        and "JAX_PERSISTENT_CACHE_ENABLE_XLA_CACHES" not in os.environ
        and jax.default_backend() == "cpu"
    ):
        # XLA's GPU autotuning cache sits in the folder and its path enters every key: off on the
        # CPU (it has nothing to tune), so a cache folder copied or mounted elsewhere still serves
        jax.config.update("jax_persistent_cache_enable_xla_caches", "none")
    if jax.config.jax_compilation_cache_dir != str(folder):
        jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    return folder


def run_once_options() -> dict:
    """Compiler options of a program a match runs once and that is small in its data (the parameter
    initialisation, the output refit): on the CPU, XLA without LLVM's optimisation passes
    (``xla_backend_optimization_level`` 0) compiles it in about half the time, and its one run costs
    little either way; other backends keep their defaults. The options are part of the compilation
    cache's key.
    """
    import jax

    return {"xla_backend_optimization_level": 0} if jax.default_backend() == "cpu" else {}


@functools.cache
def _static_box():
    """An Equinox module holding one value in its tree structure (no leaves): what a program returns
    beside its arrays so that JAX keeps it with each trace.
    """
    import equinox as eqx

    class StaticBox(eqx.Module):
        value: object = eqx.field(static=True)

    return StaticBox


def jit_run_once(fn):
    """``fn`` compiled as one program with :func:`run_once_options`.

    Like ``equinox.filter_jit`` (which takes no compiler options) for arguments that are arrays,
    pytrees of arrays or None: the arrays of ``fn``'s output (JAX or NumPy) come from the program
    as JAX arrays; its other leaves (functions, static fields) are returned in the output's tree
    structure, so each trace (one per argument shape) keeps its own.
    """
    import equinox as eqx
    import jax

    box = _static_box()

    @functools.wraps(fn)  # the program keeps fn's name (compilation logs, the cache's file names)
    def arrays_of(*args):
        out = fn(*args)
        return eqx.filter(out, eqx.is_array), box(eqx.filter(out, eqx.is_array, inverse=True))

    program = jax.jit(arrays_of, compiler_options=run_once_options())

    def call(*args):
        arrays, static = program(*args)
        return eqx.combine(arrays, static.value)

    call.lower = program.lower  # lower(*args).compile(): compiled ahead, found by the first call
    return call
