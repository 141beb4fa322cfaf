"""Does a wider backbone lift AP@0.7 once trained to the end? Two single-agent networks (No Fusion)
trained from scratch by the same sequence of chunks (the same seeds and batches): the shipped size
and the wide one (filters 64/128/256, upsampling 128: box_levers.py's "wide", the paper's widths; a
step costs about 2.1x the shipped one's). After 1,000 steps the wide one was further along
(docs/results/detectors.md, "What sharpens the boxes"); this asks where each ends.

Each call trains one size up to CHUNKS chunks of SEQUENCE (default: one more chunk) and scores it
after every chunk. The weights and their card go to DIR/SIZE/ (single.pt, single.json): commit
them and the next sitting continues from them alone, on an empty machine. An interrupted chunk
resumes from runs/size-sequence/SIZE/last.pt on the same machine. Scores: DIR/SIZE/chunk-K.json,
AP@0.3/0.5/0.7 on normal-val and heuristic under both yardsticks (ours: global sort; the paper's: per
frame), with the shared point stage and without it, and the share of the visible vehicles (10+
fused points) whose best candidate fits at IoU 0.5-0.7 only (miss_stages.py's near misses).

After the last chunk, ``--branches`` fits the IoU and refinement branches on the frozen network
(train.yaml's iou_branch block, as the shipped single's were) and scores it again (DIR/SIZE/branches.json).

``--attfuse [CHUNKS]`` then trains AttFuse at that size from that size's single network by
ATTFUSE_SEQUENCE, one more chunk (or up to CHUNKS), and scores it after each (DIR/SIZE/attfuse.pt,
attfuse.json, attfuse-chunk-K.json; the same sets and figures as the single's). After its last chunk,
``--attfuse --branches`` fits AttFuse's branches as the shipped AttFuse's were (DIR/SIZE/attfuse-branches.json).

``--fusions`` scores the two models that are the single network itself, No Fusion and Late Fusion,
of each size with its branches and of the shipped weights, with the point stage, on normal-val,
heuristic and that model's own challenging set (scenes attacked against its shipped model), both
yardsticks: DIR/fusions.json, printed as a table. ``--bootstrap`` gives the gaps between the same
models on SET with their paired-bootstrap intervals (ap_bootstrap.py).

``SIZE --attack [COUNT]`` attacks SIZE's AttFuse as it stands by the paper's protocol on the first
COUNT (100) scenes of normal's train split, as the shipped AttFuse's own set was made (a set named
by its chunks). ``--own`` scores the shipped AttFuse and each size's AttFuse as it stands on
AttFuse's own challenging set (OWN_SET) or on SET: AP and the near misses among the moved and
unmoved vehicles (near_misses.py), DIR/own.json. ``--bootstrap-attfuse`` gives the paired gaps
between those AttFuse weights on those sets.

    .venv/bin/python docs/experiments/size_sequence.py DIR SIZE [CHUNKS]    (SIZE: shipped or wide)
    .venv/bin/python docs/experiments/size_sequence.py DIR SIZE --branches
    .venv/bin/python docs/experiments/size_sequence.py DIR SIZE --attfuse [CHUNKS]
    .venv/bin/python docs/experiments/size_sequence.py DIR SIZE --attfuse --branches
    .venv/bin/python docs/experiments/size_sequence.py DIR --table
    .venv/bin/python docs/experiments/size_sequence.py DIR --fusions
    .venv/bin/python docs/experiments/size_sequence.py DIR SIZE --attack [COUNT]
    .venv/bin/python docs/experiments/size_sequence.py DIR --own [SET]
    .venv/bin/python docs/experiments/size_sequence.py DIR --bootstrap SET [RESAMPLES]
    .venv/bin/python docs/experiments/size_sequence.py DIR --bootstrap-attfuse [RESAMPLES]
"""
from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

from asg.datasets import scenes_of
from asg.objective.pooled import REATTACK_PAIR, pooled_pair
from asg.evaluation import evaluate_detector
from asg.perception.fusion.attfuse import AttFuseDetector
from asg.perception.fusion.single import LateFusion, NoFusion
from asg.training.config import load_train_config
from asg.training.train import train

