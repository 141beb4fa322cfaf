"""Which agents' views of a scene: its ego's alone, or every sensing agent's in turn (one closed
set for training examples, the branch fit and exports)."""
from __future__ import annotations

from dataclasses import replace
from enum import Enum
from typing import Iterator

from sumo_scenarios.errors import InputError

from .scene import Scene


class Views(str, Enum):
    """The views of a frame: ``EGO``, as its ego sees it (as at inference); ``ALL``, as each sensing
    agent sees it in turn, that agent the detecting one (the same frame from each centre)."""

    EGO = "ego"
    ALL = "all"


def every_view(scenes: Iterator[Scene]) -> Iterator[Scene]:
    """Each scene as it is, then as each collaborator sees it: that agent the ego, the ego and the
    other collaborators its collaborators, id ``SCENE-as-AGENT``. A scene whose links were degraded
    (``link``: what each collaborator's message went through on its way to the ego) is refused:
    those records are the ego's and do not hold for another receiver."""
    for scene in scenes:
        if scene.link:
            raise InputError(f"{scene.scene_id}: its collaborators' links were degraded on the way to its ego; "
                             "export it with --views ego")
        yield scene
        for agent_id in scene.collaborators:
            others = tuple(a for a in scene.sensing_ids if a != agent_id)
            yield replace(scene, scene_id=f"{scene.scene_id}-as-{agent_id}", ego_id=agent_id, collaborators=others)
