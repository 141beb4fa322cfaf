"""``asg finetune --fusion attfuse --on challenging-attfuse-train``: train a detector further on the
challenging scenes generated against it, then measure what that bought (the paper's Table II).

Stages, each resumable and recorded in the output folder ``OUT`` (default runs/finetune/FUSION-ft/):

1. **train**: one chunk from the model's weights (shipped, or ``--weights``) on batches mixing the
   challenging set with normal frames (train.yaml's ``finetune`` block: ``challenging_share`` of
   each batch from the challenging set (its ``asg`` part), the rest from the train split of the
   ``mix_with`` sets); checkpoints in ``OUT/last.pt``; writes ``OUT/FUSION-ft.pt`` and its card
   ``OUT/FUSION-ft.json``. An OpenCOOD model folder (``--fusion opencood:DIR``) is trained by
   OpenCOOD's own trainer instead, ``epochs`` (the block's ``opencood`` part) on the same scenes
   exported in the OPV2V layout, into ``OUT/model`` (asg.workflows.trainers: the target's trainer,
   as a harden round's).
2. **evaluate**: the model before and after on ``eval_sets`` and on ``challenging-FUSION-val`` (the
   val split attacked against the original model; built if missing), cached in ``OUT/eval/``.
3. **re-attack**: the paper's protocol run again on normal-val against the fine-tuned weights
   (``OUT/reattack/``, a challenging set of its own), beside the original model under its own attack.

``OUT/run.json`` records the settings: a rerun with other settings is refused (``force`` starts
over). The shipped weights are never written.
"""
from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path
from typing import Callable

from sumo_scenarios.atomic import write_text_atomic
from sumo_scenarios.errors import InputError
from sumo_scenarios.paths import runs_dir

from ..cli_args import COUNT, executor_from_args, fusion_arg, training_run_args
from ..io.run_record import claim, with_defaults
from ..objective.pooled import FINETUNE_PAIR, REATTACK_PAIR, PooledAP, pair_json, pooled_pair
from ..training.config import FINETUNE_BLOCK, FinetuneConfig, load_finetune_config, record_in_todays_form, train_block
from ..perception.targets import Target, Training
from .trainers.base import Model
from .trainers.chunk import MixedBatches, mixed_sources  # noqa: F401  (this module's API too: scripts)


def finetuned_name(target: Target) -> str:
    """The fine-tuned model's name (its weights file's stem and its card's): the target's label + -ft."""
    return f"{target.label}-ft"


def default_out(target: Target) -> Path:
    return runs_dir() / "finetune" / finetuned_name(target)


