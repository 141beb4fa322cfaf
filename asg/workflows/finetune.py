"""``asg finetune --fusion attfuse --on challenging-attfuse-train``: train a detector further on the
challenging scenes generated against it, then measure what that bought (the paper's Table II).

Stages, each resumable and recorded in the output folder ``OUT`` (default runs/finetune/FUSION-ft/):

1. **train**: one chunk from the model's weights (shipped, or ``--weights``) on batches mixing the
   challenging set with normal frames (train.yaml's ``finetune`` block: ``challenging_share`` of
   each batch from the challenging set, the rest from the train split of the ``mix_with`` sets);
   checkpoints in ``OUT/last.pt``; writes ``OUT/FUSION-ft.pt`` and its card ``OUT/FUSION-ft.json``.
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
import time
from dataclasses import asdict
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from sumo_scenarios.atomic import atomic_path, write_text_atomic
from sumo_scenarios.errors import InputError
from sumo_scenarios.paths import runs_dir

from ..cli_args import COUNT, executor_from_args, fusion_arg, training_run_args
from ..datasets import iter_frames
from ..io.curves import LOSS_CURVE, LossCurve
from ..io.run_record import claim, with_defaults
from ..objective.pooled import FINETUNE_PAIR, REATTACK_PAIR, PooledAP, pair_json, pooled_pair
from ..sensors import load_lidar_spec
from ..training.checkpoint import load_checkpoint
from ..perception.data import Augmentation, make_sample
from ..training.loop import BRANCH_KEYS, Batches, Steps, augment_record, corner_record, make_scheduler, draw_examples, run_steps
from ..perception.fusion import build_network, detector_config_of, feed_of
from ..training.config import FinetuneConfig, load_finetune_config, weights_for
from ..perception.weights_io import load_state, weights_path


class MixedBatches:
    """Batches whose examples come from several sources: each example's source drawn with
    ``shares`` (summing to 1), then an example of that source uniformly."""

    def __init__(self, sources: list[Batches], shares: list[float], labels: tuple[str, ...] = (),
                 augmentation: Augmentation = Augmentation()):
        if any(not s.items for s in sources):
            raise InputError("a fine-tuning source holds no training example")
        self.sources = sources
        #: each source's name, for the card's example counts
        self.labels = labels or tuple(str(i) for i in range(len(sources)))
        self.shares = np.asarray(shares, dtype=float) / float(np.sum(shares))
        self.augmentation = augmentation

    def draw(self, rng: np.random.Generator, batch: int, anchors: np.ndarray, cfg, timer=None):
        which = rng.choice(len(self.sources), size=batch, p=self.shares)
        examples = [self.sources[int(s)].items[int(rng.integers(len(self.sources[int(s)].items)))] for s in which]
        return draw_examples(examples, rng, anchors, cfg, self.sources[0].feed, timer, self.augmentation)


def finetuned_name(fusion: str) -> str:
    return f"{fusion}-ft"


def default_out(fusion: str) -> Path:
    return runs_dir() / "finetune" / finetuned_name(fusion)


def finetune(fusion: str, on: str, out: Path | None = None, *, steps: int | None = None,
             weights: Path | None = None, threads: int = 2, force: bool = False, executor=None,
             stages: tuple[str, ...] = ("train", "evaluate", "reattack"), config: FinetuneConfig | None = None,
             log: Callable[[str], None] = print, progress: Callable[[int, int, float], None] | None = None) -> dict:
    """Run (or resume) the fine-tuning of ``fusion`` on challenging set ``on``; returns its card.

    ``weights``: start from this file instead of the shipped weights. ``executor``: where the
    evaluations and the re-attack run (default this process). ``stages``: a subset of train,
    evaluate, reattack (the later ones need the trained weights)."""
    from .challenging import challenging_scenes

    name = weights_for(fusion)
    fcfg = config or load_finetune_config()
    total = steps or fcfg.steps
    out = Path(out) if out is not None else default_out(fusion)
    start = Path(weights) if weights is not None else weights_path(name)
    challenging_scenes(on)  # one clear line if the set is not built
    from ..datasets import check_set_name
    from ..generator.run import file_digest

    for set_name in fcfg.eval_sets:  # refused now, not after the training
        check_set_name(set_name)

    settings = {"fusion": fusion, "on": on, "start_weights": str(start), "start_sha256": file_digest(start),
                "steps": total, "config": asdict(fcfg)}
    claim(out, settings, force, what="a fine-tuning run",  # a setting added since: the default that reproduces it
          as_today=lambda record: with_defaults(record, {"config": asdict(FinetuneConfig())}))
    ft_weights = out / f"{finetuned_name(fusion)}.pt"
    card_path = out / f"{finetuned_name(fusion)}.json"
    card = json.loads(card_path.read_text()) if card_path.is_file() else {}
    if "train" in stages and not card.get("trained"):
        card = {"weights": ft_weights.name, "fusion": fusion, "start": {"weights": str(start), "sha256": settings["start_sha256"]},
                "trained": train_chunk(name, on, start, ft_weights, out / "last.pt", fcfg, total, threads, log, progress)}
        write_text_atomic(card_path, json.dumps(card, indent=1))
    if not card.get("trained") and set(stages) - {"train"}:
        raise InputError(f"{out}: no fine-tuned weights yet; run the train stage first")
    if "evaluate" in stages:
        card["evaluation"] = evaluate_before_after(fusion, start, ft_weights, fcfg, out / "eval", executor, log)
        write_text_atomic(card_path, json.dumps(card, indent=1))
    if "reattack" in stages:
        card["reattack"] = reattack(fusion, ft_weights, out / "reattack", executor, log)
        write_text_atomic(card_path, json.dumps(card, indent=1))
    return card


def training_sources(name: str, on: str, fcfg: FinetuneConfig, log: Callable[[str], None]) -> MixedBatches:
    """The challenging set and the train split of each ``mix_with`` set, rendered, as mixed batches."""
    from .challenging import challenging_scenes

    return mixed_sources(name, {on: list(challenging_scenes(on))}, fcfg, log)


def mixed_sources(name: str, first: dict[str, list], fcfg: FinetuneConfig, log: Callable[[str], None]) -> MixedBatches:
    """Mixed batches of ``first`` ({label: scenes}: ``challenging_share`` of each batch, split
    evenly among the labels that hold scenes) and the train split of each ``mix_with`` set (the
    rest, in equal shares), every scene rendered with the LiDAR."""
    from ..datasets import build_dataset, dataset_path

    spec = load_lidar_spec()
    feed = feed_of(name)
    t0 = time.perf_counter()
    labels = [k for k, v in first.items() if v]
    views = fcfg.challenging_views or fcfg.views
    sources = [Batches(feed, [make_sample(s, spec) for s in first[k]], views) for k in labels]
    for mix in fcfg.mix_with:
        if not (dataset_path(mix) / "index.json").is_file():
            log(f"building data set {mix} ...")
            build_dataset(mix)
        sources.append(Batches(feed, [make_sample(s, spec) for s in iter_frames(mix, "train")], fcfg.views))
    rest = (1.0 - fcfg.challenging_share) / max(len(fcfg.mix_with), 1)
    shares = [fcfg.challenging_share / max(len(labels), 1)] * len(labels) + [rest] * len(fcfg.mix_with)
    batches = MixedBatches(sources, shares, (*labels, *fcfg.mix_with), fcfg.augment)
    counts = ", ".join(f"{n} {len(b.items)}" for n, b in zip(batches.labels, sources))
    log(f"training examples: {counts} ({time.perf_counter() - t0:.0f} s to render)")
    return batches


def train_chunk(name: str, on: str, start: Path, weights_out: Path, ckpt: Path, fcfg: FinetuneConfig, total: int,
                threads: int, log: Callable[[str], None], progress) -> dict:
    """Train ``total`` steps from ``start`` (resuming ``ckpt``), write ``weights_out``; the record
    of the chunk for the card."""
    return fit_chunk(name, start, weights_out, ckpt, fcfg, total, threads, log, progress,
                     lambda: training_sources(name, on, fcfg, log)) | {"on": on}


def fit_chunk(name: str, start: Path, weights_out: Path, ckpt: Path, fcfg: FinetuneConfig, total: int,
              threads: int, log: Callable[[str], None], progress, sources: Callable[[], MixedBatches]) -> dict:
    """Train ``total`` steps from the weights ``start`` on the batches ``sources()`` draws
    (resuming ``ckpt``), write ``weights_out``; the record of the chunk for a card."""
    cfg = detector_config_of(name)
    torch.set_num_threads(threads)
    torch.manual_seed(fcfg.seed)
    rng = np.random.default_rng([fcfg.seed, 0])
    model = build_network(name, cfg)
    load_state(model, start, allow_missing=BRANCH_KEYS)
    opt = torch.optim.Adam(model.parameters(), lr=fcfg.lr, weight_decay=fcfg.weight_decay)
    sched = make_scheduler(opt, fcfg, total)
    step, wall_s = 0, 0.0
    state = load_checkpoint(ckpt)
    if state is not None:
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
        step, wall_s = int(state["step"]), float(state["wall_s"])
        rng.bit_generator.state = json.loads(state["rng"])
        torch.set_rng_state(state["torch_rng"])
        log(f"resumed fine-tuning at step {step}")
    batches = sources()
    curve = LossCurve(ckpt.with_name(LOSS_CURVE), resumed_at=step)
    wall_s = run_steps(model, opt, sched, batches, rng, Steps(step, total, fcfg.batch_size, fcfg.checkpoint_every, fcfg.corner_loss),
                       cfg, ckpt, wall_s, {}, log, progress, curve.add)
    with atomic_path(weights_out) as tmp:
        torch.save(model.state_dict(), tmp)
    ckpt.unlink(missing_ok=True)
    log(f"wrote {weights_out} after {total} steps, {wall_s / 60:.1f} min of training")
    return {"mix_with": list(fcfg.mix_with), "challenging_share": fcfg.challenging_share,
            "examples": {n: len(b.items) for n, b in zip(batches.labels, batches.sources)},
            "steps": total, "batch_size": fcfg.batch_size, "lr": fcfg.lr, "schedule": fcfg.schedule,
            "seed": fcfg.seed, "views": fcfg.views, "challenging_views": fcfg.challenging_views or fcfg.views,
            **augment_record(fcfg.augment), **corner_record(fcfg),
            "threads": threads, "wall_s": round(wall_s, 1)}


def evaluate_before_after(fusion: str, start: Path, ft_weights: Path, fcfg: FinetuneConfig, cache: Path,
                          executor, log: Callable[[str], None]) -> dict:
    """{set: {"before", "after": a pooled AP each ({"ap", "ap_per_frame"}: AP by threshold ours and
    ranked per frame, the paper's yardstick), "frames": N}} on each eval set and the original
    model's challenging val set (built if missing); each result cached in ``cache`` (one cached
    before the paper's yardstick was recorded is evaluated again)."""
    from .challenging import own_val_set
    from ..evaluation import evaluate

    own_val = own_val_set(fusion, executor, log)
    table = {}
    for set_name_ in (*fcfg.eval_sets, own_val):
        row = {}
        for when, path in zip(FINETUNE_PAIR, (start, ft_weights)):
            hit = cache / f"{when}-{set_name_}.json"
            result = json.loads(hit.read_text()) if hit.is_file() else {}
            if not result or PooledAP.from_result(result).ap_per_frame is None:
                result = evaluate(fusion, set_name_, weights_file=str(path), executor=executor)
                result = PooledAP.from_result(result).to_json() | {"frames": result["frames"]}
                cache.mkdir(parents=True, exist_ok=True)
                write_text_atomic(hit, json.dumps(result))
            row[when] = PooledAP.from_result(result).to_json(4)
            row["frames"] = result["frames"]
        pair = pooled_pair(row, FINETUNE_PAIR)
        log(f"{set_name_}: AP@0.7 ours / per frame {pair['before'].text()} -> {pair['after'].text()}")
        table[set_name_] = row
    return table


def reattack(fusion: str, ft_weights: Path, out: Path, executor, log: Callable[[str], None]) -> dict:
    """The paper's protocol on normal-val against the fine-tuned weights (a challenging set in
    ``out``), beside the original model under its own attack (challenging-FUSION-val)."""
    from .challenging import build_challenging, set_name
    from ..datasets import data_root

    log("re-attacking the fine-tuned model on normal-val ...")
    built = build_challenging(fusion, "val", executor=executor, weights_file=str(ft_weights), out=out)
    mine = json.loads((built / "index.json").read_text())
    original = json.loads((data_root() / set_name(fusion, "val") / "index.json").read_text())

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
    p.add_argument("--steps", type=COUNT, default=None, help="override train.yaml's finetune steps")
    p.add_argument("--weights", type=Path, default=None, metavar="PATH",
                   help="start from this weights file instead of the shipped ones")
    p.add_argument("--out", type=Path, default=None, help="output folder (default runs/finetune/FUSION-ft)")
    p.add_argument("--stages", default="train,evaluate,reattack",
                   help="comma-separated subset of train, evaluate, reattack (default all three)")
    training_run_args(p, "finetune")


def run(args: argparse.Namespace) -> int:
    from rich.table import Table

    from ..objective import ap_text
    from ..perception import check_weights_file
    from ..progress import console, loss_progress, progress_bar, stdout

    weights_for(args.fusion)  # one line for an unknown fusion
    stages = tuple(s.strip() for s in args.stages.split(",") if s.strip())
    unknown = sorted(set(stages) - {"train", "evaluate", "reattack"})
    if unknown or not stages:
        raise InputError(f"--stages takes train, evaluate and reattack, got {args.stages!r}")
    if args.weights is not None:
        check_weights_file(args.fusion, args.weights)
    config = load_finetune_config(args.config)
    on = args.on or f"challenging-{args.fusion}-train"
    with progress_bar() as bar, executor_from_args(args, 10**6) as executor:  # one worker per core by default
        report = loss_progress(bar, bar.add_task(f"fine-tuning {args.fusion}", total=None), f"fine-tuning {args.fusion}")
        card = finetune(args.fusion, on, args.out, steps=args.steps, weights=args.weights, threads=args.threads,
                        force=args.force, executor=executor, stages=stages, config=config, log=console.print,
                        progress=report)
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
    console.print(f"weights and card: {card.get('weights')} in {args.out or default_out(args.fusion)}")
    return 0
