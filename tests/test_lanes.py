import math

import numpy as np
import pytest

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


#: a spoiled line of a SUMO net (what is replaced, by what) -> what the one line says
BAD_NET = {
    ('shape="', 'shape="nan,'): "centerline: a coordinate is not finite",
    ('shape="', 'shape="1e300,0 '): "centerline: a coordinate is not finite or beyond",
    ('shape="', 'shape="x,y '): "is not x,y pairs",
    ('shape="', 'shape="5 '): "is not x,y pairs",
    ('speed="', 'width="wide" speed="'): "width 'wide",
    ('speed="', 'speed="-'): "speed_mps: -",
}


@pytest.mark.parametrize("spoil", sorted(BAD_NET))
def test_a_spoiled_net_is_refused_in_one_line_naming_it(spoil, tmp_path):
    """A net is a file a user hands in (``asg simulate --net``, ``asg towns import``): a lane's shape
    that is not finite x,y pairs, or a width or speed that is not a number in range, is refused
    naming the file and the lane, instead of a traceback or scenes that cannot be loaded again."""
    from sumo_scenarios.errors import InputError
    from sumo_scenarios.lanes import LaneMap
    from sumo_scenarios.paths import nets_dir

    text = (nets_dir() / "fiveleg.net.xml").read_text()
    old, new = spoil
    import re

    lane = next(m for m in re.finditer(r"<lane [^>]*>", text) if old in m.group(0))  # the first lane that has it
    at = lane.start() + lane.group(0).index(old)
    path = tmp_path / "spoiled.net.xml"
    path.write_text(text[:at] + new + text[at + len(old):])
    with pytest.raises(InputError) as exc:
        LaneMap.from_sumo_net(path)
    assert str(exc.value).startswith(f"{path}: lane ") and BAD_NET[spoil] in str(exc.value), str(exc.value)
