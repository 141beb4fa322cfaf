"""Milliseconds OpenCOOD's ``load_yaml`` takes a file of an exported training set, as shipped
(PyYAML's pure-Python full ``Loader``) and as asg's trainer child reads it
(asg.perception.opencood.trainer.libyaml_reading: libyaml under a safe loader with OpenCOOD's float
resolver), and whether the two give the same dicts.

    python docs/experiments/opencood_yaml_time.py EXPORT_DIR [--files 40] [--rounds 3] [--out FILE.json]

EXPORT_DIR is an ``asg export --format opv2v`` folder; the first ``--files`` agent yaml files in
path order are read ``--rounds`` times each way, alternating, in one process; medians over rounds
of the mean milliseconds a file. Nothing is written into EXPORT_DIR.
"""
from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("export_dir", type=Path)
    p.add_argument("--files", type=int, default=40)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args()

    from asg.perception.opencood.runtime import module
    from asg.perception.opencood.trainer import libyaml_reading

    utils = module("hypes_yaml.yaml_utils")
    shipped = utils.load_yaml
    libyaml_reading()
    patched = utils.load_yaml
    files = sorted(str(f) for f in args.export_dir.glob("*/*/*.yaml"))[:args.files]
    if not files:
        raise SystemExit(f"{args.export_dir}: no agent yaml files; give an 'asg export --format opv2v' folder")
    ms: dict[str, list[float]] = {"shipped": [], "libyaml": []}
    for _ in range(args.rounds):
        for name, load in (("shipped", shipped), ("libyaml", patched)):
            start = time.perf_counter()
            for f in files:
                load(f)
            ms[name].append(1000 * (time.perf_counter() - start) / len(files))
    for f in files:
        np.testing.assert_equal(patched(f), shipped(f))
    result = {"files": len(files), "rounds": args.rounds, "same_dicts": True,
              **{f"{name}_ms": round(statistics.median(v), 1) for name, v in ms.items()},
              "ratio": round(statistics.median(ms["shipped"]) / statistics.median(ms["libyaml"]), 2)}
    print(json.dumps(result))
    if args.out:
        args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
