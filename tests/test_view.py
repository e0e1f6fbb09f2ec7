"""``ncflow view``: the offline HTML page of a result (ncflow.view.page, cli/view.py).

The result folder is built without training: a generated humanoid pair (retriangulated target,
exact ground truth), frames interpolated from the rest source to the posed source, and a map that
is exact except on every seventh target vertex, which is sent to a neighbouring source vertex, so
its geodesic error is known in closed form (the length of that edge over sqrt(source area): the
geodesic between the ends of an edge is the edge). The page's data are decoded in Python and
compared with the result's arrays; the browser tests load the page in headless Chromium.
"""

from __future__ import annotations

import html as html_lib
import json
import re
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from browser_checks import Page as _Page
from browser_checks import browser_test
from ncflow.cli import main
from ncflow.errors import InputError
from ncflow.geometry.barycentric import round_to_vertex, surface_points
from ncflow.geometry.mesh import face_areas
from ncflow.io.result import ResultFolder, read_result, write_result
from ncflow.synthetic.characters import make_character, pose_character
from ncflow.synthetic.pairs import make_pair
from ncflow.view.page import (
    NO_DATA_RGB,
    decode_array,
    dequantize_positions,
    encode_array,
    error_colors,
    quantize_positions,
    write_view,
)

N_FRAMES = 5
WRONG_EVERY = 7

# ----------------------------------------------------------------------------------------------
# The result folder


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    ch = make_character("humanoid", 0, 40)
    pair = make_pair("humanoid", 0, resolution=40, target_resolution=36, character=ch)
    posed = pose_character(ch, pair.info["pose_b"])
    rest, faces = pair.source.vertices, pair.source.faces
    tv, tf = pair.target.vertices, pair.target.faces
    nv, nt = rest.shape[0], tv.shape[0]
    # ground truth as a vertex map: the source vertex nearest each target vertex's true point
    truth = round_to_vertex(faces, pair.ground_truth.face, pair.ground_truth.bary)
    # the predicted map: exactly that vertex, except every 7th target vertex goes to a neighbour
    vertex_face = np.full(nv, -1)
    neighbour = np.full(nv, -1)
    for c in range(3):  # a face around every vertex, and the next corner of that face
        vertex_face[faces[:, c]] = np.arange(len(faces))
        neighbour[faces[:, c]] = faces[:, (c + 1) % 3]
    assert vertex_face.min() >= 0
    pred = truth.copy()
    wrong = np.arange(0, nt, WRONG_EVERY)
    pred[wrong] = neighbour[truth[wrong]]
    face = vertex_face[pred]
    bary = (faces[face] == pred[:, None]).astype(np.float64)
    expected = np.zeros(nt)
    root_area = np.sqrt(face_areas(rest, faces).sum())
    expected[wrong] = np.linalg.norm(rest[truth[wrong]] - rest[pred[wrong]], axis=1) / root_area
    times = np.linspace(0.0, 1.0, N_FRAMES)
    frames = np.stack([(1 - t) * rest + t * posed.vertices for t in times])
    joints = np.stack([(1 - t) * pair.skeleton.positions + t * posed.joints for t in times])
    maps = {
        "map_face": face,
        "map_bary": bary,
        "p2p_tgt_to_src": pred,
        "p2p_src_to_tgt": np.zeros(nv, np.int64),
    }
    base = tmp_path_factory.mktemp("view")
    inputs = dict(
        deformed_source=posed.vertices,
        source_faces=faces,
        maps=maps,
        frames=frames,
        frame_times=times,
        skeleton_target=pair.skeleton.with_positions(posed.joints),
        skeleton_frames=joints,
    )
    result = write_result(base / "result", ResultFolder(target_vertices=tv, target_faces=tf, **inputs))
    old = write_result(base / "old", ResultFolder(**inputs))  # a result without target.ply
    gt = base / "gt.txt"
    gt.write_text("".join(f"{i}\n" for i in truth))
    stored = read_result(result, check_animation=False)  # the PLY files hold float32 coordinates
    return {
        "result": result,
        "old": old,
        "gt": gt,
        "target_file": _target_copy(result, base),
        "rest": stored.frames[0],
        "faces": faces,
        "frames": stored.frames,
        "times": times,
        "joints": joints,
        "parents": pair.skeleton.parents,
        "tv": stored.target_vertices,
        "tf": tf,
        "map_face": face,
        "map_bary": bary,
        "expected": expected,
        "wrong": wrong,
    }


