"""Skeleton files (TGF, JSON, glTF dispatch), validation errors, placement checks and the CLI."""

import json

import numpy as np
import pytest

from ncflow.cli import main
from ncflow.errors import InputError
from ncflow.geometry.skeleton import Skeleton
from ncflow.io.skeletons import load_skeleton, save_skeleton
from ncflow.skeleton.checks import check_inside
from ncflow.synthetic.shapes import sphere, tube

# a small hand-like tree: root 0, chain 0-1-2, branch 1-3-4, branch 0-5
POS = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 2.0, 0.5], [0.7, 1.5, 0.0], [1.2, 2.0, 0.1], [-0.6, -0.4, 0.2]])
PAR = np.array([-1, 0, 1, 1, 3, 0])
NAMES = ["root", "spine", "head", "arm", "hand", "leg"]


def write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


def assert_one_line_error(exc_info, path, *words):
    msg = str(exc_info.value)
    assert "\n" not in msg
    assert str(path) in msg
    for w in words:
        assert w in msg, msg


# ----------------------------------------------------------------------------------------------
# round trips and accepted variants


def test_tgf_and_json_round_trips(tmp_path):
    radii = np.array([np.nan, 0.05, np.nan, 0.2, 0.1, np.nan])
    skel = Skeleton.from_arrays(POS, PAR, NAMES, radii)
    save_skeleton(tmp_path / "s.tgf", skel)
    save_skeleton(tmp_path / "s.json", skel)
    a = load_skeleton(tmp_path / "s.tgf")
    b = load_skeleton(tmp_path / "s.json")
    for s in (a, b):
        np.testing.assert_array_equal(s.positions, skel.positions)  # repr() keeps every bit
        np.testing.assert_array_equal(s.parents, skel.parents)
    assert a.names is None and a.radii is None  # TGF holds neither
    assert b.names == tuple(NAMES)
    np.testing.assert_array_equal(b.radii, radii)
    np.testing.assert_allclose(b.bone_radii(0.1), [0.05, 0.1, 0.2, 0.1, 0.1])
    text = (tmp_path / "s.tgf").read_text().splitlines()
    assert text[0].startswith("1 ") and text[6] == "#" and text[7] == "1 2"  # 1-based


def test_libigl_tgf_with_flag_columns(tmp_path):
    p = write(
        tmp_path,
        "igl.tgf",
        "1 0 0 0\n2 0 1 0\n3 0 2 0.5\n4 0.7 1.5 0\n5 1.2 2 0.1\n6 -0.6 -0.4 0.2\n#\n"
        "1 2 1 0 0\n2 3 1 0 0\n2 4 1 0 0\n4 5 1 0 0\n1 6 1 0 0\n#\n",
    )
    s = load_skeleton(p)
    np.testing.assert_array_equal(s.positions, POS)
    np.testing.assert_array_equal(s.parents, PAR)
    np.testing.assert_array_equal(s.bones, [[0, 1], [1, 2], [1, 3], [3, 4], [0, 5]])
    np.testing.assert_allclose(s.bone_lengths, np.linalg.norm(POS[1:] - POS[PAR[1:]], axis=1))


def test_zero_based_tgf_equals_one_based(tmp_path):
    one = write(tmp_path, "one.tgf", "1 0 0 0\n2 1 0 0\n3 1 1 0\n#\n1 2\n2 3\n")
    zero = write(tmp_path, "zero.tgf", "0 0 0 0\n1 1 0 0\n2 1 1 0\n#\n0 1\n1 2\n")
    mixed = write(tmp_path, "mixed.tgf", "1 0 0 0\n2 1 0 0\n3 1 1 0\n#\n0 1\n1 2\n")  # ids 1-based, edges 0-based
    ref = load_skeleton(one)
    for p in (zero, mixed):
        s = load_skeleton(p)
        np.testing.assert_array_equal(s.positions, ref.positions)
        np.testing.assert_array_equal(s.parents, [-1, 0, 1])


