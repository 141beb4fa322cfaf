"""ASAM OpenSCENARIO 1.2 of each scene (``DIR/SCENE.xosc``), written with scenariogeneration, and
the road network as OpenDRIVE (``DIR/TOWN.xodr``, written by SUMO's netconvert from the net).

Every vehicle is a ScenarioObject placed by a TeleportAction at its final pose (WorldPosition
x, y, z, heading in radians: OpenDRIVE's and SUMO's right-handed frame, x east, y north, so no
conversion) with an AbsoluteSpeedAction at its speed; roadside units are MiscObjects (poles).
Entity names say their role: ``ego_ID``, ``collaborator_ID``, ``vehicle_ID``, ``rsu_ID``. The
storyboard holds the Init only and stops after ``STOP_AFTER_S``: a scene is one instant, for a
simulator (esmini, CARLA's ScenarioRunner) to start from.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

from sumo_scenarios import sumo_tools
from sumo_scenarios.atomic import atomic_path
from sumo_scenarios.checks import inside
from sumo_scenarios.errors import InputError

from ...scene import Scene
from .base import EXPORT_FORMATS, net_of

#: OpenSCENARIO 1.x minor version written (scenariogeneration ships the 1.0 to 1.3 schemas)
OSC_MINOR_VERSION = 2
#: the storyboard's stop trigger: simulation time in seconds
STOP_AFTER_S = 10.0
#: a vehicle's performance limits (OpenSCENARIO requires them): m/s, m/s^2
MAX_SPEED_MPS, MAX_ACCEL_MPS2, MAX_DECEL_MPS2 = 70.0, 10.0, 10.0


def entity_name(scene: Scene, agent_id: str) -> str:
    agent = scene.agent(agent_id)
    role = ("ego" if agent_id == scene.ego_id else "collaborator" if agent_id in scene.collaborators
            else "rsu" if agent.kind == "rsu" else "vehicle")
    return f"{role}_{agent_id}"


@EXPORT_FORMATS.register("openscenario")
class XoscWriter:
    reads_net = True

    def __init__(self, out: Path, net: Path | None = None):
        self.out = out
        self.net = net
        self.roads: dict[str, str] = {}  # net path -> xodr file name

    def write(self, scene: Scene) -> None:
        from scenariogeneration import xosc

        road = self._opendrive(net_of(scene, self.net), scene.town)
        entities, init = xosc.Entities(), xosc.Init()
        for agent in scene.agents:
            name = entity_name(scene, agent.agent_id)
            box = xosc.BoundingBox(agent.width_m, agent.length_m, agent.height_m, 0.0, 0.0, agent.height_m / 2)
            if agent.kind == "rsu":
                entities.add_scenario_object(name, xosc.MiscObject(name, 100.0, xosc.MiscObjectCategory.pole, box))
            else:
                entities.add_scenario_object(name, _vehicle(xosc, name, agent, box))
                init.add_init_action(name, xosc.AbsoluteSpeedAction(
                    float(agent.speed_mps), xosc.TransitionDynamics(xosc.DynamicsShapes.step, xosc.DynamicsDimension.time, 0)))
            init.add_init_action(name, xosc.TeleportAction(
                xosc.WorldPosition(float(agent.x_m), float(agent.y_m), float(agent.z_m), float(agent.yaw_rad), 0.0, 0.0)))
        stop = xosc.ValueTrigger("stop", 0, xosc.ConditionEdge.rising,
                                 xosc.SimulationTimeCondition(STOP_AFTER_S, xosc.Rule.greaterThan), "stop")
        scenario = xosc.Scenario(f"asg {scene.scene_id}", "asg", xosc.ParameterDeclarations(), entities,
                                 xosc.StoryBoard(init, stop), xosc.RoadNetwork(roadfile=road), xosc.Catalog(),
                                 osc_minor_version=OSC_MINOR_VERSION)
        path = inside(self.out, self.out / f"{scene.scene_id}.xosc")
        with atomic_path(path) as tmp:
            scenario.write_xml(str(tmp))

    def _opendrive(self, net: Path, town: str) -> str:
        """The OpenDRIVE file of ``net`` in DIR (written once per net by netconvert); its name."""
        key = str(net.resolve())
        if key not in self.roads:
            name = f"{town}.xodr"
            path = inside(self.out, self.out / name)
            with atomic_path(path) as tmp:
                done = subprocess.run([sumo_tools.binary("netconvert"), "--sumo-net-file", str(net),
                                       "--opendrive-output", str(tmp), "--no-warnings"], capture_output=True, text=True)
                if done.returncode != 0:  # raised inside: the partial file is removed, never renamed
                    last = (done.stderr.strip().splitlines() or ["no message"])[-1]
                    raise InputError(f"{net}: netconvert could not write OpenDRIVE ({last}); check the net")
            self.roads[key] = name
        return self.roads[key]

    def close(self) -> None:
        pass


def _vehicle(xosc, name: str, agent, box):
    category = xosc.VehicleCategory.truck if any(k in agent.type_id.lower() for k in ("truck", "bus")) \
        else xosc.VehicleCategory.car
    wheel_m = 0.7
    front = xosc.Axle(0.5, wheel_m, agent.width_m * 0.8, agent.length_m * 0.3, wheel_m / 2)
    rear = xosc.Axle(0.0, wheel_m, agent.width_m * 0.8, -agent.length_m * 0.3, wheel_m / 2)
    return xosc.Vehicle(name, category, box, front, rear, MAX_SPEED_MPS, MAX_ACCEL_MPS2, MAX_DECEL_MPS2)
