"""A fake detector for fast search tests: ground truth for every box with enough fused points."""
from __future__ import annotations

import numpy as np
import torch

from asg.perception.fusion.base import V2XDetector
from asg.sensors.frame import CooperativeFrame


class OracleDetector(V2XDetector):
    """Detects exactly the vehicles (in range) with at least ``min_points`` LiDAR points, score by visibility."""

    def __init__(self, min_points: int = 30):
        self.min_points = min_points
        super().__init__(load=False)

    def build_model(self) -> torch.nn.Module:
        return torch.nn.Identity()

    def detect(self, frame: CooperativeFrame):
        boxes = frame.ego_boxes
        n = frame.points_in_boxes()["fused"]
        keep = n >= self.min_points
        scores = np.clip(n[keep] / 200.0, 0.21, 1.0)
        return self._clip(boxes[keep], scores)

    def attention_weights(self, frame: CooperativeFrame, cells: str = "all") -> dict[str, float]:
        """Weights proportional to each agent's point count (a stand-in for AttFuse's attention)."""
        counts = {a: float(len(frame.clouds[a])) for a in frame.sensing_ids}
        total = sum(counts.values())
        return {a: c / total for a, c in counts.items()}


def oracle_factory(cfg):
    """A detector factory (``--detector fakes:oracle_factory``): the oracle as target and ACS model."""
    det = OracleDetector()
    return det, det


class _DiesOnce(OracleDetector):
    """The oracle, but the first call of the whole test (marker file absent) kills its process."""

    def __init__(self, marker: str):
        self.marker = marker
        super().__init__()

    def detect(self, frame):
        import os
        import signal
        from pathlib import Path

        if not Path(self.marker).exists():
            Path(self.marker).write_text("killed once")
            os.kill(os.getpid(), signal.SIGKILL)
        return super().detect(frame)


def dies_once_factory(cfg):
    """A detector factory whose worker process is killed mid-scene once (marker: $ASG_TEST_MARKER)."""
    import os

    det = _DiesOnce(os.environ["ASG_TEST_MARKER"])
    return det, det


# ---- detector factories that misbehave (tests/test_robustness.py: one line each, nothing left) ----
class _Misbehaving(OracleDetector):
    """The oracle whose detect() returns ``make(boxes, scores)`` instead."""

    def __init__(self, make):
        self.make = make
        super().__init__()

    def detect(self, frame):
        return self.make(*super().detect(frame))


def _misbehaving(make):
    def factory(cfg):
        det = _Misbehaving(make)
        return det, det
    return factory


nan_factory = _misbehaving(lambda b, s: (np.full((1, 7), np.nan), np.ones(1)))
none_factory = _misbehaving(lambda b, s: None)
string_factory = _misbehaving(lambda b, s: ("boxes", "scores"))
shape_factory = _misbehaving(lambda b, s: (np.ones((2, 5)), np.ones(2)))
negative_size_factory = _misbehaving(lambda b, s: (np.array([[5.0, 0, 0, -4.0, 2.0, 1.5, 0]]), np.ones(1)))
score_factory = _misbehaving(lambda b, s: (np.array([[5.0, 0, 0, 4.0, 2.0, 1.5, 0]]), np.array([7.0])))
million_factory = _misbehaving(lambda b, s: (np.tile([5.0, 0, 0, 4.0, 2.0, 1.5, 0], (1_000_000, 1)), np.full(1_000_000, 0.5)))


def _exit(*_):
    import sys

    sys.exit(0)


exit_in_detect_factory = _misbehaving(_exit)


def _hard_exit(*_):
    import os

    os._exit(0)


hard_exit_in_detect_factory = _misbehaving(_hard_exit)


def _forever(*_):
    import time

    while True:
        time.sleep(0.05)


hang_factory = _misbehaving(_forever)


def _swallow_then_answer(boxes, scores):
    """Swallows the time limit's TimeoutError (an ``except BaseException``), then answers late."""
    import time

    started = time.monotonic()
    while time.monotonic() - started < 3.0:
        try:
            time.sleep(0.05)
        except BaseException:  # noqa: B036  (the misbehaviour under test)
            pass
    return boxes, scores


swallowing_hang_factory = _misbehaving(_swallow_then_answer)


def raising_factory(cfg):
    raise RuntimeError("no GPU found")


def exit_factory(cfg):
    raise SystemExit(0)


def wrong_return_factory(cfg):
    return "a detector"


NOT_CALLABLE = 3


def hang_with_short_limit_factory(cfg):
    """hang_factory's detector in a worker whose time limit per call is 1 s (set in the worker's own
    process: the factory runs there; a Ray actor gets no test's monkeypatch)."""
    import asg.perception.plugins as plugins

    plugins.CALL_TIME_LIMIT_S = 1.0
    return hang_factory(cfg)


class _NoAttention(OracleDetector):
    """The oracle with the base class's attention: None (a model that gives none)."""

    def attention_weights(self, frame, cells: str = "all"):
        return None


def no_acs_model_factory(cfg):
    """A factory that returns no ACS model: ACS-A borrows the shipped AttFuse's attention."""
    return OracleDetector(), None


def none_attention_factory(cfg):
    """A factory whose ACS model's attention_weights returns None."""
    det = _NoAttention()
    return det, det


def _swallow_forever(boxes, scores):
    """Never returns: swallows every exception (the time limit's TimeoutErrors included)."""
    import time

    while True:
        try:
            time.sleep(0.05)
        except BaseException:  # noqa: B036  (the misbehaviour under test)
            pass


def stuck_with_short_limit_factory(cfg):
    """A detector that never returns and swallows every exception, in a process whose time limit is
    1 s and which gives up after 2 swallowed TimeoutErrors (set where the factory runs)."""
    import asg.perception.plugins as plugins

    plugins.CALL_TIME_LIMIT_S, plugins.STUCK_ALARMS = 1.0, 2
    return _misbehaving(_swallow_forever)(cfg)


class _SwallowsOneSignal(OracleDetector):
    """The oracle whose first detect() sends its process ``sig`` inside ``except BaseException``."""

    def __init__(self, sig):
        self.sig = sig
        super().__init__()

    def detect(self, frame):
        import os
        import time

        if self.sig is not None:
            sig, self.sig = self.sig, None
            try:
                os.kill(os.getpid(), sig)
                time.sleep(1.0)  # the handler runs here, and its exception is swallowed
            except BaseException:  # noqa: B036  (the misbehaviour under test)
                pass
        return super().detect(frame)


def sigint_swallowed_factory(cfg):
    import signal

    det = _SwallowsOneSignal(signal.SIGINT)
    return det, det


def sigterm_swallowed_factory(cfg):
    import signal

    det = _SwallowsOneSignal(signal.SIGTERM)
    return det, det
