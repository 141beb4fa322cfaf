
import sys
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


# ---- asg towns import ------------------------------------------------------------------------
MINI_OSM = """<?xml version="1.0" encoding="UTF-8"?>
<osm version="0.6" generator="hand">
  <bounds minlat="48.1000" minlon="11.5000" maxlat="48.1040" maxlon="11.5060"/>
  <node id="1" lat="48.1000" lon="11.5000"/><node id="2" lat="48.1020" lon="11.5000"/>
  <node id="3" lat="48.1040" lon="11.5000"/><node id="4" lat="48.1020" lon="11.5030"/>
  <node id="5" lat="48.1020" lon="11.5060"/><node id="6" lat="48.1020" lon="11.4970"/>
  <node id="11" lat="48.1023" lon="11.5005"/><node id="12" lat="48.1023" lon="11.5012"/>
  <node id="13" lat="48.1028" lon="11.5012"/><node id="14" lat="48.1028" lon="11.5005"/>
  <node id="21" lat="48.1013" lon="11.5005"/><node id="22" lat="48.1013" lon="11.5015"/>
  <node id="23" lat="48.1017" lon="11.5015"/><node id="24" lat="48.1017" lon="11.5005"/>
  <way id="100"><nd ref="1"/><nd ref="2"/><nd ref="3"/><tag k="highway" v="secondary"/><tag k="lanes" v="2"/></way>
  <way id="101"><nd ref="6"/><nd ref="2"/><nd ref="4"/><nd ref="5"/><tag k="highway" v="residential"/></way>
  <way id="200"><nd ref="11"/><nd ref="12"/><nd ref="13"/><nd ref="14"/><nd ref="11"/><tag k="building" v="yes"/><tag k="height" v="21.5"/></way>
  <way id="201"><nd ref="21"/><nd ref="22"/><nd ref="23"/><nd ref="24"/><nd ref="21"/><tag k="building" v="apartments"/><tag k="building:levels" v="4"/></way>
</osm>
"""


@pytest.fixture
def user_home(tmp_path, monkeypatch):
    home = tmp_path / "home"
    monkeypatch.setenv("ASG_HOME", str(home))
    return home


def _cli(capsys, *argv):
    from asg.cli import main

    code = main(list(argv))
    return code, capsys.readouterr()


def test_an_opendrive_town_works_like_a_bundled_one(capsys, tmp_path, user_home):
    """An OpenDRIVE file (netconvert's of a bundled town) becomes a town: listed, simulated, generated."""
    import json

    from sumo_scenarios import sumo_tools
    from asg.scene.from_log import ExtractParams, extract_scenes

    xodr = tmp_path / "grid.xodr"
    sumo_tools.run([sumo_tools.binary("netconvert"), "--sumo-net-file", str(towns.nets_dir() / "grid_small.net.xml"),
                    "--opendrive-output", str(xodr)], "netconvert")
    code, out = _cli(capsys, "towns", "import", str(xodr), "--name", "my_xodr")
    assert code == 0, out.err
    assert (user_home / "towns" / "my_xodr.net.xml").is_file() and (user_home / "towns" / "my_xodr.poly.xml").is_file()
    code, out = _cli(capsys, "towns", "list", "--json")
    listed = {t["name"]: t for t in json.loads(out.out)}
    assert set(BUNDLED) < set(listed) and listed["my_xodr"]["buildings"] > 0
    town = towns.load_town("my_xodr")
    assert not town.buildings_generated and town.lane_map.lanes
    log = tmp_path / "log"
    code, out = _cli(capsys, "simulate", "--town", "my_xodr", "--duration", "20", "--warmup", "30", "--out", str(log))
    assert code == 0, out.err
    scenes = list(extract_scenes(log, ExtractParams(every=10, min_vehicles=1)))
    assert scenes and all(s.town == "my_xodr" for s in scenes) and any(a.kind == "rsu" for a in scenes[0].agents)


def test_an_osm_extract_brings_its_buildings_with_their_heights(capsys, tmp_path, user_home):
    osm = tmp_path / "mini.osm"
    osm.write_text(MINI_OSM)
    code, out = _cli(capsys, "towns", "import", str(osm), "--name", "mini")
    assert code == 0, out.err
    town = towns.load_town("mini")
    heights = sorted(round(b.height_m, 1) for b in town.buildings)
    assert heights == [12.0, 21.5]  # 4 levels x 3 m; the height tag
    assert not town.lane_map.drivable.is_empty
    # a second import of that name is refused, --force replaces it; a bundled name is never taken
    code, out = _cli(capsys, "towns", "import", str(osm), "--name", "mini")
    assert code == 2 and "--force" in out.err
    assert _cli(capsys, "towns", "import", str(osm), "--name", "mini", "--force")[0] == 0
    code, out = _cli(capsys, "towns", "import", str(osm), "--name", "grid_small")
    assert code == 2 and "bundled town" in out.err