from box_levers import SIZES as BOX_LEVER_SIZES  # this folder's
from miss_stages import STAGES, rows_of
from near_misses import shares

#: the two sizes compared, as box_levers.py defines them
SIZES = {name: BOX_LEVER_SIZES[name] for name in ("shipped", "wide")}
#: the chunks, each (steps, one-cycle peak lr): the shipped single's one-cycle chunks (0.002, 0.001,
#: 0.0005) after one more at 0.002 in place of its first two (a step schedule at 0.002); its other
#: settings (train.yaml's single block: data, batch, seed)
SEQUENCE = ((3000, 0.002), (3000, 0.002), (3000, 0.001), (3000, 0.0005))
#: AttFuse's chunks from the single network (one-cycle; train.yaml's attfuse block otherwise: all
#: views, batch 4): the shipped AttFuse's peaks (0.001, then 0.0005 and below), in longer chunks
ATTFUSE_SEQUENCE = ((3000, 0.001), (3000, 0.001), (3000, 0.0005), (2000, 0.00025))
#: the models trained by chunks: {fusion: (weights name, its chunks)}
MODELS = {"none": ("single", SEQUENCE), "attfuse": ("attfuse", ATTFUSE_SEQUENCE)}
SETS = ("normal-val", "heuristic")
#: the models that are the single network itself, each with the sets --fusions scores it on
FUSIONS = {"none": (NoFusion, (*SETS, "challenging-none-train")),
           "late": (LateFusion, (*SETS, "challenging-late-train"))}
#: AttFuse's own challenging set: the first 100 scenes of normal's train split attacked against the
#: shipped AttFuse with its stage (tables.md's; asg dataset build challenging --fusion attfuse
#: --split train --count 100)
OWN_SET = "challenging-attfuse-train"
#: training threads (ASG_THREADS, default 2)
THREADS = int(os.environ.get("ASG_THREADS", "2"))
#: the attack's worker processes (ASG_WORKERS, default 2)
WORKERS = int(os.environ.get("ASG_WORKERS", "2"))


def card_chunks(weights_dir: Path, name: str) -> list[dict]:
    """The chunks NAME's card lists (none before its first chunk)."""
    card = weights_dir / f"{name}.json"
    return json.loads(card.read_text())["chunks"] if card.is_file() else []


def chunks_done(weights_dir: Path, name: str = "single") -> int:
    """The training chunks in NAME's card (its branch fit, if any, is not one)."""
    return sum(1 for c in card_chunks(weights_dir, name) if c.get("part", "all") == "all")


def branches_fitted(weights_dir: Path, name: str = "single") -> bool:
    return any(c.get("part") == "branches" for c in card_chunks(weights_dir, name))


def train_chunk(out: Path, size: str, k: int) -> Path:
    """Chunk ``k`` (0-based) of SEQUENCE for ``size``: weights and card in OUT/SIZE/."""
    steps, lr = SEQUENCE[k]
    tcfg = replace(load_train_config("single"), steps=steps, lr=lr, schedule="onecycle")
    return train("none", out_dir=Path("runs") / "size-sequence" / size, train_config=tcfg,
                 detector_config=SIZES[size], weights_dir=out / size, validate=False,
                 threads=THREADS, log=lambda m: print(f"[{size}] {m}", flush=True))


def train_attfuse_chunk(out: Path, size: str, k: int) -> Path:
    """Chunk ``k`` (0-based) of ATTFUSE_SEQUENCE for ``size``; the first starts from OUT/SIZE/single.pt."""
    steps, lr = ATTFUSE_SEQUENCE[k]
    tcfg = replace(load_train_config("attfuse"), steps=steps, lr=lr, schedule="onecycle")
    return train("attfuse", out_dir=Path("runs") / "size-sequence" / f"{size}-attfuse", train_config=tcfg,
                 detector_config=SIZES[size], weights_dir=out / size, validate=False, threads=THREADS,
                 init_from="single" if k == 0 else None, log=lambda m: print(f"[{size} attfuse] {m}", flush=True))


