"""Your detector as the target: the plugin protocol and the ``asg.detectors`` entry point group.

A detector plugin is a factory, registered under a name in the ``asg.detectors`` entry point group
of its package (``[project.entry-points."asg.detectors"] mynet = "mypkg.detector:make"``), that
returns an object with

    detect(frame: CooperativeInput) -> (boxes, scores)
        boxes (K, 7) x, y, z, l, w, h, yaw in the ego's sensor frame (x forward, y left, z up,
        metres, yaw in radians from x), (x, y, z) the box centre; scores (K,) in [0, 1]

and optionally ``attention(frame) -> {agent_id: weight}`` (weights summing to 1), which the
collaborator search then uses instead of the shipped AttFuse's attention. ``asg generate``,
``asg evaluate``, ``asg dataset build challenging`` and the benchmarks take the name as
``--fusion NAME``. The shipped models are not in the group: they are asg's fusion registry (FUSIONS).
Worked example: docs/plugins.md; a bad plugin (import error, an exit, wrong shapes, non-finite
numbers, more than MAX_BOXES boxes, a call running over CALL_TIME_LIMIT_S) is one line naming it,
exit 2. A ``--detector module:function`` factory's detectors get the same checks (CheckedDetector).
"""
from __future__ import annotations

from dataclasses import dataclass
from importlib import metadata

import os

import numpy as np

from sumo_scenarios.errors import InputError

from .. import interrupts
from ..registry import DETECTOR_ENTRY_POINTS, detector_entry_names
from ..sensors.frame import CooperativeFrame
from .data import in_range

#: a detector from outside (a plugin, a ``--detector`` factory) returning more boxes a frame is refused
MAX_BOXES = 1000
#: ...and one whose ``detect`` (or ``attention``) call takes longer than this (s) is stopped
CALL_TIME_LIMIT_S = 120.0
#: bounds of a detection (ego frame): beyond them a number is garbage, not a box (1e300 overflows the IoU)
MAX_BOX_CENTRE_M = 10_000.0
MAX_BOX_SIZE_M = 100.0
MAX_BOX_YAW_RAD = 1_000.0
#: TimeoutErrors (one a second past the limit) a call may swallow before the process gives up on it
STUCK_ALARMS = 10


@dataclass(frozen=True)
class CooperativeInput:
    """One cooperative frame as a plugin sees it (no ground truth).

    ``agent_ids``: the sensing agents, the ego first. ``clouds[a]``: (N, 4) float32 x, y, z,
    intensity in agent ``a``'s sensor frame. ``poses[a]``: (4, 4) float64 transform from ``a``'s
    sensor frame to the world (the town's network frame, x east, y north, z up, metres)."""

    ego_id: str
    agent_ids: tuple[str, ...]
    clouds: dict[str, np.ndarray]
    poses: dict[str, np.ndarray]


def cooperative_input(frame: CooperativeFrame) -> CooperativeInput:
    poses = {}
    for a in frame.sensing_ids:
        p = frame.poses[a]
        m = np.eye(4)
        m[:3, :3] = p.rotation()
        m[:3, 3] = p.origin
        poses[a] = m
    order = (frame.ego_id, *[a for a in frame.sensing_ids if a != frame.ego_id])
    return CooperativeInput(frame.ego_id, order, {a: frame.clouds[a] for a in order}, poses)


def plugin_names() -> list[str]:
    return detector_entry_names()


def load_plugin(name: str) -> "PluginDetector | None":
    """The detector plugin registered as ``name``, built and wrapped (None if no plugin has that
    name); InputError if it cannot be imported or built."""
    found = [ep for ep in metadata.entry_points(group=DETECTOR_ENTRY_POINTS) if ep.name == name]
    if not found:
        return None
    ep = found[0]
    try:
        factory = ep.load()
        plugin = factory()
    except (Exception, SystemExit) as exc:  # a plugin may fail in any way (even exit): name it, say how
        raise InputError(f"detector plugin '{name}' ({ep.value}) could not be loaded: "
                         f"{type(exc).__name__}: {exc}".splitlines()[0]) from None
    if isinstance(plugin, PluginDetector) or _is_shipped(plugin):
        return plugin
    if not callable(getattr(plugin, "detect", None)):
        raise InputError(f"detector plugin '{name}' ({ep.value}) returned {type(plugin).__name__}, which has no "
                         "detect(frame) method; see docs/plugins.md")
    return PluginDetector(name, plugin)