def finetune(target: Target, on: str, out: Path | None = None, *, steps: int | None = None,
             weights: Path | None = None, threads: int = 2, force: bool = False, executor=None,
             stages: tuple[str, ...] = ("train", "evaluate", "reattack"), config: FinetuneConfig | None = None,
             config_path: Path | None = None, log: Callable[[str], None] = print,
             progress: Callable[[int, int, float], None] | None = None) -> dict:
    """Run (or resume) the fine-tuning of ``target`` on challenging set ``on``; returns its card.
    The target's trainer (asg.workflows.trainers: asg's own, or OpenCOOD's for an OpenCOOD model
    folder) trains it.

    ``weights``: start from this file instead of the shipped weights. ``executor``: where the
    evaluations and the re-attack run (default this process). ``stages``: a subset of train,
    evaluate, reattack (the later ones need the trained model). ``config_path``: the ``--config``
    file ``config`` came from (None: train.yaml)."""
    from .challenging import challenging_scenes
    from .trainers import round_trainer

    fcfg = config or load_finetune_config()
    fcfg = fcfg.with_trainer(Training.ASG.value, steps=steps) if steps else fcfg
    trainer = round_trainer(target, fcfg, threads, config_path)
    shipped = train_block(FINETUNE_BLOCK, None)
    given = dict(train_block(FINETUNE_BLOCK, config_path)) if config_path else {}
    if steps:  # --steps sets asg's trainer
        asg = Training.ASG.value
        given[asg] = {**given.get(asg, shipped.get(asg, {})), "steps": steps}
    trainer.check(weights, given, shipped)
    start = trainer.start(weights)
    out = Path(out) if out is not None else default_out(target)
    challenging_scenes(on)  # one clear line if the set is not built
    from ..datasets import check_set_name

    for set_name in fcfg.eval_sets:  # refused now, not after the training
        check_set_name(set_name)
    settings = {"fusion": target.name, "on": on, **trainer.settings(start), "steps": fcfg.asg.steps, "config": asdict(fcfg)}
    claim(out, settings, force, what="a fine-tuning run", as_today=_as_today)
    name = finetuned_name(target)
    card_path = out / f"{name}.json"
    card = json.loads(card_path.read_text()) if card_path.is_file() else {}
    if "train" in stages and not card.get("trained"):
        model, trained = trainer.train(start, {on: list(challenging_scenes(on))}, out, log, progress, name=name)
        card = {"weights": str(model.path.relative_to(out)), "fusion": target.name,
                "start": {"weights": str(start.path), "sha256": trainer.digest(start)}, "trained": trained | {"on": on}}
        write_text_atomic(card_path, json.dumps(card, indent=1))
    if not card.get("trained") and set(stages) - {"train"}:
        raise InputError(f"{out}: no fine-tuned model yet; run the train stage first")
    tuned = trainer.model_at(out / card["weights"]) if card.get("trained") else None
    if "evaluate" in stages:
        card["evaluation"] = evaluate_before_after(target, start, tuned, fcfg, out / "eval", executor, log)
        write_text_atomic(card_path, json.dumps(card, indent=1))
    if "reattack" in stages:
        card["reattack"] = reattack(target, tuned, out / "reattack", executor, log)
        write_text_atomic(card_path, json.dumps(card, indent=1))
    return card


def _as_today(record: dict) -> dict:
    """A run.json written before today's settings, in today's form
    (asg.training.config.record_in_todays_form), a setting added since taking the default that
    reproduces it."""
    return with_defaults(record_in_todays_form(record, FinetuneConfig), {"config": asdict(FinetuneConfig()),
                                                                         "point_stage": None})


def evaluate_before_after(target: Target, start: Model, tuned: Model, fcfg: FinetuneConfig, cache: Path,
                          executor, log: Callable[[str], None]) -> dict:
    """``start`` and ``tuned`` (the fine-tuned model): {set: {"before", "after": a pooled AP each ({"ap", "ap_per_frame"}: AP by threshold ours and
    ranked per frame, the paper's yardstick), "frames": N}} on each eval set and the original
    model's challenging val set (built if missing); each result cached in ``cache`` (one cached
    before the paper's yardstick was recorded is evaluated again)."""
    from .challenging import own_val_set
    from ..evaluation import evaluate

    own_val = own_val_set(target, executor, log)
    table = {}
    for set_name_ in (*fcfg.eval_sets, own_val):
        row = {}
        for when, model in zip(FINETUNE_PAIR, (start, tuned)):
            hit = cache / f"{when}-{set_name_}.json"
            result = json.loads(hit.read_text()) if hit.is_file() else {}
            if not result or PooledAP.from_result(result).ap_per_frame is None:
                result = evaluate(model.target, set_name_, weights_file=model.weights_arg, executor=executor)
                result = PooledAP.from_result(result).to_json() | {"frames": result["frames"]}
                cache.mkdir(parents=True, exist_ok=True)
                write_text_atomic(hit, json.dumps(result))
            row[when] = PooledAP.from_result(result).to_json(4)
            row["frames"] = result["frames"]
        pair = pooled_pair(row, FINETUNE_PAIR)
        log(f"{set_name_}: AP@0.7 ours / per frame {pair['before'].text()} -> {pair['after'].text()}")
        table[set_name_] = row
    return table