def test_joints_in_any_order_are_sorted_with_file_mapping(tmp_path):
    # the same tree, node lines shuffled (ids kept), edges referring to ids
    perm = np.array([4, 2, 0, 5, 1, 3])
    ids = perm + 1
    lines = [f"{i} {x} {y} {z}" for i, (x, y, z) in zip(ids, POS[perm])]
    edges = [f"{PAR[j] + 1} {j + 1}" for j in (4, 2, 5, 1, 3)]
    s = load_skeleton(write(tmp_path, "shuffled.tgf", "\n".join(lines + ["#"] + edges) + "\n"))
    assert s.parents[0] == -1 and np.all(s.parents[1:] < np.arange(1, 6))  # topological
    np.testing.assert_array_equal(s.to_file_order(s.positions), POS[perm])  # back to file order
    np.testing.assert_array_equal(s.from_file_order(POS[perm]), s.positions)
    np.testing.assert_array_equal(s.positions[0], POS[0])  # root = node 1
    assert s.label(0) == "node 1"
    # same bones as the unshuffled skeleton (as sets of position pairs)
    ref = Skeleton.from_arrays(POS, PAR)
    key = lambda sk: sorted(tuple(np.r_[sk.positions[a], sk.positions[c]]) for a, c in sk.bones)  # noqa: E731
    assert key(s) == key(ref)


def test_tgf_edges_written_child_to_parent_are_rooted_at_first_node(tmp_path):
    p = write(tmp_path, "rev.tgf", "1 0 0 0\n2 0 1 0\n3 0 2 0\n4 1 1 0\n#\n2 1\n3 2\n4 2\n")
    s = load_skeleton(p)
    np.testing.assert_array_equal(s.parents, [-1, 0, 1, 1])
    np.testing.assert_array_equal(s.positions[0], [0, 0, 0])


# ----------------------------------------------------------------------------------------------
# validation errors (one line each, naming the file)

TGF_OK_NODES = "1 0 0 0\n2 0 1 0\n3 0 2 0\n"
BAD_TGF = {
    "nan": ("1 0 0 0\n2 0 nan 0\n#\n1 2\n", ["node 2", "NaN or infinite"]),
    "inf": ("1 0 0 0\n2 0 inf 0\n#\n1 2\n", ["NaN or infinite"]),
    "edge_out_of_range": (TGF_OK_NODES + "#\n1 2\n2 7\n", ["line 6", "node 7", "out of range"]),
    "undefined_id": ("1 0 0 0\n5 0 1 0\n9 0 2 0\n#\n1 5\n5 4\n", ["node 4", "not defined"]),
    "no_root": (TGF_OK_NODES + "#\n1 2\n2 3\n3 1\n", ["no root"]),
    "several_roots": (TGF_OK_NODES + "4 0 3 0\n#\n1 2\n3 4\n", ["2 root joints", "node 1", "node 3"]),
    "cycle": (TGF_OK_NODES + "4 0 3 0\n#\n2 3\n3 4\n4 2\n", ["cycle", "never reach the root"]),
    "zero_length": ("1 0 0 0\n2 0 1 0\n3 0 1 0\n#\n1 2\n2 3\n", ["zero-length bone", "node 2", "node 3"]),
    "self_parent": (TGF_OK_NODES + "#\n1 2\n2 2\n", ["line 6", "own parent"]),
    "duplicate_edge": (TGF_OK_NODES + "#\n1 2\n2 1\n", ["listed twice"]),
    "bad_line": ("1 0 0\n#\n", ["line 1", "id x y z"]),
    "no_separator": (TGF_OK_NODES, ["no '#' line"]),
    "no_edges": (TGF_OK_NODES + "#\n", ["no edges"]),
    "one_joint": ("1 0 0 0\n#\n1 1\n", ["own parent"]),
}


@pytest.mark.parametrize("case", sorted(BAD_TGF))
def test_bad_tgf_files(tmp_path, case):
    text, words = BAD_TGF[case]
    p = write(tmp_path, f"{case}.tgf", text)
    with pytest.raises(InputError) as exc:
        load_skeleton(p)
    assert_one_line_error(exc, p, *words)


