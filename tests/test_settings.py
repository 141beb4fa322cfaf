"""One source for every setting: each component's dataclass defaults are what its yaml says."""
import dataclasses
import inspect

import pytest

from asg.perception.config import DetectorConfig, load_detector_config
from asg.generator_config import GenerateConfig, load_generate_config, search_params
from asg.registry import lookup, names
from asg.sensors import LidarSpec, load_lidar_spec


def test_generate_yaml_mirrors_generate_config():
    assert load_generate_config() == GenerateConfig()


def test_detector_yaml_mirrors_detector_config():
    assert load_detector_config() == DetectorConfig()


def test_lidar_preset_mirrors_lidar_spec():
    assert load_lidar_spec("v2xp") == LidarSpec()


def _optimizer_defaults(name: str) -> dict:
    """The optimiser's own default for each of its settings (GA keeps them in GAParams)."""
    from asg.search.genetic import GAParams

    if name == "ga":
        return {f.name: f.default for f in dataclasses.fields(GAParams)}
    sig = inspect.signature(lookup("search", name).__init__).parameters
    return {k: sig[k].default for k in lookup("search", name).settings()}


@pytest.mark.parametrize("name", names("search"))
def test_search_yaml_mirrors_the_optimiser_defaults(name):
    assert search_params(name) == _optimizer_defaults(name)
