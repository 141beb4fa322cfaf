"""Train an OpenCOOD model with OpenCOOD's own trainer (opencood/tools/train.py, unmodified) on asg's
``detector-train`` set exported in the OPV2V layout; resumable (rerun the same command).

    python docs/experiments/opencood_train.py MODEL_DIR TRAIN_EXPORT VAL_EXPORT [--fusion intermediate|fcooper]
        [--epochs 15] [--layers 3,5,8]
    python docs/experiments/opencood_train.py NEW_DIR TRAIN_EXPORT VAL_EXPORT --finetune-from MODEL_DIR --epochs 3

MODEL_DIR gets OpenCOOD's stock hypes of the fusion (point_pillar_intermediate_fusion.yaml: AttFuse;
point_pillar_fcooper.yaml: F-Cooper) with three changes, each written into its config.yaml:
- the data folders (``root_dir``, ``validate_dir``);
- the range, [-51.2, 51.2] m in x and y (the stock [-140.8, 140.8] x [-40, 40] would leave out
  the corners of asg's 48 m evaluation square, and its ground truth beyond 40 m to the side);
- ``--layers``: the backbone stages' depths, only when given (the stock depths are 3, 5, 8).
Then OpenCOOD's trainer runs with ``--model_dir MODEL_DIR``: it saves ``net_epochN.pth`` after every
epoch and, rerun, resumes from the highest N (the model's weights; its optimizer restarts, as
OpenCOOD's own resume does), on the data folders of the command (those of its config replaced). ``MODEL_DIR`` is then a target: ``--fusion opencood:MODEL_DIR``.

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

import yaml

from asg.perception.opencood.folder import HypesLoader
from asg.perception.opencood.runtime import module
from asg.perception.opencood.trainer import run_trainer, seed_from

STOCK = {"intermediate": "point_pillar_intermediate_fusion.yaml", "fcooper": "point_pillar_fcooper.yaml"}
RANGE_M = [-51.2, -51.2, -3.0, 51.2, 51.2, 1.0]


def write_config(model_dir: Path, fusion: str, train: Path, val: Path, epochs: int, layers: list[int] | None) -> Path:
    """MODEL_DIR/config.yaml from OpenCOOD's stock hypes; a resumed run keeps its config, with the
    data folders given now (a run may move to a larger export between epochs)."""
    path = model_dir / "config.yaml"
    if path.is_file():
        hypes = yaml.load(path.read_text(), Loader=HypesLoader)
        if (hypes.get("root_dir"), hypes.get("validate_dir")) != (str(train), str(val)):
            print(f"{path}: data folders now {train} and {val}")
            hypes.update(root_dir=str(train), validate_dir=str(val))
            path.write_text(yaml.safe_dump(yaml.safe_load(yaml.safe_dump(hypes)), sort_keys=False))
        return path
    stock = Path(module("hypes_yaml").__file__).parent / STOCK[fusion]
    hypes = yaml.load(stock.read_text(), Loader=HypesLoader)
    hypes = yaml.safe_load(yaml.safe_dump(hypes))
    hypes.update(root_dir=str(train), validate_dir=str(val))
    hypes["train_params"]["epoches"] = epochs
    hypes["preprocess"]["cav_lidar_range"] = list(RANGE_M)
    hypes["postprocess"]["anchor_args"]["cav_lidar_range"] = list(RANGE_M)
    hypes["model"]["args"]["lidar_range"] = list(RANGE_M)
    if layers:
        hypes["model"]["args"]["base_bev_backbone"]["layer_nums"] = layers
    model_dir.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(hypes, sort_keys=False))
    return path


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("model_dir", type=Path)
    p.add_argument("train", type=Path)
    p.add_argument("val", type=Path)
    p.add_argument("--fusion", choices=sorted(STOCK), default="intermediate")
    p.add_argument("--epochs", type=int, default=15)
    p.add_argument("--layers", default=None, help="backbone stage depths, e.g. 1,2,2 (default OpenCOOD's 3,5,8)")
    p.add_argument("--finetune-from", type=Path, default=None, help="a trained model folder: --epochs more from its checkpoint")
    args = p.parse_args()
    layers = [int(x) for x in args.layers.split(",")] if args.layers else None
    if args.finetune_from:
        seed_from(args.model_dir, args.finetune_from, args.train.resolve(), args.val.resolve(), args.epochs)
    write_config(args.model_dir, args.fusion, args.train.resolve(), args.val.resolve(), args.epochs, layers)
    run_trainer(args.model_dir)


if __name__ == "__main__":
    main()