BAD_JSON = {
    "parent_out_of_range": (
        {"parents": [-1, 0, 5], "positions": POS[:3].tolist()},
        ["joint 2", "parent 5", "out of range"],
    ),
    "no_root": ({"parents": [1, 2, 0], "positions": POS[:3].tolist()}, ["no root"]),
    "several_roots": ({"parents": [-1, 0, -1, 2], "positions": POS[:4].tolist()}, ["2 root joints"]),
    "cycle": ({"parents": [-1, 2, 1], "positions": POS[:3].tolist()}, ["cycle", "joint 1", "joint 2"]),
    "zero_length": (
        {"names": ["a", "b", "c"], "parents": [-1, 0, 1], "positions": [[0, 0, 0], [1, 0, 0], [1, 0, 0]]},
        ["zero-length bone", "'b'", "'c'"],
    ),
    "nan": ({"parents": [-1, 0], "positions": [[0, 0, 0], [float("nan"), 0, 0]]}, ["joint 1", "NaN"]),
    "inf": ({"parents": [-1, 0], "positions": [[0, 0, 0], [1e400, 0, 0]]}, ["joint 1", "infinite"]),
    "one_joint": ({"parents": [-1], "positions": [[0, 0, 0]]}, ["at least 2 joints"]),
    "missing_key": ({"positions": POS.tolist()}, ["missing key 'parents'"]),
    "length_mismatch": ({"parents": [-1, 0], "positions": POS[:3].tolist()}, ["'parents' has 2 entries"]),
    "non_int_parents": ({"parents": [-1, 0.5], "positions": POS[:2].tolist()}, ["list of integers"]),
    "bad_positions": ({"parents": [-1, 0], "positions": [[0, 0], [1, 0]]}, ["[x, y, z]"]),
    "names_length": ({"names": ["a"], "parents": [-1, 0], "positions": POS[:2].tolist()}, ["'names' has 1"]),
    "negative_radius": ({"parents": [-1, 0], "positions": POS[:2].tolist(), "radii": [None, -1]}, ["'radii' entry 1"]),
}


@pytest.mark.parametrize("case", sorted(BAD_JSON))
def test_bad_json_files(tmp_path, case):
    data, words = BAD_JSON[case]
    p = write(tmp_path, f"{case}.json", json.dumps(data))
    with pytest.raises(InputError) as exc:
        load_skeleton(p)
    assert_one_line_error(exc, p, *words)


def test_other_load_errors(tmp_path):
    with pytest.raises(InputError) as exc:
        load_skeleton(tmp_path / "missing.tgf")
    assert_one_line_error(exc, tmp_path / "missing.tgf", "no such file")
    p = write(tmp_path, "s.bvh", "HIERARCHY\n")
    with pytest.raises(InputError) as exc:
        load_skeleton(p)
    assert_one_line_error(exc, p, "unsupported skeleton format")
    p = write(tmp_path, "broken.json", "{not json")
    with pytest.raises(InputError) as exc:
        load_skeleton(p)
    assert_one_line_error(exc, p, "not valid JSON")
    p = write(tmp_path, "ok.tgf", TGF_OK_NODES + "#\n1 2\n2 3\n")
    with pytest.raises(InputError) as exc:
        load_skeleton(p, time=1.0)
    assert_one_line_error(exc, p, "glTF")
    with pytest.raises(InputError) as exc:
        save_skeleton(tmp_path / "out.obj", load_skeleton(p))
    assert_one_line_error(exc, tmp_path / "out.obj", ".tgf or .json")


# ----------------------------------------------------------------------------------------------
# placement against a mesh


def test_check_inside_closed_and_open_meshes():
    v, f = sphere(3, radius=1.0)
    inside = Skeleton.from_arrays([[0, 0, 0], [0.5, 0, 0], [0, 0.5, 0.2]], [-1, 0, 0])
    assert check_inside(inside, v, f) == []
    on_surface = Skeleton.from_arrays([[0, 0, 0], [0, 0, 1.0]], [-1, 0])  # a tip joint on a vertex
    assert check_inside(on_surface, v, f) == []
    outside = Skeleton.from_arrays([[0, 0, 0], [0.5, 0, 0], [1.6, 0, 0]], [-1, 0, 1], ["a", "b", "tip"])
    w = check_inside(outside, v, f)
    assert len(w) == 1 and "'tip'" in w[0] and "outside" in w[0]
    dist = float(w[0].split("distance ")[1].split(",")[0])
    assert abs(dist - 0.6) < 0.01  # icosphere faces lie slightly inside the unit sphere
    # open tube along z (radius 0.5, length 2): winding number still ~0.7-0.9 on the axis
    v, f = tube(0.5, 2.0)
    near = Skeleton.from_arrays([[0, 0, -0.8], [0, 0, 0.8], [0.53, 0, 0.8]], [-1, 0, 1])  # last: just outside
    assert check_inside(near, v, f) == []
    far = Skeleton.from_arrays([[0, 0, 0], [0, 0, 3.0]], [-1, 0])
    w = check_inside(far, v, f)
    assert len(w) == 1 and "joint 1" in w[0] and "outside the (open) mesh" in w[0]
    assert abs(float(w[0].split("distance ")[1].split(",")[0]) - np.sqrt(4.25)) < 1e-3  # to the end rim


# ----------------------------------------------------------------------------------------------
# CLI


