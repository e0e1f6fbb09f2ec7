"""Settings and integer options are checked when they are read: finite, in range, one short error line.

Configuration files (TOML and YAML), ``--set`` overrides and the command-line integer options; the
YAML reader refuses aliases (a few hundred bytes of nested aliases, "billion laughs", expand to
gigabytes and once made a 35 MB error message) and keys that are not words. No matching runs here.
"""

from __future__ import annotations

import time

import pytest

from ncflow.cli import main
from ncflow.config import QUOTE_LIMIT, apply_overrides, load_config, preset
from ncflow.errors import InputError

BILLION_LAUGHS = (
    'a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]\n'
    "b: &b [*a,*a,*a,*a,*a,*a,*a,*a,*a]\n"
    "c: &c [*b,*b,*b,*b,*b,*b,*b,*b,*b]\n"
    "d: &d [*c,*c,*c,*c,*c,*c,*c,*c,*c]\n"
    "e: &e [*d,*d,*d,*d,*d,*d,*d,*d,*d]\n"
    "f: &f [*e,*e,*e,*e,*e,*e,*e,*e,*e]\n"
    "g: &g [*f,*f,*f,*f,*f,*f,*f,*f,*f]\n"
    "seed: *g\n"
)


@pytest.mark.parametrize(
    "name, text, message",
    [
        ("seed_inf.toml", "seed = inf\n", "seed must be a finite integer"),
        ("seed_neg.toml", "seed = -1\n", "seed must be at least 0"),
        ("seed_big.toml", "seed = 4294967296\n", "seed must be at most 4294967295"),
        ("seed_frac.toml", "seed = 1.5\n", "seed: expected an integer"),
        ("seed_bool.toml", "seed = true\n", "seed: expected an integer"),
        ("clip.toml", "clip_norm = nan\n", "clip_norm must be finite"),
        ("clip0.toml", "clip_norm = 0.0\n", "clip_norm must be positive"),
        ("lr.toml", '[[phases]]\nmetric = "varifold"\nsteps = 5\nlr = -1e-3\n', "learning rates"),
        ("lr_inf.toml", '[[phases]]\nmetric = "varifold"\nsteps = 5\nlr = inf\n', "phases[0].lr must be finite"),
        ("lr_end.toml", '[[phases]]\nmetric = "varifold"\nsteps = 5\nlr_end = nan\n', "lr_end must be finite"),
        ("quad.toml", '[[phases]]\nmetric = "varifold"\nsteps = 5\nquadrature = 3\n', "quadrature must be 1 or 4"),
        ("quad_nc.toml", "[[phases]]\nsteps = 5\nquadrature = 4\n", "quadrature applies to the Varifold only"),
        ("edges.toml", "[sampling]\nsurface_edges = -7\n", "surface_edges must be non-negative (0 means all edges)"),
        ("eps.toml", "[constraints]\neps = -inf\n", "constraints.eps must be finite"),
        ("weights.toml", "[weights]\ntissue = -1\n", "weights.tissue must be non-negative"),
        ("decay.toml", "weight_decay = nan\n", "weight_decay must be finite"),
        ("guard.toml", "divergence_guard = 0.5\n", "divergence_guard"),
        ("frames.toml", "frames = 1e300\n", "frames must be at most"),
        ("working.toml", "working_vertices = -5\n", "working_vertices must be at least 100"),
        ("jit.toml", 'jit_cache = ""\n', "jit_cache must be auto, none or a folder"),
        ("placement.toml", 'placement = "sideways"\n', "placement must be 'auto' or 'none'"),
        ("table.toml", "flow = 3\n", "flow: expected a table"),
        ("int_keys.yaml", "1: 2\n", "setting names must be words, got 1 (int)"),
        ("int_subkeys.yaml", "flow:\n  7: 8\n", "setting names must be words, got flow.7"),
        ("laughs.yaml", BILLION_LAUGHS, "YAML aliases (*name) are not allowed"),
        ("list.yaml", "- 1\n- 2\n", "configuration must be a mapping"),
        ("long.yaml", "seed: " + "9x" * 50_000 + "\n", "seed: expected an integer"),
        ("deep.yaml", "seed: " + "[" * 20_000 + "\n", "cannot parse configuration"),
    ],
)
def test_bad_settings_are_one_short_line(tmp_path, name, text, message):
    path = tmp_path / name
    path.write_text(text)
    t0 = time.perf_counter()
    with pytest.raises(InputError) as info:
        load_config(path)
    assert time.perf_counter() - t0 < 5.0
    err = str(info.value)
    assert message in err, err
    assert err.startswith(str(path)) and len(err.splitlines()) == 1
    # at most ~80 characters of any value are quoted
    assert len(err) < len(str(path)) + 2 * QUOTE_LIMIT + 120, len(err)


def test_billion_laughs_is_refused_early_and_briefly(tmp_path):
    path = tmp_path / "laughs.yaml"
    path.write_text(BILLION_LAUGHS)
    assert len(BILLION_LAUGHS) < 400
    with pytest.raises(InputError, match="aliases") as info:
        load_config(path)
    assert len(str(info.value)) < 200
    huge = tmp_path / "huge.toml"
    huge.write_text("# padding\n" * 200_000)
    with pytest.raises(InputError, match="too large"):
        load_config(huge)


