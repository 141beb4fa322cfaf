"""``asg harden``: the command of asg.workflows.harden (asg.cli's COMMAND_MODULES): an asg model's
rounds, or an OpenCOOD model's round by its own trainer (asg.workflows.harden_opencood), as the
target's training kind says."""
from __future__ import annotations

import argparse
from pathlib import Path

from . import MAX_ROUNDS
from ..cli_args import executor_from_args, fusion_arg, training_run_args, whole
from ..objective.pooled import REATTACK_PAIR, PooledAP, pooled_pair
from ..training.config import train_block, weights_for
from .harden import DATA_KINDS, HARDEN_BLOCK, STARTED_FROM, default_out, harden, is_kept, load_harden_config



def _run_opencood(args: argparse.Namespace) -> int:
    """``asg harden --fusion opencood:DIR``: one round by OpenCOOD's trainer (asg.workflows.harden_opencood)."""
    from rich.table import Table

    from ..objective.pooled import FINETUNE_PAIR, pooled_pair
    from ..perception.targets import resolve_target
    from ..progress import console, stdout
    from .harden_opencood import check_opencood_run, check_opencood_settings, harden_opencood

    check_opencood_run(args)
    resolve_target(args.fusion).check().check_trainable()  # before the folder is claimed or any scene attacked
    config = load_harden_config(args.config, data=args.data)
    if args.config is not None:
        check_opencood_settings(args.config, train_block(HARDEN_BLOCK, args.config), train_block(HARDEN_BLOCK, None))
    out = args.out or default_out(resolve_target(args.fusion).label, config.data)
    with executor_from_args(args, 10**6) as executor:
        card = harden_opencood(args.fusion, out, config, executor, force=args.force, log=console.print)
    table = Table(title=f"asg harden --fusion {args.fusion} ({card['data']}, {card['epochs']} epochs): AP@0.7 ours / "
                        "per frame, and the gap with its 95 % paired interval")
    for col in ("set", "frames", "before", "after", "gap (ours)", "gap (per frame)"):
        table.add_column(col, justify="left" if col == "set" else "right")
    for set_name, row in card["evaluation"].items():
        pair = pooled_pair(row, FINETUNE_PAIR)
        gaps = [f"{100 * g['gap']:+.1f} [{100 * g['low']:+.1f}, {100 * g['high']:+.1f}]" for g in row["gap"].values()]
        table.add_row(set_name, str(row["frames"]), pair["before"].text(), pair["after"].text(), *gaps)
    if "reattack" in card:
        before, after = (pooled_pair(card["reattack"][w], ("challenging",))["challenging"] for w in FINETUNE_PAIR)
        table.add_row("own attack on normal-val", str(card["reattack"]["frames"]), before.text(), after.text(), "", "")
    stdout.print(table)
    kept = card.get("guard", {}).get("kept", True)
    console.print(f"card: {out}/card.json; the model: {card['model']}" + ("" if kept else " (worse on the guard set: not kept)"))
    return 0


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

    from ..perception.targets import Training, resolve_target
    from ..progress import console, loss_progress, progress_bar, stdout

    training = resolve_target(args.fusion).training  # one line for an unknown fusion
    if training is Training.OPENCOOD:
        return _run_opencood(args)
    weights_for(args.fusion)  # one line for a target asg's trainer cannot train
    space = tuple(k.strip() for k in args.space.split(",") if k.strip()) if args.space else None
    config = load_harden_config(args.config, data=args.data)
    out = args.out or default_out(args.fusion, config.data)
    with progress_bar() as bar, executor_from_args(args, 10**6) as executor:
        report = loss_progress(bar, bar.add_task(f"hardening {args.fusion}", total=None), f"hardening {args.fusion}")
        card = harden(args.fusion, args.rounds, out, weights=args.weights, config=config, space=space,
                      executor=executor, threads=args.threads, force=args.force, log=console.print, progress=report)
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
    console.print(f"card and weights: {out}/card.json, {out}/round-K/weights.pt"
                  + (f"; the weights kept: {kept}" if kept else ""))
    return 0
