"""What the fcd log costs `asg bench simulate`: libsumo on the bench's 10 dense minutes of grid_small
(same routes every time) recording SUMO's default fcd attributes (`x,y,z,angle,type,speed,pos,lane,slope`,
gzipped, what `asg simulate` asked for before), the attributes it asks for now on a flat net
(sumo_scenarios.fcd.FCD_ATTRIBUTES, gzipped), and no log; median of ROUNDS alternating rounds.
usage: .venv/bin/python docs/experiments/fcd_attributes.py [ROUNDS]
"""
import statistics
import sys
import tempfile
import time
from pathlib import Path

import libsumo
import yaml

from sumo_scenarios.fcd import FCD_ATTRIBUTES
from sumo_scenarios.simulate import SimulationRequest, simulate_sumo

VARIANTS = {
    "sumo_defaults": "x,y,z,angle,type,speed,pos,lane,slope",
    "ours": ",".join(FCD_ATTRIBUTES),
    "no_log": None,
}


def main(rounds: int) -> None:
    tmp = Path(tempfile.mkdtemp())
    log = tmp / "log"
    simulate_sumo(SimulationRequest(out_dir=log, town="grid_small", seed=1, duration_s=540.0, warmup_s=60.0,
                                    density="dense", step_s=0.1))
    max_vehicles = yaml.safe_load((log / "meta.yaml").read_text())["stats"]["max_vehicles"]
    times = {name: [] for name in VARIANTS}
    sizes = {}
    for _ in range(rounds):
        for name, attributes in VARIANTS.items():
            args = ["sumo", "-n", str(log / "map.net.xml"), "-r", str(log / "routes.rou.xml"), "--step-length", "0.1",
                    "--begin", "0", "--end", "600.2", "--seed", "1", "--max-num-vehicles", str(max_vehicles),
                    "--time-to-teleport", "60", "--collision.action", "warn", "--collision.check-junctions", "false",
                    "--no-step-log", "true", "--no-warnings", "true", "--duration-log.disable", "true"]
            out = tmp / f"{name}.xml.gz"
            if attributes:
                args += ["--fcd-output", str(out), "--device.fcd.period", "0.5", "--device.fcd.begin", "60",
                         "--fcd-output.attributes", attributes]
            t = time.perf_counter()
            libsumo.start(args)
            libsumo.simulationStep(600.1)
            libsumo.close()
            times[name].append(time.perf_counter() - t)
            sizes[name] = out.stat().st_size if attributes else 0
    for name, values in times.items():
        print(f"{name:14s} median {statistics.median(values):6.2f} s  runs {[round(v, 2) for v in values]}  "
              f"log {sizes[name] / 1e6:.1f} MB")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 3)