def _is_shipped(obj) -> bool:
    from .fusion.base import V2XDetector

    return isinstance(obj, V2XDetector)


class PluginDetector:
    """Adapter: a plugin behind the interface the generator uses (``detect(frame)`` on a
    CooperativeFrame, ``attention_weights``), its outputs checked."""

    def __init__(self, name: str, plugin):
        self.registry_name = name
        self.plugin = plugin
        self.has_attention = callable(getattr(plugin, "attention", None))

    def detect(self, frame: CooperativeFrame) -> tuple[np.ndarray, np.ndarray]:
        where = f"detector plugin '{self.registry_name}'"
        out = guarded_call(where, "detect()", self.plugin.detect, cooperative_input(frame))
        boxes, scores = check_detections(self.registry_name, out)
        keep = in_range(boxes)
        return boxes[keep], scores[keep]

    def attention_weights(self, frame: CooperativeFrame, cells: str = "all") -> dict[str, float] | None:
        if not self.has_attention:
            return None
        where = f"detector plugin '{self.registry_name}'"
        weights = guarded_call(where, "attention()", self.plugin.attention, cooperative_input(frame))
        return check_attention(where, weights, frame.sensing_ids)


class CheckedDetector:
    """A ``--detector module:function`` factory's detector (``detect(CooperativeFrame)``, optionally
    ``attention_weights``) behind the same checks as a plugin: each call under the time limit, its
    output checked (shapes, finite, sizes, scores, MAX_BOXES), any failure one InputError."""

    def __init__(self, where: str, detector):
        self.where = where
        self.detector = detector
        self.has_attention = callable(getattr(detector, "attention_weights", None))

    def detect(self, frame: CooperativeFrame) -> tuple[np.ndarray, np.ndarray]:
        return _checked(self.where, guarded_call(self.where, "detect()", self.detector.detect, frame))

    def attention_weights(self, frame: CooperativeFrame, cells: str = "all") -> dict[str, float] | None:
        if not self.has_attention:
            return None
        weights = guarded_call(self.where, "attention_weights()", self.detector.attention_weights, frame, cells)
        return None if weights is None else check_attention(self.where, weights, frame.sensing_ids)


class _DetectorExit(BaseException):
    """os._exit called by a detector from outside (see guarded_call)."""


def guarded_call(where: str, what: str, fn, *args):
    """``fn(*args)`` of a detector from outside: an exception, ``sys.exit()`` or a call running
    past CALL_TIME_LIMIT_S (measured where the process's main thread runs it) is one InputError."""
    import signal
    import threading

    timed = threading.current_thread() is threading.main_thread()

    alarms = 0

    def too_long(*_):
        nonlocal alarms
        alarms += 1
        if alarms > STUCK_ALARMS:  # every TimeoutError swallowed: no raise can end this call
            interrupts.give_up(f"{overtime} (it swallowed {STUCK_ALARMS} TimeoutErrors: it catches "
                               "every exception; let a detector's exceptions through)")
        raise TimeoutError

    import time

    overtime = InputError(f"{where}: {what} ran over {CALL_TIME_LIMIT_S:g} s on one frame; stopped")
    real_exit = os._exit

    def refuse_exit(code=0):  # os._exit inside the call would end the run with its code and no word
        raise _DetectorExit(code)

    os._exit = refuse_exit
    if timed:
        previous = signal.signal(signal.SIGALRM, too_long)
        # after the limit, again every second: a call that swallows one TimeoutError (an
        # ``except BaseException``) gets the next, and its late answer is refused below
        signal.setitimer(signal.ITIMER_REAL, CALL_TIME_LIMIT_S, 1.0)
    started = time.monotonic()
    try:
        out = fn(*args)
    except TimeoutError:
        raise overtime from None
    except _DetectorExit as exc:
        raise InputError(f"{where}: {what} called os._exit({exc.args[0]}); a detector must return its "
                         "detections, not end the process") from None
    except (Exception, SystemExit) as exc:  # outside code may fail in any way: name it, say how
        raise InputError(f"{where}: {what} failed: {type(exc).__name__}: {exc}".splitlines()[0]) from None
    finally:
        os._exit = real_exit
        if timed:
            signal.setitimer(signal.ITIMER_REAL, 0.0)
            signal.signal(signal.SIGALRM, previous)
    if timed and time.monotonic() - started > CALL_TIME_LIMIT_S:
        raise overtime
    return out


