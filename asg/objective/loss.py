"""The adversarial objective: a weighted sum of AP at several IoU thresholds (lower = harder)."""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class ObjectiveConfig:
    """L_adv = sum_t w_t AP@t; the paper: w = 1.0, 0.8, 0.5 at IoU 0.3, 0.5, 0.7."""

    weights: dict[str, float] = field(default_factory=lambda: {"0.3": 1.0, "0.5": 0.8, "0.7": 0.5})

    @property
    def thresholds(self) -> tuple[float, ...]:
        return tuple(float(k) for k in self.weights)


def adversarial_loss(ap: dict[str, float], cfg: ObjectiveConfig = ObjectiveConfig()) -> float:
    """Weighted AP; ``ap`` maps threshold strings ("0.3") to AP fractions."""
    return float(sum(w * ap[k] for k, w in cfg.weights.items()))