def test_overrides_are_checked_and_new_settings_keep_working(tmp_path):
    for item, message in [
        ("clip_norm=nan", "clip_norm must be finite"),
        ("seed=-1", "seed must be at least 0"),
        ("seed=inf", "seed must be a finite integer"),
        ("flow.width=1e400", "flow.width must be a finite integer"),
        ("sampling.surface_edges=-7", "surface_edges must be non-negative"),
        ("constraints.margin=nan", "constraints.margin must be finite"),
        ("working_vertices=50", "working_vertices must be at least 100"),
        ("x" * 500 + "=1", "unknown setting"),
        ("a b=1", "is not a setting name"),
        ("flow.widht=3", r"unknown setting\(s\) flow.widht; did you mean flow.width\?"),
        ("repiar.weld_tolerance=0", r"unknown setting\(s\) repiar; did you mean repair\?"),
        ("repair.weld_tolerance=0.5", r"repair.weld_tolerance must be in \[0, 0.01\]"),
        ("repair.min_component=1", r"repair.min_component must be in \[0, 1\)"),
    ]:
        with pytest.raises(InputError, match=message) as info:
            apply_overrides(preset("fast"), [item])
        assert len(str(info.value)) < 300
    cfg = apply_overrides(
        preset("fast"),
        ["working_vertices=none", "jit_cache=none", "placement=none", "pose_search=false", "sampling.surface_edges=0"],
    )
    assert cfg.working_vertices is None and cfg.jit_cache == "none" and cfg.placement == "none"
    assert cfg.pose_search is False and cfg.sampling.surface_edges == 0
    assert apply_overrides(preset("fast"), ["working_vertices=500", "jit_cache=auto"]).working_vertices == 500
    assert apply_overrides(preset("fast"), [f"jit_cache={tmp_path / 'jit'}"]).jit_cache == str(tmp_path / "jit")
    path = tmp_path / "c.yaml"
    path.write_text("preset: paper\nseed: 7\nworking_vertices: null\nplacement: none\npose_search: false\n")
    cfg = load_config(path)
    assert (cfg.preset, cfg.seed, cfg.working_vertices, cfg.placement, cfg.pose_search) == (
        "paper",
        7,
        None,
        "none",
        False,
    )
    assert load_config(None, "paper").sampling.surface_edges == 0  # 0: all edges


@pytest.mark.parametrize(
    "args, message",
    [
        (["match", "s.ply", "t.ply", "--skeleton", "k.tgf", "--out", "o", "--seed", "-1"], "--seed must be at least 0"),
        (["match", "s.ply", "t.ply", "--skeleton", "k.tgf", "--out", "o", "--seed", "4294967296"], "--seed"),
        (["match", "s.ply", "t.ply", "--skeleton", "k.tgf", "--out", "o", "--seed", "inf"], "invalid int value"),
        (
            ["match", "s.ply", "t.ply", "--skeleton", "k.tgf", "--out", "o", "--steps", "0"],
            "--steps must be at least 1",
        ),
        (
            ["match", "s.ply", "t.ply", "--skeleton", "k.tgf", "--out", "o", "--frames", "1"],
            "--frames must be at least 2",
        ),
        (
            ["match", "s.ply", "t.ply", "--skeleton", "k.tgf", "--out", "o", "--set", "seed=nan"],
            "seed must be a finite",
        ),
        (["demo", "--out", "o", "--pair-seed", "-3"], "--pair-seed must be at least 0"),
        (["benchmark", "p.csv", "--out", "o", "--jobs", "-1"], "--jobs must be at least 0"),
        (["batch", "p.csv", "--out", "o", "--threads", "0"], "--threads must be at least 1"),
        (["make-pairs", "o", "--n", "0"], "--n must be at least 1"),
        (["make-pairs", "o", "--seed", "-1"], "--seed must be at least 0"),
        (["make-pairs", "o", "--resolution", "inf"], "--resolution must be finite"),
        (["make-shape", "sphere", "o.ply", "--resolution", "100000"], "--resolution must be at most"),
        (["make-shape", "sphere", "o.ply", "--bend", "nan"], "--bend must be finite"),
        (["distance", "a.ply", "b.ply", "--sigma", "inf"], "--sigma must be finite"),
        (["pose", "a.glb", "--out", "o.ply", "--skin", "-1"], "--skin must be at least 0"),
    ],
)
def test_cli_integer_and_number_options_are_checked(tmp_path, monkeypatch, capsys, args, message):
    monkeypatch.chdir(tmp_path)
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # nothing written


def test_make_shape_under_an_existing_file_is_one_line(tmp_path, capsys):
    blocker = tmp_path / "notes.txt"
    blocker.write_text("mine\n")
    assert main(["make-shape", "sphere", str(blocker / "shape.ply")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "which is not a folder" in err, err
    assert blocker.read_text() == "mine\n" and sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]