def fit_branches(out: Path, size: str, model: str = "none") -> Path:
    """The IoU and refinement branches of MODEL's weights in OUT/SIZE/ (single.pt or attfuse.pt),
    fitted on the frozen network."""
    tag = size if model == "none" else f"{size}-{model}"
    return train(model, out_dir=Path("runs") / "size-sequence" / tag, iou_branch=True,
                 detector_config=SIZES[size], weights_dir=out / size, validate=False,
                 threads=THREADS, log=lambda m: print(f"[{tag}] {m}", flush=True))


def ap_entry(detector, set_name: str) -> dict:
    """AP@0.3/0.5/0.7 of ``detector`` on ``set_name`` under both yardsticks, and its frame count."""
    scores = evaluate_detector(detector, scenes_of(set_name))
    return {"ap": scores["ap"], "ap_per_frame": scores["ap_per_frame"], "frames": scores["frames"]}


def score(out: Path, size: str, k: int, label: str | None = None, model: str = "none") -> dict:
    """The scores after chunk ``k`` (1-based count of chunks done), kept in OUT/SIZE/LABEL.json
    (``label`` defaults to chunk-K; "branches" after the branch fit); ``model``: none (the single
    network) or attfuse."""
    path = out / size / f"{label or f'chunk-{k}'}.json"
    if path.is_file():
        return json.loads(path.read_text())
    name, detector_class = {"none": ("single", NoFusion), "attfuse": ("attfuse", AttFuseDetector)}[model]
    card = json.loads((out / size / f"{name}.json").read_text())
    # the card names the base settings file; the size's own settings are these
    result = {"size": size, "model": model, "detector": asdict(SIZES[size]), "chunks": k,
              "branches": branches_fitted(out / size, name),
              "steps": card["steps"], "train_wall_s": card["train_wall_s"], "sets": {}}
    for stage in (True, False):
        cfg = replace(SIZES[size], point_stage=stage)
        detector = detector_class(cfg=cfg, weights_file=str(out / size / f"{name}.pt"))
        for set_name in SETS:
            t0 = time.perf_counter()
            entry = ap_entry(detector, set_name)
            if stage:
                rows = rows_of(set_name, detector, cfg)
                entry["near_miss_pct"] = round(100 * float((rows[:, 1] == STAGES.index("best candidate 0.5-0.7")).mean()), 1)
            entry["eval_s"] = round(time.perf_counter() - t0, 1)
            result["sets"][f"{set_name}{'' if stage else ' (no stage)'}"] = entry
            print(f"[{size} {model}] {path.stem} {set_name} stage={stage}: {entry}", flush=True)
    path.write_text(json.dumps(result, indent=1))
    return result


def table(out: Path) -> None:
    print("| size | chunks | steps | set | AP@0.5 / 0.7 | AP@0.7 per frame | no stage AP@0.7 | near misses (%) |")
    print("|---|---|---|---|---|---|---|---|")
    for size_dir in sorted(p for p in out.iterdir() if p.is_dir()):
        paths = sorted(size_dir.glob("chunk-*.json"), key=lambda p: int(p.stem.split("-")[1]))
        paths += [size_dir / "branches.json"] if (size_dir / "branches.json").is_file() else []
        paths += sorted(size_dir.glob("attfuse-chunk-*.json"), key=lambda p: int(p.stem.split("-")[2]))
        paths += [size_dir / "attfuse-branches.json"] if (size_dir / "attfuse-branches.json").is_file() else []
        for path in paths:
            table_rows(json.loads(path.read_text()))


def table_rows(r: dict) -> None:
    chunks = f"{r['chunks']}{' + branches' if r.get('branches') else ''}"
    for set_name in SETS:
        s, n = r["sets"][set_name], r["sets"][f"{set_name} (no stage)"]
        model = f"{r['size']}{' attfuse' if r.get('model') == 'attfuse' else ''}"
        print(f"| {model} | {chunks} | {r['steps']} | {set_name} | {100 * s['ap']['0.5']:.1f} / "
              f"{100 * s['ap']['0.7']:.1f} | {100 * s['ap_per_frame']['0.7']:.1f} | {100 * n['ap']['0.7']:.1f} | "
              f"{s['near_miss_pct']} |")


def single_weights(out: Path) -> dict[str, tuple]:
    """{label: (detector settings, weights file or None for the shipped)}: the shipped single weights
    ("shipped weights") and each size's with its branches fitted."""
    weights = {"shipped weights": (NoFusion.detector_config(), None)}
    weights.update({size: (SIZES[size], str(out / size / "single.pt")) for size in SIZES if branches_fitted(out / size)})
    return weights


