"""One source for every setting: each component's dataclass defaults are what its yaml says."""
import dataclasses
import inspect

import pytest

from asg.perception.config import DetectorConfig, load_detector_config
from asg.generator.config import GenerateConfig, load_generate_config, search_params
from asg.search import SEARCHES
from asg.sensors import LidarSpec, load_lidar_spec


def test_generate_yaml_mirrors_generate_config():
    assert load_generate_config() == GenerateConfig()


def test_detector_yaml_mirrors_detector_config():
    assert load_detector_config() == DetectorConfig()


def test_lidar_preset_mirrors_lidar_spec():
    assert load_lidar_spec("v2xp") == LidarSpec()


def test_the_opencood_training_block_mirrors_its_config():
    from asg.training.config import OpenCOODTrainConfig, load_finetune_config
    from asg.workflows.harden import load_harden_config

    assert load_harden_config().opencood == OpenCOODTrainConfig() == load_finetune_config().opencood


def _optimizer_defaults(name: str) -> dict:
    """The optimiser's own default for each of its settings (GA keeps them in GAParams)."""
    from asg.search.genetic import GAParams

    if name == "ga":
        return {f.name: f.default for f in dataclasses.fields(GAParams)}
    sig = inspect.signature(SEARCHES.entry(name).__init__).parameters
    return {k: sig[k].default for k in SEARCHES.entry(name).settings()}


@pytest.mark.parametrize("name", SEARCHES.names())
def test_search_yaml_mirrors_the_optimiser_defaults(name):
    assert search_params(name) == _optimizer_defaults(name)


def test_the_paper_protocol_is_one_flag(capsys, tmp_path):
    """--protocol paper resolves to the paper's search: BO at 50, turns in 15 deg steps within
    +-45 deg, 3 movers, 2 collaborators, its objective; the GA at 8 x 15 evaluations; flags still win;
    the config's other settings are kept."""
    import numpy as np

    from asg.generator.config import load_generate_config, protocols

    assert "paper" in protocols()
    cfg = load_generate_config(protocol="paper")
    assert (cfg.search, cfg.budget, cfg.acs, cfg.perturbed, cfg.sensing_agents, cfg.lidar) == ("bo", 50, "attention", 3, 3, "v2xp")
    assert cfg.objective.weights == {"0.3": 1.0, "0.5": 0.8, "0.7": 0.5}
    assert (cfg.space.dxy_m, cfg.space.dyaw_deg, cfg.space.dyaw_step_deg) == (2.5, 45.0, 15.0)
    assert np.allclose(np.degrees(cfg.space.yaw_levels() * np.radians(45.0)), [-45, -30, -15, 0, 15, 30, 45])
    assert cfg.space.max_draw_factor == load_generate_config().space.max_draw_factor  # kept from generate.yaml
    assert load_generate_config(protocol="paper", search="ga").budget == 120
    assert load_generate_config(protocol="paper", search="ga", budget=7).budget == 7
    assert load_generate_config().space.yaw_levels() is None  # ours: any turn
    from test_cli import run

    code, err = run(capsys, "generate", "--protocol", "nope", "--out", str(tmp_path / "o"))
    assert code == 2 and "--protocol" in err and not (tmp_path / "o").exists()


def test_turn_steps_hold_in_every_draw():
    """With the turn levels of dyaw_step_deg, every drawn turn is one of them, each level drawn."""
    import numpy as np

    from asg.search.spaces.poses import MoveSlot
    from conftest import car

    slot = MoveSlot(car("v0", 0, 0), np.array([2.5, 2.5, np.radians(45.0)]), np.array([-1.0, -2 / 3, -1 / 3, 0.0, 1 / 3, 2 / 3, 1.0]))
    x = slot.draw(np.random.default_rng(0), 4000)
    turns = np.degrees(x[:, 2] * np.radians(45.0))
    assert np.allclose(turns / 15.0, np.round(turns / 15.0)) and set(np.round(turns).astype(int)) == {-45, -30, -15, 0, 15, 30, 45}
    assert np.abs(x[:, :2]).max() <= 1.0 and len(np.unique(x[:, 0])) > 3000


def test_one_evaluation_range_everywhere():
    """The 48 m evaluation range: the scenes' near radius (sumo_scenarios.log), the ground truth the
    AP counts (asg.perception.data.in_range), the plausibility re-check, and the detectors' BEV grid
    (DetectorConfig and its yaml, pointpillars.yaml) must be one number."""
    import numpy as np

    from asg.perception.config import DetectorConfig, load_detector_config
    from asg.perception.data import in_range
    from asg.scene.feasibility import EVAL_RANGE_M
    from sumo_scenarios.log import NEAR_RADIUS_M

    assert NEAR_RADIUS_M == EVAL_RANGE_M == DetectorConfig().range_m == load_detector_config().range_m
    edge = np.array([[EVAL_RANGE_M, 0, 0, 4, 2, 1.5, 0], [EVAL_RANGE_M + 0.01, 0, 0, 4, 2, 1.5, 0]])
    assert in_range(edge).tolist() == [True, False]
