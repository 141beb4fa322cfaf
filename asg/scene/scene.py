"""A Scene: one frame of traffic with an ego agent, buildings and lane geometry; saved as YAML.

Schema (every key required unless marked optional)::

    scene_id: str
    town: str            # town or net name
    source: sumo | highway-env | recording
    time_s: float        # simulation time of the frame
    ego: str             # agent id of the ego (an RSU or a vehicle)
    collaborators: [str] # optional: sensing agents besides the ego
    log: str | null      # optional: the log folder it came from
    link: {COLLABORATOR_ID: LinkState}   # optional: what the V2X link did (link.py); absent = perfect
    agents: [Agent]      # see agent.py; vehicles and RSUs
    buildings: [{id, height_m, footprint: [[x, y], ...]}]
    lanes: {lanes: [...], junctions: [...]}   # sumo_scenarios.lanes.LaneMap.to_dict()
    recording: Recording # source recording only: the recorded frame behind it (recording.py)
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Mapping, Sequence

import yaml

from sumo_scenarios import checks
from sumo_scenarios.atomic import write_text_atomic
from sumo_scenarios.buildings import Building
from sumo_scenarios.errors import InputError
from sumo_scenarios.log import SOURCES  # where scenes come from (their one home)
from sumo_scenarios.lanes import LaneMap
from sumo_scenarios.strict import check_yaml_size, load_strict_yaml

from .agent import Agent
from .link import LinkState
from .recording import RECORDING_SOURCE, Recording

REQUIRED_KEYS = ("scene_id", "town", "source", "time_s", "ego", "agents", "buildings", "lanes")
#: the keys a scene file may hold besides those (Scene.to_dict writes no other)
OPTIONAL_KEYS = ("collaborators", "log", "link", "recording")
#: where a scene's frame comes from: a traffic log's source, or a recording
SCENE_SOURCES = (*SOURCES, RECORDING_SOURCE)


@dataclass(frozen=True, eq=False)
class Scene:
    scene_id: str
    town: str
    source: str
    time_s: float
    ego_id: str
    agents: tuple[Agent, ...]
    buildings: tuple[Building, ...]
    lane_map: LaneMap
    collaborators: tuple[str, ...] = ()
    log: str | None = None
    #: per collaborator, what the V2X link did to its message (none listed: a perfect link)
    link: Mapping[str, LinkState] = field(default_factory=dict)
    #: the recorded frame behind a scene of source ``recording`` (None for a simulated one)
    recording: Recording | None = None

    # ---- lookups ---------------------------------------------------------------------------
    def agent(self, agent_id: str) -> Agent:
        for a in self.agents:
            if a.agent_id == agent_id:
                return a
        raise KeyError(agent_id)

    @property
    def ego(self) -> Agent:
        return self.agent(self.ego_id)

    @property
    def vehicles(self) -> tuple[Agent, ...]:
        return tuple(a for a in self.agents if a.is_vehicle)

    @property
    def is_empty(self) -> bool:
        """Nothing to see: no vehicle, no building and no recorded scan."""
        return not self.vehicles and not self.buildings and self.recording is None

    @property
    def keeps_past(self) -> bool:
        """Can its earlier frames be had (its traffic log)? Not for a recording."""
        return self.recording is None

    def can_sense(self, agent_id: str) -> bool:
        """Can ``agent_id`` share a LiDAR scan (be a collaborator)? Every agent of a simulated
        scene; in a recording, the agents whose scan was recorded."""
        return self.recording is None or agent_id in self.recording.views

    @property
    def sensing_ids(self) -> tuple[str, ...]:
        """The ego then its collaborators: the agents whose LiDAR is shared."""
        return (self.ego_id, *self.collaborators)

    # ---- edits -----------------------------------------------------------------------------
    def with_agents(self, agents: Sequence[Agent]) -> "Scene":
        return replace(self, agents=tuple(agents))

    def with_collaborators(self, ids: Sequence[str]) -> "Scene":
        """Other collaborators (their link records go: they describe the old ones' messages)."""
        return replace(self, collaborators=tuple(ids), link={})

    def with_link(self, link: Mapping[str, LinkState]) -> "Scene":
        """The scene with this link record (perfect states left out)."""
        return replace(self, link={k: v for k, v in link.items() if not v.is_perfect})

    def moved(self, moves: dict[str, tuple[float, float, float]]) -> "Scene":
        """A copy with agents displaced: ``moves[agent_id] = (dx_m, dy_m, dyaw_rad)``."""
        return self.with_agents([a.moved(*moves[a.agent_id]) if a.agent_id in moves else a for a in self.agents])

    # ---- YAML ------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {
            "scene_id": self.scene_id, "town": self.town, "source": self.source, "time_s": float(self.time_s),
            "ego": self.ego_id, "collaborators": list(self.collaborators), "log": self.log,
            "agents": [a.to_dict() for a in self.agents],
            "buildings": [b.to_dict() for b in self.buildings],
            "lanes": self.lane_map.to_dict(),
        } | ({"link": {k: v.to_dict() for k, v in self.link.items()}} if self.link else {}) | (
            {"recording": self.recording.to_dict()} if self.recording is not None else {})

    @staticmethod
    def from_dict(d: dict, where: str = "scene") -> "Scene":
        if not isinstance(d, dict):
            raise InputError(f"{where}: not a scene (expected a mapping); give a file written by 'asg scenes extract'")
        missing = [k for k in REQUIRED_KEYS if k not in d]
        if missing:
            raise InputError(f"{where}: scene is missing key '{missing[0]}'; re-extract it with 'asg scenes extract'")
        unknown = [str(k) for k in d if k not in REQUIRED_KEYS + OPTIONAL_KEYS]
        if unknown:
            raise InputError(f"{where}: unknown key '{unknown[0][:60]}' in a scene (known: "
                             f"{', '.join(REQUIRED_KEYS + OPTIONAL_KEYS)}); fix or re-extract it")
        for key in ("town", "log"):
            if d.get(key) is not None and not isinstance(d[key], str):
                raise InputError(f"{where}: '{key}' must be text, got a {type(d[key]).__name__}")
        try:
            agents = tuple(Agent.from_dict(a) for a in _items(d["agents"], "agents"))
            scene = Scene(
                scene_id=checks.safe_id(d["scene_id"], "scene_id"), town=str(d["town"]),
                source=str(d["source"]), time_s=checks.number(d["time_s"], "time_s", 0.0, 1.0e7),
                ego_id=str(d["ego"]), agents=agents,
                buildings=tuple(Building.from_dict(b) for b in _items(d["buildings"], "buildings")),
                lane_map=LaneMap.from_dict(d["lanes"]),
                collaborators=tuple(str(c) for c in _items(d.get("collaborators"), "collaborators")),
                log=None if d.get("log") is None else str(d["log"]),
                link=_link(d.get("link")),
                recording=None if d.get("recording") is None else Recording.from_dict(d["recording"]),
            )
        except InputError as exc:  # each part names itself; the file is named once, here
            raise InputError(f"{where}: {exc}") from None
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise InputError(f"{where}: malformed scene ({type(exc).__name__}: {exc}); re-extract it") from None
        if scene.source not in SCENE_SOURCES:
            raise InputError(f"{where}: source {scene.source!r} is not one of {', '.join(SCENE_SOURCES)}")
        if (scene.source == RECORDING_SOURCE) != (scene.recording is not None):
            raise InputError(f"{where}: a scene of source {RECORDING_SOURCE!r} holds a 'recording' block, and only "
                             "such a scene does; re-import it with 'asg scenes import'")
        if scene.recording is not None:
            unrecorded = next((a for a in scene.sensing_ids if a not in scene.recording.views), None)
            if unrecorded is not None:
                raise InputError(f"{where}: sensing agent '{unrecorded}' has no recorded scan; a recording's "
                                 "sensing agents are the agents of its views")
        ids = Counter(a.agent_id for a in agents)
        if not agents:
            raise InputError(f"{where}: the scene has no agents; pick a frame with traffic")
        dup = next((i for i, n in ids.items() if n > 1), None)
        if dup is not None:
            raise InputError(f"{where}: agent id '{dup}' appears twice; ids must be unique")
        for needed in scene.sensing_ids:
            if needed not in ids:
                raise InputError(f"{where}: agent '{needed}' named as ego or collaborator is not in 'agents'")
        if len(set(scene.sensing_ids)) != len(scene.sensing_ids):
            raise InputError(f"{where}: the ego or a collaborator is named twice")
        stray = next((k for k in scene.link if k not in scene.collaborators), None)
        if stray is not None:
            raise InputError(f"{where}: link record for '{stray}', which is not a collaborator")
        return scene


