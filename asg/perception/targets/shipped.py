"""A shipped model (``--fusion attfuse``): a registered fusion of asg.perception.fusion with its
weights in the package, trained by asg's own trainer."""
from __future__ import annotations

from ..fusion import FUSIONS, has_own_attention
from .base import TARGET_KINDS, Target, Training


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
        return FUSIONS.entry(self.name)(weights_file=weights_file, **options)

    def check(self, weights_file: str | None = None) -> "ShippedTarget":
        """Its name; a ``weights_file`` is loaded to check it (the shipped weights are checked by
        their tests, not on every command)."""
        if weights_file:
            self.detector(weights_file)
        return self

    @property
    def own_attention(self) -> bool:
        return has_own_attention(FUSIONS.entry(self.name))

    @property
    def shipped_weights(self) -> str:
        return FUSIONS.entry(self.name).weights

    def shipped_entry(self):
        return FUSIONS.entry(self.name)
