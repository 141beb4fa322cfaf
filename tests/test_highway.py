import pytest

from asg.scene.from_log import ExtractParams, extract_scenes
from sumo_scenarios.errors import InputError
from sumo_scenarios.highway import HighwayRequest, simulate_highway
from sumo_scenarios.log import open_log


@pytest.mark.slow
def test_sixty_seconds_of_highway_env(highway_log):
    log = open_log(highway_log)
    frames = list(log.frames())
    assert len(frames) == 121
    assert max(len(f.vehicles) for f in frames) >= 5
    assert log.meta.source == "highway-env" and log.meta.env == "intersection-v0"
    assert log.rsus and log.buildings and log.lane_map.lanes
    # vehicles sit on the recorded lane geometry
    from asg.scene.from_log import frame_vehicles

    agents = frame_vehicles(log, frames[60])
    assert sum(log.lane_map.point_on_road(a.x_m, a.y_m) for a in agents) >= 0.9 * len(agents)


@pytest.mark.slow
def test_highway_scenes(highway_log, tmp_path):
    scenes = list(extract_scenes(highway_log, ExtractParams(every=20)))
    assert scenes and all(s.source == "highway-env" for s in scenes)
    assert all(s.ego.kind == "rsu" for s in scenes)


@pytest.mark.slow
def test_scenes_of_vehicles_backing_up_load_again(highway_log, tmp_path):
    """highway-env's intersection vehicles back up a little when stopped close behind another (a
    negative speed in the log): every scene extracted from it is saved and loaded again."""
    from asg.scene import save_scene
    from asg.scene.scene import load_scene

    scenes = list(extract_scenes(highway_log, ExtractParams(every=1, ego="vehicle")))
    assert any(a.speed_mps < 0 for s in scenes for a in s.agents)
    for s in scenes:
        save_scene(s, tmp_path / f"{s.scene_id}.yaml")
        assert load_scene(tmp_path / f"{s.scene_id}.yaml").agents == s.agents


def test_unknown_env():
    with pytest.raises(InputError, match="unknown highway-env scenario"):
        simulate_highway(HighwayRequest(out_dir=None, env_id="racetrack-v9"))  # type: ignore[arg-type]
