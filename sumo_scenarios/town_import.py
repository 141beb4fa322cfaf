"""``asg towns import FILE --name NAME``: a user's map as a town, through SUMO's own converters.

OpenDRIVE (``.xodr``, e.g. CARLA's towns) and SUMO nets (``.net.xml``) go through ``netconvert``
and get procedural buildings (as the bundled towns); OpenStreetMap (``.osm``) goes through
``netconvert --osm-files`` and its building footprints through ``polyconvert`` (SUMO's OSM type
map), each building's height from its ``height`` tag (metres), else ``building:levels`` x
:data:`LEVEL_HEIGHT_M`, else :data:`DEFAULT_HEIGHT_M`; an extract with no building gets procedural
ones. The town is written to the user's towns folder (:func:`~sumo_scenarios.paths.user_towns_dir`)
as ``NAME.net.xml`` + ``NAME.poly.xml``, and then works wherever a bundled town does.

Every map file is hostile until read: it must be well-formed XML with no document type declaration
(which is where entity expansion and external entities live), and the converted net must hold a
drivable lane with finite coordinates within :data:`MAX_COORD_M`. Anything else is one line
(InputError) and nothing is written.
"""
from __future__ import annotations

import contextlib
import math
import re
import shutil
import tempfile
import xml.etree.ElementTree as ET
import xml.parsers.expat
from pathlib import Path

from . import sumo_tools
from .buildings import Building, generate_buildings, parse_height_m, read_buildings, write_buildings
from .errors import InputError
from .lanes import LaneMap, parse_net_root
from .paths import nets_dir, user_towns_dir

#: the map kinds ``asg towns import`` takes, by file name ending
KINDS = {".xodr": "opendrive", ".osm": "osm", ".osm.xml": "osm", ".net.xml": "sumo"}
#: metres a storey, for an OSM building with ``building:levels`` and no ``height``
LEVEL_HEIGHT_M = 3.0
#: metres, for an OSM building with neither tag (read_buildings' default)
DEFAULT_HEIGHT_M = 10.0
#: a converted net whose coordinates reach beyond this (m) from its origin is refused
MAX_COORD_M = 1.0e6
#: a converted net placed farther than this (m) from the map's origin (netconvert's netOffset; a
#: UTM projection is within 1e7) is refused: its source coordinates were absurd
MAX_OFFSET_M = 1.0e8
#: a map file larger than this (bytes) is refused before parsing
MAX_FILE_BYTES = 2 * 1024**3


#: numbers a map may hold, by element and attribute (OpenDRIVE's roads and geometries in metres,
#: OSM's nodes in degrees): anything else (1e12 m, 1e300, NaN) is refused before netconvert runs,
#: which spent a minute on a road 1e12 m long and dropped one at 1e300 without a word
_NUMBER_LIMITS = {
    "road": {"length": (0.0, MAX_COORD_M)},
    "geometry": {"s": (0.0, MAX_COORD_M), "x": (-MAX_COORD_M, MAX_COORD_M), "y": (-MAX_COORD_M, MAX_COORD_M),
                 "length": (0.0, MAX_COORD_M)},  # a negative length made netconvert grow past 9 GB
    "node": {"lat": (-90.0, 90.0), "lon": (-180.0, 180.0)},
}
#: a town's name: letters, digits, _ and - (it becomes NAME.net.xml and is given as --town NAME)
_TOWN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,63}")
#: seconds netconvert may take on one map (a city extract takes well under a minute)
NETCONVERT_LIMIT_S = 600.0


def map_kind(path: Path) -> str:
    name = path.name.lower()
    for ending, kind in sorted(KINDS.items(), key=lambda kv: -len(kv[0])):
        if name.endswith(ending):
            return kind
    raise InputError(f"{path}: not a map asg imports (give an OpenDRIVE .xodr, an OpenStreetMap .osm or a SUMO .net.xml)")


