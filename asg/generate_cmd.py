"""``asg generate`` on the command line: turn the flags into typed settings, call
:func:`asg.generate.generate` with a progress bar, print the before/after table."""
from __future__ import annotations

import argparse
from pathlib import Path

from rich.table import Table

from sumo_scenarios.errors import InputError

from .executors import Executor, build_executor, default_workers
from .generate import LOG_DIR, SceneSource, WORK_DIR, check_scenes, factory_models, generate, load_scenes, prepare_run, run_settings
from .pipeline import load_generate_config
from .progress import console, progress_bar, stdout

#: the no-argument demo: a held-out town, the strongest shipped model as target (Early Fusion:
#: ahead of Late at AP@0.7, in a third of Late's inference time; AttFuse still steers the
#: collaborator search), a short budget
DEMO = {"town": "fiveleg", "count": 2, "budget": 15, "fusion": "early"}
#: scenes generated when --count is not given
DEFAULT_COUNT = 10


def with_space_flags(cfg, plausibility: str | None, spaces: str | None):
    """``cfg`` with the --plausibility and --space flags (``spaces``: comma-separated names) applied."""
    from dataclasses import replace

    from .search import SpaceConfig

    changes = {}
    if plausibility is not None:
        changes["plausibility"] = plausibility
    if spaces is not None:
        changes["kinds"] = tuple(k.strip() for k in spaces.split(",") if k.strip())
    if not changes:
        return cfg
    fields = {f: getattr(cfg.space, f) for f in SpaceConfig.__dataclass_fields__} | changes
    return replace(cfg, space=SpaceConfig(**fields))


def run_generate(args: argparse.Namespace) -> int:
    """``asg generate`` with parsed ``args``."""
    import shutil

    demo = args.town is None and args.net is None and args.scenes is None
    source = SceneSource(town=DEMO["town"] if demo else args.town, net=args.net, scenes=args.scenes)
    count = args.count if args.count is not None else (DEMO["count"] if demo else DEFAULT_COUNT)
    budget = args.budget if args.budget is not None else (DEMO["budget"] if demo else None)
    fusion = args.fusion or (DEMO["fusion"] if demo else None)
    if args.weights is not None and args.detector:
        raise InputError("--weights picks the weights of a shipped --fusion; your --detector factory loads its own")
    cfg = load_generate_config(args.config, fusion=fusion, search=args.search, acs=args.acs,
                               aps=None if args.aps is None else args.aps == "on", budget=budget, perturbed=args.movers,
                               weights=None if args.weights is None else str(args.weights))
    cfg = with_space_flags(cfg, args.plausibility, args.space)
    if cfg.weights and not args.detector:
        from .perception import check_weights_file

        check_weights_file(cfg.fusion, cfg.weights)
    if args.detector:  # built once here, so that a broken factory is refused before anything is written
        factory_models(args.detector, cfg)
    executor = executor_from_args(args, count)  # checked before anything is written
    out = Path(args.out)
    fresh = not out.exists()
    prepare_run(out, run_settings(cfg, args.seed, count, source.describe()), force=args.force)
    try:
        scenes = load_scenes(source, count, args.seed, out / WORK_DIR,
                             log_dir=out / LOG_DIR if cfg.space.needs_past else None)
        check_scenes(cfg, scenes)
    except BaseException:
        if fresh:  # bad input: leave no trace of the folder this run created
            shutil.rmtree(out, ignore_errors=True)
        raise
    finally:
        shutil.rmtree(out / WORK_DIR, ignore_errors=True)
    if args.count is not None and len(scenes) < count:
        console.print(f"the source holds {len(scenes)} usable scenes (asked for {count}); generating {len(scenes)}")
    if demo:
        console.print(f"demo: {len(scenes)} scenes of the bundled town '{source.town}', {cfg.fusion} + "
                      f"ACS-{cfg.acs} + {cfg.search}, budget {cfg.budget}")
    with progress_bar() as bar, executor:
        scene_task = bar.add_task("scenes", total=len(scenes))
        in_process = executor.workers == 1 and executor.registry_name == "local"
        eval_task = bar.add_task("evaluations", total=cfg.budget, visible=in_process)

        def on_scene(done: int, total: int, scene_id: str) -> None:
            bar.update(scene_task, completed=len(scenes) - total + done)
            bar.update(eval_task, completed=0)

        try:
            run = generate(cfg, scenes, out, seed=args.seed, detector_factory=args.detector, executor=executor,
                           on_scene=on_scene, on_step=lambda step: bar.update(eval_task, completed=step))
        except InputError:
            if fresh and not list((out / "scenes").glob("*/result.json")):  # nothing done: leave no folder
                shutil.rmtree(out, ignore_errors=True)
            raise
        bar.update(scene_task, completed=len(scenes))
    for scene_id, why in run.skipped:
        console.print(f"[yellow]skipped {scene_id}: {why}")
    print_table(run.summary, stdout)
    console.print(f"wrote {out}/summary.json and {len(run.summary['scenes'])} scene folders")
    return 0


def executor_from_args(args: argparse.Namespace, items: int) -> Executor:
    """The executor of ``--executor``, ``--workers`` (default: one per core, at most ``items``) and
    ``--address``: one thread per worker."""
    workers = args.workers if args.workers is not None else default_workers(items)
    return build_executor(args.executor, workers, threads=1, address=args.address)


def print_table(summary: dict, out) -> None:
    """The before/after AP table of a run's summary on rich console ``out``."""
    from .io.run import after_acs_ap

    table = Table(title="AP before / after (fractions)")
    table.add_column("scene")
    for col in ("normal 0.3/0.5/0.7", "after ACS", "final", "moved", "s"):
        table.add_column(col, justify="right")
    fmt = lambda ap: " / ".join(f"{ap[k]:.2f}" for k in ("0.3", "0.5", "0.7"))
    for e in summary["scenes"]:
        table.add_row(e["scene_id"][-32:], fmt(e["ap_normal"]), fmt(e["ap_after_acs"]), fmt(e["ap_final"]),
                      str(len(e.get("moved", e["perturbed"] if e["delta"] else []))), f"{e['seconds']:.1f}")
    agg = summary["aggregate"]
    after_ap, pooled = after_acs_ap(agg.get("ap_after_acs"), agg["mean_scene_ap_after_acs"])
    table.add_row("[bold]pooled", fmt(agg["ap_normal"]), fmt(after_ap) + ("" if pooled else "*"),
                  fmt(agg["ap_challenging"]), "", f"{agg['seconds_per_scene_median']:.1f}")
    out.print(table)
    if not pooled:
        out.print("* mean over scenes (this folder has scenes written before after-ACS detections were stored)")
