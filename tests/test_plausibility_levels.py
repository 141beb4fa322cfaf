"""Plausibility levels: ``paper`` (drivable area, no collision, in range) and ``traffic`` (also in a
lane of its own direction, heading within 30 deg), checked by the search's checker and by the
independent re-check alike; a traffic-level run publishes no wrong-way vehicle."""
import json
import math

import numpy as np
import pytest

from asg.scene import Scene, load_scene
from asg.scene.feasibility import FeasibilityChecker
from asg.scene.recheck import recheck

from conftest import car
from test_robustness import _road, _scene_dict, oracle_run


def test_own_lane_heading_and_direction(cross_map):
    lanes = _road()
    ok = lambda x, y, yaw_deg: lanes.in_own_lane((x, y), math.radians(yaw_deg), car("c", x, y, math.radians(yaw_deg)).footprint_xy(),
                                               math.radians(30.0))
    assert ok(0.0, -4.8, 20.0)                # 20 deg, the front corner still on an eastbound lane
    assert not ok(0.0, -1.6, 28.0)            # 28 deg from the inner lane: a corner in the westbound lane
    assert ok(0.0, -1.6, 0.0)                 # eastbound lane, heading east
    assert ok(0.0, -3.2, 0.0)                 # straddling the two eastbound lanes: a lane change
    assert not ok(0.0, -1.6, 180.0)           # eastbound lane, heading west
    assert not ok(0.0, 1.6, 0.0)              # centre in the westbound lane, heading east
    assert not ok(0.0, -1.6, 40.0)            # 40 deg off the lane
    assert ok(0.0, 1.6, 180.0) and ok(0.0, 4.8, 175.0)
    # in a junction the corners may leave the lanes; the centre must still follow one
    junction = lambda x, y, yaw_deg: cross_map.in_own_lane((x, y), math.radians(yaw_deg),
                                                          car("c", x, y, math.radians(yaw_deg)).footprint_xy(), math.radians(30.0))
    assert junction(-6.0, -1.6, 0.0) and not junction(-6.0, -1.6, 180.0)


def test_own_lanes_of_many_vehicles_at_once_answer_each_alone(cross_map):
    """One query for many vehicles: each answer is the vehicle's own (none shifted onto another's
    corners), mixed with vehicles that fail on their centre, on a corner, or pass in a junction."""
    rng = np.random.default_rng(3)
    for lanes in (_road(), cross_map):
        poses = np.column_stack([rng.uniform(-25, 25, 60), rng.uniform(-4, 4, 60), rng.uniform(-math.pi, math.pi, 60)])
        poses[::3, 2], poses[1::3, 2] = 0.0, math.pi  # headed along the road, one way or the other: some pass
        cars = [car("c", x, y, yaw) for x, y, yaw in poses]
        one = [lanes.in_own_lane((c.x_m, c.y_m), c.yaw_rad, c.footprint_xy(), math.radians(30.0)) for c in cars]
        many = lanes.in_own_lanes(poses[:, :2], poses[:, 2], np.stack([c.footprint_xy() for c in cars]), math.radians(30.0))
        assert list(many) == one and 3 <= sum(one) <= 57


def test_checker_and_recheck_agree_on_random_moves():
    scene = Scene.from_dict(_scene_dict())
    movers = ["v2", "u1"]
    checker = FeasibilityChecker(scene, movers, "traffic", 30.0)
    rng = np.random.default_rng(4)
    seen = set()
    for _ in range(150):
        d = rng.uniform(-1, 1, size=(2, 3)) * np.array([2.5, 2.5, math.radians(45.0)])
        moved = {vid: scene.agent(vid).moved(*dv) for vid, dv in zip(movers, d)}
        final = scene.with_agents([moved.get(a.agent_id, a) for a in scene.agents])
        a, b = checker.check(moved), recheck(scene, final, "traffic", 30.0)
        assert a.wrong_way == b.wrong_way, (d, a, b)
        seen.add(a.wrong_way)
    assert seen >= {0, 1}  # both outcomes occur: the comparison is not vacuous
    assert recheck(scene, scene, "paper").wrong_way is None


@pytest.mark.slow
def test_a_traffic_run_publishes_no_wrong_way_vehicle(capsys, tmp_path):
    out = oracle_run(tmp_path, 2, "--budget", "6", "--plausibility", "traffic")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["config"]["space"]["plausibility"] == "traffic"
    for entry in summary["scenes"]:
        assert entry["plausibility"] == {"collisions": 0, "off_road": 0, "out_of_range": 0, "wrong_way": 0}
        final = load_scene(out / "scenes" / entry["scene_id"] / "final.yaml")
        initial = load_scene(out / "scenes" / entry["scene_id"] / "after_acs.yaml")
        assert recheck(initial, final, "traffic", 30.0).wrong_way == 0
    capsys.readouterr()


def test_movers_sets_how_many_vehicles_move(capsys, tmp_path):
    out = oracle_run(tmp_path, 1, "--budget", "4", "--movers", "5")
    entry = json.loads((out / "summary.json").read_text())["scenes"][0]
    assert len(entry["perturbed"]) == 5 and len(set(entry["perturbed"])) == 5
    capsys.readouterr()
