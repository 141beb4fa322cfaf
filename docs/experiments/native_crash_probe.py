"""Who handles the fatal signals (SIGSEGV & co.) of this process, and which native threads live on,
as the test suite's process goes through its phases: imports, libsumo, torch, Embree, a Ray batch
(``ray.init`` ... ``ray.shutdown``, directly and through asg's RayExecutor); then Ray started and
shut down several times with renders, torch and garbage collection in between.

    python docs/experiments/native_crash_probe.py [ROUNDS] [SECONDS_PER_ROUND]

Prints each phase's handler owner (the shared object its address falls in) and, after Ray, the
native threads still alive. What it showed (docs/results/README.md, "The suite's crash"): every
library leaves pytest's faulthandler in place except Ray, whose ``ray.init`` installs Abseil's
failure handler and whose ``ray.shutdown`` leaves SIG_DFL; Ray's GCS client and gRPC threads live on
after ``ray.shutdown``.
"""
from __future__ import annotations

import ctypes
import faulthandler
import gc
import os
import signal
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))

from asg.executors.fatal_signals import handler_address, saved_fatal_handlers  # noqa: E402

_libc = ctypes.CDLL(None)


class _DlInfo(ctypes.Structure):
    _fields_ = [("dli_fname", ctypes.c_char_p), ("dli_fbase", ctypes.c_void_p), ("dli_sname", ctypes.c_char_p),
                ("dli_saddr", ctypes.c_void_p)]


def owners() -> dict[str, str]:
    """{signal name: the shared object its handler lives in, or SIG_DFL / SIG_IGN}."""
    out = {}
    for sig, buf in saved_fatal_handlers().items():
        address = handler_address(buf)
        if address <= 1:
            out[signal.Signals(sig).name] = ("SIG_DFL", "SIG_IGN")[address]
            continue
        info = _DlInfo()
        _libc.dladdr(ctypes.c_void_p(address), ctypes.byref(info))
        out[signal.Signals(sig).name] = Path((info.dli_fname or b"?").decode()).name
    return out


def threads() -> list[str]:
    names = []
    for task in os.listdir("/proc/self/task"):
        try:
            names.append(Path(f"/proc/self/task/{task}/comm").read_text().strip())
        except OSError:
            pass
    return sorted(set(names))


def main(rounds: int = 4, seconds: float = 30.0) -> None:
    import numpy as np
    import torch
    import trimesh

    from asg.executors import build_executor
    from asg.sensors import load_lidar_spec
    from asg.sensors.raycast import EmbreeCaster
    from asg.sensors.world import World
    from conftest import car, cross_map, make_scene, rsu
    from sumo_scenarios.simulate import SimulationRequest, simulate_sumo

    faulthandler.enable()
    print("faulthandler on:", owners()["SIGSEGV"])
    with tempfile.TemporaryDirectory() as tmp:
        simulate_sumo(SimulationRequest(out_dir=Path(tmp) / "log", town="grid_small", seed=1, duration_s=5.0))
    torch.nn.functional.conv2d(torch.randn(1, 4, 32, 32), torch.randn(4, 4, 3, 3))
    box = trimesh.creation.box()
    EmbreeCaster(box.vertices[box.faces]).first_hits(np.array([[-3.0, 0, 0]]), np.array([[1.0, 0, 0]]))
    print("after libsumo, torch, Embree:", owners()["SIGSEGV"])
    import ray

    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False, logging_level="ERROR")
    print("ray.init directly:", owners()["SIGSEGV"])
    ray.shutdown()
    print("ray.shutdown directly:", owners()["SIGSEGV"], "| native threads left:", threads())
    faulthandler.disable()  # (enable() alone does nothing while faulthandler believes it is on)
    faulthandler.enable()
    with build_executor("ray", 1) as executor:
        executor.connect()
        print("asg's RayExecutor, Ray running:", owners()["SIGSEGV"])
    print("asg's RayExecutor, after shutdown:", owners()["SIGSEGV"])

    @ray.remote
    def square(x):
        return x * x

    lane_map = cross_map.__wrapped__()
    spec = load_lidar_spec()
    rng = np.random.default_rng(1)
    for r in range(rounds):
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level="ERROR")
        assert ray.get([square.remote(i) for i in range(8)])[3] == 9
        ray.shutdown()
        faulthandler.disable()  # Ray left SIG_DFL: a crash below would otherwise be silent
        faulthandler.enable()
        started = time.time()
        while time.time() - started < seconds:
            cars = [car(f"v{k}", float(rng.uniform(-40, 40)), float(rng.choice([-1.6, 1.6]))) for k in range(8)]
            scene = make_scene(lane_map, [rsu("r0", 8.0, 8.0), *cars], ego="r0", collaborators=("v0", "v1"))
            World(scene, spec).render_many(["r0", "v0", "v1"])
            torch.nn.functional.conv2d(torch.randn(2, 16, 64, 64), torch.randn(16, 16, 3, 3)).sum()
            gc.collect()
        print(f"round {r}: Ray started and shut down, {seconds:g} s of work after it: no crash", flush=True)


if __name__ == "__main__":
    main(*(int(sys.argv[1]),) if len(sys.argv) > 1 else (), *(float(sys.argv[2]),) if len(sys.argv) > 2 else ())