@pytest.mark.parametrize("case,text,needle", [
    ("entity-bomb", '<?xml version="1.0"?><!DOCTYPE osm [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;">'
                    ']><osm version="0.6"><node id="1" lat="48.1" lon="11.5"><tag k="n" v="&b;"/></node></osm>', "document type"),
    ("external-entity", '<?xml version="1.0"?><!DOCTYPE osm [<!ENTITY x SYSTEM "file:///etc/passwd">]>'
                        '<osm version="0.6"><node id="1" lat="48.1" lon="11.5"><tag k="n" v="&x;"/></node></osm>', "document type"),
    ("empty", "", "empty"),
    ("not-xml", "highway=primary\n", "not well-formed"),
    ("no-drivable-lane", MINI_OSM.replace('v="secondary"', 'v="footway"').replace('v="residential"', 'v="footway"'),
     "no lane a car may drive on"),
    ("coordinates-1e300", MINI_OSM.replace('lat="48.1000" lon="11.5000"/>', 'lat="1e300" lon="11.5000"/>'), "is not a number"),
])
def test_a_hostile_or_useless_map_is_one_line_and_writes_nothing(capsys, tmp_path, user_home, case, text, needle):
    from test_cli import assert_one_line_error

    osm = tmp_path / "map.osm"
    osm.write_text(text)
    code, out = _cli(capsys, "towns", "import", str(osm), "--name", "t")
    assert code == 2
    assert_one_line_error(out.err, needle)
    assert not [p for p in user_home.rglob("*") if p.is_file()]  # nothing written, no temporary left


def test_an_opendrive_map_at_absurd_coordinates_is_refused(capsys, tmp_path, user_home):
    import re

    from sumo_scenarios import sumo_tools
    from test_cli import assert_one_line_error

    xodr = tmp_path / "grid.xodr"
    sumo_tools.run([sumo_tools.binary("netconvert"), "--sumo-net-file", str(towns.nets_dir() / "grid_small.net.xml"),
                    "--opendrive-output", str(xodr)], "netconvert")
    xodr.write_text(re.sub(r' x="[-0-9.e+]*"', ' x="1e300"', xodr.read_text()))
    code, out = _cli(capsys, "towns", "import", str(xodr), "--name", "far")
    assert code == 2
    assert_one_line_error(out.err, "is not a number")  # refused before netconvert runs
    assert not [p for p in user_home.rglob("*") if p.is_file()]


@pytest.mark.parametrize("height, want", [("21.5 m", 21.5), ("21.5m", 21.5), ("tall", 12.0), ("-3", 12.0), ("nan", 12.0)])
def test_osm_heights_in_any_written_form(capsys, tmp_path, user_home, height, want):
    """A height tag with its unit, or not a height at all: the building keeps the height it can
    have (the tag's, else its levels'), never a traceback."""
    osm = tmp_path / "mini.osm"
    osm.write_text(MINI_OSM.replace('<tag k="height" v="21.5"/>', f'<tag k="height" v="{height}"/><tag k="building:levels" v="4"/>'))
    code, out = _cli(capsys, "towns", "import", str(osm), "--name", "mini")
    assert code == 0, out.err
    heights = sorted(round(b.height_m, 1) for b in towns.load_town("mini").buildings)
    assert heights == sorted([12.0, want])


def test_a_poly_file_with_a_broken_shape_is_one_line(tmp_path):
    from sumo_scenarios.buildings import read_buildings
    from sumo_scenarios.errors import InputError

    poly = tmp_path / "x.poly.xml"
    poly.write_text('<additional><poly id="b" type="building" shape="0,0 a,b 5,5"/></additional>')
    with pytest.raises(InputError, match="not x,y numbers"):
        read_buildings(poly)


@pytest.mark.parametrize("name", ["x.net.xml", "x:y", "a b", "_x", "x" * 65])
def test_a_town_name_that_is_not_a_plain_name_is_refused(capsys, tmp_path, user_home, name):
    """--name x.net.xml was listed and resolved as x (its OSM buildings ignored); x:y passed and
    failed inside netconvert."""
    osm = tmp_path / "mini.osm"
    osm.write_text(MINI_OSM)
    code, out = _cli(capsys, "towns", "import", str(osm), "--name", name)
    assert code == 2 and "letters, digits" in out.err and "Traceback" not in out.err
    assert not (user_home / "towns").exists()


@pytest.mark.parametrize("edit, needle", [
    (lambda t: t.replace(' lat="48.1040"', ' lat="1e300"', 1), "lat="),
    (lambda t: t.replace(' lon="11.5060"', ' lon="nan"', 1), "lon="),
])
def test_absurd_numbers_in_a_map_are_refused_before_netconvert(capsys, tmp_path, user_home, edit, needle):
    """A node at 1e300 was dropped without a word; an OpenDRIVE length of 1e12 kept netconvert busy
    for a minute: refused in one line, and no empty towns folder is left."""
    osm = tmp_path / "mini.osm"
    osm.write_text(edit(MINI_OSM))
    code, out = _cli(capsys, "towns", "import", str(osm), "--name", "mini")
    assert code == 2 and needle in out.err and len(out.err.strip().splitlines()) == 1
    assert not (user_home / "towns").exists()


