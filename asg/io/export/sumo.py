"""SUMO route and state files that continue the traffic from each final scene: ``DIR/SCENE.rou.xml``,
``DIR/SCENE.sumocfg`` (net: the scene's town, referenced by absolute path) and ``DIR/SCENE.state.xml``
(SUMO's own snapshot, written by SUMO from the routes: ``sumo -n NET --load-state SCENE.state.xml``).

Every vehicle departs at time 0 on the lane it stands on (the nearest normal lane when it stands
inside a junction or off its recorded lane after a move), at its position along that lane (SUMO's
``departPos`` is the vehicle's front), with its speed and without SUMO's insertion checks (the scene
is plausible already: the vehicles stand where the scene has them), on a route that starts with that edge and
follows the first permitted connection onward for up to ``ROUTE_EDGES`` edges; its vType carries
its length, width and height (a type whose vehicles differ in size, as a recording's cars do, is
one vType a size: ``TYPE@LxWxH``). Roadside units are not traffic and are left out. Read the files with
sumolib or run them: ``sumo -c DIR/SCENE.sumocfg``.
"""
from __future__ import annotations

import math
from collections import Counter
from pathlib import Path
from xml.sax.saxutils import quoteattr

from sumo_scenarios.atomic import atomic_path, write_text_atomic
from sumo_scenarios.checks import inside
from sumo_scenarios.errors import InputError
from sumo_scenarios.geometry import heading_gap_rad

from ...scene import Scene
from .base import EXPORT_FORMATS, net_of

#: edges on each vehicle's route (its own, then the first permitted successors)
ROUTE_EDGES = 12
#: search radius for a vehicle's lane, metres
LANE_SEARCH_M = 10.0
#: the state file: SUMO inserts the vehicles at its first step (STEP_S) and saves them at STATE_TIME_S
STEP_S = 0.1
STATE_TIME_S = 0.1


@EXPORT_FORMATS.register("sumo")
class RoutesWriter:
    reads_net = True

    def __init__(self, out: Path, net: Path | None = None):
        self.out = out
        self.net = net
        self.nets: dict[str, object] = {}

    def write(self, scene: Scene) -> None:
        net_path = net_of(scene, self.net)
        net = self._net(net_path)
        types, vehicles = _vtypes(scene.vehicles), []
        for agent in sorted(scene.vehicles, key=lambda a: a.agent_id):
            lane, pos = _place(net, agent)
            edges = _route(lane.getEdge())
            vehicles.append(
                f'    <vehicle id={quoteattr(agent.agent_id)} type={quoteattr(types[_size(agent)])} depart="0.00" '
                f'departLane="{lane.getIndex()}" departPos="{pos:.2f}" departSpeed="{max(agent.speed_mps, 0.0):.2f}" '
                f'insertionChecks="none">\n'
                f'        <route edges={quoteattr(" ".join(e.getID() for e in edges))}/>\n    </vehicle>')
        vtypes = [f'    <vType id={quoteattr(t)} length="{size[1]}" width="{size[2]}" height="{size[3]}"/>'
                  for size, t in sorted(types.items(), key=lambda kv: kv[1])]
        routes = inside(self.out, self.out / f"{scene.scene_id}.rou.xml")
        config = inside(self.out, self.out / f"{scene.scene_id}.sumocfg")
        try:
            write_text_atomic(routes, "<routes>\n" + "\n".join(vtypes + vehicles) + "\n</routes>\n")
            write_text_atomic(config, (
                "<configuration>\n    <input>\n"
                f"        <net-file value={quoteattr(str(net_path.resolve()))}/>\n"
                f"        <route-files value={quoteattr(routes.name)}/>\n"
                "    </input>\n    <time>\n        <begin value=\"0\"/>\n    </time>\n</configuration>\n"))
            self._state(config, inside(self.out, self.out / f"{scene.scene_id}.state.xml"))
        except BaseException:  # a scene's files are all written or none is
            routes.unlink(missing_ok=True)
            config.unlink(missing_ok=True)
            raise

    @staticmethod
    def _state(config: Path, state: Path) -> None:
        """SUMO's own state file of the scene: the routes run for one step, saved at STATE_TIME_S."""
        import subprocess

        from sumo_scenarios import sumo_tools

        with atomic_path(state) as tmp:
            done = subprocess.run([sumo_tools.binary("sumo"), "-c", str(config), "--step-length", f"{STEP_S}",
                                   "--end", f"{2 * STATE_TIME_S}", "--save-state.times", f"{STATE_TIME_S}",
                                   "--save-state.files", str(tmp), "--no-step-log", "--no-warnings"],
                                  capture_output=True, text=True, env=sumo_tools.sumo_env())
            if done.returncode != 0 or not tmp.stat().st_size:
                cause = sumo_tools.first_error([line.strip() for line in done.stderr.splitlines() if line.strip()])
                raise InputError(f"{config}: SUMO could not load the exported routes ({cause or 'no message'})")

    def _net(self, path: Path):
        import sumolib

        key = str(path.resolve())
        if key not in self.nets:
            try:
                self.nets[key] = sumolib.net.readNet(str(path))
            except Exception as exc:  # sumolib raises several types for broken nets
                raise InputError(f"{path}: not a readable SUMO net ({type(exc).__name__}); check --net") from None
        return self.nets[key]

    def close(self) -> None:
        pass