def bootstrap(out: Path, set_name: str, resamples: int) -> None:
    """ap_bootstrap.py's paired gaps between FUSIONS of single_weights (labels FUSION/WEIGHTS)."""
    from ap_bootstrap import main as bootstrap_main  # this folder's

    weights = single_weights(out)
    labels = [f"{fusion}/{label.replace(' ', '-')}" for fusion in FUSIONS for label in weights]

    def build(specs) -> dict:
        found = {}
        for spec in specs:
            fusion, _, label = spec.partition("/")
            cfg, weights_file = weights[label.replace("-", " ")]
            found[spec] = FUSIONS[fusion][0](cfg=replace(cfg, point_stage=True), weights_file=weights_file)
        return found

    bootstrap_main(set_name, resamples, tuple(labels), build)


def attfuse_weights(out: Path) -> dict[str, tuple]:
    """{label: (detector settings with the point stage on, weights file or None for the shipped)}:
    the shipped AttFuse ("shipped weights") and each size's AttFuse as it stands ("SIZE attfuse K":
    K chunks done)."""
    weights = {"shipped weights": (replace(AttFuseDetector.detector_config(), point_stage=True), None)}
    for size in SIZES:
        k = chunks_done(out / size, "attfuse")
        if k:
            fitted = " + branches" if branches_fitted(out / size, "attfuse") else ""
            weights[f"{size} attfuse {k}{fitted}"] = (replace(SIZES[size], point_stage=True), str(out / size / "attfuse.pt"))
    return weights


def attack_set(out: Path, size: str) -> str:
    """The name of the challenging set attacked against SIZE's AttFuse as it stands (its chunks,
    "b" once its branches are fitted, in the name: other weights make another set)."""
    fitted = "b" if branches_fitted(out / size, "attfuse") else ""
    return f"challenging-attfuse-{size}-{chunks_done(out / size, 'attfuse')}{fitted}-train"


def attfuse_target(_generate_cfg) -> tuple:
    """The generator's detector factory (``size_sequence:attfuse_target``): the AttFuse of the size
    and folder main_attack names, with the shared stage, as the target and as ACS-A's attention."""
    size, out = os.environ["SIZE_SEQUENCE_SIZE"], Path(os.environ["SIZE_SEQUENCE_DIR"])
    detector = AttFuseDetector(cfg=replace(SIZES[size], point_stage=True), weights_file=str(out / size / "attfuse.pt"))
    return detector, detector


def main_attack(out: Path, size: str, count: int) -> None:
    """The paper's protocol (asg dataset build challenging's: ACS-A + BO, budget 50, the same seed)
    over the first COUNT scenes of normal's train split against SIZE's AttFuse: DATA/attack_set(...);
    resumable; WORKERS processes of one thread each."""
    from asg.datasets import data_root
    from asg.executors.base import build_executor
    from asg.perception.targets import resolve_target
    from asg.workflows.challenging import build_challenging

    if not chunks_done(out / size, "attfuse"):
        sys.exit(f"{out / size}: no AttFuse chunk trained yet (--attfuse)")
    here = str(Path(__file__).resolve().parent)
    os.environ.update(SIZE_SEQUENCE_SIZE=size, SIZE_SEQUENCE_DIR=str(out.resolve()),
                      PYTHONPATH=os.pathsep.join(filter(None, (here, os.environ.get("PYTHONPATH")))))
    sys.path.insert(0, here)
    with build_executor("local", WORKERS) as executor:
        built = build_challenging(resolve_target("attfuse"), "train", executor, count=count, detector_factory="size_sequence:attfuse_target",
                                  out=data_root() / attack_set(out, size))
    index = json.loads((built / "index.json").read_text())
    pair = pooled_pair(index, REATTACK_PAIR)
    print(f"{built}: {index['frames']} scenes; AP@0.7 ours / per frame {pair['normal'].text()} -> {pair['challenging'].text()}")


