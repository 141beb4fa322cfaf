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
    assert ' lane="' in head and ' pos="' not in head and ' z="' not in head  # a flat net: no z, no slope
    routes = (sumo_log / "routes.rou.xml").read_text()
    assert 'vType id="truck"' in routes and 'height="3.40"' in routes
    meta = yaml.safe_load((sumo_log / "meta.yaml").read_text())
    assert {r["id"] for r in meta["rsus"]} and meta["vehicle_types"][0]["length_m"] > 4


@pytest.mark.slow
def test_same_seed_same_log(sumo_log, tmp_path):
    again = tmp_path / "again"
    simulate_sumo(SimulationRequest(out_dir=again, town="grid_small", seed=3, duration_s=60.0, density="normal", warmup_s=60.0))
    assert list(read_fcd(again / "fcd.xml.gz")) == list(read_fcd(sumo_log / "fcd.xml.gz"))


@pytest.mark.slow
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


def test_net_with_elevation_records_z(tmp_path):
    """A net whose shapes carry z gets z (and slope) in its log; a flat one does not (above)."""
    import re

    from sumo_scenarios.paths import nets_dir
    from sumo_scenarios.simulate import net_has_elevation

    flat = nets_dir() / "roundabout.net.xml"
    assert not net_has_elevation(flat)
    raised = re.sub(r'shape="([^"]*)"', lambda m: 'shape="' + " ".join(p + ",2.00" for p in m.group(1).split()) + '"',
                    flat.read_text())
    net = tmp_path / "raised.net.xml"
    net.write_text(raised)
    assert net_has_elevation(net)
    simulate_sumo(SimulationRequest(out_dir=tmp_path / "u", net=net, seed=1, duration_s=5.0, warmup_s=20.0))
    vehicles = [v for f in read_fcd(tmp_path / "u" / "fcd.xml.gz") for v in f.vehicles]
    assert vehicles and all(v.z_m == pytest.approx(2.0) for v in vehicles)


def test_net_with_a_broken_shape_is_refused(tmp_path):
    from sumo_scenarios.errors import InputError
    from sumo_scenarios.simulate import net_has_elevation

    net = tmp_path / "bad.net.xml"
    net.write_text('<net><edge id="e"><lane id="e_0" shape="0,0,x 1,1,1"/></edge></net>')
    with pytest.raises(InputError, match="not numbers"):
        net_has_elevation(net)
