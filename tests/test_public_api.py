"""The public API: what ``ncflow`` exports (``__all__``) is pinned, so that a change to it is a decision
(and a line of CHANGELOG.md), never an accident of a refactoring."""

import importlib
import inspect

import ncflow

PUBLIC = [
    "Config",
    "InputError",
    "MatchResult",
    "Matcher",
    "Mesh",
    "NcflowError",
    "PointCloud",
    "Skeleton",
    "TrainingError",
    "__version__",
    "compress_normal_cycle",
    "compress_varifold",
    "fit_normalization",
    "load_config",
    "load_mesh",
    "load_skeleton",
    "load_target",
    "match",
    "mesh_topology",
    "normal_cycle",
    "normal_cycle_distance",
    "preset",
    "read_result",
    "rig_result",
    "save_mesh",
    "save_skeleton",
    "track_sequence",
    "transfer",
    "transfer_skin_weights",
    "varifold",
    "varifold_distance",
    "write_view",
]


def test_the_public_names_are_pinned():
    assert sorted(ncflow.__all__) == PUBLIC
    for name in PUBLIC:
        assert getattr(ncflow, name) is not None, name


def test_match_is_a_plain_function_and_the_steps_are_a_package():
    assert inspect.isfunction(ncflow.match)
    assert list(inspect.signature(ncflow.match).parameters) == [
        "source",
        "target",
        "skeleton",
        "config",
        "quiet",
        "stream",
        "start",
    ]
    import ncflow.matcher.prepare as prepare  # the package of the steps stays importable by its dotted name

    assert callable(prepare.prepare)


def test_the_subpackages_export_what_they_say():
    for name in ("config", "evaluate", "runs", "skeleton", "retarget", "view", "matcher", "measures", "flow"):
        module = importlib.import_module(f"ncflow.{name}")
        missing = [n for n in module.__all__ if not hasattr(module, n)]
        assert not missing, (name, missing)
    assert (
        inspect.isfunction(ncflow.transfer) and ncflow.transfer is importlib.import_module("ncflow.retarget").transfer
    )
