"""An OpenCOOD AttFuse folder whose network starts from asg's wide AttFuse (`attfuse-wide`), for
OpenCOOD's own trainer to fine-tune: OpenCOOD's model and code throughout, asg's trained tensors
as its starting point instead of OpenCOOD's random initialisation.

    python docs/experiments/opencood_from_asg.py OUT_DIR TRAIN_EXPORT VAL_EXPORT [--epochs 1] [--lr 0.0005]
    python docs/experiments/opencood_train.py OUT_DIR TRAIN_EXPORT VAL_EXPORT   # then OpenCOOD's trainer

The two networks are the same PointPillars at asg's wide size (pillar net of 64, stages of 64 /
128 / 256 filters with 1 / 2 / 2 extra layers, each upsampled to 128 channels, a 1x1 head on the
384), so the config takes asg's grid (0.5 m pillars, x and y in [-48, 48] m, z in [-5, 1.5] m: a
96 x 96 head grid whose anchor centres are asg's) and asg's four anchors a cell (4.6 x 1.9 x 1.6 m
and 10 x 2.5 x 3.3 m at z -1 m, each at yaw 0 and 90 deg). OpenCOOD's stock hypes give one size
(l, w, h scalars); its post-processor multiplies them into an array of one entry per anchor, so
lists of one entry per anchor (``r`` with as many) give each its own size, the same anchors as
asg's in the same order (tested). The tensors, each checked for its shape:
- the pillar net: OpenCOOD's point features are asg's nine (x, y, z, intensity, offsets to the
  pillar's mean, offsets to its centre in x, y) plus the offset to its centre in z, whose column
  starts at 0;
- the backbone: stage k's convolutions and norms one for one (OpenCOOD pads before the strided
  convolution, asg pads in it: the same function); the first upsampling is asg's 1x1 convolution,
  OpenCOOD's 1x1 transposed convolution (its weight transposed); the others as they are;
- the head: the classification and box channels of asg's four anchors, the box residuals
  reordered from asg's (l, w, h) to OpenCOOD's (h, w, l)
  (both encode x, y by the anchor's diagonal, z by its height, sizes by logarithms, yaw by the
  difference);
- asg's attention: its value projection V folded into the two layers that read the fused map
  (:func:`fold_value_projection`); its query and key projections left out (OpenCOOD's attention
  compares the maps themselves, and fuses every stage where asg's fuses the first);
- left out: asg's direction classifier and its IoU and refinement branches.
OpenCOOD reads the exports in CARLA's frame, asg's mirrored in y; the tensors are not mirrored:
asg's detectors train with clouds flipped across x, so each has learnt both. The folder's
``net_epoch1.pth`` holds the converted tensors (OpenCOOD's resume loads a checkpoint only from an
epoch of 1 or more); OpenCOOD's trainer then continues as from its own epoch 1, ``--epochs`` more at
``--lr`` (the config's ``epoches`` is 1 + ``--epochs``).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import torch
import yaml

from asg.perception.config import load_detector_config
from asg.perception.opencood.folder import read_hypes, stock_hypes
from asg.perception.opencood.runtime import module
from asg.perception.weights_io import WEIGHTS_DIR
from sumo_scenarios.paths import configs_dir

STOCK = "point_pillar_intermediate_fusion.yaml"
#: OpenCOOD's box residual j (x, y, z, h, w, l, yaw) is asg's residual ORDER[j] (x, y, z, l, w, h, yaw)
ORDER = (0, 1, 2, 5, 4, 3, 6)


def write_config(out: Path, train: Path, val: Path, detector_file: str, epochs: int, lr: float) -> dict:
    """OpenCOOD's stock AttFuse hypes at asg's grid, size and car anchor (module docstring)."""
    cfg = load_detector_config(configs_dir() / "detectors" / detector_file)
    r, (z0, z1) = cfg.range_m, cfg.z_range_m
    lidar_range = [-r, -r, z0, r, r, z1]
    voxel = [cfg.pillar_m, cfg.pillar_m, z1 - z0]
    hypes = stock_hypes(STOCK)
    hypes.update(root_dir=str(train.resolve()), validate_dir=str(val.resolve()))
    hypes["preprocess"]["cav_lidar_range"] = lidar_range
    hypes["preprocess"]["args"]["voxel_size"] = voxel
    hypes["postprocess"]["anchor_args"]["cav_lidar_range"] = lidar_range
    per_anchor = [(size, rotation) for size in cfg.anchors for rotation in cfg.anchor_rotations_deg]  # asg's order
    hypes["postprocess"]["anchor_args"].update(
        l=[size[0] for size, _ in per_anchor], w=[size[1] for size, _ in per_anchor],
        h=[size[2] for size, _ in per_anchor], r=[rotation for _, rotation in per_anchor], num=len(per_anchor))
    model = hypes["model"]["args"]
    model.update(anchor_num=len(per_anchor), anchor_number=len(per_anchor))
    model["lidar_range"] = lidar_range
    model["voxel_size"] = voxel
    model["base_bev_backbone"].update(layer_nums=list(cfg.layers), num_filters=list(cfg.filters),
                                      num_upsample_filter=[cfg.upsample_channels] * 3)
    model["pillar_vfe"]["num_filters"] = [cfg.pfn_channels]
    hypes["train_params"]["epoches"] = 1 + epochs
    hypes["optimizer"]["lr"] = lr
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.yaml").write_text(yaml.safe_dump(hypes, sort_keys=False))
    return hypes


def converted(asg_state: dict, oc_state: dict) -> dict:
    """OpenCOOD's state dict from asg's (module docstring); every tensor checked for its shape."""
    out = dict(oc_state)

    def put(key: str, value: torch.Tensor) -> None:
        if out[key].shape != value.shape:
            raise ValueError(f"{key}: OpenCOOD's {tuple(out[key].shape)} against {tuple(value.shape)} converted")
        out[key] = value.to(out[key].dtype).clone()

    linear = torch.zeros_like(oc_state["pillar_vfe.pfn_layers.0.linear.weight"])
    linear[:, :9] = asg_state["encoder.linear.weight"]
    put("pillar_vfe.pfn_layers.0.linear.weight", linear)
    for part in ("weight", "bias", "running_mean", "running_var", "num_batches_tracked"):
        put(f"pillar_vfe.pfn_layers.0.norm.{part}", asg_state[f"encoder.norm.{part}"])
    for key, value in asg_state.items():
        if key.startswith("backbone.stages."):
            _, _, stage, index, part = key.split(".")
            put(f"backbone.blocks.{stage}.{int(index) + 1}.{part}", value)  # after OpenCOOD's ZeroPad2d
        elif key.startswith("backbone.ups."):
            _, _, stage, index, part = key.split(".")
            if stage == "0" and index == "0":
                value = value.transpose(0, 1)  # Conv2d (out, in, 1, 1) -> ConvTranspose2d (in, out, 1, 1)
            put(f"backbone.deblocks.{stage}.{index}.{part}", value)
    fold_value_projection(asg_state, out)
    put("cls_head.weight", asg_state["head.cls.weight"])
    put("cls_head.bias", asg_state["head.cls.bias"])
    box_rows = [7 * slot + j for slot in range(len(asg_state["head.cls.bias"])) for j in ORDER]
    put("reg_head.weight", asg_state["head.box.weight"][box_rows])
    put("reg_head.bias", asg_state["head.box.bias"][box_rows])
    return out


def fold_value_projection(asg_state: dict, out: dict) -> None:
    """asg's AttFuse fuses the first stage's maps as sum_j a_j (V x_j + b) = V (sum_j a_j x_j) + b
    (its attention weights sum to 1); OpenCOOD's attention has no V: its fused map is sum_j a_j x_j.
    The two consumers of asg's fused map, the second stage's first convolution and the first
    upsampling, take V into their weights (W V) and b into the norm after them (its running mean
    lowered by W b summed over the kernel: exact away from the map's zero-padded border)."""
    v, b = asg_state["fusion.v.weight"].float(), asg_state["fusion.v.bias"].float()
    conv = out["backbone.blocks.1.1.weight"].float()  # (C_out, C, 3, 3)
    out["backbone.blocks.1.1.weight"] = torch.einsum("ochw,ci->oihw", conv, v)
    out["backbone.blocks.1.2.running_mean"] = out["backbone.blocks.1.2.running_mean"] - torch.einsum("ochw,c->o", conv, b)
    up = out["backbone.deblocks.0.0.weight"].float()[:, :, 0, 0]  # ConvTranspose2d (C, C_up)
    out["backbone.deblocks.0.0.weight"] = (v.t() @ up)[:, :, None, None]
    out["backbone.deblocks.0.1.running_mean"] = out["backbone.deblocks.0.1.running_mean"] - b @ up


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out", type=Path)
    p.add_argument("train", type=Path)
    p.add_argument("val", type=Path)
    p.add_argument("--weights", default="attfuse-wide", help="asg's shipped weights (their network must be the wide size)")
    p.add_argument("--detector-config", default="pointpillars-wide.yaml")
    p.add_argument("--epochs", type=int, default=1, help="epochs of OpenCOOD's trainer to run from the converted tensors")
    p.add_argument("--lr", type=float, default=0.0005)
    args = p.parse_args()
    write_config(args.out, args.train, args.val, args.detector_config, args.epochs, args.lr)
    network = module("tools.train_utils").create_model(read_hypes(args.out))
    asg_state = torch.load(WEIGHTS_DIR / f"{args.weights}.pt", map_location="cpu", weights_only=True)
    state = converted(asg_state, network.state_dict())
    network.load_state_dict(state)  # strict: every tensor OpenCOOD's network has
    torch.save(state, args.out / "net_epoch1.pth")
    print(f"{args.out}: config.yaml and net_epoch1.pth from {args.weights}.pt")


if __name__ == "__main__":
    main()
