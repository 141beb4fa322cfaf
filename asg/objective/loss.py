"""The adversarial objective: a weighted sum of AP at several IoU thresholds (lower = harder)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from sumo_scenarios.errors import InputError

from .ap import REPORTED_THRESHOLDS


@dataclass(frozen=True)
class ObjectiveConfig:
    """L_adv = sum_t w_t AP@t; the paper: w = 1.0, 0.8, 0.5 at IoU 0.3, 0.5, 0.7."""

    weights: dict[str, float] = field(default_factory=lambda: {"0.3": 1.0, "0.5": 0.8, "0.7": 0.5})

    def __post_init__(self) -> None:
        for key, w in self.weights.items():
            try:
                t = float(key)
            except ValueError:
                t = math.nan
            if not 0.0 < t < 1.0 or f"{t:g}" != key:
                raise InputError(f"objective.weights: key {key!r} is not an IoU threshold written like 0.3, 0.5 or 0.7")
            if not math.isfinite(w) or w < 0.0:
                raise InputError(f"objective.weights.{key}: weight {w} must be a finite number >= 0")
        if not self.weights or sum(self.weights.values()) <= 0.0:
            raise InputError("objective.weights: give at least one positive weight")

    @property
    def thresholds(self) -> tuple[float, ...]:
        """The loss's thresholds together with the reported ones, ascending: what AP is computed at."""
        return tuple(sorted({*REPORTED_THRESHOLDS, *(float(k) for k in self.weights)}))


def adversarial_loss(ap: dict[str, float], cfg: ObjectiveConfig = ObjectiveConfig()) -> float:
    """Weighted AP; ``ap`` maps threshold strings ("0.3") to AP fractions."""
    return float(sum(w * ap[k] for k, w in cfg.weights.items()))
