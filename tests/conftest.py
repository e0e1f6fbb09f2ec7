"""Test-wide settings: float64 JAX so that references agree to 1e-6 and better.

Library code follows the dtype of its inputs; tests of float32 behaviour pass float32 arrays.
"""

import jax

jax.config.update("jax_enable_x64", True)


import os  # noqa: E402
import tempfile  # noqa: E402

# keep the tetrahedralisation cache of test runs out of the user's home
os.environ.setdefault("NCFLOW_CACHE_DIR", tempfile.mkdtemp(prefix="ncflow-test-cache-"))

# identical training steps compiled by several matcher runs in one session are reused
jax.config.update("jax_compilation_cache_dir", tempfile.mkdtemp(prefix="ncflow-test-jit-"))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
