"""Every setting of an OpenCOOD config that the adapter's models (OpenCOOD's PointPillars family) and
datasets read, checked before any of OpenCOOD's code runs on it: types, signs, ranges, required keys
by model and dataset, model and dataset kinds that fit, and the sizes they multiply into (a BEV grid,
a voxel buffer, a backbone) kept under stated caps, so that no value makes OpenCOOD allocate gigabytes
or crash the process. One InputError naming the key and what it must be.

The caps (docs/opencood.md): a BEV grid of at most MAX_GRID_CELLS cells (OpenCOOD's stock OPV2V
range at 0.4 m: 140,800), at most MAX_VOXEL_VALUES values in the voxel buffer (voxels x points x 4),
at most MAX_BACKBONE_PARAMS weights in the 2D backbone, and at most MAX_ANCHORS anchors.
"""
from __future__ import annotations

import math
from pathlib import Path

from sumo_scenarios.errors import InputError

MAX_GRID_CELLS = 4_000_000
MAX_VOXEL_VALUES = 100_000_000
MAX_BACKBONE_PARAMS = 200_000_000
MAX_ANCHORS = 20_000_000
#: the farthest a range may reach from the sensor (m), and the tallest it may be
MAX_RANGE_M, MAX_HEIGHT_M = 500.0, 50.0
#: OpenCOOD's pre- and post-processors by name (its build_preprocessor and build_postprocessor assert these)
PREPROCESSORS = ("SpVoxelPreprocessor", "VoxelPreprocessor", "BasePreprocessor", "BevPreprocessor")
POSTPROCESSORS = ("VoxelPostprocessor", "BevPostprocessor")
#: the models that fuse features (they read record_len: an intermediate-fusion dataset only)
INTERMEDIATE_MODELS = ("point_pillar_intermediate", "point_pillar_fcooper", "point_pillar_v2vnet")
#: the models that read max_cav (from their args, and the dataset from train_params)
MAX_CAV_MODELS = ("point_pillar_fcooper", "point_pillar_v2vnet")


class _Checker:
    def __init__(self, hypes: dict, path: Path):
        self.hypes = hypes
        self.path = path

    def fail(self, key: str, what: str):
        raise InputError(f"{self.path}: {key} must be {what}; compare with OpenCOOD's hypes_yaml")

    def get(self, key: str):
        """The value at the dotted ``key``; one line if a mapping on the way, or the key, is missing."""
        value = self.hypes
        for part in key.split("."):
            if not isinstance(value, dict) or part not in value:
                raise InputError(f"{self.path}: lacks {key}, which OpenCOOD reads; compare with OpenCOOD's hypes_yaml")
            value = value[part]
        return value

    def optional(self, key: str, default):
        """The value at ``key``, or OpenCOOD's ``default`` where the config leaves it out."""
        parent, _, last = key.rpartition(".")
        holder = self.mapping(parent) if parent else self.hypes
        return holder.get(last, default)

    def mapping(self, key: str) -> dict:
        value = self.get(key)
        if not isinstance(value, dict):
            self.fail(key, "a mapping")
        return value

    def name(self, key: str, choices) -> str:
        value = self.get(key)
        if not isinstance(value, str) or value not in choices:
            self.fail(key, f"one of {', '.join(choices)} (got {str(value)[:40]!r})")
        return value

    def number(self, key: str, lo: float, hi: float, value=None, lo_open: bool = False) -> float:
        value = self.get(key) if value is None else value
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not -1e300 < value < 1e300 \
                or not math.isfinite(value) or not (lo < value if lo_open else lo <= value) or value > hi:
            self.fail(key, f"a number in {'(' if lo_open else '['}{lo:g}, {hi:g}] (got {str(value)[:40]!r})")
        return float(value)

    def whole(self, key: str, lo: int, hi: int, value=None) -> int:
        value = self.get(key) if value is None else value
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            self.fail(key, f"a whole number from {lo} to {hi} (got {str(value)[:40]!r})")
        return value

    def flag(self, key: str) -> bool:
        value = self.get(key)
        if not isinstance(value, bool):
            self.fail(key, f"true or false (got {str(value)[:40]!r})")
        return value

    def numbers(self, key: str, count: int | tuple[int, int], lo: float, hi: float, whole: bool = False) -> list:
        value = self.get(key)
        lo_n, hi_n = (count, count) if isinstance(count, int) else count
        if not isinstance(value, list) or not lo_n <= len(value) <= hi_n:
            self.fail(key, f"a list of {lo_n}{'' if lo_n == hi_n else f' to {hi_n}'} numbers (got {str(value)[:60]!r})")
        return [self.whole(key, int(lo), int(hi), v) if whole else self.number(key, lo, hi, v) for v in value]

    def lidar_range(self, key: str) -> list[float]:
        r = self.numbers(key, 6, -MAX_RANGE_M, MAX_RANGE_M)
        if not (r[3] > r[0] and r[4] > r[1] and r[5] > r[2]) or r[5] - r[2] > MAX_HEIGHT_M:
            self.fail(key, f"[x_min, y_min, z_min, x_max, y_max, z_max] with each max above its min and at most "
                           f"{MAX_HEIGHT_M:g} m tall (got {r})")
        return r


