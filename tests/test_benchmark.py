"""``ncflow benchmark``: a two-pair run on tiny capsule pairs, interruption and resume, the report."""

import json

import numpy as np
import pytest
from matplotlib.image import imread

import ncflow.runs.benchmark as bench
from ncflow.cli import build_parser, main
from ncflow.cli.options import config_from_args
from ncflow.config import preset
from ncflow.evaluate import ground_truth_from_vertex_map
from ncflow.evaluate.aggregate import aggregate_rows, mean_curve_band
from ncflow.geometry.mesh import Mesh
from ncflow.skeleton import Skeleton
from ncflow.synthetic.pairs import Pair, write_pairs
from ncflow.synthetic.shapes import bend, capsule

# a tiny configuration: one data term (one compiled step), small nets, few samples, 20 steps, no rigid
# placement and no pose search (the capsule pairs need neither; these tests are about the benchmark's
# bookkeeping, and test_placement.py, test_pose_search.py and test_invariance.py test those stages).
# The runs happen in Dask worker processes, which share the test run's compilation cache
# ($NCFLOW_CACHE_DIR/jax, see conftest.py): both pairs share their source, so the second pair's training
# step (and every later run's) is read back instead of compiled again (~20 s each).
TINY = [
    "--steps",
    "20",
    "--frames",
    "3",
    "--metric",
    "varifold",
    "--set",
    "flow.width=16",
    "--set",
    "flow.depth=2",
    "--set",
    "flow.gso_width=8",
    "--set",
    "flow.gso_depth=1",
    "--set",
    "sampling.bone_samples=8",
    "--set",
    "sampling.tissue_samples=32",
    "--set",
    "sampling.surface_edges=128",
    "--set",
    "compress=500",
    "--set",
    "placement=none",
    "--set",
    "pose_search=false",
]


@pytest.fixture(scope="module")
def pairs_csv(tmp_path_factory):
    """Two capsule pairs (same source and skeleton, targets bent by 30 and 50 degrees; identity ground truth).
    Neither target passes through itself, so both take the bone weights of the current place and one
    training step serves both (a bend of 55° or more would switch the second to the weights at the
    start: another program, compiled again).
    """
    vs, fs = capsule(radius=0.4, length=3.0, n_around=10, n_along=12)
    source = Mesh(vs, fs, "capsule")
    skel = Skeleton.from_arrays(np.array([[0, 0, -1.6], [0, 0, 0.0], [0, 0, 1.6]]), np.array([-1, 0, 1]))
    gt = ground_truth_from_vertex_map(np.arange(len(vs)), source, len(vs))
    pairs = [
        Pair(f"bend_{a}", source, Mesh(bend(vs, float(a)), fs, f"bend_{a}"), skel, gt, "capsule") for a in (30, 50)
    ]
    return write_pairs(pairs, tmp_path_factory.mktemp("pairs"))


def _mtimes(run_dir):
    return {p.name: p.stat().st_mtime_ns for p in run_dir.iterdir() if p.is_file()}


def _rows(report, method="ncflow"):
    return {r["pair"]: r for r in report["runs"] if r["method"] == method}


