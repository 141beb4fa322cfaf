"""OpenCOOD model folders as targets: ``--fusion opencood:DIR``.

DIR is OpenCOOD's own layout: its ``config.yaml`` (the hypes its trainer saved) and a checkpoint,
``latest.pth`` or ``net_epochN.pth``. Frames go through OpenCOOD's own dataset code (its pre-processor,
ego choice, projection and anchors), its model's forward and its own post-processor (score
threshold, NMS); asg only converts a cooperative frame in (the OPV2V layout's yaml and cloud, in
memory, as ``asg export --format opv2v`` writes them) and the boxes out. Needs the ``opencood``
extra (``pip install 'asg[opencood]'``: opencoodx with spconv's CPU wheel). docs/opencood.md.
"""
from __future__ import annotations

from pathlib import Path

from sumo_scenarios.errors import InputError

#: the prefix of a ``--fusion`` that names an OpenCOOD model folder
PREFIX = "opencood:"


def is_opencood(name: str) -> bool:
    return isinstance(name, str) and name.startswith(PREFIX)


def model_dir_of(name: str) -> Path:
    """The folder of ``opencood:DIR``; InputError if it is empty or not a folder."""
    text = name[len(PREFIX):]
    if not text.strip():
        raise InputError("--fusion opencood: needs a folder, e.g. --fusion opencood:runs/opencood/attfuse")
    folder = Path(text)
    if not folder.is_dir():
        raise InputError(f"--fusion {name!r}: {text!r} is not a folder; give OpenCOOD's model folder "
                         "(its config.yaml and latest.pth or net_epochN.pth)")
    return folder


def target_label(name: str) -> str:
    """A file-name-safe label of ``opencood:DIR`` for what is made against it (a challenging set's
    name): the folder's name and the first 8 hex digits of the sha256 of its config and checkpoint,
    so that another model, or the same folder retrained, gets its own."""
    import hashlib
    import re

    folder = model_dir_of(name)
    h = hashlib.sha256()
    for path in model_files(folder).values():
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    stem = re.sub(r"[^A-Za-z0-9_-]+", "_", folder.resolve().name)[:40].strip("_-") or "model"
    return f"opencood-{stem}-{h.hexdigest()[:8]}"


_BUILT: dict = {}


def build_opencood_detector(name: str):
    """The OpenCOOD model of ``opencood:DIR``, ready to detect (asg.perception.opencood.detector);
    built once a process for the same folder, config and checkpoint."""
    from .detector import OpenCOODDetector

    folder = model_dir_of(name)
    key = (name, *model_files_stamp(folder))
    if key not in _BUILT:
        _BUILT.clear()
        _BUILT[key] = OpenCOODDetector(folder, name)
    return _BUILT[key]


def model_files(folder: Path) -> dict[str, Path]:
    """{"config": config.yaml, "checkpoint": the checkpoint OpenCOOD loads} of a model folder."""
    from .folder import checkpoint_of

    return {"config": folder / "config.yaml", "checkpoint": checkpoint_of(folder)}


def model_files_stamp(folder: Path) -> tuple:
    """What changes when the folder's config or checkpoint changes (paths, sizes, times)."""
    out = []
    for path in (folder / "config.yaml", *sorted(folder.glob("*.pth"))):
        try:
            st = path.stat()
            out.append((path.name, st.st_size, st.st_mtime_ns))
        except OSError:
            out.append((path.name, None, None))
    return tuple(out)


def check_opencood(name: str) -> str:
    """Refuse (one InputError) an ``opencood:DIR`` that cannot be run, before any work starts:
    the extra missing, the folder, its config or its checkpoint. Builds the model once."""
    build_opencood_detector(name)
    return name
