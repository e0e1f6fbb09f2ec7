"""ncflow's cache folder and JAX's persistent compilation cache (issue 17)."""

import os
import subprocess
import sys
import textwrap

import pytest

SCRIPT = textwrap.dedent(
    """
    import sys
    import jax, jax.numpy as jnp
    from ncflow.cache import configure_compilation_cache
    folder = configure_compilation_cache(sys.argv[1])
    print("FOLDER", folder)
    f = jax.jit(lambda x: jnp.sin(x) @ jnp.cos(x).T + jnp.tanh(x).sum())
    for n in range(3, 40):  # a few executables, each compiled once
        f(jnp.ones((n, n))).block_until_ready()
    """
)


def _run(tmp_path, setting, env_value=None):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NCFLOW_", "JAX_"))}
    env["NCFLOW_CACHE_DIR"] = str(tmp_path / "cache")
    if env_value is not None:
        env["NCFLOW_JIT_CACHE"] = env_value
    out = subprocess.run([sys.executable, "-c", SCRIPT, setting], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    return next(line.split(" ", 1)[1] for line in out.stdout.splitlines() if line.startswith("FOLDER "))


def _files(folder):
    return [os.path.join(d, f) for d, _, fs in os.walk(folder) for f in fs] if os.path.isdir(folder) else []


def test_cache_is_on_by_default_in_the_cache_folder(tmp_path):
    folder = _run(tmp_path, "auto")
    assert folder == str(tmp_path / "cache" / "jax")
    assert len(_files(folder)) > 0


@pytest.mark.parametrize("setting, env_value", [("none", None), ("auto", "off"), (None, "0")])
def test_cache_can_be_disabled_by_setting_or_environment(tmp_path, setting, env_value):
    folder = _run(tmp_path, setting or "auto", env_value)
    assert folder == "None"
    assert _files(tmp_path / "cache") == []


def test_cache_can_be_moved(tmp_path):
    target = tmp_path / "elsewhere"
    folder = _run(tmp_path, "auto", str(target))
    assert folder == str(target)
    assert len(_files(target)) > 0 and _files(tmp_path / "cache") == []


def test_jit_cache_setting_in_config():
    from ncflow.config import apply_overrides, preset

    assert preset("fast").jit_cache == "auto"
    assert apply_overrides(preset("fast"), ["jit_cache=none"]).jit_cache == "none"