def check_map_file(path: Path) -> None:
    """Refuse a map file that is missing, empty, too large, not well-formed XML, or declares a
    document type (entity definitions, external entities): read once with expat, nothing expanded."""
    if not path.is_file():
        raise InputError(f"{path}: map file not found; check the path")
    size = path.stat().st_size
    if size == 0:
        raise InputError(f"{path}: the map file is empty")
    if size > MAX_FILE_BYTES:
        raise InputError(f"{path}: the map file is over {MAX_FILE_BYTES // 1024**3} GiB; cut a smaller extract")

    def refuse_doctype(*_):
        raise InputError(f"{path}: the map declares a document type (<!DOCTYPE ...>: entities or an external DTD); "
                         f"asg reads maps without one: remove it")

    def check_numbers(tag: str, attrs: dict) -> None:
        for key, (lo, hi) in _NUMBER_LIMITS.get(tag, {}).items():
            if key not in attrs:
                continue
            try:
                value = float(attrs[key])
            except ValueError:
                value = math.nan
            if not (math.isfinite(value) and lo <= value <= hi):
                raise InputError(f"{path}: <{tag} {key}=\"{attrs[key][:40]}\"> is not a number in [{lo:g}, {hi:g}] "
                                 f"(line {parser.CurrentLineNumber}); fix or remove that element")

    parser = xml.parsers.expat.ParserCreate()
    parser.StartDoctypeDeclHandler = refuse_doctype
    parser.EntityDeclHandler = refuse_doctype
    parser.ExternalEntityRefHandler = refuse_doctype
    parser.StartElementHandler = check_numbers
    try:
        with open(path, "rb") as fh:
            parser.ParseFile(fh)
    except xml.parsers.expat.ExpatError as exc:
        raise InputError(f"{path}: not well-formed XML ({xml.parsers.expat.ErrorString(exc.code)}, line {exc.lineno}); "
                         f"give the map file itself") from None


def import_town(source: Path, name: str, force: bool = False, towns_dir: Path | None = None) -> Path:
    """Convert map ``source`` into town ``name`` in ``towns_dir`` (default the user's towns folder);
    returns its net path. ``force`` replaces an imported town of that name (never a bundled one)."""
    source = Path(source)
    if not _TOWN_NAME.fullmatch(name):
        raise InputError(f"--name {name[:60]!r}: a town's name is letters, digits, _ and - (at most 64, no dots or "
                         "colons), e.g. --name town01")
    if (nets_dir() / f"{name}.net.xml").is_file():
        raise InputError(f"--name {name}: a bundled town has that name; choose another")
    towns_dir = Path(towns_dir) if towns_dir is not None else user_towns_dir()
    net_out, poly_out = towns_dir / f"{name}.net.xml", towns_dir / f"{name}.poly.xml"
    if net_out.is_file() and not force:
        raise InputError(f"--name {name}: an imported town of that name exists ({net_out}); --force replaces it")
    kind = map_kind(source)
    check_map_file(source)
    made = _make_folder(towns_dir)
    try:
        with tempfile.TemporaryDirectory(dir=towns_dir, prefix=f".import-{name}.") as tmp:
            net = Path(tmp) / f"{name}.net.xml"
            sumo_tools.run([sumo_tools.binary("netconvert"), *_netconvert_input(kind, source), "-o", str(net),
                            "--no-warnings"], f"netconvert of {source.name}", timeout_s=NETCONVERT_LIMIT_S)
            lane_map = _check_net(net, source)
            buildings = _osm_buildings(source, net, Path(tmp)) if kind == "osm" else []
            write_buildings(Path(tmp) / poly_out.name, buildings or generate_buildings(lane_map, 1))
            # the net last: a town exists once its net does
            shutil.move(str(Path(tmp) / poly_out.name), poly_out)
            shutil.move(str(net), net_out)
    except BaseException:
        for folder in made:  # a failed first import leaves no empty towns folder behind
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise
    return net_out


def map_lanes(source: Path) -> LaneMap:
    """The lanes of a map file in the map's own frame: a SUMO net's as it holds them; an OpenDRIVE
    map's converted by netconvert and moved back by netconvert's netOffset, so that they lie where
    the map's own coordinates put them (CARLA's world frame, y mirrored). One InputError for a
    file that is not a map, as for :func:`import_town`."""
    source = Path(source)
    kind = map_kind(source)
    if kind == "osm":
        raise InputError(f"{source}: an OpenStreetMap extract has no frame a recording shares; give the recording's "
                         "OpenDRIVE map (.xodr) or a SUMO net")
    check_map_file(source)
    if kind == "sumo":
        return _check_net(source, source)
    with tempfile.TemporaryDirectory(prefix="asg-map-") as tmp:
        net = Path(tmp) / "map.net.xml"
        sumo_tools.run([sumo_tools.binary("netconvert"), *_netconvert_input(kind, source), "-o", str(net),
                        "--no-warnings"], f"netconvert of {source.name}", timeout_s=NETCONVERT_LIMIT_S)
        lane_map = _check_net(net, source)
        location = parse_net_root(net).find("location")
        dx, dy = _floats(location.get("netOffset", "0,0"))[:2] if location is not None else (0.0, 0.0)
    return lane_map.translated(-dx, -dy)


