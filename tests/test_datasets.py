"""Data set selection: the Heuristic set's filters (vehicles in range, the most occluded share)."""
from dataclasses import replace

from asg.datasets import DatasetSpec, _fewest_points, _kept, load_spec
from asg.scene import Scene

from test_robustness import _scene_dict


def test_vehicles_in_range_filter():
    scene = Scene.from_dict(_scene_dict())  # an RSU ego and 9 vehicles around it
    spec = DatasetSpec(towns=("x",))
    assert _kept(replace(spec, vehicles_in_range=(5, 30)), scene)
    assert not _kept(replace(spec, vehicles_in_range=(20, 30)), scene)


def test_fewest_points_keeps_that_share_in_log_order():
    logs = [("a", [{"scene_id": "a1", "mean_points_in_box": 50.0}, {"scene_id": "a2", "mean_points_in_box": 5.0}]),
            ("b", [{"scene_id": "b1", "mean_points_in_box": 7.0}, {"scene_id": "b2", "mean_points_in_box": 90.0}])]
    kept = _fewest_points(DatasetSpec(towns=("x",), fewest_points_share=0.5), logs)
    assert [[d["scene_id"] for d in dicts] for _, dicts in kept] == [["a2"], ["b1"]]
    assert _fewest_points(DatasetSpec(towns=("x",)), logs) == logs


def test_heuristic_spec_is_held_out_and_never_trains():
    heuristic, train, normal = load_spec("heuristic"), load_spec("detector-train"), load_spec("normal")
    assert not set(heuristic.towns) & set(train.towns) and len(heuristic.towns) >= 4
    assert "suburb" not in normal.towns and heuristic.split == "test" and heuristic.max_logs == 14


def test_holdout_town_is_in_no_other_set():
    import yaml

    from sumo_scenarios.paths import configs_dir

    names = list(yaml.safe_load((configs_dir() / "datasets.yaml").read_text()))
    holdout = load_spec("holdout")
    others = {t for name in names if name != "holdout" for t in load_spec(name).towns}
    assert holdout.towns and not set(holdout.towns) & others and holdout.split == "test"