def _target_copy(result: Path, base: Path) -> Path:
    path = base / "target_copy.ply"
    shutil.copyfile(result / "target.ply", path)
    return path


def _page_data(path: Path) -> dict:
    text = path.read_text(encoding="ascii")
    m = re.search(r'<script type="application/json" id="ncflow-data">(.*?)</script>', text, re.S)
    assert m is not None
    return json.loads(m.group(1))


def _positions(spec: dict, data: dict) -> np.ndarray:
    """Decoded positions (n, 3), or frames (K, n, 3) from their (K, 3, n) coordinate planes."""
    q = decode_array(spec)
    if q.ndim == 3:
        q = q.transpose(0, 2, 1)
    return dequantize_positions(q, np.asarray(data["bbox"]["min"]), np.asarray(data["bbox"]["max"]))


def _half_step(data: dict) -> np.ndarray:
    return (np.asarray(data["bbox"]["max"]) - np.asarray(data["bbox"]["min"])) / 65535 / 2 + 1e-12


def _rest_colours(case, face, bary) -> np.ndarray:
    """Position colours of the rest source at surface points: (p - lo) / (hi - lo) per axis."""
    rest = case["rest"]
    lo, hi = rest.min(0), rest.max(0)
    return (surface_points(rest, case["faces"], face, bary) - lo) / (hi - lo)


# ----------------------------------------------------------------------------------------------
# No network reference in the page

# every way a page can reach the network: element sources and links, CSS urls, script imports,
# fetch/XHR/sockets/beacons/workers
_NETWORK = [
    r"<script\b[^>]*\bsrc\s*=",
    r"<link\b",
    r"<iframe\b|<img\b|<object\b|<embed\b|<video\b|<audio\b|<source\b",
    r"\b(?:src|href|action|poster|srcset)\s*=\s*[\"']?\s*(?:https?:|//|ftp:)",
    r"url\(\s*[\"']?\s*(?:https?:|//)",
    r"@import\b",
    r"\bimport\s*\(",
    r"\bimport\b[^;\n]{0,200}?\bfrom\s*[\"']",
    r"\bfetch\s*\(",
    r"XMLHttpRequest",
    r"WebSocket|EventSource|sendBeacon|importScripts|\bWorker\s*\(",
]
# the only absolute addresses allowed: XML namespace names, which browsers never request
_NAMESPACES = {"http://www.w3.org/1999/xhtml", "http://www.w3.org/2000/svg"}


def _network_references(text: str) -> list[str]:
    found = [m.group(0) for pattern in _NETWORK for m in re.finditer(pattern, text, re.I)]
    urls = set(re.findall(r"(?:https?|ftp|wss?)://[^\s\"'<>)]*", text, re.I)) - _NAMESPACES
    return found + sorted(urls)


def test_the_network_check_catches_references():
    for snippet in (
        '<script src="https://cdn.example.com/three.js"></script>',
        '<link rel="stylesheet" href="style.css">',
        "fetch('data.bin')",
        "x = new XMLHttpRequest()",
        'import("./mod.js")',
        'import {a} from "three"',
        "background: url(//example.com/a.png)",
        "see http://example.com",
    ):
        assert _network_references(snippet), snippet
    assert _network_references('document.createElementNS("http://www.w3.org/1999/xhtml", "a")') == []


# ----------------------------------------------------------------------------------------------
# The page's data


