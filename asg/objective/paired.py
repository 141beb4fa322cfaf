"""The gap between two detectors' AP on the same frames, with a 95 % interval (paired bootstrap),
and the per-frame matches it needs, kept on disk without pickles.

A resample draws the frames with replacement (the same draw for both detectors, kept in the set's
order) and recomputes each detector's AP from its frames' fixed matches (asg.objective.ap's
``frame_matches``: matching is per frame, so a resample's AP is exactly ``average_precision`` of
the drawn frames). The interval is the 2.5-97.5 % range of the gaps over the resamples.
"""
from __future__ import annotations

import zipfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from sumo_scenarios.atomic import atomic_path
from sumo_scenarios.errors import InputError
from sumo_scenarios.npz import load_npz

from .ap import DEFAULT_AP_METHOD, REPORTED_THRESHOLDS, FrameMatches, ap_from_matches, check_ap_method

#: resamples of a gap's interval, and their seed (the same interval for the same frames)
RESAMPLES = 1000
SEED = 0


@dataclass(frozen=True)
class ApGap:
    """AP(after) - AP(before) at ``threshold`` on the same ``frames``, in [-1, 1], with its 95 % interval."""

    threshold: float
    gap: float
    low: float
    high: float
    frames: int

    def to_dict(self) -> dict:
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> "ApGap":
        """The gap ``to_dict`` wrote (extra keys, such as a guard's, are ignored)."""
        return cls(float(d["threshold"]), float(d["gap"]), float(d["low"]), float(d["high"]), int(d["frames"]))

    @property
    def not_worse(self) -> bool:
        """The guard's rule: not worse unless the whole 95 % interval lies below zero."""
        return self.high >= 0.0

    def guard_record(self, set_name: str) -> dict:
        """{"set", "threshold", "gap", "low", "high", "frames", "kept"}: a guard's verdict on this gap."""
        return {"set": set_name, **self.to_dict(), "kept": self.not_worse}


def _ap(matches: Sequence[FrameMatches], idx: np.ndarray, threshold: float, method: str) -> float:
    picked = [matches[i][threshold] for i in idx]
    return ap_from_matches([p[0] for p in picked], [p[1] for p in picked], sum(p[2] for p in picked), method=method)


def paired_ap_gap(before: Sequence[FrameMatches], after: Sequence[FrameMatches], threshold: float = 0.7,
                  method: str = DEFAULT_AP_METHOD, resamples: int = RESAMPLES, seed: int = SEED) -> ApGap:
    """The gap of ``after`` over ``before`` (each a list of one detector's matched frames, the same
    frames in the same order) at ``threshold``, ranked by ``method``, with its interval."""
    check_ap_method(method)
    if len(before) != len(after) or not before:
        raise ValueError(f"paired frames needed: {len(before)} before, {len(after)} after")
    n = len(before)
    every = np.arange(n)
    gap = _ap(after, every, threshold, method) - _ap(before, every, threshold, method)
    rng = np.random.default_rng(seed)
    gaps = []
    for _ in range(resamples):
        idx = np.sort(rng.integers(0, n, n))  # kept in the set's order (the per-frame yardstick reads it)
        gaps.append(_ap(after, idx, threshold, method) - _ap(before, idx, threshold, method))
    low, high = np.percentile(gaps, [2.5, 97.5])
    return ApGap(threshold, float(gap), float(low), float(high), n)


def save_matches(path: Path, matches: Sequence[FrameMatches]) -> None:
    """``matches`` (one detector's frames) as an .npz of plain arrays, written atomically."""
    arrays: dict[str, np.ndarray] = {}
    for t in REPORTED_THRESHOLDS:
        arrays[f"scores@{t:g}"] = np.concatenate([np.asarray(m[t][0], float) for m in matches]) if matches else np.zeros(0)
        arrays[f"tp@{t:g}"] = np.concatenate([np.asarray(m[t][1], bool) for m in matches]) if matches else np.zeros(0, bool)
        arrays[f"counts@{t:g}"] = np.array([len(m[t][0]) for m in matches], dtype=np.int64)
        arrays[f"gt@{t:g}"] = np.array([m[t][2] for m in matches], dtype=np.int64)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)


def load_matches(path: Path) -> list[FrameMatches]:
    """The matches :func:`save_matches` wrote (no pickles); InputError naming the file if damaged."""
    try:
        z = load_npz(path)
        per_threshold = {}
        for t in REPORTED_THRESHOLDS:
            counts, gt = z[f"counts@{t:g}"], z[f"gt@{t:g}"]
            scores, tp = z[f"scores@{t:g}"], z[f"tp@{t:g}"].astype(bool)
            if counts.sum() != len(scores) or len(tp) != len(scores) or len(gt) != len(counts) or \
                    (counts < 0).any() or (gt < 0).any() or not np.isfinite(scores).all():
                raise ValueError("inconsistent arrays")
            cuts = np.cumsum(counts)[:-1]
            per_threshold[t] = list(zip(np.split(scores, cuts), np.split(tp, cuts), (int(g) for g in gt))) \
                if len(counts) else []
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise InputError(f"{path}: damaged matches ({type(exc).__name__}); delete it to score again") from None
    n = len(per_threshold[REPORTED_THRESHOLDS[0]])
    if any(len(v) != n for v in per_threshold.values()):
        raise InputError(f"{path}: damaged matches (frame counts differ); delete it to score again")
    return [{t: per_threshold[t][i] for t in REPORTED_THRESHOLDS} for i in range(n)]
