"""The network on other CPU runtimes: the dense tail of AttFuse (its later backbone stages, the
upsampling and the head, after the fusion: about half the network's time) under torch eager,
torch.jit (traced, frozen, optimize_for_inference: oneDNN's fusions), torch.compile (inductor,
its weights frozen as constants; compiled once for the map's fixed shape, the compile's seconds
reported) and ONNX Runtime (CPU provider, all graph optimisations), one thread each, on FRAMES
normal scenes; medians of REPEATS rounds, the rounds alternating; the largest difference of each
runtime's class logits and box residuals from eager's. Needs onnx and onnxruntime (not asg's dependencies: pip install onnxruntime onnx).
usage: .venv/bin/python docs/experiments/network_runtimes.py [FRAMES] [REPEATS]
"""
import io
import itertools
import json
import statistics
import sys
import time

import torch

from asg.datasets import scenes_of
from asg.perception import build_detector
from asg.scene.neighbours import with_nearest_collaborators
from asg.sensors import load_lidar_spec, simulate_frame


class Tail(torch.nn.Module):
    """AttFuse after its fusion (stage1 placement): fused first-stage map (1, C, n/2, n/2) → head outputs."""

    def __init__(self, model):
        super().__init__()
        self.model = model

    def forward(self, x):
        return self.model.head(self.model.backbone.after_first_stage(x))


def fused_maps(det, frames) -> list[torch.Tensor]:
    """The tail's input of each frame, captured from AttFuse's own forward pass."""
    maps, backbone = [], det.model.backbone
    original = backbone.after_first_stage
    backbone.after_first_stage = lambda first: (maps.append(first.clone().contiguous()), original(first))[1]
    try:
        with torch.no_grad():
            for f in frames:
                det.model([det._sample(f, det._clouds(f))])
    finally:
        backbone.after_first_stage = original
    return maps


def main(count: int, repeats: int) -> None:
    import onnxruntime as ort

    torch.set_num_threads(1)
    spec = load_lidar_spec()
    frames = [simulate_frame(with_nearest_collaborators(s, 2), spec) for s in itertools.islice(scenes_of("normal"), count)]
    det = build_detector("attfuse")
    assert det.model.placement == "stage1"
    tail = Tail(det.model).eval()
    maps = fused_maps(det, frames)
    with torch.no_grad():
        frozen = torch.jit.optimize_for_inference(torch.jit.freeze(torch.jit.trace(tail, (maps[0],)).eval()))
        buf = io.BytesIO()
        torch.onnx.export(tail, (maps[0],), buf, input_names=["x"], output_names=["cls", "box", "dir", "feat"],
                          opset_version=17, dynamo=False)
    options = ort.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    session = ort.InferenceSession(buf.getvalue(), options, providers=["CPUExecutionProvider"])
    arrays = [m.numpy() for m in maps]
    import torch._inductor.config as inductor

    inductor.freezing = True
    compiled = torch.compile(tail, dynamic=False)
    with torch.no_grad():
        t = time.perf_counter()
        compiled(maps[0])
        compile_s = time.perf_counter() - t
    runs = {
        "torch eager": lambda: [tail(m) for m in maps],
        "torch.jit frozen": lambda: [frozen(m) for m in maps],
        "torch.compile frozen": lambda: [compiled(m) for m in maps],
        "onnxruntime": lambda: [[torch.from_numpy(o) for o in session.run(None, {"x": a})] for a in arrays],
    }
    times = {name: [] for name in runs}
    with torch.no_grad():
        outs = {name: run() for name, run in runs.items()}  # warm-up, and the outputs compared
        for _ in range(repeats):
            for name, run in runs.items():
                t = time.perf_counter()
                run()
                times[name].append((time.perf_counter() - t) / len(maps) * 1e3)
        whole = [det._sample(f, det._clouds(f)) for f in frames]
        t = time.perf_counter()
        for s in whole:
            det.model([s])
        whole_ms = (time.perf_counter() - t) / len(whole) * 1e3
    eager = outs["torch eager"]
    result = {"frames": len(maps), "repeats": repeats, "threads": 1, "whole_network_eager_ms": round(whole_ms, 2),
              "torch_compile_s": round(compile_s, 1), "torch": torch.__version__,
              "tail_ms_median": {n: round(statistics.median(v), 2) for n, v in times.items()},
              "largest_difference_from_eager": {
                  n: {"cls_logit": max(float((e[0] - o[0]).abs().max()) for e, o in zip(eager, out)),
                      "box_residual": max(float((e[1] - o[1]).abs().max()) for e, o in zip(eager, out))}
                  for n, out in outs.items() if n != "torch eager"}}
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 8, int(sys.argv[2]) if len(sys.argv) > 2 else 5)
