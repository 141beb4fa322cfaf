"""Train an OpenCOOD model with OpenCOOD's own trainer (opencood/tools/train.py, unmodified) on asg's
``detector-train`` set exported in the OPV2V layout; resumable (rerun the same command).

    python docs/experiments/opencood_train.py MODEL_DIR TRAIN_EXPORT VAL_EXPORT [--fusion intermediate|fcooper]
        [--epochs 15] [--layers 3,5,8] [--lr 0.002] [--backbone-from TRAINED_DIR]
    python docs/experiments/opencood_train.py NEW_DIR TRAIN_EXPORT VAL_EXPORT --finetune-from MODEL_DIR --epochs 3

MODEL_DIR gets OpenCOOD's stock hypes of the fusion (point_pillar_intermediate_fusion.yaml: AttFuse;
point_pillar_fcooper.yaml: F-Cooper) with these changes, each written into its config.yaml:
- the data folders (``root_dir``, ``validate_dir``);
- the range, [-51.2, 51.2] m in x and y (the stock [-140.8, 140.8] x [-40, 40] would leave out
  the corners of asg's 48 m evaluation square, and its ground truth beyond 40 m to the side);
- ``--layers``: the backbone stages' depths, only when given (the stock depths are 3, 5, 8);
- ``--lr``: the optimizer's rate, only when given.
Then OpenCOOD's trainer runs with ``--model_dir MODEL_DIR``: it saves ``net_epochN.pth`` after every
epoch and, rerun, resumes from the highest N (the model's weights; its optimizer restarts, as
OpenCOOD's own resume does), on the data folders of the command (those of its config replaced). ``MODEL_DIR`` is then a target: ``--fusion opencood:MODEL_DIR``.

``--backbone-from MODEL_DIR`` (a new fusion from a trained one, e.g. F-Cooper from AttFuse): the new
folder's config is MODEL_DIR's (its grid, range, anchors and backbone, which the tensors taken were
trained for) with the new fusion's name, model and own arguments from its stock hypes; its first checkpoint, ``net_epochN.pth`` with MODEL_DIR's N, holds MODEL_DIR's pillar net and
backbone tensors (every tensor of the new network with the same name and shape), and OpenCOOD's
resume (``load_saved_model``, which loads with ``strict=False``) leaves the rest as initialised (F-Cooper's
``shrink_conv`` and heads, whose input differs from AttFuse's); the tensors taken and those left are
printed. ``--epochs`` more epochs then run from it. ``--lr`` sets a new folder's rate (default the
stock hypes').

``--finetune-from MODEL_DIR`` (hardening an OpenCOOD model, docs/opencood.md): NEW_DIR gets
MODEL_DIR's config with the new data folders and its checkpoint (the highest ``net_epochN.pth``,
kept as ``net_epochN.pth``), and ``--epochs`` more epochs run from it by the same trainer.

The trainer runs as ``asg harden --fusion opencood:DIR`` runs it (asg/perception/opencood/trainer.py:
in a child process with spinning OpenMP threads, after asg's runtime preparation, which
``python -m opencood.tools.train`` lacks; checkpoints written whole, OpenCOOD's later ego rule, its
yaml read by libyaml, AttFuse's attention computed for the ego's row alone: OpenCOOD's function).
Its log: MODEL_DIR/train.log (append).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import torch
import yaml

from asg.perception.opencood.folder import checkpoint_of, plain_hypes, read_hypes, stock_hypes
from asg.perception.opencood.runtime import module
from asg.perception.opencood.trainer import epoch_of, run_trainer, seed_from

STOCK = {"intermediate": "point_pillar_intermediate_fusion.yaml", "fcooper": "point_pillar_fcooper.yaml"}
RANGE_M = [-51.2, -51.2, -3.0, 51.2, 51.2, 1.0]


def write_config(model_dir: Path, fusion: str, train: Path, val: Path, epochs: int, layers: list[int] | None,
                 lr: float | None = None) -> Path:
    """MODEL_DIR/config.yaml from OpenCOOD's stock hypes; a resumed run keeps its config, with the
    data folders given now (a run may move to a larger export between epochs)."""
    path = model_dir / "config.yaml"
    if path.is_file():
        hypes = plain_hypes(path)
        if (hypes.get("root_dir"), hypes.get("validate_dir")) != (str(train), str(val)):
            print(f"{path}: data folders now {train} and {val}")
            hypes.update(root_dir=str(train), validate_dir=str(val))
            path.write_text(yaml.safe_dump(hypes, sort_keys=False))
        return path
    hypes = stock_hypes(STOCK[fusion])
    hypes.update(root_dir=str(train), validate_dir=str(val))
    hypes["train_params"]["epoches"] = epochs
    hypes["preprocess"]["cav_lidar_range"] = list(RANGE_M)
    hypes["postprocess"]["anchor_args"]["cav_lidar_range"] = list(RANGE_M)
    hypes["model"]["args"]["lidar_range"] = list(RANGE_M)
    if layers:
        hypes["model"]["args"]["base_bev_backbone"]["layer_nums"] = layers
    if lr is not None:
        hypes["optimizer"]["lr"] = lr
    model_dir.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(hypes, sort_keys=False))
    return path


def config_from_source(model_dir: Path, fusion: str, source: Path, train: Path, val: Path, epochs: int,
                       lr: float | None) -> None:
    """A new folder's config.yaml for ``--backbone-from``: the source's hypes (its grid, range,
    anchors, backbone, augmentation and post-processing, which its pillar net and backbone were
    trained for) with the new fusion's parts from its stock hypes: its ``name``, model
    ``core_method``, the model arguments and training parameters the source lacks (F-Cooper's
    ``shrink_header``, ``max_cav``) and its rate (or ``lr``). Nothing done for a resumed folder."""
    path = model_dir / "config.yaml"
    if path.is_file():
        return
    stock = stock_hypes(STOCK[fusion])
    read_hypes(source)  # refused in one line if it cannot be run
    hypes = plain_hypes(source / "config.yaml")
    hypes.update(name=stock["name"], root_dir=str(train), validate_dir=str(val))
    hypes["model"]["core_method"] = stock["model"]["core_method"]
    for part, into in ((stock["model"]["args"], hypes["model"]["args"]), (stock["train_params"], hypes["train_params"])):
        into.update({k: v for k, v in part.items() if k not in into})
    hypes["train_params"]["epoches"] = epochs
    hypes["optimizer"]["lr"] = stock["optimizer"]["lr"] if lr is None else lr
    model_dir.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(hypes, sort_keys=False))


def seed_backbone(model_dir: Path, source: Path, epochs: int) -> None:
    """``model_dir``'s first checkpoint from ``source``'s latest (module docstring); its config's
    epochs become N + ``epochs``. Nothing done if ``model_dir`` already has a checkpoint (a resumed
    run)."""
    if list(model_dir.glob("net_epoch*.pth")):
        return
    network = module("tools.train_utils").create_model(read_hypes(model_dir))
    last = checkpoint_of(source)
    given = torch.load(last, map_location="cpu", weights_only=True)
    own = network.state_dict()
    taken = {k: v.to(own[k].dtype) for k, v in given.items() if k in own and own[k].shape == v.shape}
    print(f"{len(taken)} of {len(own)} tensors from {last}; left as initialised: "
          f"{sorted({k.rsplit('.', 2)[0] for k in own if k not in taken})}")
    epoch = epoch_of(last)
    hypes_path = model_dir / "config.yaml"
    raw = yaml.safe_load(hypes_path.read_text())
    raw["train_params"]["epoches"] = epoch + epochs
    hypes_path.write_text(yaml.safe_dump(raw, sort_keys=False))
    torch.save(taken, model_dir / f"net_epoch{epoch}.pth")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("model_dir", type=Path)
    p.add_argument("train", type=Path)
    p.add_argument("val", type=Path)
    p.add_argument("--fusion", choices=sorted(STOCK), default="intermediate")
    p.add_argument("--epochs", type=int, default=15)
    p.add_argument("--layers", default=None, help="backbone stage depths, e.g. 1,2,2 (default OpenCOOD's 3,5,8)")
    p.add_argument("--finetune-from", type=Path, default=None, help="a trained model folder: --epochs more from its checkpoint")
    p.add_argument("--backbone-from", type=Path, default=None,
                   help="a trained model folder of another fusion: its pillar net and backbone start this one")
    p.add_argument("--lr", type=float, default=None, help="the rate of a new folder (default the stock hypes')")
    args = p.parse_args()
    layers = [int(x) for x in args.layers.split(",")] if args.layers else None
    if args.finetune_from:
        seed_from(args.model_dir, args.finetune_from, args.train.resolve(), args.val.resolve(), args.epochs)
    if args.backbone_from:
        config_from_source(args.model_dir, args.fusion, args.backbone_from, args.train.resolve(), args.val.resolve(),
                           args.epochs, args.lr)
    write_config(args.model_dir, args.fusion, args.train.resolve(), args.val.resolve(), args.epochs, layers, args.lr)
    if args.backbone_from:
        seed_backbone(args.model_dir, args.backbone_from, args.epochs)
    run_trainer(args.model_dir)


if __name__ == "__main__":
    main()