def _size(agent) -> tuple[str, str, str, str]:
    """(type, length, width, height) of a vehicle as the routes file writes them (cm)."""
    return agent.type_id, f"{agent.length_m:.2f}", f"{agent.width_m:.2f}", f"{agent.height_m:.2f}"


def _vtypes(vehicles) -> dict[tuple[str, str, str, str], str]:
    """{a vehicle's :func:`_size`: its vType id}: the type's own id where all its vehicles have one
    size, else ``TYPE@LxWxH`` a size (``+`` appended while another type has that id)."""
    sizes = sorted({_size(a) for a in vehicles})
    count = Counter(size[0] for size in sizes)
    ids = {size: size[0] for size in sizes if count[size[0]] == 1}
    taken = set(ids.values())
    for size in sizes:
        if size not in ids:
            name = f"{size[0]}@{size[1]}x{size[2]}x{size[3]}"
            while name in taken:
                name += "+"
            ids[size] = name
            taken.add(name)
    return ids


def _place(net, agent):
    """(lane, departPos) for ``agent``: its recorded lane if it is a normal lane within reach, else
    the nearest normal lane that allows passenger cars; departPos = front of the vehicle."""
    front_xy = (agent.x_m + math.cos(agent.yaw_rad) * agent.length_m / 2,
                agent.y_m + math.sin(agent.yaw_rad) * agent.length_m / 2)
    candidates = [(lane, d) for lane, d in net.getNeighboringLanes(agent.x_m, agent.y_m, LANE_SEARCH_M)
                  if lane.allows("passenger")]
    if not candidates:
        raise InputError(f"vehicle {agent.agent_id}: no lane within {LANE_SEARCH_M:g} m in the net; "
                         "give the scene's own net with --net")
    own = [c for c in candidates if c[0].getID() == agent.lane_id]
    lane = (own or sorted(candidates, key=lambda c: (c[1], _heading_gap(c[0], agent))))[0][0]
    pos, _ = lane.getClosestLanePosAndDist(front_xy)
    return lane, min(max(pos, agent.length_m), lane.getLength())


def _heading_gap(lane, agent) -> float:
    shape = lane.getShape()
    (x0, y0), (x1, y1) = shape[0], shape[-1]
    return heading_gap_rad(math.atan2(y1 - y0, x1 - x0), agent.yaw_rad)


def _route(edge) -> list:
    """``edge`` then the first permitted successor of each, up to ROUTE_EDGES edges, no repeats."""
    edges = [edge]
    while len(edges) < ROUTE_EDGES:
        onward = [e for e in edge.getOutgoing() if e not in edges and e.allows("passenger")]
        if not onward:
            break
        edge = sorted(onward, key=lambda e: e.getID())[0]
        edges.append(edge)
    return edges
