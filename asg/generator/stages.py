"""The stages of a scene along one run of the generator (a closed set), and the one key their AP has
in a run folder's summary (a scene's entry and the pooled aggregate alike)."""
from __future__ import annotations

import enum


class Stage(str, enum.Enum):
    """A scene's state in a run. A str: its value names the stage in detections files and summaries."""

    __str__ = str.__str__  # (enum.StrEnum from Python 3.11 on)
    __format__ = str.__format__

    NORMAL = "normal"  # as sampled from the log, with its collaborators: the paper's normal scene
    AFTER_ACS = "after_acs"  # with the collaborators the collaborator search chose
    FINAL = "final"  # after the perturbation search: the challenging scene

    @property
    def ap_key(self) -> str:
        """The key of its AP in a summary: a scene entry's AP and the aggregate's pooled AP."""
        return _AP_KEYS[self]

    @property
    def old_value(self) -> str:
        """Its spelling in run folders written before each stage had one name (the normal stage's
        scene file and detections were "initial"); read, never written."""
        return _OLD_VALUES.get(self, self.value)

    @property
    def old_pooled_key(self) -> str:
        """The key summaries written before :attr:`ap_key` was one gave its pooled AP (the final
        stage's was "ap_challenging"); read, never written."""
        return _OLD_POOLED_KEYS.get(self, _AP_KEYS[self])


_AP_KEYS = {Stage.NORMAL: "ap_normal", Stage.AFTER_ACS: "ap_after_acs", Stage.FINAL: "ap_final"}
_OLD_POOLED_KEYS = {Stage.FINAL: "ap_challenging"}
_OLD_VALUES = {Stage.NORMAL: "initial"}
