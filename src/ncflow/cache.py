"""ncflow's cache folder and JAX's persistent compilation cache in it (issue 17).

Everything ncflow caches lives under one folder: ``$NCFLOW_CACHE_DIR``, default
``$XDG_CACHE_HOME/ncflow`` (``~/.cache/ncflow``): the tetrahedralisations (``tissue/``) and JAX's
compiled executables (``jax/``). The compilation cache makes a second run of a pair skip most of
its compilation (the ``jit`` executables of the first run are read back from disk).

``$NCFLOW_JIT_CACHE`` or the ``jit_cache`` setting move or disable the compilation cache: ``auto``
(the default: ``<cache folder>/jax``, unless JAX's own ``jax_compilation_cache_dir`` is already
set, which is then respected), ``none`` (off) or a folder. The environment variable wins over the
setting, so a cluster job can turn it off without editing configurations.
"""

from __future__ import annotations

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
    if jax.config.jax_compilation_cache_dir != str(folder):
        jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    return folder
