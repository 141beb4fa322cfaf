"""Data set selection: the Heuristic set's filters (vehicles in range, the most occluded share)."""
from dataclasses import replace

import pytest

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


@pytest.mark.parametrize("change, says", [
    ({"every": 0}, "every: 0 is out of range"), ({"towns": ()}, "towns: give at least one"),
    ({"towns": ("../x",)}, "not a safe name"), ({"densities": ("rush",)}, "'rush' is not one of"),
    ({"duration_s": 1e9}, "duration_s: 1e+09 is out of range"), ({"ego_rsu_share": 2.0}, "ego_rsu_share: 2"),
    ({"total": 10, "val": 10}, "val: 10 is out of range"), ({"vehicles_in_range": (30, 20)}, "runs from high to low"),
    ({"fewest_points_share": 0.0}, "fewest_points_share: 0 is out of range")])
def test_a_data_set_spec_out_of_range_is_refused(change, says):
    """configs/datasets.yaml's sets are checked when loaded: a frame every 0 periods or a day-long
    log would loop or run for hours before failing."""
    from sumo_scenarios.errors import InputError

    with pytest.raises(InputError, match="datasets.yaml:normal") as error:
        replace(load_spec("normal"), **change).check("datasets.yaml:normal")
    assert says in str(error.value)