def _link(value) -> dict[str, LinkState]:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise TypeError("'link' must be a mapping of collaborator id to link state")
    return {str(k): LinkState.from_dict(v, str(k)) for k, v in value.items()}


def _items(value, key: str) -> list:
    """A yaml list (None = empty); anything else is malformed."""
    if value is None:
        return []
    if not isinstance(value, list):
        raise TypeError(f"'{key}' must be a list")
    return value


def scene_file(folder: Path, scene: Scene) -> Path:
    """``folder/SCENE_ID.yaml``, refused (InputError) unless the id is a safe name and the file
    stays inside ``folder``."""
    folder = Path(folder)
    return checks.inside(folder, folder / f"{checks.safe_id(scene.scene_id, 'scene id')}.yaml")


def save_scene(scene: Scene, path: str | Path) -> None:
    """Write the scene as YAML, atomically."""
    write_text_atomic(path, yaml.dump(scene.to_dict(), Dumper=_dumper(), sort_keys=False, default_flow_style=None))


def load_scene(path: str | Path) -> Scene:
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: scene file not found; check the path")
    check_yaml_size(p)
    try:
        data = load_strict_yaml(p.read_text(encoding="utf-8"))
    except InputError as exc:
        raise InputError(f"{p}: {exc}") from None
    except yaml.YAMLError:
        raise InputError(f"{p}: not valid YAML; re-extract the scene") from None
    except UnicodeDecodeError:
        raise InputError(f"{p}: not UTF-8 text; give a scene yaml written by 'asg scenes extract'") from None
    except OSError as exc:
        raise InputError(f"{p}: cannot be read ({exc.strerror}); check its permissions") from None
    except ValueError as exc:  # an integer of more digits than Python converts (its int_max_str_digits)
        raise InputError(f"{p}: a number is out of range ({str(exc).split(';')[0]}); fix the file") from None
    return _log_from(Scene.from_dict(data, str(p)), p.parent)


def _log_from(scene: Scene, folder: Path) -> Scene:
    """A relative ``log`` that names a log folder from the scene file's ``folder`` (as a run folder
    writes its own log, ``../../log``) made absolute; any other value as written."""
    from sumo_scenarios.log import META_NAME

    if not scene.log or Path(scene.log).is_absolute() or not (folder / scene.log / META_NAME).is_file():
        return scene
    return replace(scene, log=str((folder / scene.log).resolve()))


def _dumper():
    return getattr(yaml, "CSafeDumper", yaml.SafeDumper)

