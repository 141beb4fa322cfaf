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

from ...registry import TARGET_PREFIXES

#: the prefix of a ``--fusion`` that names an OpenCOOD model folder (its target kind:
#: asg.perception.targets.opencood)
PREFIX = TARGET_PREFIXES["opencood"].prefix


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