def reattack(target: Target, tuned: Model, out: Path, executor, log: Callable[[str], None]) -> dict:
    """The paper's protocol on normal-val against the fine-tuned model ``tuned`` (a challenging set
    in ``out``), beside the original ``target`` under its own attack (challenging-FUSION-val)."""
    from .challenging import build_challenging, set_name
    from ..datasets import data_root

    log("re-attacking the fine-tuned model on normal-val ...")
    built = build_challenging(tuned.target, "val", executor=executor, weights_file=tuned.weights_arg, out=out)
    mine = json.loads((built / "index.json").read_text())
    original = json.loads((data_root() / set_name(target, "val") / "index.json").read_text())

    def both(index: dict) -> dict:  # ours, and per frame where the set recorded it
        return pair_json(pooled_pair(index, REATTACK_PAIR))

    return {"frames": mine["frames"], "finetuned": both(mine),
            # the original model's own attack: the challenging val set made against it
            "original": attacked_model(original["source"]) | both(original)}


def attacked_model(source: dict) -> dict:
    """The model a challenging set was attacked against, from its index.json ``source``: its weights
    file ("shipped" for the shipped ones) and, when a detector factory was attacked, that factory."""
    return {"weights": source.get("weights") or "shipped",
            **({"detector": source["detector"]} if source.get("detector") else {})}


# ``asg finetune``: this workflow's command (asg.cli's COMMAND_MODULES)

def add_arguments(p: argparse.ArgumentParser) -> None:
    fusion_arg(p, "the model fine-tuned", required=True)
    p.add_argument("--on", default=None, metavar="SET",
                   help="challenging set to train on (default challenging-FUSION-train)")
    p.add_argument("--steps", type=COUNT, default=None, help="override the steps of asg's trainer (train.yaml's finetune.asg.steps)")
    p.add_argument("--weights", type=Path, default=None, metavar="PATH",
                   help="start from this weights file instead of the shipped ones")
    p.add_argument("--out", type=Path, default=None, help="output folder (default runs/finetune/FUSION-ft)")
    p.add_argument("--stages", default="train,evaluate,reattack",
                   help="comma-separated subset of train, evaluate, reattack (default all three)")
    training_run_args(p, "finetune")


def run(args: argparse.Namespace) -> int:
    from rich.table import Table

    from ..objective import ap_text
    from .challenging import set_name
    from ..perception.targets import resolve_target
    from ..progress import console, loss_progress, progress_bar, stdout

    stages = tuple(s.strip() for s in args.stages.split(",") if s.strip())
    unknown = sorted(set(stages) - {"train", "evaluate", "reattack"})
    if unknown or not stages:
        raise InputError(f"--stages takes train, evaluate and reattack, got {args.stages!r}")
    target = resolve_target(args.fusion)  # one line for an unknown fusion
    config = load_finetune_config(args.config)
    on = args.on or set_name(target, "train")
    with progress_bar() as bar, executor_from_args(args, 10**6) as executor:  # one worker per core by default
        report = loss_progress(bar, bar.add_task(f"fine-tuning {args.fusion}", total=None), f"fine-tuning {args.fusion}")
        card = finetune(target, on, args.out, steps=args.steps, weights=args.weights, threads=args.threads,
                        force=args.force, executor=executor, stages=stages, config=config, config_path=args.config,
                        log=console.print, progress=report)
    table = Table(title=f"asg finetune --fusion {args.fusion} --on {on}: AP@0.3 / 0.5 / 0.7, and AP@0.7 ours / "
                        "ranked per frame (the paper's yardstick)")
    for col in ("set", "frames", "before", "after", "before @0.7", "after @0.7"):
        table.add_column(col, justify="left" if col == "set" else "right")
    for set_name_, row in card.get("evaluation", {}).items():
        pair = pooled_pair(row, FINETUNE_PAIR)
        table.add_row(set_name_, str(row["frames"]), ap_text(pair["before"].ap), ap_text(pair["after"].ap),
                      pair["before"].text(), pair["after"].text())
    if "reattack" in card:
        r = card["reattack"]
        original = pooled_pair(r["original"], REATTACK_PAIR)["challenging"]
        finetuned = pooled_pair(r["finetuned"], REATTACK_PAIR)["challenging"]
        table.add_row("own attack on normal-val", str(r["frames"]), ap_text(original.ap), ap_text(finetuned.ap),
                      original.text(), finetuned.text())
    stdout.print(table)
    console.print(f"weights and card: {card.get('weights')} in {args.out or default_out(target)}")
    return 0