def test_array_codec_round_trip_with_wrapping_deltas():
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 65536, size=(6, 3, 50), dtype=np.uint16)  # deltas wrap around 2**16
    spec = encode_array(frames, "uint16", delta=True)
    np.testing.assert_array_equal(decode_array(spec), frames)
    values = rng.normal(size=(7, 3)).astype(np.float32)
    values[2, 1] = np.nan
    np.testing.assert_array_equal(decode_array(encode_array(values, "float32")), values)
    faces = rng.integers(0, 2**32, size=(9, 3), dtype=np.uint64).astype(np.uint32)
    np.testing.assert_array_equal(decode_array(encode_array(faces, "uint32")), faces)
    with pytest.raises(ValueError):
        encode_array(values, "float32", delta=True)


def test_quantised_positions_are_within_half_a_step():
    rng = np.random.default_rng(1)
    p = rng.uniform(-3.0, 5.0, size=(1000, 3))
    p[:, 2] = 0.25  # a flat axis
    lo, hi = p.min(0), p.max(0)
    back = dequantize_positions(quantize_positions(p, lo, hi), lo, hi)
    step = np.where(hi > lo, hi - lo, 0.0) / 65535
    assert np.all(np.abs(back - p) <= step / 2 + 1e-12)
    np.testing.assert_array_equal(back[:, 2], 0.25)


def test_error_colours_turbo_scale_with_grey_for_no_truth():
    import matplotlib

    e = np.array([0.0, 0.1, 0.2, 0.5, np.inf, np.nan])
    rgb = error_colors(e, 0.2)
    turbo = matplotlib.colormaps["turbo"]
    np.testing.assert_array_equal(rgb[0], np.rint(np.asarray(turbo(0.0)[:3]) * 255))
    np.testing.assert_array_equal(rgb[1], np.rint(np.asarray(turbo(0.5)[:3]) * 255))
    for k in (2, 3, 4):  # at and beyond tau_max: the top colour
        np.testing.assert_array_equal(rgb[k], np.rint(np.asarray(turbo(1.0)[:3]) * 255))
    np.testing.assert_array_equal(rgb[5], NO_DATA_RGB)


def test_page_holds_the_result_and_no_network_reference(case, tmp_path):
    out = write_view(case["result"], tmp_path / "v.html", gt=str(case["gt"]), title="<b>x</b></script>")
    text = out.read_text(encoding="ascii")
    assert _network_references(text) == []
    assert "Content-Security-Policy" in text and "default-src 'none'" in text
    assert text.count("<script") == 2 and text.count("</script>") == 2  # the title cannot close a script
    assert "<title>&lt;b&gt;x&lt;/b&gt;&lt;/script&gt; &middot; ncflow view</title>" in text
    data = _page_data(out)
    assert data["format"] == "ncflow-view/1" and data["title"] == "<b>x</b></script>"
    np.testing.assert_allclose(data["times"], case["times"])
    frames, tv = case["frames"], case["tv"]
    nv, nt = frames.shape[1], tv.shape[0]
    # no decimation below the budget: every vertex, the result's faces
    src, tgt = data["source"], data["target"]
    assert src["n_vertices"] == src["n_vertices_original"] == nv
    np.testing.assert_array_equal(decode_array(src["kept"]), np.arange(nv))
    np.testing.assert_array_equal(decode_array(src["faces"]).reshape(-1, 3), case["faces"])
    np.testing.assert_array_equal(decode_array(tgt["faces"]).reshape(-1, 3), case["tf"])
    # positions: every frame and the target, within half a quantisation step of the result
    assert data["frames"]["shape"] == [N_FRAMES, 3, nv]  # coordinate planes
    half = _half_step(data)
    assert np.all(np.abs(_positions(data["frames"], data) - frames) <= half)
    assert np.all(np.abs(_positions(tgt["positions"], data) - tv) <= half)
    # colour coordinates: rest positions normalised per axis; on the target, read at the mapped point
    rest = case["rest"]
    ref_src = decode_array(src["ref"]) / 65535
    np.testing.assert_allclose(ref_src, (rest - rest.min(0)) / (rest.max(0) - rest.min(0)), atol=0.5 / 65535 + 1e-12)
    ref_tgt = decode_array(tgt["ref"]) / 65535
    np.testing.assert_allclose(
        ref_tgt, _rest_colours(case, case["map_face"], case["map_bary"]), atol=0.5 / 65535 + 1e-9
    )
    assert np.all(data["aspect"] <= np.ones(3)) and max(data["aspect"]) == 1.0
    # the skeleton per frame
    sk = data["skeleton"]
    assert sk["parents"] == [int(p) for p in case["parents"]]
    np.testing.assert_allclose(decode_array(sk["positions"]), case["joints"], rtol=1e-6, atol=1e-6)
    # geodesic errors against the closed form; colours on the turbo scale
    err = data["error"]
    values = decode_array(err["values"]).astype(np.float64)
    expected = case["expected"]
    assert values.shape == (nt,) and np.all(expected[case["wrong"]] > 0)
    np.testing.assert_allclose(values, expected, rtol=2e-3, atol=1e-6)
    np.testing.assert_array_equal(decode_array(err["colors"]), error_colors(values, 0.2))
    assert err["tau_max"] == 0.2 and err["ticks"][0] == "0" and err["ticks"][-1].endswith("0.20")
    assert f"mean {expected.mean():.3f}" in err["summary"] and f"{nt} of {nt} target vertices" in err["summary"]


