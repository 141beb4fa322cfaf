"""Small OpenCOOD model folders for the adapter's tests: OpenCOOD's stock hypes of a fusion with the
backbone made shallow and the range cut to asg's evaluation square (so that a CPU runs it in a second),
and a checkpoint of seeded initial weights saved as OpenCOOD's trainer saves one (a state dict)."""
from __future__ import annotations

from pathlib import Path

import yaml

#: OpenCOOD's stock hypes file of each fusion the tests run
STOCK = {"intermediate": "point_pillar_intermediate_fusion.yaml", "early": "point_pillar_early_fusion.yaml",
         "late": "point_pillar_late_fusion.yaml", "fcooper": "point_pillar_fcooper.yaml"}
RANGE = [-51.2, -51.2, -3.0, 51.2, 51.2, 1.0]


def tiny_hypes(kind: str) -> dict:
    from asg.perception.opencood.folder import stock_hypes

    hypes = stock_hypes(STOCK[kind])  # aliases written out: each value its own
    hypes["preprocess"]["cav_lidar_range"] = list(RANGE)
    hypes["postprocess"]["anchor_args"]["cav_lidar_range"] = list(RANGE)
    args = hypes["model"]["args"]
    args["lidar_range"] = list(RANGE)
    # OpenCOOD's PointPillars models hard-code the pillar features (64) and the head's input (128 a
    # stage): what can shrink is the depth of the backbone's stages and their inner widths
    args["base_bev_backbone"].update(layer_nums=[1, 1, 1], num_filters=[32, 64, 64])
    return hypes


def make_model_dir(folder: Path, kind: str, seed: int = 0, score_threshold: float | None = None) -> Path:
    """``folder`` holding config.yaml and net_epoch1.pth of a small OpenCOOD model of ``kind``."""
    import torch

    from asg.perception.opencood.folder import HypesLoader  # noqa: F401
    from asg.perception.opencood.runtime import module

    hypes = tiny_hypes(kind)
    if score_threshold is not None:
        hypes["postprocess"]["target_args"]["score_threshold"] = score_threshold
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "config.yaml").write_text(yaml.safe_dump(hypes, sort_keys=False))
    parsed = getattr(module("hypes_yaml.yaml_utils"), hypes["yaml_parser"])(yaml.safe_load(yaml.safe_dump(hypes)))
    torch.manual_seed(seed)
    model = module("tools.train_utils").create_model(parsed)
    torch.save(model.state_dict(), folder / "net_epoch1.pth")
    return folder


def make_trainer_written_dir(folder: Path, kind: str, seed: int = 0, score_threshold: float | None = None) -> Path:
    """``folder`` as OpenCOOD's ``tools/train.py`` leaves it: the hypes read by OpenCOOD's own
    ``load_yaml`` (its parser adds numpy arrays and scalars) and saved by ``yaml.dump`` as its
    ``train_utils.setup_train`` does (numpy values under Python tags), beside a checkpoint."""
    from asg.perception.opencood.runtime import module

    source = make_model_dir(folder.with_name(folder.name + "-source"), kind, seed=seed, score_threshold=score_threshold)
    folder.mkdir(parents=True, exist_ok=True)
    hypes = module("hypes_yaml.yaml_utils").load_yaml(str(source / "config.yaml"))  # OpenCOOD's full loader, our file
    with open(folder / "config.yaml", "w") as outfile:
        yaml.dump(hypes, outfile)  # train_utils.setup_train's own call
    (folder / "net_epoch1.pth").write_bytes((source / "net_epoch1.pth").read_bytes())
    return folder
