"""``asg generate``: its flags (:func:`add_arguments`), and :func:`run`, which turns them into
typed settings, opens the run folder (:func:`asg.generator.run.open_run`), runs its scenes with a
progress bar and prints the before/after table."""
from __future__ import annotations

import argparse
from pathlib import Path

from sumo_scenarios.errors import InputError

from ..cli_args import COUNT, SEED, executor_args, executor_from_args, fusion_arg, weights_arg, whole
from ..collaborators import ACS_STRATEGIES
from ..search import SEARCHES
from ..scene.feasibility import PLAUSIBILITY_LEVELS
from .run import SceneSource, factory_models, open_run
from .run_folder import print_table
from .stages import Stage
from .config import ACS_OFF, GenerateConfig, load_generate_config, protocols, with_space_flags
from ..progress import console, progress_bar, stdout

#: the no-argument demo: a held-out town, the paper's main target (AttFuse, whose own attention
#: steers the collaborator search), three scenes at a short budget: a clear drop in about a minute
#: on 2 cores (docs/results/README.md, "The quick-start job"; Early Fusion on 2 scenes at budget
#: 15 showed 0.83 -> 0.79, one scene easier after ACS)
DEMO = {"town": "fiveleg", "count": 3, "budget": 20, "fusion": "attfuse"}
#: scenes generated when --count is not given
DEFAULT_COUNT = 10


def add_arguments(p: argparse.ArgumentParser) -> None:
    src = p.add_mutually_exclusive_group()
    src.add_argument("--town", help="sample normal scenes from this bundled town")
    src.add_argument("--net", type=Path, help="...or from any SUMO net")
    src.add_argument("--scenes", type=Path, help="...or take the scenes of this folder (scene yaml or a data set) or set (normal, normal-val)")
    fusion_arg(p, "the model attacked (default attfuse)")
    p.add_argument("--search", default=None, help=f"one of {', '.join(SEARCHES.names())} (default bo; ng: nevergrad)")
    p.add_argument("--acs", default=None, choices=[*ACS_STRATEGIES.names(), ACS_OFF],
                   help="collaborator search: attention (ACS-A), random (ACS-R) or off (default attention)")
    p.add_argument("--aps", default=None, choices=["on", "off"])
    p.add_argument("--movers", type=whole(0, 64, "--movers"), default=None,
                   help="vehicles the perturbation search moves (m; default 3, the paper's)")
    p.add_argument("--plausibility", default=None, choices=PLAUSIBILITY_LEVELS,
                   help="paper (default: on the drivable area, no collision, in range) or traffic (also in a lane "
                        "of its own direction, heading within 30 deg of it)")
    p.add_argument("--space", default=None, metavar="NAME[,NAME...]",
                   help="perturbation spaces searched together: poses (default, the paper's), insert, pose-error, "
                        "latency, dropout (bounds: configs/generate.yaml, space)")
    p.add_argument("--count", type=COUNT, default=None, help=f"scenes to generate (default {DEFAULT_COUNT}; demo {DEMO['count']})")
    p.add_argument("--budget", type=COUNT, default=None, help=f"evaluations per scene (default {GenerateConfig.budget}; demo {DEMO['budget']})")
    p.add_argument("--seed", type=SEED, default=1)
    p.add_argument("--config", type=Path, default=None, help="generate yaml (default configs/generate.yaml)")
    p.add_argument("--protocol", default=None, choices=protocols(),
                   help="a named protocol over the config: paper (the paper's search as its code ran it: "
                        "turns in 15 deg steps, GA 8 x 15; configs/protocols/)")
    p.add_argument("--out", type=Path, default=Path("runs/generate"), help="run folder (default runs/generate)")
    p.add_argument("--force", action="store_true",
                   help="start the run folder over when it holds a run made with other settings")
    p.add_argument("--detector", default=None, metavar="MODULE:FACTORY",
                   help="your own target: a function (config) -> (detector, ACS model or None); default the shipped --fusion")
    weights_arg(p)
    executor_args(p)


def run(args: argparse.Namespace) -> int:
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
    if cfg.weights and not args.detector:
        cfg.target.check(cfg.weights)
    if args.detector:  # built once here, so that a broken factory is refused before anything is written
        factory_models(args.detector, cfg)
    executor = executor_from_args(args, count)  # checked before anything is written
    run_folder = open_run(cfg, Path(args.out), source=source, count=count, seed=args.seed, force=args.force)
    scenes = run_folder.scenes
    if args.count is not None and len(scenes) < count:
        console.print(f"the source holds {len(scenes)} usable scenes (asked for {count}); generating {len(scenes)}")
    from ..perception.fusion import ATTENTION_LENDER

    if cfg.acs_needs_attention and not args.detector and cfg.target.borrows_attention:
        console.print(f"note: {cfg.fusion} has no attention of its own; ACS-{cfg.acs} reads the shipped "
                      f"{ATTENTION_LENDER}'s (--acs random or off for a search without it)")
    if demo:
        console.print(f"demo: {len(scenes)} scenes of the bundled town '{source.town}', {cfg.fusion} + "
                      f"ACS-{cfg.acs} + {cfg.search}, budget {cfg.budget}")
    with progress_bar() as bar, executor:
        scene_task = bar.add_task("scenes", total=len(scenes))
        eval_task = bar.add_task("evaluations", total=cfg.budget, visible=executor.in_process)

        def on_scene(done: int, total: int, scene_id: str) -> None:
            bar.update(scene_task, completed=len(scenes) - total + done)
            bar.update(eval_task, completed=0)

        done = run_folder.run(detector_factory=args.detector, executor=executor, on_scene=on_scene,
                                  on_step=lambda step: bar.update(eval_task, completed=step))
        bar.update(scene_task, completed=len(scenes))
    out = run_folder.out
    for scene_id, why in done.skipped:
        console.print(f"[yellow]skipped {scene_id}: {why}")
    print_table(done.summary, stdout)
    console.print(f"wrote {out}/summary.json and {len(done.summary['scenes'])} scene folders")
    lost = lambda e: e[Stage.NORMAL.ap_key]["0.7"] - e[Stage.FINAL.ap_key]["0.7"]  # noqa: E731
    hardest = max(done.summary["scenes"], key=lost, default=None)
    if hardest is not None and lost(hardest) > 0:
        console.print(f"the scene that lost most: {hardest['scene_id']} (AP@0.7 {hardest['ap_normal']['0.7']:.2f} -> "
                      f"{hardest['ap_final']['0.7']:.2f}; its pictures in {out / 'scenes' / hardest['scene_id']}); "
                      f"every scene on one page: asg report {out}")
    return 0
