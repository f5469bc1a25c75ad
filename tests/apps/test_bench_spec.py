"""The bench grid's specification: scene labels and folders, ``--set`` overrides."""

from __future__ import annotations

import pytest
from _bench_helpers import make_scene

from radar4dgs.apps.bench_spec import BenchError, check_scene, dotted, parse_overrides, scene_labels


def test_scene_labels_are_names_unless_they_clash(tmp_path):
    paths = [tmp_path / "x" / "seed1" / "scene", tmp_path / "x" / "seed2" / "scene", tmp_path / "y" / "drive"]
    assert scene_labels(paths) == ["seed1-scene", "seed2-scene", "drive"]
    assert scene_labels([tmp_path / "a" / "seed3"], reserved=["seed3"]) == ["a-seed3"]
    with pytest.raises(BenchError, match="more than once"):
        scene_labels([tmp_path / "s", tmp_path / "t" / ".." / "s"])


def test_the_demo_layout_prepared_beside_the_scene_is_found(tmp_path):
    scene = make_scene(tmp_path / "demo" / "scene", prepared=False)
    (tmp_path / "demo" / "prepared" / "depth").mkdir(parents=True)
    assert check_scene(scene) == tmp_path / "demo" / "prepared"


def test_set_overrides_parse_to_nested_fields():
    assert parse_overrides(["densify.max_gaussians=40000", "optim.dropout=0.2", "mask_source=gt",
                            "init.source=\"lidar\""]) == {
        "densify": {"max_gaussians": 40000}, "optim": {"dropout": 0.2}, "mask_source": "gt",
        "init": {"source": "lidar"}}
    assert dotted({"densify": {"max_gaussians": 40000}, "seed": 1}) == [("densify.max_gaussians", 40000), ("seed", 1)]
    with pytest.raises(BenchError, match="KEY=VALUE"):
        parse_overrides(["densify.max_gaussians"])