def _make_folder(folder: Path) -> list[Path]:
    """Create ``folder`` and its missing parents; the folders made, deepest first. One InputError
    where it cannot be (ASG_HOME under /proc, on a file, without permission)."""
    missing = [p for p in (folder, *folder.parents) if not p.exists()]
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{folder}: the towns folder cannot be created ({exc.strerror}); set ASG_HOME to a "
                         "writable folder") from None
    return missing


def _netconvert_input(kind: str, source: Path) -> list[str]:
    option = {"opendrive": "--opendrive-files", "osm": "--osm-files", "sumo": "--sumo-net-file"}[kind]
    return [option, str(source)]


def _check_net(net: Path, source: Path) -> LaneMap:
    """The converted net as a lane map: refused without a drivable lane or with coordinates that
    are not finite or lie beyond MAX_COORD_M."""
    root = parse_net_root(net)
    try:
        lane_map = LaneMap.from_sumo_net(net)
    except InputError:
        raise InputError(f"{source}: the map has no lane a car may drive on; give a map with roads") from None
    drivable = [lane for lane in lane_map.lanes if not lane.internal]
    if not drivable:
        raise InputError(f"{source}: the map has no lane a car may drive on; give a map with roads")
    for lane in drivable:
        xy = lane.centerline_xy
        if not all(math.isfinite(float(v)) and abs(float(v)) <= MAX_COORD_M for v in xy.ravel()):
            raise InputError(f"{source}: lane {lane.lane_id} lies beyond {MAX_COORD_M:g} m or at a coordinate that "
                             f"is not finite; give a map in metres near its origin")
    location = root.find("location")
    if location is not None:
        bounds = _floats(location.get("convBoundary", "0,0,0,0"))
        offset = _floats(location.get("netOffset", "0,0"))
        if not all(math.isfinite(v) and abs(v) <= MAX_COORD_M for v in bounds) or \
                not all(math.isfinite(v) and abs(v) <= MAX_OFFSET_M for v in offset):
            raise InputError(f"{source}: the map's coordinates are absurd (beyond {MAX_OFFSET_M:g} m from its origin, "
                             f"or a road network over {MAX_COORD_M:g} m across); give a map in metres or degrees")
    return lane_map


def _floats(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        return [math.nan]


def _osm_buildings(source: Path, net: Path, tmp: Path) -> list[Building]:
    """The extract's building footprints in the net's frame (polyconvert), heights from the tags."""
    poly = tmp / "osm.poly.xml"
    typemap = sumo_tools.sumo_home() / "data" / "typemap" / "osmPolyconvert.typ.xml"
    sumo_tools.run([sumo_tools.binary("polyconvert"), "--osm-files", str(source), "--net-file", str(net), "--type-file", str(typemap),
                    "--all-attributes", "-o", str(poly)], f"polyconvert of {source.name}")
    heights = {}
    for element in ET.parse(poly).getroot().iter("poly"):  # polyconvert's own output
        if element.get("type") == "building":
            tags = {p.get("key"): p.get("value") for p in element.iter("param")}
            heights[element.get("id")] = _height_m(tags)
    return [Building(b.building_id, b.footprint_xy, heights.get(b.building_id, DEFAULT_HEIGHT_M))
            for b in read_buildings(poly)]


def _height_m(tags: dict) -> float:
    """An OSM building's height (m): ``height`` ("21.5", "21.5 m"), else ``building:levels`` x
    LEVEL_HEIGHT_M, else DEFAULT_HEIGHT_M; a value that is not a positive number below 1 km is ignored."""
    for key, scale in (("height", 1.0), ("building:levels", LEVEL_HEIGHT_M)):
        value = parse_height_m(tags.get(key), scale)
        if value is not None:
            return value
    return DEFAULT_HEIGHT_M
