"""ncflow's cache folder and JAX's persistent compilation cache (issue 17)."""

import json
import os
import subprocess
import sys
import textwrap

import pytest

SCRIPT = textwrap.dedent(
    """
    import sys
    import jax, jax.numpy as jnp
    from ncflow.jit.cache import configure_compilation_cache
    folder = configure_compilation_cache(sys.argv[1])
    print("FOLDER", folder)
    f = jax.jit(lambda x: jnp.sin(x) @ jnp.cos(x).T + jnp.tanh(x).sum())
    for n in range(3, 9):  # six executables, each compiled once
        f(jnp.ones((n, n))).block_until_ready()
    """
)


def _run(tmp_path, setting, env_value=None):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NCFLOW_", "JAX_"))}
    env["NCFLOW_CACHE_DIR"] = str(tmp_path / "cache")
    env["JAX_PLATFORMS"] = "cpu"  # the CPU's keys (on a GPU the autotuning cache's path stays in them)
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


def test_a_cache_folder_serves_from_another_path(tmp_path):
    """The same programs compiled with the cache in two folders are filed under the same keys (the
    folder's path is not part of them), so a folder copied or mounted elsewhere still serves.
    """
    first, second = _run(tmp_path, str(tmp_path / "one")), _run(tmp_path, str(tmp_path / "two" / "deeper"))
    names = [sorted(os.path.basename(f) for f in _files(folder) if "-cache" in f) for folder in (first, second)]
    assert len(names[0]) >= 6 and names[0] == names[1]


def test_the_tests_run_with_the_jax_settings_users_get():
    import jax

    from ncflow.jit.cache import SHARE_SETTINGS, share_executables

    assert all(os.environ.get(k) == str(v).lower() for k, v in SHARE_SETTINGS.items())  # as prepare_jax puts them
    assert share_executables() and jax.config.jax_embedded_constants_max_bytes == 0  # JAX started with them


IMPORT_ONLY = textwrap.dedent(
    """
    import json, os, sys
    environ = dict(os.environ)
    import ncflow, ncflow.cli
    quiet = {"jax": "jax" in sys.modules, "environ": sorted(set(os.environ.items()) ^ set(environ.items()))}
    from ncflow.jit.cache import share_executables
    print(json.dumps({"import": quiet, "shared": share_executables()}))
    """
)

JAX_FIRST = textwrap.dedent(
    """
    import json, os
    import jax
    before = {k: jax.config.values.get(k) for k in sorted(jax.config.values) if k.startswith("jax_")}
    environ = dict(os.environ)
    import ncflow, ncflow.cli, ncflow.runs
    ncflow.match, ncflow.transfer
    changed = sorted(k for k in before if before[k] != jax.config.values.get(k))
    from ncflow.jit.cache import share_executables
    print(json.dumps({"changed": changed, "environ": sorted(set(os.environ.items()) ^ set(environ.items())),
                      "shared": share_executables()}))
    """
)


def test_importing_ncflow_sets_only_the_jax_options_it_needs_from_the_start(tmp_path):
    from ncflow.jit.cache import SHARE_SETTINGS

    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}

    def run(script):
        return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, check=True)

    # import ncflow: no JAX; the two sharing options in the environment, and JAX started later honours them
    got = json.loads(run(IMPORT_ONLY).stdout.splitlines()[-1])
    assert got["import"] == {
        "jax": False,
        "environ": sorted([k, str(v).lower()] for k, v in SHARE_SETTINGS.items()),
    }
    assert got["shared"] is True
    # a user's JAX, started first: ncflow changes neither it nor the environment, and says programs are not shared
    got = json.loads(run(JAX_FIRST).stdout.splitlines()[-1])
    assert got == {"changed": [], "environ": [], "shared": False}


