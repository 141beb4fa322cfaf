"""What a training step and a forward pass cost by backbone size: the shipped size, wider
(filters 64/128/256), deeper (layers 3/5/8), between (3/5/5, 64/128/128) and the paper's (0.4 m
pillars, layers 3/5/8, filters 64/128/256). Fresh networks, batch 4, two threads; medians of steps
4-10 on detector-train's first 24 frames, and of 5 forward passes.

    ASG_DATA=... .venv/bin/python docs/experiments/step_cost_by_size.py single|attfuse [SIZE ...]
"""
import itertools
import statistics
import sys
import time
from dataclasses import replace
import numpy as np, torch
from asg.perception.config import load_detector_config
from asg.perception.data import make_sample
from asg.perception.fusion import build_network
from asg.training.loop import Batches, train_step
from asg.perception.feeds import OWN_CLOUD, AGENT_CLOUDS
from asg.datasets import iter_frames
from asg.sensors import load_lidar_spec
torch.set_num_threads(2)
spec = load_lidar_spec()
samples = [make_sample(s, spec) for s in itertools.islice(iter_frames("detector-train", "train"), 24)]
base = load_detector_config()
sizes = {"shipped": base,
         "paper": replace(base, pillar_m=0.4, layers=(3, 5, 8), filters=(64, 128, 256), upsample_channels=128),
         "mid": replace(base, layers=(3, 5, 5), filters=(64, 128, 128), upsample_channels=64),
         "wide": replace(base, filters=(64, 128, 256), upsample_channels=128),
         "deep": replace(base, layers=(3, 5, 8)),
         }
for name in sys.argv[2:] or sizes:
    cfg = sizes[name]
    for kind, net in [(sys.argv[1], {"single": "single", "attfuse": "attfuse"}[sys.argv[1]])]:
        torch.manual_seed(0)
        model = build_network(net, cfg); model.train()
        opt = torch.optim.Adam(model.parameters(), lr=1e-4)
        b = Batches(OWN_CLOUD if kind == "single" else AGENT_CLOUDS, samples, "all")
        rng = np.random.default_rng(0); anchors = model.anchors.numpy()
        ts = []
        for k in range(10):
            t = time.perf_counter(); train_step(model, opt, None, b.draw(rng, 4, anchors, cfg)); ts.append(time.perf_counter() - t)
        model.eval()
        with torch.no_grad():
            inf = []
            for k in range(6):
                cl = [torch.from_numpy(c) for c in b.items[k][0]]
                t = time.perf_counter(); model([cl] if kind == "attfuse" else [cl[0]]); inf.append(time.perf_counter() - t)
        n = sum(p.numel() for p in model.parameters())
        print(f"{name:8s} {kind:8s} params {n/1e6:.2f}M step median {statistics.median(ts[3:]):.2f}s forward {statistics.median(inf[1:]):.3f}s", flush=True)