def score_own(out: Path, set_name: str = OWN_SET) -> dict:
    """AP under both yardsticks and near_misses.py's shares (moved and unmoved visible vehicles,
    with the stage and without) of attfuse_weights on SET_NAME (a challenging set), kept in
    OUT/own.json ({set: {weights label: scores}}), one entry a time."""
    path = out / "own.json"
    result = json.loads(path.read_text()) if path.is_file() else {}
    scored = result.setdefault(set_name, {})
    for label, (cfg, weights_file) in attfuse_weights(out).items():
        if label in scored:
            continue
        t0 = time.perf_counter()
        entry = ap_entry(AttFuseDetector(cfg=cfg, weights_file=weights_file), set_name)
        entry["near_misses"] = shares(set_name, "attfuse", cfg=cfg, weights_file=weights_file)
        scored[label] = {**entry, "eval_s": round(time.perf_counter() - t0, 1)}
        print(f"{label}: {scored[label]}", flush=True)
        path.write_text(json.dumps(result, indent=1))
    return scored


def bootstrap_attfuse(out: Path, resamples: int) -> None:
    """ap_bootstrap.py's paired gaps between the shipped AttFuse and each size's AttFuse as it
    stands (attfuse_weights), each on OWN_SET and on each attack set built so far (LABEL-on-SET;
    frames paired by scene: every one of these sets attacks the same first scenes of normal's
    train split)."""
    from ap_bootstrap import main as bootstrap_main  # this folder's
    from asg.datasets import data_root

    weights = attfuse_weights(out)
    sets = {"shipped-weights-set": OWN_SET}
    sets.update({f"{size}-set": attack_set(out, size) for size in SIZES if chunks_done(out / size, "attfuse")
                 and (data_root() / attack_set(out, size) / "index.json").is_file()})
    models = {f"{label.replace(' ', '-')}-on-{tag}": (weights[label], set_name)
              for tag, set_name in sets.items() for label in weights}

    def build(specs) -> dict:
        return {spec: AttFuseDetector(cfg=models[spec][0][0], weights_file=models[spec][0][1]) for spec in specs}

    bootstrap_main(OWN_SET, resamples, tuple(f"{name}@{set_name}" for name, (_, set_name) in models.items()), build)


def own_table(set_name: str, result: dict) -> None:
    print(f"{set_name}, AP in %, the shares in % of the visible vehicles (10+ fused points):")
    print("| weights | AP@0.5 / 0.7 | per frame | moved found | moved near misses, stage / none | "
          "unmoved found | unmoved near misses, stage / none |")
    print("|---|---|---|---|---|---|---|")
    for label, r in result.items():
        stage, none = r["near_misses"]["stage"], r["near_misses"]["no stage"]
        print(f"| {label} | {100 * r['ap']['0.5']:.1f} / {100 * r['ap']['0.7']:.1f} | "
              f"{100 * r['ap_per_frame']['0.5']:.1f} / {100 * r['ap_per_frame']['0.7']:.1f} | "
              f"{stage['moved']['found_pct']} | {stage['moved']['near_miss_pct']} / {none['moved']['near_miss_pct']} | "
              f"{stage['unmoved']['found_pct']} | {stage['unmoved']['near_miss_pct']} / {none['unmoved']['near_miss_pct']} |")


def score_fusions(out: Path) -> dict:
    """FUSIONS of each size whose branches are fitted and of the shipped weights (their own point
    stage; the sizes here use the shipped single's), kept in OUT/fusions.json, one entry a time."""
    path = out / "fusions.json"
    result = json.loads(path.read_text()) if path.is_file() else {}
    for label, (cfg, weights_file) in single_weights(out).items():
        for fusion, (model, sets) in FUSIONS.items():
            detector = model(cfg=replace(cfg, point_stage=True), weights_file=weights_file)
            for set_name in sets:
                key = f"{label} / {fusion} / {set_name}"
                if key in result:
                    continue
                t0 = time.perf_counter()
                result[key] = {**ap_entry(detector, set_name), "eval_s": round(time.perf_counter() - t0, 1)}
                print(f"{key}: {result[key]}", flush=True)
                path.write_text(json.dumps(result, indent=1))
    return result