def test_cli_info(tmp_path, capsys):
    p = tmp_path / "s.json"
    save_skeleton(p, Skeleton.from_arrays(POS, PAR, NAMES))
    assert main(["skeleton", "info", str(p)]) == 0
    out = capsys.readouterr().out
    assert "joints: 6   bones: 5   root: joint 0 ('root')" in out
    assert "joint 3 ('arm') -> joint 4 ('hand'): 0.714143" in out  # |(0.5, 0.5, 0.1)|
    assert main(["skeleton", "info", str(p), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["n_joints"] == 6 and data["n_bones"] == 5 and data["depth"] == 3
    np.testing.assert_allclose([b["length"] for b in data["bones"]], np.linalg.norm(POS[1:] - POS[PAR[1:]], axis=1))
    assert data["warnings"] == []


def test_cli_info_with_mesh_warns(tmp_path, capsys):
    from ncflow.io.meshes import save_mesh

    v, f = sphere(2, radius=1.0)
    mesh = tmp_path / "ball.ply"
    save_mesh(mesh, v, f)
    p = write(tmp_path, "s.tgf", "1 0 0 0\n2 0.5 0 0\n3 2 0 0\n#\n1 2\n2 3\n")
    assert main(["skeleton", "info", str(p), "--mesh", str(mesh)]) == 0
    out = capsys.readouterr().out
    assert "1 warning(s)" in out and "warning: node 3 is outside the mesh" in out


def test_cli_convert_round_trip(tmp_path, capsys):
    src = write(
        tmp_path,
        "in.tgf",
        "2 0 1 0\n1 0 0 0\n3 0 2 0.5\n#\n1 2 1 0 0\n2 3 1 0 0\n",
    )
    js, tgf = tmp_path / "out.json", tmp_path / "back.tgf"
    assert main(["skeleton", "convert", str(src), str(js)]) == 0
    assert main(["skeleton", "convert", str(js), str(tgf)]) == 0
    assert "3 joints, 2 bones" in capsys.readouterr().out
    data = json.loads(js.read_text())
    assert data["parents"] == [-1, 0, 1]
    np.testing.assert_array_equal(data["positions"], [[0, 0, 0], [0, 1, 0], [0, 2, 0.5]])
    assert tgf.read_text() == "1 0.0 0.0 0.0\n2 0.0 1.0 0.0\n3 0.0 2.0 0.5\n#\n1 2\n2 3\n#\n"


def test_cli_bad_file_exits_2_with_one_line(tmp_path, capsys):
    p = write(tmp_path, "loop.json", json.dumps({"parents": [1, 2, 0], "positions": POS[:3].tolist()}))
    assert main(["skeleton", "info", str(p)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err
    assert err.startswith("ncflow skeleton: error:") and str(p) in err and "no root" in err
    assert main(["skeleton", "convert", str(p), str(tmp_path / "x.obj")]) == 2
    assert ".tgf or .json" in capsys.readouterr().err


def test_bone_hops_against_a_walk_over_the_joints():
    """Joints between two bones, against a breadth-first walk over joints (a bone's walk starts at both of
    its ends; the hops to another bone are the fewest joints stepped to reach one of its ends, plus one)."""
    rng = np.random.default_rng(3)
    parents = np.array([-1] + [int(rng.integers(0, j)) for j in range(1, 15)])
    skel = Skeleton.from_arrays(rng.normal(size=(15, 3)), parents)
    neighbours = [set() for _ in range(15)]
    for j in range(1, 15):
        neighbours[j].add(int(parents[j]))
        neighbours[int(parents[j])].add(j)

    def joint_steps(starts):
        dist, frontier = {s: 0 for s in starts}, list(starts)
        while frontier:
            nxt = []
            for j in frontier:
                for k in neighbours[j]:
                    if k not in dist:
                        dist[k] = dist[j] + 1
                        nxt.append(k)
            frontier = nxt
        return dist

    bones, hops = skel.bones, skel.bone_hops
    for a in range(skel.n_bones):
        steps = joint_steps(set(bones[a]))
        for b in range(skel.n_bones):
            expected = 0 if a == b else 1 + min(steps[int(j)] for j in bones[b])
            assert hops[a, b] == expected, (a, b)
    chain = Skeleton.from_arrays(np.zeros((4, 3)) + np.arange(4)[:, None], [-1, 0, 1, 2])
    np.testing.assert_array_equal(chain.bone_hops, [[0, 1, 2], [1, 0, 1], [2, 1, 0]])
