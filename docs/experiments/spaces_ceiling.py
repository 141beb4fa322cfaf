"""How far any search over the feasible set Q could go, from an exhaustive run: random search with
a budget of Q's size (`spaces_bo_variants.py SCENES OUT rs@1000`) evaluates every member of every
scene's Q, and Q depends on the scene, the space and the seed only, not on the search or its budget.

Per scene it reads every member's loss and AP@0.7 (history.csv) and reports, over the scenes
finished (a partial run is fine): Q's optimum (the lowest loss) and its AP@0.7; the exact
expectation of random search's best of N members drawn without replacement (its rank, loss and
AP@0.7, from the order statistics of the scene's table); and, for each given run of the same
scenes, where its final scene ranks in Q and the AP of its final scenes. How smooth the loss is over
Q: the rank correlation of each member's loss with that of its nearest other member (every column
of history.csv scaled to [0, 1] over Q), which is what a model of the loss (BO's Gaussian process,
nevergrad's steps) needs to be high. "mean AP" is the mean of
the scenes' own AP@0.7; "pooled AP" pools the detections of the scenes finished, as the tables do
over all 30 (so it equals the table's value only when every scene is done).
usage: .venv/bin/python docs/experiments/spaces_ceiling.py EXHAUSTIVE_RUN [NAME=RUN_DIR ...] [--budget N]
"""
import csv
import json
import sys
from math import comb
from pathlib import Path

import numpy as np

from asg.generator.run_folder import load_detections, pooled_ap


def neighbour_correlation(run: Path) -> list[float]:
    """Per scene: Spearman correlation of a member's loss with its nearest member's (scaled columns)."""
    from scipy.spatial import cKDTree
    from scipy.stats import spearmanr

    out = []
    for hist in sorted(run.glob("scenes/*/history.csv")):
        with hist.open() as fh:
            rows = list(csv.DictReader(fh))
        cols = [k for k in rows[0] if k not in ("step", "loss") and not k.startswith("ap_")]
        x = np.array([[float(r[k]) for k in cols] for r in rows])
        span = x.max(axis=0) - x.min(axis=0)
        x = (x - x.min(axis=0)) / np.where(span > 0, span, 1.0)
        loss = np.array([float(r["loss"]) for r in rows])
        _, idx = cKDTree(x).query(x, k=2)
        out.append(float(spearmanr(loss, loss[idx[:, 1]]).statistic))
    return out


def member_table(run: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """scene id -> (losses, AP@0.7) of every evaluated member, best loss first."""
    out = {}
    for hist in sorted(run.glob("scenes/*/history.csv")):
        with hist.open() as fh:
            rows = list(csv.DictReader(fh))
        loss = np.array([float(r["loss"]) for r in rows])
        ap = np.array([float(r["ap_0.7"]) for r in rows])
        order = np.argsort(loss, kind="stable")
        out[hist.parent.name] = (loss[order], ap[order])
    return out


def best_of_weights(k: int, n: int) -> np.ndarray:
    """(k,) probability that the best of n members drawn without replacement from k has rank r."""
    n = min(n, k)
    return np.array([comb(k - r, n - 1) for r in range(1, k + 1)], dtype=float) / comb(k, n)


def finals(run: Path) -> dict[str, tuple[float, float]]:
    """scene id -> (final loss, final AP@0.7) of a finished run."""
    summary = json.loads((run / "summary.json").read_text())
    return {e["scene_id"]: (float(e["loss_final"]), float(e["ap_final"]["0.7"])) for e in summary["scenes"]}


def pooled_ap07(run: Path, scenes: list[str]) -> float:
    return 100 * pooled_ap([load_detections(run, s) for s in scenes], "final")["0.7"]


def main(argv: list[str]) -> None:
    budget = 50
    if "--budget" in argv:
        i = argv.index("--budget")
        budget = int(argv[i + 1])
        argv = argv[:i] + argv[i + 2:]
    table = member_table(Path(argv[0]))
    scenes = sorted(table)
    sizes = [len(table[s][0]) for s in scenes]
    print(f"scenes {len(scenes)}, members evaluated per scene {min(sizes)}-{max(sizes)}")
    opt_loss = np.mean([table[s][0][0] for s in scenes])
    opt_ap = np.mean([table[s][1][0] for s in scenes])
    print(f"Q's optimum: mean loss {opt_loss:.4f}, mean AP@0.7 {100 * opt_ap:.1f}, "
          f"pooled AP@0.7 {pooled_ap07(Path(argv[0]), scenes):.1f}")
    exp_loss, exp_ap, exp_rank = [], [], []
    for s in scenes:
        loss, ap = table[s]
        w = best_of_weights(len(loss), budget)
        exp_loss.append(w @ loss)
        exp_ap.append(w @ ap)
        exp_rank.append(w @ np.arange(1, len(loss) + 1))
    print(f"random search, best of {budget} (exact expectation): mean loss {np.mean(exp_loss):.4f}, "
          f"mean AP@0.7 {100 * np.mean(exp_ap):.1f}, rank {np.mean(exp_rank):.1f}")
    corr = neighbour_correlation(Path(argv[0]))
    print(f"rank correlation of a member's loss with its nearest member's: median {np.median(corr):.2f} "
          f"(scenes {min(corr):.2f} to {max(corr):.2f})")
    top = [float(np.mean(table[s][1][: max(1, len(table[s][1]) // 50)])) for s in scenes]
    print(f"mean AP@0.7 of Q's best 2% of members: {100 * np.mean(top):.1f}")
    for spec in argv[1:]:
        name, _, path = spec.partition("=")
        done = finals(Path(path))
        common = [s for s in scenes if s in done]
        ranks = [int(np.searchsorted(table[s][0], done[s][0] - 1e-6)) + 1 for s in common]
        below = sum(done[s][0] < table[s][0][0] - 1e-6 for s in common)
        print(f"{name}: {len(common)} scenes, mean final loss {np.mean([done[s][0] for s in common]):.4f}, "
              f"mean AP@0.7 {100 * np.mean([done[s][1] for s in common]):.1f}, "
              f"pooled AP@0.7 {pooled_ap07(Path(path), common):.1f}, rank in Q median "
              f"{np.median(ranks):.0f} (at the optimum in {sum(r == 1 for r in ranks)}, below Q's optimum in {below})")


if __name__ == "__main__":
    main(sys.argv[1:])
