"""``asg bench paper``: the generator's targets on the normal scenes of the held-out towns.

Runs AttFuse as the target with (ACS-A, BO), (ACS-A, GA), (ACS-A, RS), (ACS-R, BO) and, with no
collaborator search, (BO), (GA), (RS) on the same scenes and seed, and reports AP@0.3/0.5/0.7
pooled over the scenes (normal, after ACS and challenging) for each, as the paper's tables: fusion
models and collaborator search (ACS-A and ACS-R with BO), search algorithms (the paper's black-box
table is APS alone: the three no-ACS rows) and the ablation (ACS only: ACS-A's after-ACS column;
APS only: no ACS with BO). The scenes are spread evenly over the normal set, so that
both held-out towns, many logs and both ego kinds are in; they are written once to
``OUT/scenes-N``. Each configuration is an ``asg generate`` run folder under
``OUT/<acs>-<search>``, so an interrupted benchmark resumes where it stopped.
"""
from __future__ import annotations

import json
from pathlib import Path

from sumo_scenarios.errors import InputError

from ..executors import Executor
from ..generator.config import GenerateConfig
from ..generator.stages import Stage
from ..objective.ap import DEFAULT_AP_METHOD, check_ap_method

CONFIGS = (("attention", "bo"), ("attention", "ga"), ("attention", "rs"), ("random", "bo"),
           ("off", "bo"), ("off", "ga"), ("off", "rs"))


def bench_paper(out: Path, scenes: int = 30, budget: int = GenerateConfig.budget, fusion: str = "attfuse", seed: int = 1,
                executor: Executor | None = None, ap_method: str = DEFAULT_AP_METHOD) -> dict:
    """Run (or resume) the seven configurations and collect their pooled AP, ranked by
    ``ap_method`` (asg.objective.ap.AP_METHODS). Each configuration's scenes run on ``executor``
    (default: this process); a scene's result does not depend on which worker ran it."""
    from ..generator.run_folder import aggregate_ap
    check_ap_method(ap_method)
    scene_dir = out / f"scenes-{scenes}"
    todo = [(out / f"{acs}-{search}", acs, search) for acs, search in CONFIGS]
    _refuse_other_scenes(out, scene_dir, [run_dir for run_dir, _, _ in todo])
    pick_scenes(scene_dir, scenes)
    for run_dir, acs, search in todo:
        run_config(run_dir, scene_dir, acs, search, scenes, budget, fusion, seed, executor)
    table = {}
    for run_dir, acs, search in todo:
        agg = json.loads((run_dir / "summary.json").read_text())["aggregate"]
        table[f"{acs}-{search}"] = {"normal": aggregate_ap(agg, Stage.NORMAL, ap_method),
                                    "challenging": aggregate_ap(agg, Stage.FINAL, ap_method),
                                    "after_acs": aggregate_ap(agg, Stage.AFTER_ACS, ap_method),
                                    "after_acs_mean": agg["mean_scene_ap_after_acs"], "scenes": agg["scenes"],
                                    "seconds_per_scene_median": agg["seconds_per_scene_median"]}
    return {"fusion": fusion, "budget": budget, "ap_method": ap_method, "table": table}


def _refuse_other_scenes(out: Path, scene_dir: Path, run_dirs: list[Path]) -> None:
    """A resumed benchmark must run on the scenes it started with: refuse ``out`` if it holds
    another pick (``scenes-M``), or configuration runs made without ``scene_dir`` (a benchmark
    written before the pick was stored), whose done scenes would mix into the table."""
    earlier = [d.name for d in out.glob("scenes-*") if d != scene_dir]
    if not earlier and not scene_dir.is_dir() and any((d / "scenes").is_dir() for d in run_dirs):
        earlier = ["a run without its scene folder"]
    if earlier:
        raise InputError(f"{out} holds a benchmark on other scenes ({earlier[0]}); give another --out or the same --scenes")


def pick_scenes(scene_dir: Path, count: int, set_name: str = "normal") -> Path:
    """Write ``count`` scenes of ``set_name`` spread evenly over it (indices round(i * n / count))
    as ``scene_dir/NNN_<scene_id>.yaml`` (kept if already there) and return ``scene_dir``. The set
    lists its logs one after another, so the first ``count`` would all come from one log."""
    from ..datasets import scenes_of
    from ..scene import save_scene

    all_scenes = list(scenes_of(set_name))  # builds the normal set if needed (once, before any worker)
    count = min(count, len(all_scenes))
    picks = sorted({round(i * len(all_scenes) / count) for i in range(count)})
    scene_dir.mkdir(parents=True, exist_ok=True)
    for rank, i in enumerate(picks):
        path = scene_dir / f"{rank:03d}_{all_scenes[i].scene_id}.yaml"
        if not path.is_file():
            save_scene(all_scenes[i], path)  # atomic
    return scene_dir


def run_config(run_dir: Path, scene_dir: Path, acs: str, search: str, scenes: int, budget: int, fusion: str,
                seed: int, executor: Executor | None = None) -> None:
    """One configuration as an ``asg generate`` run into ``run_dir`` (resumes a partial one)."""
    from ..generator.run import SceneSource, open_run
    from ..generator.run_folder import print_table
    from ..generator.config import load_generate_config
    from ..progress import console

    cfg = load_generate_config(fusion=fusion, search=search, acs=acs, aps=True, budget=budget)
    source = SceneSource(scenes=scene_dir)
    run = open_run(cfg, run_dir, source=source, count=scenes, seed=seed).run(executor=executor)
    print_table(run.summary, console)  # per-scene tables to stderr: stdout holds the result