def test_decimated_page_animates_the_kept_vertices(case, tmp_path):
    out = write_view(case["result"], tmp_path / "v.html", gt=str(case["gt"]), max_display_vertices=400)
    data = _page_data(out)
    src, tgt = data["source"], data["target"]
    frames, tv = case["frames"], case["tv"]
    kept = decode_array(src["kept"]).astype(np.int64)
    kept_t = decode_array(tgt["kept"]).astype(np.int64)
    for k, n_original, m in ((kept, frames.shape[1], src), (kept_t, tv.shape[0], tgt)):
        assert m["n_vertices_original"] == n_original and m["n_vertices"] == k.size
        assert 200 <= k.size <= 500 and np.unique(k).size == k.size and k.min() >= 0 and k.max() < n_original
        f = decode_array(m["faces"]).reshape(-1, 3)
        assert f.min() >= 0 and f.max() < k.size and np.unique(f).size == k.size  # every shown vertex is used
    half = _half_step(data)
    assert np.all(np.abs(_positions(data["frames"], data) - frames[:, kept]) <= half)
    assert np.all(np.abs(_positions(tgt["positions"], data) - tv[kept_t]) <= half)
    rest = case["rest"]
    ref = (rest - rest.min(0)) / (rest.max(0) - rest.min(0))
    np.testing.assert_allclose(decode_array(src["ref"]) / 65535, ref[kept], atol=0.5 / 65535 + 1e-12)
    carried = _rest_colours(case, case["map_face"], case["map_bary"])
    np.testing.assert_allclose(decode_array(tgt["ref"]) / 65535, carried[kept_t], atol=0.5 / 65535 + 1e-9)
    values = decode_array(data["error"]["values"]).astype(np.float64)
    np.testing.assert_allclose(values, case["expected"][kept_t], rtol=2e-3, atol=1e-6)


def test_frames_beyond_the_budget_are_subsampled(case, tmp_path):
    out = write_view(case["result"], tmp_path / "v.html", max_display_frames=3)
    data = _page_data(out)
    np.testing.assert_allclose(data["times"], [0.0, 0.5, 1.0])
    shown = _positions(data["frames"], data)
    assert np.all(np.abs(shown - case["frames"][[0, 2, 4]]) <= _half_step(data))
    np.testing.assert_allclose(decode_array(data["skeleton"]["positions"]), case["joints"][[0, 2, 4]], atol=1e-6)
    assert data["error"] is None


