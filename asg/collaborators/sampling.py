"""Which collaborator combinations to try.

ACS-A: agent j's weight s_j is the ego row's attention toward j (AttFuse, averaged over BEV cells);
its weakness 1/s_j; a combination's weakness the sum over its members; p = softmax(w / tau).
k0 combinations are drawn from p without replacement with the Gumbel-top-k trick on log p,
which equals sequential sampling without replacement and cannot underflow (no need to raise tau
as the reference code does). ACS-R draws k0 combinations uniformly.
"""
from __future__ import annotations

import itertools
from typing import Mapping, Sequence

import numpy as np


def all_combinations(candidates: Sequence[str], size: int) -> list[tuple[str, ...]]:
    """Combinations of ``size`` candidates (of all of them if fewer); none without candidates."""
    size = min(size, len(candidates))
    return list(itertools.combinations(sorted(candidates), size)) if size > 0 else []


def combination_weakness(weights: Mapping[str, float], combos: Sequence[tuple[str, ...]]) -> np.ndarray:
    """w_I = sum over I of 1 / s_j (s_j floored at 1e-9)."""
    return np.array([sum(1.0 / max(weights[j], 1e-9) for j in c) for c in combos])


def log_softmax(x: np.ndarray) -> np.ndarray:
    m = np.max(x)
    return x - m - np.log(np.sum(np.exp(x - m)))


def attention_combinations(weights: Mapping[str, float], candidates: Sequence[str], size: int, k0: int, tau: float,
                           rng: np.random.Generator) -> tuple[list[tuple[str, ...]], np.ndarray]:
    """k0 combinations of ``size`` candidates drawn without replacement from softmax(weakness / tau),
    and the full probability vector (for reporting)."""
    combos = all_combinations(candidates, size)
    if not combos:
        return [], np.zeros(0)
    logp = log_softmax(combination_weakness(weights, combos) / tau)
    keys = logp + rng.gumbel(size=len(combos))
    order = np.argsort(-keys, kind="stable")[: min(k0, len(combos))]
    return [combos[i] for i in order], np.exp(logp)


def random_combinations(candidates: Sequence[str], size: int, k0: int, rng: np.random.Generator) -> list[tuple[str, ...]]:
    combos = all_combinations(candidates, size)
    pick = rng.choice(len(combos), size=min(k0, len(combos)), replace=False) if combos else []
    return [combos[i] for i in pick]
