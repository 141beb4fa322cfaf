"""``asg train``: the command (what a run does: :mod:`asg.training.train`).

Training reads and writes its run folder, ``runs/train/NAME/`` (NAME: the weights' name): the first
run copies there the weights it continues from (the installed or shipped ones, and those of
``--init-from``); every chunk, branch fit, point stage and model card is written there, never into
the package. ``--install`` then makes them the weights every command loads (the user's asg folder,
asg.perception.weights_io.user_weights_dir)."""
from __future__ import annotations

import argparse

from sumo_scenarios.errors import InputError

from sumo_scenarios.paths import runs_dir

from ..cli_args import COUNT, THREADS, fusion_arg
from ..perception.weights_io import install_weights, seed_run_folder
from .cards import card_validation
from .config import weights_for
from .train import train


def add_arguments(p: argparse.ArgumentParser) -> None:
    fusion_arg(p, "the model trained (none and late share weights)", required=True)
    p.add_argument("--steps", type=COUNT, default=None, help="override the configured number of steps")
    p.add_argument("--threads", type=THREADS, default=2)
    p.add_argument("--validate-only", action="store_true",
                   help="no training: re-measure the run folder's weights (at first the shipped ones) on normal-val and "
                        "update their model card there (after changing configs/detectors/pointpillars.yaml)")
    p.add_argument("--install", action="store_true",
                   help="no training: install the weights trained in runs/train/NAME/ (with their card and point stage) "
                        "as the ones every command loads (your asg folder, ASG_HOME/weights)")
    p.add_argument("--init-from", default=None, metavar="WEIGHTS",
                   help="start a new sequence of chunks from other shipped weights (e.g. single) instead of "
                        "continuing this model's own")
    p.add_argument("--iou-branch", action="store_true",
                   help="fit only the IoU and box-refinement branches on the frozen shipped weights "
                        "(train.yaml's iou_branch block; about 10 minutes)")
    p.add_argument("--point-stage", action="store_true",
                   help="fit only the point stage (each final box refined from its points) on the frozen shipped "
                        "weights (train.yaml's point_stage block; about 5 minutes)")


def run(args: argparse.Namespace) -> int:
    from ..progress import console, loss_progress, progress_bar

    if args.validate_only and (args.init_from or args.iou_branch or args.point_stage):
        raise InputError("--validate-only measures the shipped weights; it cannot be combined with --init-from, "
                         "--iou-branch or --point-stage")
    if args.point_stage and (args.init_from or args.iou_branch or args.steps is not None):
        raise InputError("--point-stage fits the stage of the shipped weights alone; it cannot be combined with "
                         "--init-from, --iou-branch or --steps (set epochs in train.yaml's point_stage block)")
    name = weights_for(args.fusion)
    run_dir = runs_dir() / "train" / name
    if args.install:
        if args.validate_only or args.init_from or args.iou_branch or args.point_stage or args.steps is not None:
            raise InputError("--install copies what runs/train/NAME/ holds; it cannot be combined with other options")
        console.print(f"installed {install_weights(run_dir, name)} (every command loads these now; delete the file "
                      "to go back to the shipped weights)")
        return 0
    seed_run_folder(run_dir, name, *([args.init_from] if args.init_from else []))
    if args.validate_only:
        card = card_validation(name, console.print, weights_dir=run_dir)
        console.print(f"updated the model card of {card['weights']} in {run_dir}")
        return 0
    if args.steps is not None and args.iou_branch:
        raise InputError("--steps does not apply to --iou-branch (a fit of epochs over the collected candidates: "
                         "set epochs in train.yaml's iou_branch block)")
    if args.point_stage:
        from .point_stage_fit import fit_point_stage

        console.print(f"weights: {fit_point_stage(args.fusion, console.print, args.threads, weights_dir=run_dir)}")
        card_validation(name, console.print, weights_dir=run_dir)
        return 0
    with progress_bar() as bar:
        report = loss_progress(bar, bar.add_task(f"training {args.fusion}", total=None), f"training {args.fusion}",
                               without_loss=f"collecting {args.fusion}'s candidates")
        out = train(args.fusion, out_dir=run_dir, steps=args.steps, progress=report, threads=args.threads,
                    log=console.print, weights_dir=run_dir, init_from=args.init_from, iou_branch=args.iou_branch)
    console.print(f"weights: {out}")
    return 0
