"""``asg harden``: the command of asg.workflows.harden (asg.cli's COMMAND_MODULES): the rounds of
any target a trainer here trains (asg's own, or OpenCOOD's for an OpenCOOD model folder)."""
from __future__ import annotations

import argparse
from pathlib import Path

from . import MAX_ROUNDS
from ..cli_args import executor_from_args, fusion_arg, training_run_args, whole
from ..objective.pooled import REATTACK_PAIR, PooledAP, pooled_pair
from .harden import DATA_KINDS, STARTED_FROM, default_out, harden, is_kept, load_harden_config


def add_arguments(p: argparse.ArgumentParser) -> None:
    fusion_arg(p, "the model hardened", required=True)
    p.add_argument("--rounds", type=whole(1, MAX_ROUNDS, "--rounds"), required=True, help="rounds to run (resumable)")
    p.add_argument("--data", default=None, choices=DATA_KINDS,
                   help="what a round trains on: adversarial (default), or a control at equal compute: random "
                        "(one plausible random perturbation a scene) or normal (the scenes unperturbed)")
    p.add_argument("--space", default=None, metavar="KIND[,KIND]",
                   help="the perturbation spaces of the attacks (default configs/generate.yaml's)")
    p.add_argument("--weights", type=Path, default=None, metavar="PATH",
                   help="start from this weights file, or a harden card (its last round), not the shipped weights")
    p.add_argument("--out", type=Path, default=None, help="output folder (default runs/harden/FUSION[-DATA])")
    training_run_args(p, "harden")


def run(args: argparse.Namespace) -> int:
    from rich.table import Table

    from ..perception.targets import resolve_target
    from ..progress import console, loss_progress, progress_bar, stdout

    target = resolve_target(args.fusion)  # one line for an unknown fusion
    space = tuple(k.strip() for k in args.space.split(",") if k.strip()) if args.space else None
    config = load_harden_config(args.config, data=args.data)
    out = args.out or default_out(target, config.data)
    with progress_bar() as bar, executor_from_args(args, 10**6) as executor:
        report = loss_progress(bar, bar.add_task(f"hardening {args.fusion}", total=None), f"hardening {args.fusion}")
        card = harden(target, args.rounds, out, weights=args.weights, config=config, space=space,
                      executor=executor, threads=args.threads, force=args.force, config_path=args.config,
                      log=console.print, progress=report)
    rows = card["rounds"]
    sets = list(rows[0]["evaluation"]) if rows else []
    table = Table(title=f"asg harden --fusion {args.fusion} ({card['data']}): AP@0.7 by round, "
                        "ours / ranked per frame (the paper's yardstick)")
    reattacked = bool(rows) and "reattack" in rows[0]
    for col in ("round", *sets, *(["re-attacked", "its start on those scenes"] if reattacked else [])):
        table.add_column(col, justify="right")
    for row in rows:
        cells = [PooledAP.from_json(row["evaluation"][s]).text() for s in sets]
        if "reattack" in row:
            started_from = row["reattack"].get(STARTED_FROM)
            cells += [pooled_pair(row["reattack"], REATTACK_PAIR)["challenging"].text(),
                      PooledAP.from_json(started_from).text() if started_from else ""]
        table.add_row(str(row["round"]) + ("" if not row["round"] or is_kept(row) else " (not kept)"), *cells)
    stdout.print(table)
    kept = card.get("weights")
    console.print(f"card: {out}/card.json; each round's model in {out}/round-K"
                  + (f"; the one kept: {kept}" if kept else ""))
    return 0
