"""One pooled AP (many frames' AP by threshold, under both yardsticks) and its one serialisation.

Every file asg writes holds a pooled AP as ``{"ap": {"0.3", "0.5", "0.7"}, "ap_per_frame": {...}}``
(the keys of :data:`RESULT_KEYS`): an evaluation result, each set of a harden card's round, the
before and after of a fine-tuning card, the normal and challenging AP of a re-attack. Cards written
before this form (AP by threshold at the top and the paper's yardstick under "per_frame") are read
by :meth:`PooledAP.from_json` and :func:`pooled_pair`, so that older run folders keep reading.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

from .ap import AP_KEYS, Yardstick, both_yardsticks

#: the key of each yardstick's AP in a pooled AP's JSON
RESULT_KEYS = {Yardstick.GLOBAL: "ap", Yardstick.PER_FRAME: "ap_per_frame"}
#: the two pooled APs of a re-attack (normal-val, and the scenes the attack found in it) and of a
#: fine-tuning's evaluation (the weights before and after), as :func:`pooled_pair` reads them
REATTACK_PAIR = ("normal", "challenging")
FINETUNE_PAIR = ("before", "after")
#: where records written before RESULT_KEYS kept the paper's yardstick
_OLD_PER_FRAME_KEY = "per_frame"


@dataclass(frozen=True)
class PooledAP:
    """AP by threshold ({"0.3", "0.5", "0.7": AP in [0, 1]}) of frames pooled, ranked with one sort
    across frames (``ap``, ours) and per frame (``ap_per_frame``, the paper's; None in a record
    written before it was kept)."""

    ap: Mapping[str, float]
    ap_per_frame: Mapping[str, float] | None = None

    def of(self, yardstick: Yardstick | str) -> Mapping[str, float] | None:
        """The AP by threshold ranked by ``yardstick`` (None: not recorded)."""
        return self.ap if Yardstick(yardstick) == Yardstick.GLOBAL else self.ap_per_frame

    def to_json(self, digits: int | None = None) -> dict:
        """``{"ap": ..., "ap_per_frame": ...}``, each AP rounded to ``digits`` if given."""
        def r(ap):
            return None if ap is None else {k: (v if digits is None else round(v, digits)) for k, v in ap.items()}

        return {RESULT_KEYS[Yardstick.GLOBAL]: r(self.ap), RESULT_KEYS[Yardstick.PER_FRAME]: r(self.ap_per_frame)}

    def text(self, key: str = "0.7") -> str:
        """AP at ``key`` in %, "ours / per frame" (e.g. "84.5 / 74.0"; "-" for one not recorded)."""
        return both_yardsticks(self.ap, self.ap_per_frame, key)

    @classmethod
    def from_result(cls, result: Mapping) -> "PooledAP":
        """The pooled AP of an evaluation result (asg.evaluation.evaluate)."""
        return cls(result[RESULT_KEYS[Yardstick.GLOBAL]], result.get(RESULT_KEYS[Yardstick.PER_FRAME]))

    @classmethod
    def from_json(cls, record: Mapping | None) -> "PooledAP | None":
        """The pooled AP a record holds: ``{"ap", "ap_per_frame"}``, or as older cards wrote it (AP by
        threshold at the top, the paper's under "per_frame"); None for None."""
        if record is None:
            return None
        if RESULT_KEYS[Yardstick.GLOBAL] in record:
            return cls.from_result(record)
        return cls({k: record[k] for k in AP_KEYS}, record.get(_OLD_PER_FRAME_KEY))


def pooled_pair(record: Mapping, names: tuple[str, str]) -> dict[str, PooledAP | None]:
    """{name: PooledAP} of a record that holds two pooled APs under ``names`` (a re-attack's
    ("normal", "challenging"), a fine-tuning's ("before", "after")): as written now (each a
    ``{"ap", "ap_per_frame"}``), or as older cards wrote them (each AP by threshold, the paper's
    under ``"per_frame": {name}``, or ``{"ap_" + name}`` as a data set's index keeps them)."""
    old = record.get(_OLD_PER_FRAME_KEY) or {}
    out: dict[str, PooledAP | None] = {}
    for name in names:
        value = record.get(name, record.get(f"ap_{name}"))
        if value is None or RESULT_KEYS[Yardstick.GLOBAL] in value:
            out[name] = PooledAP.from_json(value)
        else:
            out[name] = PooledAP(value, old.get(name, old.get(f"ap_{name}")))
    return out


def pair_json(pair: Mapping[str, PooledAP | None], digits: int | None = None) -> dict:
    """``{name: {"ap", "ap_per_frame"}}`` of :func:`pooled_pair`'s result (None stays None)."""
    return {name: None if p is None else p.to_json(digits) for name, p in pair.items()}