def check_attention(where: str, weights, sensing_ids) -> dict[str, float]:
    try:
        ok = isinstance(weights, dict) and set(weights) == set(sensing_ids) and \
            all(np.isfinite(float(v)) and float(v) >= 0 for v in weights.values())
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise InputError(f"{where}: attention must give a finite, non-negative weight for each of "
                         f"{', '.join(sensing_ids)}")
    return {k: float(v) for k, v in weights.items()}


def check_detections(name: str, out) -> tuple[np.ndarray, np.ndarray]:
    """(boxes (K, 7) float64, scores (K,) float64) from a plugin's return value, or one InputError
    naming the plugin and what is wrong."""
    return _checked(f"detector plugin '{name}'", out)


def _checked(where: str, out) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(out, (tuple, list)) or len(out) != 2:
        raise InputError(f"{where}: detect() must return (boxes, scores), got {type(out).__name__}")
    try:
        raw = [np.asarray(v) for v in out]
        if any(v.dtype.kind not in "biuf" for v in raw):  # complex numbers would lose their imaginary part
            raise TypeError
        boxes, scores = (v.astype(np.float64) for v in raw)
    except (TypeError, ValueError):
        raise InputError(f"{where}: detect() returned boxes or scores that are not real numbers") from None
    if boxes.size == 0 and scores.size == 0:
        return np.zeros((0, 7)), np.zeros(0)
    if boxes.ndim == 2 and len(boxes) > MAX_BOXES:
        raise InputError(f"{where}: detect() returned {len(boxes):,} boxes; at most {MAX_BOXES:,} a frame "
                         f"(keep the best after non-maximum suppression)")
    if boxes.ndim != 2 or boxes.shape[1] != 7:
        raise InputError(f"{where}: boxes must have shape (K, 7) (x, y, z, l, w, h, yaw), got {boxes.shape}")
    if scores.shape != (len(boxes),):
        raise InputError(f"{where}: scores must have shape ({len(boxes)},) to match the boxes, got {scores.shape}")
    if not (np.isfinite(boxes).all() and np.isfinite(scores).all()):
        raise InputError(f"{where}: detect() returned non-finite (NaN or inf) boxes or scores")
    if (boxes[:, 3:6] <= 0).any() or (scores < 0).any() or (scores > 1).any():
        raise InputError(f"{where}: box sizes must be positive and scores within [0, 1]")
    if (np.abs(boxes[:, :3]) > MAX_BOX_CENTRE_M).any() or (boxes[:, 3:6] > MAX_BOX_SIZE_M).any() or \
            (np.abs(boxes[:, 6]) > MAX_BOX_YAW_RAD).any():
        raise InputError(f"{where}: boxes must lie within {MAX_BOX_CENTRE_M:g} m of the ego, be at most "
                         f"{MAX_BOX_SIZE_M:g} m long and have |yaw| <= {MAX_BOX_YAW_RAD:g} rad")
    return boxes, scores