# ----------------------------------------------------------------------------------------------
# Command line and bad input


def _run(capsys, *argv) -> tuple[int, str, str]:
    code = main(["view", *map(str, argv)])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_cli_writes_the_page_and_reports_its_size(case, tmp_path, capsys):
    out = tmp_path / "sub" / "page.html"
    code, stdout, err = _run(capsys, case["result"], "--out", out, "--gt", case["gt"], "--gt-format", "index")
    assert code == 0, err
    assert str(out) in stdout and "MiB" in stdout
    assert _page_data(out)["error"] is not None
    # a page of ncflow view is replaced without --overwrite; nothing else is left beside it
    code, _, err = _run(capsys, case["result"], "--out", out, "--title", "again")
    assert code == 0, err
    assert _page_data(out)["title"] == "again" and _page_data(out)["error"] is None
    assert sorted(p.name for p in out.parent.iterdir()) == ["page.html"]


def _one_line_error(code: int, err: str, *words: str) -> None:
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ncflow view: error:"), err
    for w in words:
        assert w in lines[0], lines[0]


def test_cli_refuses_a_file_it_did_not_write(case, tmp_path, capsys):
    out = tmp_path / "notes.html"
    out.write_text("my own notes")
    code, _, err = _run(capsys, case["result"], "--out", out)
    _one_line_error(code, err, "not a page of ncflow view", "--overwrite")
    assert out.read_text() == "my own notes"
    code, _, err = _run(capsys, case["result"], "--out", out, "--overwrite")
    assert code == 0, err
    assert _page_data(out)["format"] == "ncflow-view/1"


def test_result_without_target_needs_the_target_option(case, tmp_path, capsys):
    out = tmp_path / "v.html"
    code, _, err = _run(capsys, case["old"], "--out", out)
    _one_line_error(code, err, "no target.ply", "--target")
    assert not out.exists()
    code, _, err = _run(capsys, case["old"], "--out", out, "--target", case["target_file"])
    assert code == 0, err
    assert np.all(np.abs(_positions(_page_data(out)["target"]["positions"], _page_data(out)) - case["tv"]) < 1e-3)


def test_bad_inputs_are_one_line_errors_and_write_nothing(case, tmp_path, capsys):
    out = tmp_path / "v.html"
    broken = tmp_path / "broken"
    shutil.copytree(case["result"], broken)
    (broken / "map_tgt_to_src.npz").unlink()
    code, _, err = _run(capsys, broken, "--out", out)
    _one_line_error(code, err, "map_tgt_to_src.npz", "missing")
    (broken / "map_tgt_to_src.npz").write_bytes(b"PK\x03\x04 not a zip")
    code, _, err = _run(capsys, broken, "--out", out)
    _one_line_error(code, err, "map_tgt_to_src.npz")
    shutil.copytree(case["result"], broken, dirs_exist_ok=True)
    bary = case["map_bary"].copy()
    bary[3] = [2.0, -0.5, -0.5]  # sums to 1, but not a point of the face
    np.savez(broken / "map_tgt_to_src.npz", face=case["map_face"], bary=bary)
    code, _, err = _run(capsys, broken, "--out", out)
    _one_line_error(code, err, "map_tgt_to_src.npz", "target vertex 3", "not barycentric")
    code, _, err = _run(capsys, tmp_path / "nowhere", "--out", out)
    _one_line_error(code, err, "nowhere")
    short_gt = tmp_path / "short.txt"
    short_gt.write_text("0\n1\n")
    code, _, err = _run(capsys, case["result"], "--out", out, "--gt", short_gt)
    _one_line_error(code, err, "short.txt")
    code, _, err = _run(capsys, case["result"], "--out", out, "--target", short_gt)  # not a mesh
    _one_line_error(code, err, "short.txt")
    code, _, err = _run(capsys, case["result"], "--out", out, "--max-vertices", "5")
    _one_line_error(code, err, "--max-vertices")
    code, _, err = _run(capsys, case["result"], "--out", tmp_path)
    _one_line_error(code, err, "folder")
    code, _, err = _run(capsys, case["result"], "--out", out, "--gt-format", "index")
    _one_line_error(code, err, "--gt")
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken", "short.txt"]
    with pytest.raises(InputError, match="at least 100"):
        write_view(case["result"], out, max_display_vertices=10)


