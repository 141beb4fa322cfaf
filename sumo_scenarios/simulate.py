"""Run SUMO in-process through libsumo and record an fcd-output log folder (see ``log.py``)."""
from __future__ import annotations

import re
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from . import checks
from .atomic import atomic_dir, remove_stale_partials_of, write_text_atomic
from .buildings import write_buildings
from .errors import InputError
from .fcd import FCD_ATTRIBUTES, FCD_ELEVATION_ATTRIBUTES, FcdFrame, FcdVehicle
from .log import BUILDINGS_NAME, FCD_NAME, NET_NAME, ROUTES_NAME, VTYPES_NAME, LogMeta, density_stats, write_meta
from .routes import DENSITIES, Density, TrafficParams, make_routes
from .rsu import place_rsus
from .towns import demand_scale, load_town
from .vehicles import VEHICLE_TYPES, vtypes_additional_xml

#: called with (simulated seconds done, seconds in total)
Progress = Callable[[float, float], None]


@dataclass(frozen=True)
class SimulationRequest:
    """What ``asg simulate`` asks for. Times in seconds; ``warmup_s`` runs before recording starts."""

    out_dir: Path
    town: str | None = None
    net: Path | None = None
    seed: int = 1
    duration_s: float = 60.0
    density: Density = "normal"
    step_s: float = 0.1
    record_period_s: float = 0.5
    warmup_s: float = 90.0
    traffic: TrafficParams | None = None  # None: defaults scaled by the town's demand_scale

    def validate(self) -> None:
        validate_times(self.duration_s, self.warmup_s)
        checks.number(self.step_s, "--step (s)", 0.0, 1.0, lo_open=True)
        checks.number(self.record_period_s, "--record-period (s)", 0.0, MAX_SECONDS, lo_open=True)
        checks.number(self.seed, "--seed", 0, 2**31 - 1)
        if self.record_period_s < self.step_s:
            raise InputError(f"--record-period ({self.record_period_s:g} s) must be at least the step ({self.step_s:g} s)")
        if self.density not in DENSITIES:
            raise InputError(f"--density must be one of {', '.join(DENSITIES)}, got {self.density!r}")


def validate_times(duration_s: float, warmup_s: float) -> None:
    """The recorded duration must be positive and the warm-up not negative (seconds), both finite
    and at most MAX_SECONDS."""
    if not duration_s > 0:  # also NaN
        raise InputError(f"--duration must be positive seconds, got {duration_s:g}")
    checks.number(duration_s, "--duration (s)", 0.0, MAX_SECONDS)
    if not warmup_s >= 0:
        raise InputError(f"--warmup must be zero or more seconds, got {warmup_s:g}")
    checks.number(warmup_s, "--warmup (s)", 0.0, MAX_SECONDS)


#: a day of simulated traffic at most
MAX_SECONDS = 86_400.0


def simulate_sumo(req: SimulationRequest, progress: Progress | None = None) -> dict:
    """Simulate and write the log folder ``req.out_dir`` atomically; returns the density stats."""
    req.validate()
    town = load_town(req.town, req.net, seed=req.seed)
    remove_stale_partials_of(req.out_dir)
    rsus = place_rsus(town.lane_map, town.buildings)
    end_s = req.warmup_s + req.duration_s
    with atomic_dir(req.out_dir) as work:
        shutil.copyfile(town.net_path, work / NET_NAME)
        write_buildings(work / BUILDINGS_NAME, town.buildings)
        vtypes = work / VTYPES_NAME
        write_text_atomic(vtypes, vtypes_additional_xml())
        traffic = req.traffic or TrafficParams(scale=demand_scale(req.town))
        routes = make_routes(work / NET_NAME, vtypes, work / ROUTES_NAME, req.seed, end_s, req.density, traffic,
                             label=req.town or str(req.net))
        for leftover in work.glob("*.trips.xml"):
            leftover.unlink()
        max_vehicles = traffic.max_vehicles(req.density, town.lane_map.lane_km())
        wall, samples = _run_libsumo(work, routes, req, end_s, max_vehicles, progress)
        sizes = {t.type_id: t.length_m for t in VEHICLE_TYPES}
        stats = density_stats(samples, list(rsus), sizes)
        stats["frames"] = int(round(req.duration_s / req.record_period_s)) + 1
        stats["max_vehicles"] = max_vehicles
        stats["wall_s"] = round(wall, 3)
        stats["steps_per_s"] = round(end_s / req.step_s / wall, 1) if wall > 0 else None
        write_meta(work, LogMeta(
            source="sumo", town=town.name, seed=req.seed, density=req.density, duration_s=req.duration_s,
            warmup_s=req.warmup_s, step_s=req.step_s, record_period_s=req.record_period_s, map_file=NET_NAME,
            buildings_file=BUILDINGS_NAME, vehicle_types=tuple(t.to_dict() for t in VEHICLE_TYPES),
            rsus=tuple(r.to_dict() for r in rsus), stats=stats, net_source=str(town.net_path),
        ))
    return stats


