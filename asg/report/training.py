"""The report's sections for training runs: ``asg harden`` (one row a round, AP@0.7 by round,
each round's training loss: asg's steps, or OpenCOOD's trainer's epochs) and ``asg finetune``
(before / after on each set, the training loss).

Every value comes from the run's own files (card.json, the fine-tuning card, loss.csv) and is
escaped; a file that is not what asg wrote ends in one InputError (asg.report.page's guard).
"""
from __future__ import annotations

import html
from pathlib import Path
from typing import Callable

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..objective import ap_text  # noqa: E402
from ..objective.pooled import FINETUNE_PAIR, REATTACK_PAIR, PooledAP, pooled_pair  # noqa: E402
from sumo_scenarios.errors import InputError  # noqa: E402

from ..io.curves import LOSS_CURVE, read_loss_curve  # noqa: E402
from ..io.json_file import read_json  # noqa: E402

#: the files that make a folder a training run
HARDEN_CARD = "card.json"


def training_kind(folder: Path) -> str | None:
    """"harden", "finetune" or None: what training run ``folder`` holds."""
    card = _json(folder / HARDEN_CARD)
    if isinstance(card, dict) and "rounds" in card:
        return "harden"
    return "finetune" if _finetune_card(folder) is not None else None


def training_folders(root: Path) -> list[Path]:
    """``root`` if it is a training run, else its sub-folders that are (sorted)."""
    if training_kind(root):
        return [root]
    return sorted(p for p in root.iterdir() if p.is_dir() and training_kind(p)) if root.is_dir() else []


def training_section(folder: Path, img: Callable, table: Callable) -> str:
    """The section of a harden or fine-tuning folder (``img(fig)``: an inline picture, ``table(head,
    rows)``: an HTML table, both escaping what they get)."""
    kind = training_kind(folder)
    if kind == "harden":
        return _harden(folder, img, table)
    return _finetune(folder, img, table)


def _harden(folder: Path, img: Callable, table: Callable) -> str:
    card = read_json(folder / HARDEN_CARD, "the hardening run")
    rounds = sorted(card["rounds"], key=lambda r: int(r["round"]))
    sets = sorted({s for r in rounds for s in r.get("evaluation", {})})
    rows = []
    for r in rounds:
        ev, re_ = r.get("evaluation", {}), r.get("reattack")
        reattacked = "-"
        if re_:
            pair = pooled_pair(re_, REATTACK_PAIR)
            reattacked = f"{pair['normal'].text()} -> {pair['challenging'].text()}"
        rows.append([str(int(r["round"])), str((r.get("data") or {}).get("kind", "start weights")),
                     _training_length(r.get("trained") or {}), *[_both(ev.get(s)) for s in sets], reattacked])
    fig, (ax_ap, ax_loss) = plt.subplots(1, 2, figsize=(12, 3.6), dpi=80)
    ks = [int(r["round"]) for r in rounds]
    for s in sets:
        ax_ap.plot(ks, [_num(r.get("evaluation", {}).get(s)) for r in rounds], marker="o", label=s)
    ax_ap.set_xlabel("round")
    ax_ap.set_ylabel("AP@0.7 (%)")
    ax_ap.set_xticks(ks)
    ax_ap.legend(fontsize=7)
    for k in ks[1:]:
        curve = read_loss_curve(folder / f"round-{k}" / LOSS_CURVE)
        if curve:
            ax_loss.plot(*np.array(curve, dtype=float).T, label=f"round {k}")
    ax_loss.set_xlabel("step")
    ax_loss.set_ylabel("training loss (mean of 50 steps)")
    if ax_loss.lines:
        ax_loss.legend(fontsize=7)
    else:
        ax_loss.text(0.5, 0.5, "no training curve recorded", ha="center", va="center", transform=ax_loss.transAxes)
    fig.tight_layout()
    return (f"<section><h2>{html.escape(folder.name)}: asg harden --fusion {html.escape(str(card.get('fusion')))} "
            f"({html.escape(str(card.get('data')))} scenes)</h2><p>AP@0.7 (%) a round on the fixed evaluation sets, "
            f"ours (one sort across frames) / ranked per frame (the paper's yardstick; '-' where a card predates it); "
            f"round 0 is the start weights; re-attacked: normal-val -> the paper's attack against the round's weights. "
            f"The chart shows ours.</p>"
            + table(["round", "data", "trained", *sets, "re-attacked"], rows) + img(fig) + "</section>")


def _training_length(trained: dict) -> str:
    """How long a round trained: asg's trainer's steps, or OpenCOOD's trainer's epochs ('-': round 0)."""
    if "epochs" in trained:
        return f"{int(trained['epochs'])} epochs of OpenCOOD's trainer"
    return f"{int(trained['steps'])} steps" if "steps" in trained else "-"


def _finetune(folder: Path, img: Callable, table: Callable) -> str:
    name, card = _finetune_card(folder)
    rows = []
    for s, v in sorted((card.get("evaluation") or {}).items()):
        pair = pooled_pair(v, FINETUNE_PAIR)
        rows.append([s, str(v.get("frames", "-")), *(ap_text(p and p.ap) for p in pair.values()),
                     *(p.text() if p else "-" for p in pair.values())])
    re_ = card.get("reattack")
    if re_:
        mine = pooled_pair(re_.get("finetuned") or re_, REATTACK_PAIR)  # a harden card keeps them at the top
        rows.append(["re-attacked on normal-val", str(re_.get("frames", "-")),
                     *(ap_text(p and p.ap) for p in mine.values()), *(p.text() if p else "-" for p in mine.values())])
    curve = read_loss_curve(folder / LOSS_CURVE)
    chart = ""
    if curve:
        fig, ax = plt.subplots(figsize=(7, 3.2), dpi=80)
        ax.plot(*np.array(curve, dtype=float).T)
        ax.set_xlabel("step")
        ax.set_ylabel("training loss (mean of 50 steps)")
        fig.tight_layout()
        chart = img(fig)
    return (f"<section><h2>{html.escape(folder.name)}: asg finetune ({html.escape(name)})</h2>"
            "<p>AP@0.3 / 0.5 / 0.7 (%) before and after, and AP@0.7 ours / ranked per frame (the paper's "
            "yardstick; '-' where the card predates it).</p>"
            + table(["set", "frames", "before", "after", "before @0.7", "after @0.7"], rows) + chart + "</section>")


def _finetune_card(folder: Path) -> tuple[str, dict] | None:
    if not (folder / "run.json").is_file():
        return None
    for p in sorted(folder.glob("*.json")):
        card = _json(p)
        if p.name != "run.json" and isinstance(card, dict) and "trained" in card and "weights" in card:
            return p.stem, card
    return None


def _json(path: Path):
    try:
        return read_json(path)
    except InputError:
        return None


def _num(record) -> float:
    """AP@0.7 (ours) in % of a pooled AP's record, NaN when missing (a gap in a chart)."""
    return 100 * float(PooledAP.from_json(record).ap["0.7"]) if record else float("nan")


def _both(record) -> str:
    """AP@0.7 of a pooled AP's record, ours / per frame, or "-"."""
    return PooledAP.from_json(record).text() if record else "-"