def test_target_of_another_size_is_refused(case, tmp_path, capsys):
    other = tmp_path / "other.ply"
    shutil.copyfile(case["result"] / "frames" / "frame_0000.ply", other)  # the source: another vertex count
    code, _, err = _run(capsys, case["result"], "--out", tmp_path / "v.html", "--target", other)
    _one_line_error(code, err, "other.ply", "not the target of this result")
    assert not (tmp_path / "v.html").exists()


# ----------------------------------------------------------------------------------------------
# In a browser


def _changed(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.mean(np.any(np.abs(a - b) > 8, axis=-1)))


@browser_test
def test_page_renders_animates_and_switches_in_chromium(case, browser, tmp_path):
    out = write_view(case["result"], tmp_path / "v.html", gt=str(case["gt"]))
    view = _Page(browser, out)
    page = view.page
    try:
        start = view.pixels()
        background = np.array([0x1B, 0x1D, 0x23])
        assert np.mean(np.any(np.abs(start - background) > 12, axis=-1)) > 0.04  # the meshes are drawn
        third = start.shape[1] // 3
        # the timeline: drive the slider itself
        page.eval_on_selector(
            "#ncv-time", "el => { el.value = '1000'; el.dispatchEvent(new Event('input', {bubbles: true})); }"
        )
        page.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
        assert page.evaluate("window.ncflowViewer.getTime()") == pytest.approx(1.0)
        assert page.inner_text("#ncv-readout").startswith("t = 1.000")
        end = view.pixels()
        assert _changed(start[:, third : 2 * third], end[:, third : 2 * third]) > 0.01  # the flowed source moved
        assert _changed(start[:, :third], end[:, :third]) < 0.002  # the source did not
        # the skeleton toggle
        page.click("#ncv-skeleton")
        page.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
        no_skeleton = view.pixels()
        assert _changed(end, no_skeleton) > 0.002
        # colours: the checker, then the geodesic error with its colour bar
        assert not page.is_visible("#ncv-colorbar")
        page.select_option("#ncv-mode", "checker")
        page.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
        checker = view.pixels()
        assert _changed(no_skeleton, checker) > 0.02
        page.select_option("#ncv-mode", "error")
        page.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
        assert page.is_visible("#ncv-colorbar")
        assert "geodesic error" in page.inner_text("#ncv-colorbar")
        error = view.pixels()
        assert _changed(checker[:, 2 * third :], error[:, 2 * third :]) > 0.02
        # the overlay: one panel
        page.click("#ncv-overlay")
        page.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
        assert _changed(error, view.pixels()) > 0.02
        assert view.errors == [] and view.requests == [view.url]
    finally:
        page.close()


