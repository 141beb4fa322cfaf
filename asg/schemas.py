"""The schema versions of the files a run or a data set writes for other programs to read: a run's
``summary.json`` and ``run.json``, a data set's ``index.json``. Each is written with its version
under ``"schema"``; a reader takes the version a file holds (a file from before versions were
written has none: :func:`schema_of` tells its shape) and refuses one from a newer asg in one line.

``summary.json`` (docs/generate.md lists its keys):
    1  the final stage's AP under ``ap_challenging`` (and ``mean_scene_ap_challenging``); no
       after-ACS stage in the aggregate; no version written
    2  one key per stage (``ap_normal``, ``ap_after_acs``, ``ap_final``), ``by_method`` per yardstick
    3  the normal stage spelled ``normal`` everywhere: a scene entry's ``collaborators`` (and in the
       scene folder, ``normal.yaml`` and the detections' keys); 2 spelled it ``initial`` there
``run.json``: 1, the settings a run was claimed with (asg.io.run_record).
``index.json``: 1, ``name``, ``frames``, ``splits`` ({split: [scene id]}) and what built it.
"""
from __future__ import annotations

import enum

from sumo_scenarios.errors import InputError

#: the key every versioned file holds its schema version under
SCHEMA_KEY = "schema"


class SchemaFile(str, enum.Enum):
    SUMMARY = "summary.json"
    RUN = "run.json"
    INDEX = "index.json"


#: the version each file is written in today
CURRENT = {SchemaFile.SUMMARY: 3, SchemaFile.RUN: 1, SchemaFile.INDEX: 1}


def stamped(kind: SchemaFile, content: dict) -> dict:
    """``content`` with today's schema version of ``kind`` first."""
    return {SCHEMA_KEY: CURRENT[kind], **{k: v for k, v in content.items() if k != SCHEMA_KEY}}


def schema_of(kind: SchemaFile, content: dict, where: str) -> int:
    """The schema version ``content`` (a file of ``kind``, read from ``where``) is written in: its
    ``schema`` key, else the shape it has (a file from before versions were written); InputError for
    a version this asg does not know (a newer one's)."""
    version = content.get(SCHEMA_KEY) if isinstance(content, dict) else None
    if version is None:
        return _unstamped(kind, content)
    if isinstance(version, bool) or not isinstance(version, int) or not 1 <= version <= CURRENT[kind]:
        raise InputError(f"{where}: {kind.value} of schema {str(version)[:20]!r}, which this asg does not know "
                         f"(it reads 1 to {CURRENT[kind]}); read it with the asg that wrote it, or upgrade asg")
    return version


def _unstamped(kind: SchemaFile, content) -> int:
    if kind is SchemaFile.SUMMARY and isinstance(content, dict):
        aggregate = content.get("aggregate")
        return 1 if isinstance(aggregate, dict) and "ap_challenging" in aggregate else 2
    return 1


def unversioned(content: dict) -> dict:
    """``content`` without its schema version (what a comparison of settings reads)."""
    return {k: v for k, v in content.items() if k != SCHEMA_KEY}
