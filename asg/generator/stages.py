"""The stages of a scene along one run of the generator (a closed set), and the keys their AP has
in a run folder's files."""
from __future__ import annotations

import enum


class Stage(str, enum.Enum):
    """A scene's state in a run. A str: its value names the stage in detections files and summaries."""

    __str__ = str.__str__  # (enum.StrEnum from Python 3.11 on)
    __format__ = str.__format__

    NORMAL = "initial"  # as sampled from the log
    AFTER_ACS = "after_acs"  # with the collaborators the collaborator search chose
    FINAL = "final"  # after the perturbation search: the challenging scene

    @property
    def scene_key(self) -> str:
        """The key of its AP in a summary's scene entry."""
        return _SCENE_KEYS[self]

    @property
    def pooled_key(self) -> str:
        """The key of its pooled AP in a summary's aggregate (the final stage's: "ap_challenging")."""
        return _POOLED_KEYS[self]


_SCENE_KEYS = {Stage.NORMAL: "ap_normal", Stage.AFTER_ACS: "ap_after_acs", Stage.FINAL: "ap_final"}
_POOLED_KEYS = {Stage.NORMAL: "ap_normal", Stage.AFTER_ACS: "ap_after_acs", Stage.FINAL: "ap_challenging"}