#: simulated seconds between the samples that the density statistics are computed on
STATS_EVERY_S = 5.0


def _run_libsumo(work: Path, routes: Path, req: SimulationRequest, end_s: float, max_vehicles: int,
                 progress: Progress | None) -> tuple[float, list[FcdFrame]]:
    """Step SUMO to ``end_s``; SUMO writes the fcd log itself. Returns wall seconds and the
    vehicle samples (every ``STATS_EVERY_S`` after the warm-up) for the density statistics."""
    import libsumo

    args = [
        "sumo", "-n", str(work / NET_NAME), "-r", str(routes),
        "--step-length", str(req.step_s), "--begin", "0", "--end", f"{end_s + 2 * req.step_s:.2f}",
        "--seed", str(req.seed), "--fcd-output", str(work / FCD_NAME),
        "--device.fcd.period", str(req.record_period_s), "--device.fcd.begin", f"{req.warmup_s:.2f}",
        "--fcd-output.attributes", ",".join(fcd_attributes(work / NET_NAME)),
        "--max-num-vehicles", str(max_vehicles), "--time-to-teleport", "60", "--collision.action", "warn", "--collision.check-junctions", "false",
        "--no-step-log", "true", "--no-warnings", "true", "--duration-log.disable", "true",
    ]
    started = time.perf_counter()
    try:
        libsumo.start(args)
    except Exception as exc:  # libsumo raises its own TraCIException/FatalTraCIError
        raise InputError(f"SUMO refused the simulation: {exc}") from None
    samples: list[FcdFrame] = []
    try:
        t = 0.0
        next_sample = req.warmup_s
        while t < end_s - 1e-9:
            t = min(end_s, t + STATS_EVERY_S, max(next_sample, t + req.step_s))
            libsumo.simulationStep(t)
            if t >= next_sample - 1e-9:
                samples.append(_sample(libsumo, t))
                next_sample += STATS_EVERY_S
            if progress is not None:
                progress(t, end_s)
        libsumo.simulationStep()  # one more step so that the frame at end_s is written
    finally:
        libsumo.close()
    return time.perf_counter() - started, samples


def fcd_attributes(net_path: Path) -> tuple[str, ...]:
    """The fcd attributes to record on this net: ``z`` and ``slope`` only where it has elevation (as
    SUMO's own default does for ``z``), never ``pos``."""
    if net_has_elevation(net_path):
        return FCD_ATTRIBUTES[:2] + FCD_ELEVATION_ATTRIBUTES[:1] + FCD_ATTRIBUTES[2:] + FCD_ELEVATION_ATTRIBUTES[1:]
    return FCD_ATTRIBUTES


def net_has_elevation(net_path: Path) -> bool:
    """Whether any ``shape`` in the ``.net.xml`` has a point with a non-zero z (netconvert writes 2-D
    shapes on a flat net)."""
    for match in re.finditer(rb'shape="([^"]*)"', Path(net_path).read_bytes()):
        points = [p.split(b",") for p in match.group(1).split()]
        if any(len(p) == 3 for p in points):
            try:
                if any(len(p) == 3 and float(p[2]) != 0.0 for p in points):
                    return True
            except ValueError:
                raise InputError(f"{net_path}: a shape holds a point that is not numbers "
                                 f"({match.group(1)[:60].decode(errors='replace')!r}); rebuild the net with netconvert") from None
    return False


def _sample(libsumo, time_s: float) -> FcdFrame:
    v = libsumo.vehicle
    rows = []
    for vid in v.getIDList():
        x, y = v.getPosition(vid)
        rows.append(FcdVehicle(vid, x, y, 0.0, v.getAngle(vid), v.getTypeID(vid), 0.0, ""))
    return FcdFrame(time_s, tuple(rows))
