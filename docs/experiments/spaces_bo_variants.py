"""Searches and their settings in the union of spaces (31 dimensions): AttFuse, ACS-A, budget 50,
on the spaces table's 30 benchmark scenes; AP over the final scenes (as `asg bench paper --table
spaces`) for random search, BO with other initial-design sizes (`n_initial`) and confidence bounds
(`kappa`), other nevergrad optimisers, and any of them at another budget (`@N`: the ceiling that
more evaluations reach).
usage: .venv/bin/python docs/experiments/spaces_bo_variants.py SCENES_DIR OUT VARIANT [VARIANT...]
  VARIANT: rs | bo | bo:n_initial=10 | bo:kappa=1.0 | ng:optimizer=TwoPointsDE | rs@250 | ...
  (each variant runs in this process on one thread; run two commands side by side for two cores,
  or set WORKERS=2 in the environment for two worker processes: random search and the searches'
  defaults only, as a variant's changed settings stay in this process; MOVERS=M moves M vehicles
  instead of the configured 3, NQ=N draws a feasible set Q of N members instead of 1000)
"""
import json
import os
import sys
from dataclasses import replace
from pathlib import Path

import asg.generator.pipeline as pipeline
from asg.benchmarks.tables import UNION
from asg.executors import build_executor
from asg.datasets import scenes_of
from asg.generator.run import open_run
from asg.generator.pipeline import load_generate_config, with_space_flags
from asg.generator.run_folder import aggregate_ap
from asg.generator.stages import Stage


def _value(text: str):
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def run_variant(scenes: Path, out: Path, variant: str) -> dict:
    name, _, budget = variant.partition("@")
    search, _, overrides = name.partition(":")
    params = {k: _value(v) for k, v in (kv.split("=") for kv in overrides.split(",") if kv)}
    defaults = pipeline.search_params
    pipeline.search_params = lambda name: defaults(name) | (params if name == search else {})
    try:
        movers = os.environ.get("MOVERS")
        cfg = with_space_flags(load_generate_config(fusion="attfuse", acs="attention", search=search,
                                                    budget=int(budget) if budget else None,
                                                    perturbed=int(movers) if movers else None), None, UNION)
        n_q = os.environ.get("NQ")
        if n_q:
            cfg = replace(cfg, space=replace(cfg.space, n_q=int(n_q)))
        run_dir = out / (variant.replace(":", "_").replace(",", "_").replace("=", "").replace("@", "_budget")
                         + (f"_movers{movers}" if movers else "") + (f"_nq{n_q}" if n_q else ""))
        run_folder = open_run(cfg, run_dir, scenes=list(scenes_of(str(scenes))),
                              record={"scenes": str(scenes), "variant": variant}, seed=1)
        workers = int(os.environ.get("WORKERS", "0"))
        if workers and params:
            raise SystemExit("WORKERS applies to variants without settings (the workers read the searches' yaml)")
        executor = build_executor("local", workers) if workers else None
        agg = run_folder.run(artifacts=False, executor=executor).summary["aggregate"]
    finally:
        pipeline.search_params = defaults
    return {"variant": variant, "budget": cfg.budget, "movers": cfg.perturbed, "n_q": cfg.space.n_q, "scenes": agg["scenes"], "normal": agg["ap_normal"], "challenging": aggregate_ap(agg, Stage.FINAL)}


if __name__ == "__main__":
    for v in sys.argv[3:]:
        print(json.dumps(run_variant(Path(sys.argv[1]), Path(sys.argv[2]), v)), flush=True)
