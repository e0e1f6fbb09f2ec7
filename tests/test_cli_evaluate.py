"""``ncflow evaluate`` on synthetic result folders: a perfect result, a shifted map, bad inputs."""

import json
import math
import shutil

import numpy as np
import pytest
from matplotlib.image import imread

from ncflow.cli import main
from ncflow.evaluate.plots import EVALUATION_PLOTS
from ncflow.evaluate.score import EVALUATION_FILE
from ncflow.io.arrays import json_safe
from ncflow.io.meshes import save_mesh
from ncflow.io.result import ResultFolder, write_result
from ncflow.matcher.correspondence import correspondence_maps
from ncflow.synthetic.shapes import capsule

EPS = 3e-4
BONE = {
    "bone": "root -> tip",
    "g_endpoint": 1e-4,
    "g_trajectory": 1.5e-4,
    "rms_distance_endpoint": 0.01,
    "satisfied": True,
}
CONSTRAINTS = {"mode": "mdmm", "eps": EPS, "max_violation_ratio": 0.5, "all_satisfied": True, "bones": [BONE]}


def _rotation(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _strict_loads(text: str):
    def refuse(name):
        raise ValueError(f"non-standard JSON constant {name}")

    return json.loads(text, parse_constant=refuse)


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """Source capsule, its rigidly moved copy as target, and result folders (perfect and shifted map)."""
    d = tmp_path_factory.mktemp("evaluate")
    vs, fs = capsule(radius=0.4, length=2.0, n_around=10, n_along=8)
    times = np.linspace(0.0, 1.0, 3)
    shift = np.array([0.5, 0.2, -0.3])
    frames = np.stack([vs @ _rotation(0.6 * t).T + t * shift for t in times])  # rigid at every time
    target = frames[-1]
    save_mesh(d / "source.ply", vs, fs)
    save_mesh(d / "target.ply", target, fs)
    maps = correspondence_maps(vs, fs, target, target, fs)
    common = {"deformed_source": target, "source_faces": fs, "frames": frames, "frame_times": times}
    write_result(d / "perfect", ResultFolder(maps=maps, metrics={"constraints": CONSTRAINTS}, **common))
    shifted = dict(maps, map_face=np.roll(maps["map_face"], 7), map_bary=np.roll(maps["map_bary"], 7, axis=0))
    write_result(d / "shifted", ResultFolder(maps=shifted, **common))
    return d, vs, fs


def _evaluate(d, name, *extra):
    return main(
        [
            "evaluate",
            str(d / name),
            "--source",
            str(d / "source.ply"),
            "--target",
            str(d / "target.ply"),
            "--gt",
            "identity",
            *extra,
        ]
    )


def _image(path):
    img = imread(path)
    assert img.ndim == 3 and img.shape[0] >= 300 and img.shape[1] >= 900, img.shape
    assert np.ptp(img[..., :3]) > 0.5 and img[..., :3].std() > 0.02  # not a blank picture
    return img


def _panels_differ(img) -> float:
    """Mean absolute difference between the 'predicted' and 'ground truth' panels (below the titles)."""
    h, w = img.shape[:2]
    third = w // 3
    rows = slice(int(0.15 * h), h)
    return float(np.abs(img[rows, third : 2 * third, :3] - img[rows, 2 * third : 3 * third, :3]).mean())


def test_perfect_result_scores_perfectly(case, capsys):
    d, vs, fs = case
    assert _evaluate(d, "perfect") == 0
    out = capsys.readouterr().out
    assert "AUC(0.20) 1.000" in out and "wrote evaluation.json" in out
    rec = _strict_loads((d / "perfect" / EVALUATION_FILE).read_text())
    h = rec["headline"]
    assert h["geodesic_auc"] > 1 - 1e-6 and h["geodesic_mean"] < 1e-6
    assert h["chamfer_mean"] < 1e-6 and h["chamfer_auc"] > 1 - 1e-5  # PLY stores float32 coordinates
    assert h["conformal_mean"] < 1e-5 and h["conformal_auc"] > 1 - 1e-4  # rigid frames: no distortion
    assert rec["summary"]["inverted_triangles"] == [0, 0, 0]
    assert max(abs(x) for x in rec["summary"]["volume_change"]) < 1e-5
    assert rec["n_frames"] == 3 and rec["n_target"] == len(vs) and rec["n_ground_truth"] == len(vs)
    # the conformal statistics run over all frames x triangles
    assert rec["summary"]["conformal"]["n"] == 3 * len(fs)
    # bones come from metrics.json: ratio max(g_ep, g_tr)/eps, rms in unit-cube units
    b = rec["bones"]
    assert b["max_violation_ratio"] == 0.5 and b["per_bone"][0]["ratio"] == pytest.approx(1.5e-4 / EPS)
    assert b["per_bone"][0]["rms_distance_unit_cube"] == pytest.approx(0.01 * rec["summary"]["unit_cube_scale"])
    # curves: PCK = 1 at every threshold above 0 for a perfect map
    geo = rec["curves"]["geodesic"]
    assert len(geo["tau"]) == 101 and geo["tau"][-1] == pytest.approx(0.2) and min(geo["pck"][1:]) == 1.0
    assert rec["non_finite_as_null"] == []
    assert set(rec["plots"]) == set(EVALUATION_PLOTS)
    for name in EVALUATION_PLOTS.values():
        _image(d / "perfect" / name)
    # the colour transfer through the predicted map looks like the one through the ground truth
    assert _panels_differ(imread(d / "perfect" / EVALUATION_PLOTS["color_transfer"])) < 0.01


def test_shifted_map_scores_lower_and_json_output(case, capsys):
    d, *_ = case
    assert _evaluate(d, "shifted", "--json") == 0
    printed = _strict_loads(capsys.readouterr().out)
    rec = _strict_loads((d / "shifted" / EVALUATION_FILE).read_text())
    assert printed == rec
    assert rec["headline"]["geodesic_auc"] < 0.8 and rec["headline"]["geodesic_mean"] > 0.1
    # Chamfer and distortion do not depend on the map
    assert rec["headline"]["chamfer_auc"] > 1 - 1e-5
    assert rec["bones"] is None  # no constraints in metrics.json
    assert _panels_differ(_image(d / "shifted" / EVALUATION_PLOTS["color_transfer"])) > 0.02


def _assert_one_line_error(capsys, *needles):
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for n in needles:
        assert n in err, err


def test_wrong_size_ground_truth_exit_2_nothing_written(case, tmp_path, capsys):
    d, vs, _ = case
    res = tmp_path / "res"
    shutil.copytree(d / "shifted", res)
    for f in [EVALUATION_FILE, *EVALUATION_PLOTS.values()]:
        (res / f).unlink(missing_ok=True)
    before = sorted(p.name for p in res.iterdir())
    gt = tmp_path / "short.txt"
    gt.write_text("".join(f"{i}\n" for i in range(len(vs) - 1)))
    rc = main(
        ["evaluate", str(res), "--source", str(d / "source.ply"), "--target", str(d / "target.ply"), "--gt", str(gt)]
    )
    assert rc == 2
    _assert_one_line_error(capsys, "short.txt", f"expected {len(vs)}", f"got {len(vs) - 1}")
    assert sorted(p.name for p in res.iterdir()) == before  # no evaluation.json, no plots, no temporary files


def test_missing_result_file_exit_2(case, tmp_path, capsys):
    d, *_ = case
    res = tmp_path / "res"
    shutil.copytree(d / "shifted", res)
    (res / EVALUATION_FILE).unlink()
    (res / "map_tgt_to_src.npz").unlink()
    assert (
        main(
            [
                "evaluate",
                str(res),
                "--source",
                str(d / "source.ply"),
                "--target",
                str(d / "target.ply"),
                "--gt",
                "identity",
            ]
        )
        == 2
    )
    _assert_one_line_error(capsys, "map_tgt_to_src.npz", "missing result file")
    assert not (res / EVALUATION_FILE).exists()


def test_wrong_source_mesh_exit_2(case, tmp_path, capsys):
    d, *_ = case
    other_v, other_f = capsule(radius=0.4, length=2.0, n_around=8, n_along=8)
    save_mesh(tmp_path / "other.ply", other_v, other_f)
    assert (
        main(
            [
                "evaluate",
                str(d / "perfect"),
                "--source",
                str(tmp_path / "other.ply"),
                "--target",
                str(d / "target.ply"),
                "--gt",
                "identity",
                "--no-plots",
            ]
        )
        == 2
    )
    _assert_one_line_error(capsys, "other.ply", "not the source of this result")


def test_json_safe_replaces_non_finite_values_and_lists_them():
    value = {"a": [1.0, float("nan")], "b": {"c": np.float64(np.inf), "d": np.arange(2)}, "e": (np.True_, 3)}
    safe, replaced = json_safe(value)
    assert safe == {"a": [1.0, None], "b": {"c": None, "d": [0, 1]}, "e": [True, 3]}
    assert replaced == ["a[1]", "b.c"]
    json.dumps(safe, allow_nan=False)


def test_flat_sheet_volume_change_written_as_null_and_reported(tmp_path, capsys):
    # a flat sheet encloses no volume: its volume change is NaN, which strict JSON writes as null
    n = 6
    x, y = np.meshgrid(np.linspace(0.0, 1.0, n), np.linspace(0.0, 1.0, n))
    vs = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    fs = np.concatenate([np.stack([a, a + 1, a + n + 1], 1), np.stack([a, a + n + 1, a + n], 1)])
    target = vs + np.array([0.1, 0.0, 0.3])
    save_mesh(tmp_path / "s.ply", vs, fs)
    save_mesh(tmp_path / "t.ply", target, fs)
    maps = correspondence_maps(vs, fs, target, target, fs)
    write_result(
        tmp_path / "res",
        ResultFolder(
            deformed_source=target,
            source_faces=fs,
            maps=maps,
            frames=np.stack([vs, target]),
            frame_times=np.array([0.0, 1.0]),
        ),
    )
    assert (
        main(
            [
                "evaluate",
                str(tmp_path / "res"),
                "--source",
                str(tmp_path / "s.ply"),
                "--target",
                str(tmp_path / "t.ply"),
                "--gt",
                "identity",
                "--no-plots",
            ]
        )
        == 0
    )
    assert "3 non-finite value(s) written as null" in capsys.readouterr().out
    rec = _strict_loads((tmp_path / "res" / EVALUATION_FILE).read_text())
    assert rec["summary"]["volume_change"] == [None, None]
    assert rec["non_finite_as_null"] == [
        "headline.max_abs_volume_change",
        "summary.volume_change[0]",
        "summary.volume_change[1]",
    ]
    assert rec["headline"]["max_abs_volume_change"] is None and rec["headline"]["geodesic_auc"] > 1 - 1e-6
    assert rec["plots"] == {} and not any(p.suffix == ".png" for p in (tmp_path / "res").iterdir())
