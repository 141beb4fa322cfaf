import math

import numpy as np
import pytest
import yaml

from asg.scene import Agent, Scene, load_scene, save_scene
from asg.scene.from_log import ExtractParams, extract_scenes
from sumo_scenarios.errors import InputError


def test_scene_yaml_round_trip(sumo_log, tmp_path):
    scenes = list(extract_scenes(sumo_log, ExtractParams(every=40)))
    assert len(scenes) == 4  # frames 0, 40, 80, 120
    for s in scenes:
        path = tmp_path / f"{s.scene_id}.yaml"
        save_scene(s, path)
        back = load_scene(path)
        assert back.to_dict() == s.to_dict()
        assert back.ego.kind == "rsu"
        assert all(np.hypot(a.x_m - back.ego.x_m, a.y_m - back.ego.y_m) <= 120.0 for a in back.agents)
        assert back.buildings and back.lane_map.lanes


def test_extract_vehicle_ego(sumo_log):
    s = next(iter(extract_scenes(sumo_log, ExtractParams(every=60, ego="vehicle"))))
    assert s.ego.kind == "vehicle"


def test_agent_geometry():
    a = Agent("v", "vehicle", "car", 10.0, 5.0, 0.0, math.pi / 2, 4.0, 2.0, 1.5)
    fp = a.footprint_xy()
    assert np.allclose(sorted(fp[:, 0]), [9, 9, 11, 11]) and np.allclose(sorted(fp[:, 1]), [3, 3, 7, 7])
    moved = a.moved(1.0, -1.0, math.pi)
    assert (moved.x_m, moved.y_m) == (11.0, 4.0) and math.isclose(moved.yaw_rad, -math.pi / 2)
    assert a.box7()[2] == pytest.approx(0.75)


def test_scene_missing_key(sumo_log, tmp_path):
    s = next(iter(extract_scenes(sumo_log, ExtractParams(every=120))))
    data = s.to_dict()
    del data["ego"]
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(InputError, match="missing key 'ego'"):
        load_scene(path)


@pytest.mark.parametrize("field, value, says", [
    ("scene_id", "../up", "scene_id"), ("time_s", -1.0, "time_s"),
    ("link", {"COLLAB": {"delay_s": 0.1}}, "link of 'COLLAB': delayed by 0.1 s")])
def test_a_bad_field_names_the_file_once_and_the_field(sumo_log, tmp_path, field, value, says):
    """An error in a scene file is one line: the file once, then the field that is wrong."""
    s = next(iter(extract_scenes(sumo_log, ExtractParams(every=120, collaborators=1))))
    data = s.to_dict()
    data[field] = {s.collaborators[0]: value["COLLAB"]} if field == "link" else value
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(InputError) as error:
        load_scene(path)
    message = str(error.value)
    assert message.count(str(path)) == 1 and message.startswith(f"{path}: ")
    assert says.replace("COLLAB", s.collaborators[0]) in message


def test_scene_unknown_ego(sumo_log):
    s = next(iter(extract_scenes(sumo_log, ExtractParams(every=120))))
    data = s.to_dict()
    data["ego"] = "nobody"
    with pytest.raises(InputError, match="'nobody'"):
        Scene.from_dict(data)


def test_a_yaml_file_larger_than_any_asg_reads_is_not_read(tmp_path):
    """A scene or settings file of 64 MB or more is none asg or a user wrote: refused by its size,
    before it is read into memory and parsed (a sparse file here: no disk is filled)."""
    from sumo_scenarios.strict import MAX_YAML_BYTES, read_yaml

    big = tmp_path / "big.yaml"
    with open(big, "w") as fh:
        fh.write("scene_id: x\n")
        fh.truncate(MAX_YAML_BYTES + 1)
    for read in (load_scene, read_yaml):
        with pytest.raises(InputError, match=f"{big}: larger than 64 MB"):
            read(big)
