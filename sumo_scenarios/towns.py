"""SUMO towns: build them reproducibly from ``configs/towns.yaml``, list them, resolve a name or path.

A town is ``nets/NAME.net.xml`` plus ``nets/NAME.poly.xml`` (buildings). Generated towns come from
netgenerate (grid, spider, random); hand-written ones from plain XML in ``nets/plain/`` through
netconvert. A user's own maps become towns of the same form in the user's towns folder
(``asg towns import``, sumo_scenarios.town_import), found by name after the bundled ones.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from . import checks
from .atomic import atomic_path
from .buildings import Building, BuildingParams, generate_buildings, read_buildings, write_buildings
from .errors import InputError
from .lanes import LaneMap, parse_net_root
from .paths import configs_dir, nets_dir, user_towns_dir
from .strict import load_dataclass
from . import sumo_tools


@dataclass(frozen=True)
class TownSpec:
    """One town of ``configs/towns.yaml``."""

    name: str
    kind: Literal["grid", "spider", "random", "plain"]
    description: str = ""
    seed: int = 1
    lanes: int = 2
    speed_mps: float = 13.89
    junction_type: str = "traffic_light"
    options: tuple[str, ...] = ()
    plain: str | None = None
    #: multiplies the traffic demand of ``asg simulate`` (towns differ in how long vehicles stay)
    demand_scale: float = 1.0


@dataclass(frozen=True)
class TownsConfig:
    towns: tuple[TownSpec, ...]
    buildings: BuildingParams = field(default_factory=BuildingParams)


#: the netgenerate / netconvert options a town may add: its kind's own families and the defaults of
#: lanes, junctions and signals. None names a file: an option such as ``--log``,
#: ``--save-configuration`` or ``--plain-output-prefix`` would write wherever the file said.
TOWN_OPTION_PREFIXES = ("--grid.", "--spider.", "--rand.", "--default.", "--tls.", "--junctions.",
                        "--geometry.", "--roundabouts.", "--ramps.", "--no-turnarounds")
#: a town's numbers, (lowest, highest)
TOWN_LIMITS = {"seed": (0, 2**31 - 1), "lanes": (1, 8), "speed_mps": (1.0, 70.0), "demand_scale": (0.01, 10.0)}


def load_towns_config(path: str | Path | None = None) -> TownsConfig:
    """The towns of ``path`` (default configs/towns.yaml), each checked (:func:`check_town`)."""
    where = str(path or configs_dir() / "towns.yaml")
    cfg = load_dataclass(TownsConfig, path or configs_dir() / "towns.yaml")
    names = [spec.name for spec in cfg.towns]
    for spec in cfg.towns:
        check_town(spec, where)
        if names.count(spec.name) > 1:
            raise InputError(f"{where}: town '{spec.name}' is named twice; give each town its own name")
    cfg.buildings.check(f"{where}: buildings")
    return cfg


def check_town(spec: TownSpec, where: str) -> None:
    """InputError naming ``where`` and the town unless its name (and plain files' name) is a safe
    file name, its numbers are within TOWN_LIMITS and every element of its options that starts with
    ``-`` is an option of TOWN_OPTION_PREFIXES' families (``--grid.number 4`` or ``--grid.number=4``)."""
    name = checks.safe_id(spec.name, f"{where}: a town's name")
    at = f"{where}: town '{name}'"
    if spec.plain is not None:
        checks.safe_id(spec.plain, f"{at} plain")
    checks.safe_id(spec.junction_type, f"{at} junction_type")
    for key, (lo, hi) in TOWN_LIMITS.items():
        checks.number(getattr(spec, key), f"{at} {key}", lo, hi)
    for option in spec.options:
        if not isinstance(option, str):
            raise InputError(f"{at}: option {option!r} is not text; write every option and value as a string")
        if option.startswith("-") and not option.startswith(TOWN_OPTION_PREFIXES):
            raise InputError(f"{at}: option {option[:60]!r} is not one a town may set (those starting "
                             f"{', '.join(TOWN_OPTION_PREFIXES)}); asg names every file itself")


def _netgenerate_args(spec: TownSpec, out: Path) -> list[str]:
    kind_flag = {"grid": "--grid", "spider": "--spider", "random": "--rand"}[spec.kind]
    return [
        sumo_tools.binary("netgenerate"), kind_flag,
        "--default.lanenumber", str(spec.lanes),
        "--default.speed", str(spec.speed_mps),
        "--default.junctions.type", spec.junction_type,
        "--no-turnarounds", "true",
        "--seed", str(spec.seed),
        *spec.options,
        "-o", str(out),
    ]


def _netconvert_args(spec: TownSpec, out: Path, plain_dir: Path) -> list[str]:
    base = plain_dir / (spec.plain or spec.name)
    nod, edg = Path(f"{base}.nod.xml"), Path(f"{base}.edg.xml")
    for f in (nod, edg):
        if not f.is_file():
            raise InputError(f"town '{spec.name}': plain-XML file {f} not found; add it or fix 'plain:'")
    args = [sumo_tools.binary("netconvert"), "-n", str(nod), "-e", str(edg), "--no-turnarounds", "true", "--seed", str(spec.seed)]
    con = Path(f"{base}.con.xml")
    if con.is_file():
        args += ["-x", str(con)]
    return args + list(spec.options) + ["-o", str(out)]


def build_town(spec: TownSpec, out_dir: Path, building_params: BuildingParams) -> Path:
    """Build ``out_dir/NAME.net.xml`` and ``NAME.poly.xml``; returns the net path."""
    net_path = out_dir / f"{spec.name}.net.xml"
    with atomic_path(net_path) as tmp:
        if spec.kind == "plain":
            sumo_tools.run(_netconvert_args(spec, tmp, nets_dir() / "plain"), f"netconvert for town '{spec.name}'")
        else:
            sumo_tools.run(_netgenerate_args(spec, tmp), f"netgenerate for town '{spec.name}'")
        LaneMap.from_sumo_net(tmp)  # refuse to publish a net we cannot read back
    lane_map = LaneMap.from_sumo_net(net_path)
    write_buildings(out_dir / f"{spec.name}.poly.xml", generate_buildings(lane_map, spec.seed, building_params))
    return net_path


@dataclass(frozen=True)
class TownInfo:
    """What ``asg towns list`` prints for a town."""

    name: str
    net: str
    area_km2: float
    lanes_min: int
    lanes_max: int
    lane_count: int
    junctions: int
    traffic_lights: int
    buildings: int


def town_info(net_path: Path) -> TownInfo:
    root = parse_net_root(net_path)
    lanes_per_edge = [
        len(e.findall("lane")) for e in root.iter("edge") if e.get("function") not in ("internal", "walkingarea", "crossing")
    ]
    junctions = [j for j in root.iter("junction") if j.get("type") not in ("internal", "dead_end")]
    conv = root.find("location")
    xmin, ymin, xmax, ymax = (float(v) for v in conv.get("convBoundary").split(",")) if conv is not None else (0, 0, 0, 0)
    poly = net_path.with_name(net_path.name.replace(".net.xml", ".poly.xml"))
    return TownInfo(
        name=net_path.name.replace(".net.xml", ""),
        net=str(net_path),
        area_km2=round((xmax - xmin) * (ymax - ymin) / 1e6, 3),
        lanes_min=min(lanes_per_edge, default=0),
        lanes_max=max(lanes_per_edge, default=0),
        lane_count=sum(lanes_per_edge),
        junctions=len(junctions),
        traffic_lights=sum(1 for j in junctions if j.get("type", "").startswith("traffic_light")),
        buildings=len(read_buildings(poly)) if poly.is_file() else 0,
    )


def list_towns(directory: Path | None = None) -> list[Path]:
    """The nets of ``directory``, or the bundled towns then the user's imported ones (a bundled
    name first: an import never takes it)."""
    if directory is not None:
        return sorted(Path(directory).glob("*.net.xml"))
    bundled = sorted(nets_dir().glob("*.net.xml"))
    names = {p.name for p in bundled}
    return bundled + [p for p in sorted(user_towns_dir().glob("*.net.xml")) if p.name not in names]


@dataclass(frozen=True)
class TownMap:
    """A resolved town: its name, net path, lane map and buildings."""

    name: str
    net_path: Path
    lane_map: LaneMap
    buildings: tuple[Building, ...]
    buildings_generated: bool


def resolve_net(town: str | None = None, net: str | Path | None = None) -> tuple[str, Path]:
    """A town name or a user net path → (name, net path); unknown names raise InputError."""
    if (town is None) == (net is None):
        raise InputError("give exactly one of --town NAME or --net PATH")
    if net is not None:
        p = Path(net)
        parse_net_root(p)
        return p.name.replace(".net.xml", "").replace(".xml", ""), p
    found = {q.name.replace(".net.xml", ""): q for q in list_towns()}
    if str(town) not in found:  # a name, never a path
        known = ", ".join(found) or "none (run 'asg towns build')"
        raise InputError(f"unknown town '{town}'; known towns: {known} (your own maps: 'asg towns import')")
    return str(town), found[str(town)]


def demand_scale(town: str | None) -> float:
    """The town's ``demand_scale`` from configs/towns.yaml (1.0 for user nets and unknown names)."""
    if town is None:
        return 1.0
    for spec in load_towns_config().towns:
        if spec.name == town:
            return spec.demand_scale
    return 1.0


def load_town(town: str | None = None, net: str | Path | None = None, seed: int = 1) -> TownMap:
    """Load a town's lanes and buildings; a net without a ``.poly.xml`` gets buildings generated now."""
    name, net_path = resolve_net(town, net)
    lane_map = LaneMap.from_sumo_net(net_path)
    poly = net_path.with_name(net_path.name.replace(".net.xml", ".poly.xml"))
    if poly.is_file() and poly != net_path:
        return TownMap(name, net_path, lane_map, tuple(read_buildings(poly)), False)
    return TownMap(name, net_path, lane_map, tuple(generate_buildings(lane_map, seed)), True)