def fusions_table(result: dict) -> None:
    print("| weights | model | set | AP@0.5 / 0.7 | AP@0.5 / 0.7 per frame |")
    print("|---|---|---|---|---|")
    for key, r in result.items():
        label, fusion, set_name = key.split(" / ")
        print(f"| {label} | {fusion} | {set_name} | {100 * r['ap']['0.5']:.1f} / {100 * r['ap']['0.7']:.1f} | "
              f"{100 * r['ap_per_frame']['0.5']:.1f} / {100 * r['ap_per_frame']['0.7']:.1f} |")


def main_branches(out: Path, size: str, model: str = "none") -> None:
    """Fit MODEL's branches after its last chunk and score it (OUT/SIZE/branches.json for the
    single network, attfuse-branches.json for AttFuse)."""
    name, sequence = MODELS[model]
    done = chunks_done(out / size, name)
    if done < len(sequence):
        sys.exit(f"{out / size}: {done} of {len(sequence)} {name} chunks trained; the branches are fitted after the last")
    if not branches_fitted(out / size, name):
        fit_branches(out, size, model)
    score(out, size, done, "branches" if model == "none" else f"{name}-branches", model)


def main_attfuse(out: Path, size: str, chunks: int | None) -> None:
    if not branches_fitted(out / size):
        sys.exit(f"{out / size}: AttFuse starts from the single network after its branch fit (--branches)")
    target = min(chunks if chunks is not None else chunks_done(out / size, "attfuse") + 1, len(ATTFUSE_SEQUENCE))
    while chunks_done(out / size, "attfuse") < target:
        train_attfuse_chunk(out, size, chunks_done(out / size, "attfuse"))
        k = chunks_done(out / size, "attfuse")
        score(out, size, k, f"attfuse-chunk-{k}", "attfuse")


def main(out: Path, size: str, chunks: int | None) -> None:
    (out / size).mkdir(parents=True, exist_ok=True)
    target = min(chunks if chunks is not None else chunks_done(out / size) + 1, len(SEQUENCE))
    while chunks_done(out / size) < target:
        train_chunk(out, size, chunks_done(out / size))
        score(out, size, chunks_done(out / size))


if __name__ == "__main__":
    if len(sys.argv) >= 3 and not sys.argv[2].startswith("--") and sys.argv[2] not in SIZES:
        sys.exit(f"size must be one of {', '.join(SIZES)}")
    if len(sys.argv) == 3 and sys.argv[2] == "--table":
        table(Path(sys.argv[1]))
    elif len(sys.argv) in (4, 5) and sys.argv[2] == "--bootstrap":
        bootstrap(Path(sys.argv[1]), sys.argv[3], int(sys.argv[4]) if len(sys.argv) == 5 else 1000)
    elif len(sys.argv) in (3, 4) and sys.argv[2] == "--bootstrap-attfuse":
        bootstrap_attfuse(Path(sys.argv[1]), int(sys.argv[3]) if len(sys.argv) == 4 else 1000)
    elif len(sys.argv) in (3, 4) and sys.argv[2] == "--own":
        own_set = sys.argv[3] if len(sys.argv) == 4 else OWN_SET
        own_table(own_set, score_own(Path(sys.argv[1]), own_set))
    elif len(sys.argv) == 3 and sys.argv[2] == "--fusions":
        fusions_table(score_fusions(Path(sys.argv[1])))
    elif len(sys.argv) in (4, 5) and sys.argv[3] == "--attack":
        main_attack(Path(sys.argv[1]), sys.argv[2], int(sys.argv[4]) if len(sys.argv) == 5 else 100)
    elif len(sys.argv) == 5 and sys.argv[3:] == ["--attfuse", "--branches"]:
        main_branches(Path(sys.argv[1]), sys.argv[2], "attfuse")
    elif len(sys.argv) in (4, 5) and sys.argv[3] == "--attfuse":
        main_attfuse(Path(sys.argv[1]), sys.argv[2], int(sys.argv[4]) if len(sys.argv) == 5 else None)
    elif len(sys.argv) == 4 and sys.argv[3] == "--branches":
        main_branches(Path(sys.argv[1]), sys.argv[2])
    elif len(sys.argv) in (3, 4):
        main(Path(sys.argv[1]), sys.argv[2], int(sys.argv[3]) if len(sys.argv) == 4 else None)
    else:
        sys.exit(__doc__)
