
import pytest
from shapely.geometry import Polygon

from sumo_scenarios import towns
from sumo_scenarios.errors import InputError
from sumo_scenarios.lanes import LaneMap

BUNDLED = [p.name.replace(".net.xml", "") for p in towns.list_towns()]


def test_at_least_six_bundled_towns_with_buildings():
    cfg = towns.load_towns_config()
    assert len(cfg.towns) >= 6
    assert set(BUNDLED) == {t.name for t in cfg.towns}
    kinds = {t.kind for t in cfg.towns}
    assert {"grid", "spider", "random", "plain"} <= kinds
    infos = [towns.town_info(p) for p in towns.list_towns()]
    assert all(i.buildings > 0 for i in infos)
    assert min(i.lanes_min for i in infos) == 1 and max(i.lanes_max for i in infos) == 4
    assert sum(i.traffic_lights for i in infos) > 0


@pytest.mark.parametrize("name", BUNDLED)
def test_buildings_never_on_the_road(name):
    town = towns.load_town(name)
    assert town.buildings and not town.buildings_generated
    for b in town.buildings:
        assert not town.lane_map.drivable.intersects(Polygon(b.footprint_xy)), b.building_id
        assert 3.0 <= b.height_m <= 40.0


def test_build_is_reproducible(tmp_path):
    cfg = towns.load_towns_config()
    spec = {t.name: t for t in cfg.towns}
    for name in ("grid_small", "roundabout"):
        net = towns.build_town(spec[name], tmp_path, cfg.buildings)
        bundled = towns.nets_dir() / f"{name}.net.xml"
        # the header comment records when and from which paths netconvert ran: compare from <location> on
        body = lambda text: text[text.index("<location"):]
        assert body(net.read_text()) == body(bundled.read_text())
        assert (tmp_path / f"{name}.poly.xml").read_text() == (towns.nets_dir() / f"{name}.poly.xml").read_text()


def test_user_net_without_buildings_gets_them(tmp_path):
    net = tmp_path / "mine.net.xml"
    net.write_text((towns.nets_dir() / "fiveleg.net.xml").read_text())
    town = towns.load_town(net=net)
    assert town.buildings_generated and len(town.buildings) > 5
    assert town.name == "mine"


def test_unknown_town_names_known_ones():
    with pytest.raises(InputError, match="unknown town 'atlantis'.*grid_small"):
        towns.resolve_net("atlantis")


def test_unknown_key_in_towns_yaml(tmp_path):
    bad = tmp_path / "towns.yaml"
    bad.write_text("towns:\n  - name: a\n    kind: grid\n    lanez: 2\n")
    with pytest.raises(InputError, match="unknown key 'lanez'"):
        towns.load_towns_config(bad)


def test_lane_less_net_is_refused(tmp_path):
    net = tmp_path / "empty.net.xml"
    net.write_text('<net version="1.20"><location netOffset="0,0" convBoundary="0,0,1,1"/></net>')
    with pytest.raises(InputError, match="no lanes"):
        LaneMap.from_sumo_net(net)