def check_settings(hypes: dict, path: Path) -> None:
    """Refuse (one InputError) a config the adapter would hand OpenCOOD to fail on; see the module
    docstring. ``hypes`` as read (before OpenCOOD's yaml_parser)."""
    c = _Checker(hypes, path)
    model = c.get("model.core_method")
    fusion = c.get("fusion.core_method")
    if (model in INTERMEDIATE_MODELS) != (fusion == "IntermediateFusionDataset"):
        c.fail("fusion.core_method", f"IntermediateFusionDataset for {model}, and only for a model that fuses "
                                     f"features ({', '.join(INTERMEDIATE_MODELS)}; got {fusion})")
    c.name("yaml_parser", ("load_point_pillar_params",))
    c.name("preprocess.core_method", PREPROCESSORS)
    voxel = c.numbers("preprocess.args.voxel_size", 3, 0.02, 20.0)
    r = c.lidar_range("preprocess.cav_lidar_range")
    cells = math.prod(round((r[i + 3] - r[i]) / voxel[i]) for i in range(2))
    if cells > MAX_GRID_CELLS:
        c.fail("preprocess.cav_lidar_range / voxel_size", f"a BEV grid of at most {MAX_GRID_CELLS:,} cells "
                                                          f"(this range at this voxel size gives {cells:,})")
    points = c.whole("preprocess.args.max_points_per_voxel", 1, 1024)
    for split in ("train", "test"):
        voxels = c.whole(f"preprocess.args.max_voxel_{split}", 1, MAX_GRID_CELLS)
        if voxels * points * 4 > MAX_VOXEL_VALUES:
            c.fail(f"preprocess.args.max_voxel_{split}", f"at most {MAX_VOXEL_VALUES:,} values with "
                                                         f"max_points_per_voxel (got {voxels * points * 4:,})")
    augment = c.get("data_augment")
    if not isinstance(augment, list) or not all(isinstance(a, dict) and isinstance(a.get("NAME"), str) for a in augment):
        c.fail("data_augment", "a list of augmentations, each a mapping with a NAME")
    _postprocess(c, cells)
    _model(c, model, voxel, r)
    if model in MAX_CAV_MODELS:
        c.whole("train_params.max_cav", 1, 64)
        c.whole("model.args.max_cav", 1, 64)


def _postprocess(c: _Checker, cells: int) -> None:
    c.name("postprocess.core_method", POSTPROCESSORS)
    c.lidar_range("postprocess.anchor_args.cav_lidar_range")
    rotations = c.numbers("postprocess.anchor_args.r", (1, 8), -360.0, 360.0)
    num = c.whole("postprocess.anchor_args.num", 1, 8)
    if num != len(rotations):
        c.fail("postprocess.anchor_args.num", f"the number of rotations r ({len(rotations)}), got {num}")
    for key in ("l", "w", "h"):  # one size for every anchor, or one per anchor
        if isinstance(c.get(f"postprocess.anchor_args.{key}"), list):
            c.numbers(f"postprocess.anchor_args.{key}", num, 0.0, 30.0)
        else:
            c.number(f"postprocess.anchor_args.{key}", 0.0, 30.0, lo_open=True)
    stride = c.whole("postprocess.anchor_args.feature_stride", 1, 16,
                     c.optional("postprocess.anchor_args.feature_stride", 2))  # OpenCOOD's default
    if cells // (stride * stride) * num > MAX_ANCHORS:
        c.fail("postprocess.anchor_args.feature_stride", f"a stride that keeps at most {MAX_ANCHORS:,} anchors")
    for key in ("pos_threshold", "neg_threshold", "score_threshold"):
        c.number(f"postprocess.target_args.{key}", 0.0, 1.0)
    c.name("postprocess.order", ("hwl",))  # its anchors take hwl or lhw, its corners hwl or lwh
    c.whole("postprocess.max_num", 1, 10_000)
    c.number("postprocess.nms_thresh", 0.0, 1.0)


def _model(c: _Checker, model: str, voxel: list[float], lidar_range: list[float]) -> None:
    c.numbers("model.args.voxel_size", 3, 0.02, 20.0)
    c.lidar_range("model.args.lidar_range")
    anchors = c.whole("model.args.anchor_number", 1, 8)
    if anchors != c.get("postprocess.anchor_args.num"):
        c.fail("model.args.anchor_number", f"postprocess.anchor_args.num ({c.get('postprocess.anchor_args.num')})")
    for key in ("use_norm", "with_distance", "use_absolute_xyz"):
        c.flag(f"model.args.pillar_vfe.{key}")
    c.numbers("model.args.pillar_vfe.num_filters", (1, 4), 1, 1024, whole=True)
    c.whole("model.args.point_pillar_scatter.num_features", 1, 1024)
    stages = len(c.numbers("model.args.base_bev_backbone.layer_nums", (1, 6), 0, 64, whole=True))
    layers = c.get("model.args.base_bev_backbone.layer_nums")
    c.numbers("model.args.base_bev_backbone.layer_strides", stages, 1, 8, whole=True)
    filters = c.numbers("model.args.base_bev_backbone.num_filters", stages, 1, 1024, whole=True)
    c.numbers("model.args.base_bev_backbone.upsample_strides", stages, 0.125, 16.0)
    c.numbers("model.args.base_bev_backbone.num_upsample_filter", stages, 1, 1024, whole=True)
    weights = sum((n + 1) * f * f * 9 for n, f in zip(layers, filters))
    if weights > MAX_BACKBONE_PARAMS:
        c.fail("model.args.base_bev_backbone", f"a backbone of at most {MAX_BACKBONE_PARAMS:,} weights "
                                               f"(layer_nums x num_filters give about {weights:,})")
    c.whole("model.args.compression", 0, 1024, c.optional("model.args.compression", 0))