def test_benchmark_interrupted_then_resumed(pairs_csv, tmp_path, capsys):
    out = tmp_path / "bench"
    args = ["benchmark", str(pairs_csv), "--out", str(out), *TINY]
    runs = out / "runs" / "ncflow"

    # 1) Ctrl-C as soon as the first run is reported (the second is then waiting or running, --jobs 1):
    #    the first run is complete, nothing of the second, and the report is written all the same
    def interrupt(line):
        if line.startswith("[1/2]"):
            raise KeyboardInterrupt

    cfg = config_from_args(build_parser().parse_args(args))
    with pytest.raises(KeyboardInterrupt):
        bench.run_benchmark(pairs_csv, out, cfg, jobs=1, progress=False, log=interrupt)
    assert (runs / "bend_30" / "evaluation.json").is_file() and not (runs / "bend_50").exists()
    rows = _rows(json.loads((out / "report.json").read_text()))
    assert rows["bend_30"]["status"] == "ok"
    assert rows["bend_50"]["status"] == "failed" and "interrupted" in rows["bend_50"]["error"]
    first = _mtimes(runs / "bend_30")

    # 2) the same command again: only the second pair is matched and evaluated
    assert main(args) == 0
    assert _mtimes(runs / "bend_30") == first
    printed = capsys.readouterr().out
    assert "ncflow/bend_30: skipped" in printed and "ncflow/bend_50: matched" in printed

    # 3) a lost evaluation.json: re-evaluated from the saved result (no new match), in 2 worker processes
    (runs / "bend_30" / "evaluation.json").unlink()
    second = _mtimes(runs / "bend_50")
    assert main([*args, "--jobs", "2"]) == 0
    after = _mtimes(runs / "bend_30")
    assert after["deformed_source.ply"] == first["deformed_source.ply"]
    assert after["evaluation.json"] > first["evaluation.json"]
    assert _mtimes(runs / "bend_50") == second
    printed = capsys.readouterr().out
    assert "ncflow/bend_30: evaluated" in printed and "ncflow/bend_50: skipped" in printed

    # the report: both pairs, the method, the dataset, numbers equal to the per-run evaluations
    report = json.loads((out / "report.json").read_text())
    assert [m["id"] for m in report["methods"]] == ["ncflow"] and report["datasets"] == ["capsule"]
    rows = _rows(report)
    assert set(rows) == {"bend_30", "bend_50"} and all(r["status"] == "ok" for r in rows.values())
    aucs = []
    for name, row in rows.items():
        ev = json.loads((runs / name / "evaluation.json").read_text())
        assert ev["benchmark"] == {"method": "ncflow", "pair": name, "dataset": "capsule"}
        for key in ("geodesic_auc", "chamfer_auc", "conformal_auc", "geodesic_mean", "max_bone_violation_ratio"):
            assert row[key] == pytest.approx(ev["headline"][key], rel=1e-12)
        assert row["match_seconds"] == pytest.approx(ev["timings"]["match"])
        assert 0.0 < row["geodesic_auc"] <= 1.0 and row["max_bone_violation_ratio"] >= 0.0
        aucs.append(row["geodesic_auc"])
    (summary,) = report["summary"]
    assert (summary["method"], summary["dataset"], summary["n"], summary["n_failed"]) == ("ncflow", "capsule", 2, 0)
    assert summary["geodesic_auc"]["mean"] == pytest.approx(np.mean(aucs))
    assert summary["geodesic_auc"]["std"] == pytest.approx(np.std(aucs, ddof=1))
    assert summary["max_bone_violation_ratio"]["max"] == pytest.approx(
        max(r["max_bone_violation_ratio"] for r in rows.values())
    )
    md = (out / "report.md").read_text()
    assert "## capsule" in md and "| ncflow | 2 |" in md and "bend_30" in md and "bend_50" in md
    assert f"{np.mean(aucs):.3f} ± {np.std(aucs, ddof=1):.3f}" in md
    img = imread(out / report["plots"]["capsule"])
    assert img.shape[0] >= 300 and img.shape[1] >= 1000 and img[..., :3].std() > 0.02

    # a different configuration is refused before anything runs
    assert main(["benchmark", str(pairs_csv), "--out", str(out), *TINY[2:], "--steps", "21"]) == 2
    assert "another configuration" in capsys.readouterr().err