@pytest.mark.parametrize("per_octave", [1, 2, 4])
def test_bucket_is_the_smallest_allowed_size_not_below_n(per_octave):
    from ncflow.jit.buckets import bucket

    # the allowed sizes, brute force: multiples of 2^k / per_octave within each octave [2^k, 2^(k+1)]
    allowed = sorted(
        {m * (2**k // per_octave) for k in range(3, 20) for m in range(per_octave, 2 * per_octave + 1)} | {8}
    )
    for n in list(range(0, 600)) + [1023, 1024, 1025, 2232, 3162, 99_999]:
        expected = min(a for a in allowed if a >= max(n, 8))
        assert bucket(n, per_octave) == expected, n
        assert bucket(n, per_octave) < max(n, 8) * (1 + 1 / per_octave) + 1e-9


def test_jit_cache_setting_in_config():
    from ncflow.config import apply_overrides, preset

    assert preset("fast").jit_cache == "auto"
    assert apply_overrides(preset("fast"), ["jit_cache=none"]).jit_cache == "none"


SHARED = textwrap.dedent(
    """
    import os, sys
    import numpy as np
    import ncflow
    from ncflow.jit.cache import share_executables
    from ncflow.config import apply_overrides, preset, scale_steps
    from ncflow.geometry.mesh import Mesh
    from ncflow.matcher import Matcher
    from ncflow.skeleton import Skeleton
    from ncflow.synthetic.shapes import bend, capsule

    print("SHARED", share_executables())
    folder = sys.argv[1]
    sets = ["flow.width=8", "flow.depth=1", "flow.gso_width=4", "flow.gso_depth=1", "flow.n_times=3",
            "sampling.bone_samples=5", "sampling.surface_edges=0", "weights.surface=0", "weights.tissue=0",
            "compress=120", "placement=none", "pose_search=false", f"jit_cache={folder}"]
    cfg = scale_steps(apply_overrides(preset("fast"), sets), 2)
    # two characters of other mesh sizes in the same size buckets (86 and 83 vertices: 88 padded; 252 and
    # 243 edges: 256; 168 and 162 faces: 176), other proportions, another middle joint, other bends
    # (neither passing through itself, so both take the bone weights of the current place)
    for length, joint, angle, around, along in ((3.0, 0.0, 40.0, 7, 10), (2.4, 0.35, 55.0, 9, 7)):
        vs, fs = capsule(radius=0.4, length=length, n_around=around, n_along=along)
        print("VERTICES", len(vs))
        ends = length / 2 + 0.1
        skel = Skeleton.from_arrays(np.array([[0, 0, -ends], [0, 0, joint], [0, 0, ends]]), np.array([-1, 0, 1]))
        m = Matcher(Mesh(vs, fs, "source"), Mesh(bend(vs, angle), fs, "target"), skel, cfg, quiet=True)
        m.run()
        print("MODE", m.setup.skinning_weights["mode"])
        print("STEPS", sorted(f for f in os.listdir(folder) if f.startswith("jit_step-")))
        print("OUTPUTS", sorted(f for f in os.listdir(folder) if f.startswith("jit_output_")))
        target = ("jit_target_measure-", "jit_kernel_matvec-", "jit_kernel_self_sum-")
        print("TARGET", sorted(f for f in os.listdir(folder) if f.startswith(target)))
    """
)


def test_a_second_character_of_similar_size_reuses_the_compiled_training_step(tmp_path):
    """Two sources of other mesh sizes in the same size buckets, with different proportions, skeletons
    (so bone-weight widths) and targets: the second match finds its training step, its two output
    programs and its target's measures and compression in the compilation cache (issue 17's "pairs
    of similar size share compiled executables"), because the arrays are arguments of the programs
    (:func:`ncflow.jit.cache.share_executables`), not constants written into them, and the source and
    the target are padded to their size buckets (:func:`ncflow.jit.buckets.pad_mesh`).
    """
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NCFLOW_", "JAX_"))}
    env["NCFLOW_CACHE_DIR"] = str(tmp_path / "cache")
    out = subprocess.run(
        [sys.executable, "-c", SHARED, str(tmp_path / "jit")], env=env, capture_output=True, text=True, timeout=600
    )
    assert out.returncode == 0, out.stderr[-3000:]
    lines = out.stdout.splitlines()
    assert "SHARED True" in lines and lines.count("MODE current") == 2
    assert [line for line in lines if line.startswith("VERTICES ")] == ["VERTICES 86", "VERTICES 83"]
    first, second = [line for line in lines if line.startswith("STEPS ")]
    assert first != "STEPS []" and second == first
    # and the output phase's two programs (the flow of the padded source with the bone samples, the refit)
    first, second = [line for line in lines if line.startswith("OUTPUTS ")]
    assert first.count("jit_output_") == 2 and second == first
    # and the target's: its two measures (of the mesh padded to its buckets) and their compression
    # (each Normal Cycle and Varifold, 168 and 162 faces, 252 and 243 edges, compressed to 120 points)
    first, second = [line for line in lines if line.startswith("TARGET ")]
    assert first.count("jit_target_measure-") == 2 and first.count("jit_kernel_matvec-") >= 2 and second == first


def test_jit_run_once_gives_what_filter_jit_gives():
    """A module with static fields (a name, activations) and a NumPy field, built by one program: the
    leaves of ``equinox.filter_jit`` to rounding (the NumPy field returned as a JAX array, as there); a
    second key gives the second key's values.
    """
    import equinox as eqx
    import jax
    import numpy as np

    from ncflow.jit.cache import jit_run_once

    class Net(eqx.Module):
        mlp: eqx.nn.MLP
        table: np.ndarray
        scale: jax.Array
        name: str = eqx.field(static=True)

    def make(key, scale):
        return Net(eqx.nn.MLP(3, 2, 8, 2, key=key), np.arange(4.0), 2.0 * scale, "net")

    keys = jax.random.split(jax.random.key(7))
    scale = jax.numpy.asarray(1.5)
    once = jit_run_once(make)
    for key in keys:
        got, want = once(key, scale), eqx.filter_jit(make)(key, scale)
        got_leaves, want_leaves = (jax.tree_util.tree_leaves(eqx.filter(m, eqx.is_array)) for m in (got, want))
        assert len(got_leaves) == len(want_leaves) == 8
        for g, w in zip(got_leaves, want_leaves):  # rounding: LLVM's optimisations contract a multiply-add
            assert g.shape == w.shape and g.dtype == w.dtype
            np.testing.assert_allclose(np.asarray(g), np.asarray(w), rtol=1e-12, atol=1e-15)
        assert isinstance(got.mlp.layers[0].weight, jax.Array) and got.mlp.activation is want.mlp.activation
        assert isinstance(got.table, jax.Array) and np.array_equal(got.table, np.arange(4.0))
        assert float(got.scale) == 3.0 and got.name == "net"
        x = jax.numpy.ones(3)
        np.testing.assert_allclose(np.asarray(got.mlp(x)), np.asarray(want.mlp(x)), rtol=1e-12, atol=1e-15)
    first, second = once(keys[0], scale), once(keys[1], scale)
    assert not np.array_equal(np.asarray(first.mlp.layers[0].weight), np.asarray(second.mlp.layers[0].weight))


def test_jit_run_once_keeps_each_shapes_static_part_and_passes_its_options(monkeypatch):
    """Calls with shapes 3, 5, 3: the static part of each result is its own call's (the third call
    replays the first trace); options the compiler rejects make the call fail, so they reach it.
    """
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    import ncflow.jit.cache as cache

    class Sized(eqx.Module):
        x: jax.Array
        n: int = eqx.field(static=True)

    once = cache.jit_run_once(lambda x: Sized(2.0 * x, x.shape[0]))
    for n in (3, 5, 3):
        out = once(jnp.ones(n))
        assert out.n == n and out.x.shape == (n,) and float(out.x.sum()) == 2.0 * n
    monkeypatch.setattr(cache, "run_once_options", lambda: {"xla_no_such_option_in_any_backend": 1})
    with pytest.raises(Exception, match="xla_no_such_option_in_any_backend"):
        cache.jit_run_once(lambda x: x + 1.0)(jnp.ones(4))
