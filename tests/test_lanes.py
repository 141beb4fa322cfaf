import math

import numpy as np

from asg.scene.agent import footprint_xy


def test_footprint_on_lane_is_drivable(cross_map):
    car = footprint_xy(-40.0, -1.6, 0.0, 4.6, 1.85)
    assert cross_map.footprint_on_road(car)


def test_footprint_in_junction_is_drivable(cross_map):
    turning = footprint_xy(0.0, 0.0, math.radians(45), 4.6, 1.85)
    assert cross_map.footprint_on_road(turning)


def test_footprint_off_road_is_not_drivable(cross_map):
    assert not cross_map.footprint_on_road(footprint_xy(-40.0, 20.0, 0.0, 4.6, 1.85))
    # half on the kerb: 1.5 m beyond the outer lane edge at y = -3.2
    assert not cross_map.footprint_on_road(footprint_xy(-40.0, -3.7, 0.0, 4.6, 1.85))


def test_vectorised_matches_scalar(cross_map):
    fps = np.stack([footprint_xy(x, -1.6, 0.0, 4.6, 1.85) for x in (-90.0, -40.0, 0.0, 120.0)])
    got = cross_map.footprints_on_road(fps)
    assert got.tolist() == [cross_map.footprint_on_road(f) for f in fps] == [True, True, True, False]


def test_locate_gives_lane_offset_and_heading(cross_map):
    pos = cross_map.locate(-50.0, -1.0)
    assert pos.lane_id == "we_0"
    assert math.isclose(pos.station_m, 50.0)
    assert math.isclose(pos.lateral_m, 0.6, abs_tol=1e-9)  # left of an eastbound lane is +y
    assert math.isclose(pos.heading_rad, 0.0)
    assert pos.on_lane
    west = cross_map.locate(50.0, 1.0)
    assert west.lane_id == "ew_0" and math.isclose(abs(west.heading_rad), math.pi)
    assert math.isclose(west.lateral_m, 0.6, abs_tol=1e-9)  # left of a westbound lane is -y
    north = cross_map.locate(1.6, -30.0)
    assert north.lane_id == "sn_0" and math.isclose(north.heading_rad, math.pi / 2)


def test_locate_off_lane(cross_map):
    pos = cross_map.locate(-50.0, -9.0)
    assert pos.lane_id == "we_0" and not pos.on_lane and pos.lateral_m < -3


def test_crop_and_dict_round_trip(cross_map):
    from sumo_scenarios.lanes import LaneMap

    back = LaneMap.from_dict(cross_map.to_dict())
    assert back.to_dict() == cross_map.to_dict()
    small = cross_map.crop((-60.0, 0.0), 10.0)
    assert {l.lane_id for l in small.lanes} == {"we_0", "ew2_0"}
