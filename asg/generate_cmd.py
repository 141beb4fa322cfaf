"""``asg generate`` on the command line: turn the flags into typed settings, call
:func:`asg.generate.generate` with a progress bar, print the before/after table."""
from __future__ import annotations

import argparse
from pathlib import Path

from sumo_scenarios.errors import InputError

from .cli_args import executor_from_args
from .generate import SceneSource, factory_models, open_run
from .io.run import print_table
from .generator_config import load_generate_config, with_space_flags
from .progress import console, progress_bar, stdout

#: the no-argument demo: a held-out town, the paper's main target (AttFuse, whose own attention
#: steers the collaborator search), three scenes at a short budget: a clear drop in about a minute
#: on 2 cores (docs/results/README.md, "The quick-start job"; Early Fusion on 2 scenes at budget
#: 15 showed 0.83 -> 0.79, one scene easier after ACS)
DEMO = {"town": "fiveleg", "count": 3, "budget": 20, "fusion": "attfuse"}
#: scenes generated when --count is not given
DEFAULT_COUNT = 10


def run_generate(args: argparse.Namespace) -> int:
    """``asg generate`` with parsed ``args``."""
    demo = args.town is None and args.net is None and args.scenes is None
    source = SceneSource(town=DEMO["town"] if demo else args.town, net=args.net, scenes=args.scenes)
    count = args.count if args.count is not None else (DEMO["count"] if demo else DEFAULT_COUNT)
    budget = args.budget if args.budget is not None else (DEMO["budget"] if demo else None)
    fusion = args.fusion or (DEMO["fusion"] if demo else None)
    if args.weights is not None and args.detector:
        raise InputError("--weights picks the weights of a shipped --fusion; your --detector factory loads its own")
    cfg = load_generate_config(args.config, protocol=args.protocol, fusion=fusion, search=args.search, acs=args.acs,
                               aps=None if args.aps is None else args.aps == "on", budget=budget, perturbed=args.movers,
                               weights=None if args.weights is None else str(args.weights))
    cfg = with_space_flags(cfg, args.plausibility, args.space)
    if not args.detector:  # refused here, before a town is simulated or a worker starts
        from .perception import check_fusion

        check_fusion(cfg.fusion)
    if cfg.weights and not args.detector:
        from .perception import check_weights_file

        check_weights_file(cfg.fusion, cfg.weights)
    if args.detector:  # built once here, so that a broken factory is refused before anything is written
        factory_models(args.detector, cfg)
    executor = executor_from_args(args, count)  # checked before anything is written
    run_folder = open_run(cfg, Path(args.out), source=source, count=count, seed=args.seed, force=args.force)
    scenes = run_folder.scenes
    if args.count is not None and len(scenes) < count:
        console.print(f"the source holds {len(scenes)} usable scenes (asked for {count}); generating {len(scenes)}")
    if demo:
        console.print(f"demo: {len(scenes)} scenes of the bundled town '{source.town}', {cfg.fusion} + "
                      f"ACS-{cfg.acs} + {cfg.search}, budget {cfg.budget}")
    with progress_bar() as bar, executor:
        scene_task = bar.add_task("scenes", total=len(scenes))
        eval_task = bar.add_task("evaluations", total=cfg.budget, visible=executor.in_process)

        def on_scene(done: int, total: int, scene_id: str) -> None:
            bar.update(scene_task, completed=len(scenes) - total + done)
            bar.update(eval_task, completed=0)

        run = run_folder.generate(detector_factory=args.detector, executor=executor, on_scene=on_scene,
                                  on_step=lambda step: bar.update(eval_task, completed=step))
        bar.update(scene_task, completed=len(scenes))
    out = run_folder.out
    for scene_id, why in run.skipped:
        console.print(f"[yellow]skipped {scene_id}: {why}")
    print_table(run.summary, stdout)
    console.print(f"wrote {out}/summary.json and {len(run.summary['scenes'])} scene folders")
    lost = lambda e: e["ap_normal"]["0.7"] - e["ap_final"]["0.7"]  # noqa: E731
    hardest = max(run.summary["scenes"], key=lost, default=None)
    if hardest is not None and lost(hardest) > 0:
        console.print(f"the scene that lost most: {hardest['scene_id']} (AP@0.7 {hardest['ap_normal']['0.7']:.2f} -> "
                      f"{hardest['ap_final']['0.7']:.2f}; its pictures in {out / 'scenes' / hardest['scene_id']}); "
                      f"every scene on one page: asg report {out}")
    return 0