@browser_test
def test_url_hash_sets_the_view_and_nothing_is_requested_without_the_policy(case, browser, tmp_path):
    out = write_view(case["result"], tmp_path / "v.html")
    # bypass_csp: the page itself must request nothing, not only be stopped by its policy
    view = _Page(browser, out, "#t=0.5&mode=checker&skeleton=0", bypass_csp=True)
    try:
        state = view.page.evaluate("window.ncflowViewer.state()")
        assert state["t"] == pytest.approx(0.5) and state["mode"] == "checker" and state["skeleton"] is False
        assert view.page.evaluate("document.querySelector('#ncv-mode option[value=error]')") is None  # no truth
        frames = view.page.evaluate("window.ncflowViewer.frames")
        assert frames == N_FRAMES
        # keys: the next and previous written frame (frames at t = 0, 0.25, ..., 1)
        view.page.keyboard.press("ArrowRight")
        assert view.page.evaluate("window.ncflowViewer.getTime()") == pytest.approx(0.75)
        view.page.keyboard.press("ArrowLeft")
        view.page.keyboard.press("ArrowLeft")
        assert view.page.evaluate("window.ncflowViewer.getTime()") == pytest.approx(0.25)
        # play moves the time on; pause stops it
        view.page.click("#ncv-play")
        deadline = time.monotonic() + 10
        while view.page.evaluate("window.ncflowViewer.getTime()") == pytest.approx(0.25):
            assert time.monotonic() < deadline, "play did not move the time"
            time.sleep(0.05)
        view.page.click("#ncv-play")
        assert view.page.inner_text("#ncv-play") == "Play"
        paused = view.page.evaluate("window.ncflowViewer.getTime()")
        time.sleep(0.2)
        assert view.page.evaluate("window.ncflowViewer.getTime()") == paused
        view.page.evaluate("window.ncflowViewer.setTime(0.0)")
        a = view.pixels()
        view.page.evaluate("window.ncflowViewer.setTime(0.75)")
        assert _changed(a, view.pixels()) > 0.005
        assert view.errors == [] and view.requests == [view.url]
        assert html_lib.unescape(view.page.title()).endswith("ncflow view")
    finally:
        view.page.close()


def _with_seen(case, tmp_path) -> tuple[Path, np.ndarray]:
    """The case's result folder again with ``source_seen.txt``: the source's upper half shown, the rest not."""
    folder = tmp_path / "partial"
    shutil.copytree(case["result"], folder)
    rest = case["rest"]
    seen = (rest[:, 1] > np.median(rest[:, 1])).astype(np.float64)
    (folder / "source_seen.txt").write_text("".join(f"{v:.4f}\n" for v in seen))
    return folder, seen


def test_page_carries_what_a_partial_target_shows(case, tmp_path):
    folder, seen = _with_seen(case, tmp_path)
    np.testing.assert_array_equal(read_result(folder, check_animation=False).source_seen, seen)
    data = _page_data(write_view(folder, tmp_path / "v.html"))
    kept = decode_array(data["source"]["kept"])
    np.testing.assert_array_equal(decode_array(data["seen"]["values"]), np.rint(seen[kept] * 255))
    whole = _page_data(write_view(case["result"], tmp_path / "w.html"))
    assert whole["seen"] is None  # no source_seen.txt: no such colour mode
    (folder / "source_seen.txt").write_text("".join("1.5\n" for _ in seen))
    with pytest.raises(InputError, match=r"source_seen\.txt.*outside \[0, 1\]"):
        read_result(folder, check_animation=False)


@browser_test
def test_shown_colours_the_source_by_what_the_target_shows_in_chromium(case, browser, tmp_path):
    folder, _ = _with_seen(case, tmp_path)
    view = _Page(browser, write_view(folder, tmp_path / "v.html"))
    page = view.page
    try:
        third = view.pixels().shape[1] // 3
        before = view.pixels()
        page.select_option("#ncv-mode", "shown")
        page.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
        after = view.pixels()
        assert page.evaluate("window.ncflowViewer.state()")["mode"] == "shown"
        assert _changed(before[:, :third], after[:, :third]) > 0.02  # the source is recoloured
        assert _changed(before[:, 2 * third :], after[:, 2 * third :]) < 0.002  # the target is not
        # the source's two colours: orange where shown, blue where not
        src = after[:, :third].reshape(-1, 3).astype(float)
        orange = np.sum((src[:, 0] > src[:, 2] + 60) & (src[:, 0] > 90))
        blue = np.sum((src[:, 2] > src[:, 0] + 40) & (src[:, 2] > 70))
        assert orange > 200 and blue > 200
        assert "shown by the target" in page.inner_text("#ncv-stage")
        assert view.errors == [] and view.requests == [view.url]
    finally:
        page.close()