@pytest.mark.parametrize("length", ["1e12", "-5"])
def test_an_opendrive_road_of_absurd_length_is_refused_at_once(capsys, tmp_path, user_home, length):
    """A length of 1e12 kept netconvert busy for a minute; a negative one grew it to 9 GB."""
    xodr = tmp_path / "long.xodr"
    xodr.write_text('<?xml version="1.0"?><OpenDRIVE><header revMajor="1" revMinor="4"/>'
                    '<road id="1" length="10" junction="-1"><planView><geometry s="0" x="0" y="0" hdg="0" '
                    f'length="{length}"><line/></geometry></planView></road></OpenDRIVE>')
    code, out = _cli(capsys, "towns", "import", str(xodr), "--name", "long")
    assert code == 2 and "length=" in out.err and len(out.err.strip().splitlines()) == 1


def test_a_sumo_program_that_outgrows_its_memory_is_one_line(monkeypatch):
    """Whatever input makes a SUMO program explode, its memory is capped and the end is one line."""
    from sumo_scenarios import sumo_tools
    from sumo_scenarios.errors import InputError

    monkeypatch.setattr(sumo_tools, "MAX_TOOL_MEMORY_BYTES", 64 * 1024**2)
    hungry = [sys.executable, "-c", "import sys; b = bytearray(256 * 1024**2); sys.exit(0)"]
    with pytest.raises(InputError) as exc:
        sumo_tools.run(hungry, "a hungry program")
    assert "a hungry program ran out of its 0.0625 GiB" in str(exc.value) and "\n" not in str(exc.value)


def test_asg_home_where_no_folder_can_be_is_one_line(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("ASG_HOME", "/proc/asg-home")
    osm = tmp_path / "mini.osm"
    osm.write_text(MINI_OSM)
    code, out = _cli(capsys, "towns", "import", str(osm), "--name", "mini")
    assert code == 2 and "ASG_HOME" in out.err and "Traceback" not in out.err


def test_netconverts_own_error_reaches_the_user(capsys, tmp_path, user_home):
    """Not "Quitting (on error).": the line that says what is wrong."""
    bad = tmp_path / "bad.net.xml"
    bad.write_text('<net version="1.9"><edge id="e" from="a" to="b"><lane id="e_0" index="0" length="-5" shape="0,0 1,1"/></edge></net>')
    code, out = _cli(capsys, "towns", "import", str(bad), "--name", "bad")
    assert code == 2 and "Quitting" not in out.err


_GRID = {"name": "g", "kind": "grid", "seed": 1, "options": ["--grid.number", "3"]}


@pytest.mark.parametrize("town, buildings, says", [
    ({"name": "../escaped"}, {}, "not a safe name"),  # wrote escaped.net.xml beside --out
    ({"options": ["--grid.number", "3", "--log", "LOG"]}, {}, "option '--log' is not one a town may set"),
    ({"options": ["--save-configuration=LOG"]}, {}, "is not one a town may set"),
    ({"options": ["-o", "LOG"]}, {}, "option '-o'"),
    ({"options": ["--grid.number", "--plain-output-prefix=LOG"]}, {}, "is not one a town may set"),
    ({"kind": "plain", "plain": "../../x"}, {}, "plain: id '../../x' is not a safe name"),
    ({"lanes": 0}, {}, "lanes: 0 is out of range"), ({"demand_scale": 0}, {}, "demand_scale: 0 is out of range"),
    ({}, {"spacing_m": 0}, "buildings.spacing_m: 0 is out of range"),
    ({}, {"height_m": [30, 4]}, "buildings.height_m: [30, 4] runs from high to low")])
def test_a_hostile_towns_config_is_one_line_and_writes_nothing(capsys, tmp_path, town, buildings, says):
    """A towns yaml is a file a user hands to `asg towns build`: its town names become file names
    and its options go to netgenerate, whose file options (--log, --save-configuration, -o) wrote
    wherever the yaml said. Only the options of a town's shape are taken."""
    import yaml

    from test_cli import assert_one_line_error, run

    log = tmp_path / "written.log"
    spec = {k: ([o.replace("LOG", str(log)) for o in v] if k == "options" else v) for k, v in {**_GRID, **town}.items()}
    config = tmp_path / "towns.yaml"
    config.write_text(yaml.safe_dump({"towns": [spec], "buildings": buildings}))
    out = tmp_path / "out" / "nets"
    out.mkdir(parents=True)
    code, err = run(capsys, "towns", "build", "--config", str(config), "--out", str(out))
    assert code == 2
    assert_one_line_error(err, says)
    assert sorted(p.name for p in tmp_path.rglob("*") if p.is_file()) == ["towns.yaml"]


def test_a_town_named_twice_is_refused(tmp_path):
    import yaml

    config = tmp_path / "towns.yaml"
    config.write_text(yaml.safe_dump({"towns": [_GRID, {**_GRID, "options": list(_GRID["options"])}]}))
    with pytest.raises(InputError, match="town 'g' is named twice"):
        towns.load_towns_config(config)
