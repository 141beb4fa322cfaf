import gzip

import pytest
import yaml

from sumo_scenarios.fcd import read_fcd
from sumo_scenarios.log import open_log
from sumo_scenarios.simulate import SimulationRequest, simulate_sumo
from sumo_scenarios.vehicles import VEHICLE_TYPES


def test_sixty_seconds_of_sumo_traffic(sumo_log):
    log = open_log(sumo_log)
    frames = list(log.frames())
    assert len(frames) == 121  # 60 s at 0.5 s, both ends included
    assert frames[0].time_s == pytest.approx(60.0) and frames[-1].time_s == pytest.approx(120.0)
    types = {v.type_id for f in frames for v in f.vehicles}
    assert len(types) >= 3 and types <= {t.type_id for t in VEHICLE_TYPES}
    assert log.meta.source == "sumo" and log.meta.town == "grid_small" and log.meta.seed == 3
    assert len(log.rsus) >= 4
    assert log.vehicle_size("bus") == (12.0, 2.55, 3.1)
    # every recorded vehicle is on the drivable area (front bumper and box centre)
    from asg.scene.from_log import frame_vehicles

    agents = frame_vehicles(log, frames[-1])
    on = sum(log.lane_map.point_on_road(a.x_m, a.y_m) for a in agents)
    assert on >= 0.98 * len(agents)


def test_log_is_real_sumo_fcd_with_vtypes(sumo_log):
    with gzip.open(sumo_log / "fcd.xml.gz", "rt") as fh:
        head = fh.read(5000)
    assert "<fcd-export" in head
    routes = (sumo_log / "routes.rou.xml").read_text()
    assert 'vType id="truck"' in routes and 'height="3.40"' in routes
    meta = yaml.safe_load((sumo_log / "meta.yaml").read_text())
    assert {r["id"] for r in meta["rsus"]} and meta["vehicle_types"][0]["length_m"] > 4


def test_same_seed_same_log(sumo_log, tmp_path):
    again = tmp_path / "again"
    simulate_sumo(SimulationRequest(out_dir=again, town="grid_small", seed=3, duration_s=60.0, density="normal", warmup_s=60.0))
    assert list(read_fcd(again / "fcd.xml.gz")) == list(read_fcd(sumo_log / "fcd.xml.gz"))


def test_dense_traffic_is_dense(tmp_path):
    dense = simulate_sumo(SimulationRequest(out_dir=tmp_path / "d", town="grid_wide", seed=5, duration_s=30.0, density="dense"))
    normal = simulate_sumo(SimulationRequest(out_dir=tmp_path / "n", town="grid_wide", seed=5, duration_s=30.0, density="normal"))
    assert 20 <= dense["near_rsu_median"] <= 35
    assert dense["near_rsu_median"] >= 1.5 * normal["near_rsu_median"]


def test_user_net_runs(tmp_path):
    from sumo_scenarios.paths import nets_dir

    net = tmp_path / "user.net.xml"
    net.write_bytes((nets_dir() / "roundabout.net.xml").read_bytes())
    stats = simulate_sumo(SimulationRequest(out_dir=tmp_path / "u", net=net, seed=1, duration_s=10.0, warmup_s=30.0))
    assert stats["frames"] == 21
    assert open_log(tmp_path / "u").buildings  # generated on the fly
