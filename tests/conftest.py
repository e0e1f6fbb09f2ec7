"""Test-wide settings: runtime checks of the jaxtyping annotations, and float64 JAX.

Every function and dataclass of ``ncflow`` is checked at call time against its jaxtyping annotations (dtype,
rank, and shape names consistent across the arguments and the return value of one call) by beartype, through
jaxtyping's import hook. The hook rewrites the modules as they are imported, so it is installed here, before
anything imports ``ncflow``. Set ``NCFLOW_TYPECHECK=0`` to run without it (e.g. to time the checks).

float64 JAX so that references agree to 1e-6 and better. Library code follows the dtype of its inputs; tests
of float32 behaviour pass float32 arrays.
"""

import os
import re

# closed-over arrays as arguments of compiled programs: a match sets this when it runs
# (ncflow.jit.cache.share_executables, SHARE_SETTINGS); set here for the whole run, so that the programs of
# tests that run no match compile as a match's would (checked in test_cache.py)
os.environ.setdefault("JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS", "true")
os.environ.setdefault("JAX_EMBEDDED_CONSTANTS_MAX_BYTES", "0")

if os.environ.get("NCFLOW_TYPECHECK", "1") != "0":
    from jaxtyping import install_import_hook

    # beartype with PEP 484's implicit numeric tower (an int is a valid `float`, as for mypy and pyright).
    # jaxtyping evaluates this string as `<string>(function)` after importing its first name, `beartype`.
    install_import_hook("ncflow", "beartype.beartype(conf=beartype.BeartypeConf(is_pep484_tower=True))")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)


import atexit  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402


def _run_dir(variable: str, prefix: str) -> str:
    """``$variable``, or a fresh folder put there and removed when this process exits. pytest loads this
    file in its controlling process before it starts the pytest-xdist workers, which inherit the
    variable: the whole run shares one folder.
    """
    if variable not in os.environ:
        path = tempfile.mkdtemp(prefix=prefix)
        atexit.register(shutil.rmtree, path, ignore_errors=True)
        os.environ[variable] = path
    return os.environ[variable]


# keep the caches of test runs out of the user's home: the tetrahedra, and the compiled programs in the
# folder where ncflow looks by default (the processes that tests start, CLI runs and Dask workers, find
# it too), so identical programs are compiled once in a run, across test files and workers
_cache = _run_dir("NCFLOW_CACHE_DIR", "ncflow-test-cache-")
jax.config.update("jax_compilation_cache_dir", os.path.join(_cache, "jax"))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


import pytest  # noqa: E402


@pytest.fixture(autouse=True, scope="module")
def _free_compiled_executables():
    """Drop JAX's in-memory executables after each test module.

    One process that compiles every test's functions runs out of executable memory mappings
    ("LLVM ERROR: Unable to allocate section memory", an abort) after a few hundred compilations;
    identical functions in later modules come back from the on-disk compilation cache set above.
    """
    yield
    jax.clear_caches()


@pytest.fixture
def dot_precisions():
    """A function: the ``precision`` of every matrix product in a printed jaxpr (scan bodies and
    custom VJPs included), e.g. ``["(Precision.HIGHEST, Precision.HIGHEST)", "None"]``.
    """
    return lambda jaxpr_text: re.findall(r"dot_general\[.*?precision=(\([^)]*\)|None)", jaxpr_text, flags=re.S)


from browser_checks import browser  # noqa: E402, F401  (the headless Chromium of the viewer's tests)
