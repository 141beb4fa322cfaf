"""Detector configuration (frozen, strict) and the BEV grid it implies."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from sumo_scenarios.errors import InputError
from sumo_scenarios.paths import configs_dir
from sumo_scenarios.strict import from_mapping, read_yaml


#: where AttFuse may fuse (see ``DetectorConfig.attfuse_fusion``)
ATTFUSE_FUSIONS = ("output", "stages", "stage1", "pillars")


#: the largest BEV grid (pillars a side) and the widest layer (channels) a settings file may ask
#: for: a network beyond them would not fit in memory (the shipped: 192 pillars, 128 channels)
MAX_GRID = 1024
MAX_CHANNELS = 1024


@dataclass(frozen=True)
class DetectorConfig:
    """PointPillars settings. Frames: the detecting agent's sensor frame (x forward, metres).

    The defaults are the shipped detectors' (configs/detectors/pointpillars.yaml mirrors them; a
    test checks that the two agree). ``range_m`` is the BEV grid's half size and equals the
    evaluation range (``asg.scene.feasibility.EVAL_RANGE_M``)."""

    range_m: float = 48.0
    z_range_m: tuple[float, float] = (-5.0, 1.5)
    pillar_m: float = 0.5
    pfn_channels: int = 64
    layers: tuple[int, int, int] = (1, 2, 2)
    filters: tuple[int, int, int] = (32, 64, 128)
    upsample_channels: int = 48
    anchors: tuple[tuple[float, float, float], ...] = ((4.6, 1.9, 1.6), (10.0, 2.5, 3.3))
    anchor_z_m: float = -1.0
    anchor_rotations_deg: tuple[float, ...] = (0.0, 90.0)
    pos_iou: float = 0.6
    neg_iou: float = 0.45
    score_threshold: float = 0.2
    nms_iou: float = 0.15
    max_detections: int = 100
    #: box voting after NMS: kept boxes averaged with candidates of IoU >= vote_iou (0: off),
    #: weighted by score ** vote_power
    vote_iou: float = 0.3
    vote_power: float = 2.0
    #: IoU-aware rescoring: score = class score ** (1 - iou_rescore) * predicted IoU ** iou_rescore
    #: (0: the class score alone); the IoU branch is an MLP with iou_hidden units over the
    #: iou_patch x iou_patch head cells around each candidate
    iou_rescore: float = 1.0
    iou_hidden: int = 256
    iou_patch: int = 3
    #: box refinement: each candidate's decoded box corrected by the refinement branch (an MLP of
    #: iou_hidden units over the same iou_patch x iou_patch cells) before rescoring, NMS and voting
    box_refine: bool = True
    #: where AttFuse fuses the agents: "output" (the concatenated, upsampled backbone output; the
    #: head's 1x1 convolutions follow, so the fused prediction is linear in the agents' features) or
    #: "stages" (each backbone stage's output before its upsampling block, as the reference
    #: implementation does: the upsampling convolutions and ReLU follow the fusion), or earlier, so
    #: that the rest of the backbone sees every agent's features of a vehicle together: "stage1"
    #: (the first stage's output; stages 2 and 3 and every upsampling block run once, on the fused
    #: map) or "pillars" (the pillar canvas; the whole backbone runs once)
    attfuse_fusion: str = "stage1"
    #: the point stage (asg/perception/point_stage.py): each final box refined from the points
    #: inside it, its score rescored as score ** (1 - point_stage_rescore) * the stage's predicted
    #: IoU ** point_stage_rescore; off: the detector's boxes as they are (faster)
    point_stage: bool = True
    point_stage_rescore: float = 0.5
    #: Where2comm (asg/perception/fusion/where2comm.py): a collaborator sends the BEV cells whose
    #: smoothed confidence exceeds this (Where2comm's ``thre``); 0 sends every cell
    comm_threshold: float = 0.01

    def __post_init__(self) -> None:
        checks = [("range_m", 0 < self.range_m <= 200),
                  ("pillar_m", 0.05 <= self.pillar_m <= 10 and self.grid_size <= MAX_GRID),  # no grid of 0 m pillars
                  ("z_range_m", self.z_range_m[0] < self.z_range_m[1]),
                  ("pfn_channels", 1 <= self.pfn_channels <= MAX_CHANNELS),
                  ("upsample_channels", 1 <= self.upsample_channels <= MAX_CHANNELS),
                  ("layers", all(0 <= n <= 32 for n in self.layers)),
                  ("filters", all(1 <= n <= MAX_CHANNELS for n in self.filters)),
                  ("anchors", bool(self.anchors) and all(0 < s <= 30 for a in self.anchors for s in a)),
                  ("anchor_rotations_deg", 1 <= len(self.anchor_rotations_deg) <= 8),
                  ("neg_iou", 0 < self.neg_iou <= self.pos_iou <= 1),
                  ("score_threshold", 0 <= self.score_threshold < 1), ("nms_iou", 0 < self.nms_iou <= 1),
                  ("vote_iou", 0 <= self.vote_iou <= 1), ("vote_power", 0 <= self.vote_power <= 100),
                  ("iou_rescore", 0 <= self.iou_rescore <= 1), ("iou_hidden", 1 <= self.iou_hidden <= 4096),
                  ("iou_patch", 1 <= self.iou_patch <= 15 and self.iou_patch % 2 == 1),
                  ("max_detections", 1 <= self.max_detections <= 1000),
                  ("attfuse_fusion", self.attfuse_fusion in ATTFUSE_FUSIONS),
                  ("point_stage_rescore", 0 <= self.point_stage_rescore <= 1),
                  ("comm_threshold", 0 <= self.comm_threshold < 1)]
        for name, ok in checks:
            if not ok:
                raise InputError(f"detector config: {name} = {getattr(self, name)!r} is out of range; "
                                 "see configs/detectors/pointpillars.yaml for sensible values")

    @property
    def grid_size(self) -> int:
        """Pillars along x and along y."""
        return int(round(2 * self.range_m / self.pillar_m))

    @property
    def head_size(self) -> int:
        """Cells of the detection head along x and y (half the pillar grid)."""
        return self.grid_size // 2

    @property
    def anchors_per_cell(self) -> int:
        return len(self.anchors) * len(self.anchor_rotations_deg)


#: the shipped detectors' settings (configs/detectors/), unless a detector names another file
DEFAULT_CONFIG_FILE = "pointpillars.yaml"


#: the key by which a detector settings file names the file of the same folder it varies: its own
#: keys replace that file's (a larger or slimmer network keeps the shipped post-processing)
EXTENDS_KEY = "extends"


def load_detector_config(path: str | Path | None = None) -> DetectorConfig:
    """The settings of a detector settings file (default configs/detectors/pointpillars.yaml); a
    file with ``extends: NAME`` takes the keys of NAME (a file beside it that extends none) and
    replaces those it gives itself. Anything wrong is one InputError."""
    path = Path(path or configs_dir() / "detectors" / DEFAULT_CONFIG_FILE)
    data = read_yaml(path)
    if isinstance(data, dict) and EXTENDS_KEY in data:
        data = {**_base_settings(path, data.pop(EXTENDS_KEY)), **data}
    return from_mapping(DetectorConfig, data, str(path))


def _base_settings(path: Path, name) -> dict:
    """The keys of the file ``name`` that ``path`` extends: a file name beside it, not itself, that
    extends none (one level, so no cycle)."""
    if not isinstance(name, str) or not name or Path(name).name != name or name in (".", ".."):
        raise InputError(f"{path}: {EXTENDS_KEY} must be the name of a settings file beside it "
                         f"(e.g. {DEFAULT_CONFIG_FILE}), got {name!r}")
    base_path = path.parent / name
    if base_path.resolve() == path.resolve():
        raise InputError(f"{path}: {EXTENDS_KEY} names the file itself; name the file it varies")
    base = read_yaml(base_path)
    if not isinstance(base, dict):
        raise InputError(f"{base_path}: expected a mapping of keys to values (it is extended by {path.name})")
    if EXTENDS_KEY in base:
        raise InputError(f"{path}: extends {name}, which extends another file; extend the file at the bottom")
    return base
