"""A shipped model (``--fusion attfuse``): a registered fusion of asg.perception.fusion with its
weights in the package, trained by asg's own trainer."""
from __future__ import annotations

from pathlib import Path

from ..fusion import FUSIONS, has_own_attention
from .base import TARGET_KINDS, Target, Training

#: the detector the last check of a weights file built, under :func:`_checked_key`: the next
#: detector asked for with that file (unchanged since) is that one, so a command that checks
#: ``--weights`` before it starts reads the file once (a process keeps at most one)
_CHECKED: dict[tuple, object] = {}


def _checked_key(name: str, weights_file: str) -> tuple | None:
    """(model, the file's real path, size, modification time), or None if it cannot be read."""
    try:
        path = Path(weights_file).resolve()
        stat = path.stat()
    except OSError:
        return None
    return name, str(path), stat.st_size, stat.st_mtime_ns


@TARGET_KINDS.register("shipped")
class ShippedTarget(Target):
    order = 10
    training = Training.ASG
    header = "shipped"
    concurrent_frames = True  # measured: tests/test_generate.py

    @classmethod
    def claims(cls, name: str) -> bool:
        return name in FUSIONS

    @classmethod
    def help_names(cls) -> list[str]:
        return FUSIONS.names()

    def detector(self, weights_file: str | None = None, **options):
        """The model with its shipped weights or ``weights_file`` (the detector :meth:`check` built
        for that file, the first time it is asked for)."""
        key = _checked_key(self.name, weights_file) if weights_file and not options else None
        if key is not None and key in _CHECKED:
            return _CHECKED.pop(key)
        return FUSIONS.entry(self.name)(weights_file=weights_file, **options)

    def check(self, weights_file: str | None = None) -> "ShippedTarget":
        """Its name; a ``weights_file`` is loaded to check it (the shipped weights are checked by
        their tests, not on every command)."""
        if weights_file:
            detector = self.detector(weights_file)
            _CHECKED.clear()
            key = _checked_key(self.name, weights_file)
            if key is not None:
                _CHECKED[key] = detector
        return self

    @property
    def own_attention(self) -> bool:
        return has_own_attention(FUSIONS.entry(self.name))

    @property
    def shipped_weights(self) -> str:
        return FUSIONS.entry(self.name).weights

    def shipped_entry(self):
        return FUSIONS.entry(self.name)
