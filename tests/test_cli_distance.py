"""``ncflow distance`` and ``ncflow make-shape`` end to end."""

import json

import numpy as np
import pytest

from ncflow.cli import main
from ncflow.geometry.normalize import fit_normalization
from ncflow.geometry.topology import mesh_topology
from ncflow.io.meshes import load_mesh
from ncflow.measures import normal_cycle, normal_cycle_distance, varifold, varifold_distance


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    d = tmp_path_factory.mktemp("pair")
    a, b = d / "a.ply", d / "b.obj"
    assert main(["make-shape", "capsule", str(a), "--resolution", "12"]) == 0
    assert main(["make-shape", "capsule", str(b), "--resolution", "14", "--bend", "30"]) == 0
    return a, b


def test_distance_json_matches_library(pair, capsys):
    a, b = pair
    capsys.readouterr()
    assert main(["distance", str(a), str(b), "--metric", "normal-cycles", "--sigma", "0.3", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    ma, mb = load_mesh(a), load_mesh(b)
    ref = float(
        normal_cycle_distance(
            normal_cycle(ma.vertices, mesh_topology(ma.faces)), normal_cycle(mb.vertices, mesh_topology(mb.faces)), 0.3
        )
    )
    assert out["distance"] == pytest.approx(ref, rel=1e-9)
    assert out["metric"] == "normal-cycles" and out["sigma"] == 0.3
    assert out["n_source"] > 0 and out["n_target"] > out["n_source"] and out["seconds"] > 0


def test_distance_varifold_normalized(pair, capsys):
    a, b = pair
    capsys.readouterr()
    args = ["distance", str(a), str(b), "--metric", "varifold", "--sigma", "0.5", "--sigma-normal", "0.7"]
    assert main(args + ["--normalize", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    ma, mb = load_mesh(a), load_mesh(b)
    n = fit_normalization(ma.vertices, ma.faces)
    ref = float(
        varifold_distance(varifold(n.apply(ma.vertices), ma.faces), varifold(n.apply(mb.vertices), mb.faces), 0.5, 0.7)
    )
    assert out["distance"] == pytest.approx(ref, rel=1e-9) and out["normalized"] is True
    assert main(args) == 0
    assert "varifold distance" in capsys.readouterr().out


def test_distance_with_compression_reports_error(pair, capsys):
    a, b = pair
    capsys.readouterr()
    assert main(["distance", str(a), str(b), "--sigma", "0.3", "--compress", "200", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["compression"]["m"] == 200 and 0 <= out["compression"]["relative_error"] < 0.5


@pytest.mark.parametrize(
    "args, message",
    [
        (["--sigma", "0"], "--sigma must be positive"),
        (["--sigma", "0.2", "--compress", "0"], "--compress must be at least 1"),
    ],
)
def test_distance_bad_settings(pair, capsys, args, message):
    a, b = pair
    assert main(["distance", str(a), str(b)] + args) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


def test_distance_bad_file_exit_code(tmp_path, pair, capsys):
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 2\n")
    assert main(["distance", str(pair[0]), str(bad), "--sigma", "0.2"]) == 2
    err = capsys.readouterr().err.strip()
    assert str(bad) in err and "a face of 2 corners" in err and len(err.splitlines()) == 1


def test_make_shape_writes_loadable_mesh(tmp_path):
    out = tmp_path / "t.off"
    assert main(["make-shape", "tube", str(out), "--resolution", "9"]) == 0
    m = load_mesh(out)
    assert m.n_vertices == 81 and mesh_topology(m.faces).has_boundary
    assert np.allclose(np.linalg.norm(m.vertices[:, :2], axis=1), 0.5)