@pytest.mark.parametrize(
    "content, message",
    [
        ("name,source,target,gt\nx,a.ply,b.ply,identity\n", "missing column(s) skeleton"),
        ("name,source,target,skeleton,gt\nx,nope.ply,b.ply,s.tgf,identity\n", "line 2: source file not found"),
        ("name,source,target,skeleton,gt\n", "no pairs listed"),
        ("name,source,target,skeleton,gt,gt_format\nx,s.tgf,s.tgf,s.tgf,identity,weird\n", "unknown gt_format 'weird'"),
        (
            "name,source,target,skeleton,gt\nx,s.tgf,s.tgf,s.tgf,identity\nx,s.tgf,s.tgf,s.tgf,identity\n",
            "duplicate pair name",
        ),
    ],
)
def test_bad_csv_one_line_error_before_anything_runs(tmp_path, capsys, monkeypatch, content, message):
    (tmp_path / "s.tgf").write_text("0 0 0\n0 0 1\n#\n1 2\n")
    csv_path = tmp_path / "pairs.csv"
    csv_path.write_text(content)
    monkeypatch.setattr(bench, "run_task", lambda t: pytest.fail("a run started"))
    out = tmp_path / "bench"
    assert main(["benchmark", str(csv_path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and "pairs.csv" in err, err
    assert not out.exists()


def test_ablation_methods_are_the_table_1_rows(capsys):
    base = preset("fast")
    methods = bench.benchmark_methods(base, ablations=True)
    got = {m.label: ({p.metric for p in m.config.phases}, m.config.interp, m.config.constraints.mode) for m in methods}
    assert got == {
        "Var+SLERP+soft": ({"varifold"}, "slerp", "soft"),
        "Var+DQ": ({"varifold"}, "sclerp", "soft"),
        "Var+DQ+CO": ({"varifold"}, "sclerp", "mdmm"),
        "NC+DQ+CO": ({"normal-cycles"}, "sclerp", "mdmm"),
        "full": ({"varifold", "auto"}, "sclerp", "mdmm"),
    }
    assert methods[-1].config == base and len({m.id for m in methods}) == 5
    # every other setting is the base configuration's
    assert all(m.config.flow == base.flow and m.config.total_steps == base.total_steps for m in methods)
    assert main(["benchmark", "pairs.csv", "--out", "x", "--ablations", "--metric", "varifold"]) == 2
    assert "--ablations sets --metric" in capsys.readouterr().err


def test_aggregation_per_method_and_dataset_and_bands():
    def row(method, dataset, g, bone):
        return {
            "method": method,
            "dataset": dataset,
            "status": "ok",
            "geodesic_auc": g,
            "chamfer_auc": 0.5,
            "conformal_auc": float("nan"),
            "geodesic_mean": 0.1,
            "chamfer_mean": 0.2,
            "conformal_mean": 0.3,
            "max_bone_violation_ratio": bone,
            "match_seconds": 1.0,
            "evaluate_seconds": 0.5,
            "wall_seconds": 1.5,
        }

    rows = [
        row("a", "hand", 0.9, 1.0),
        row("a", "hand", 0.7, 3.0),
        row("a", "body", 0.5, 2.0),
        {"method": "a", "dataset": "body", "status": "failed"},
    ]
    out = {(e["method"], e["dataset"]): e for e in aggregate_rows(rows, ["a"])}
    assert set(out) == {("a", "body"), ("a", "hand"), ("a", "all")}
    hand, body, every = out[("a", "hand")], out[("a", "body")], out[("a", "all")]
    assert hand["geodesic_auc"]["mean"] == pytest.approx(0.8) and hand["geodesic_auc"]["std"] == pytest.approx(
        np.sqrt(0.02)
    )
    assert (body["n"], body["n_failed"]) == (1, 1) and np.isnan(body["geodesic_auc"]["std"])
    assert every["n"] == 3 and every["geodesic_auc"]["mean"] == pytest.approx(0.7)
    assert every["max_bone_violation_ratio"]["max"] == 3.0 and np.isnan(every["conformal_auc"]["mean"])

    curves = np.random.default_rng(0).uniform(size=(6, 11)).cumsum(axis=1) / 11
    mean, lo, hi = mean_curve_band(curves)
    np.testing.assert_allclose(mean, curves.mean(0))
    assert np.all(lo <= mean + 1e-12) and np.all(mean <= hi + 1e-12) and np.all(hi - lo > 0)
    one, lo1, hi1 = mean_curve_band(curves[:1])
    np.testing.assert_array_equal(lo1, one)
    np.testing.assert_array_equal(hi1, one)
