"""The point stage: each final box refined from the points inside it (asg/perception/point_stage.py)."""
from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest
import torch

from asg.perception.point_stage import (POINTS, PointStage, apply_residuals, box_points, refine,
                                        residual_targets)

#: torch's kernels decide these outcomes: CI runs this file again on AVX2 and default kernels
pytestmark = pytest.mark.numeric


def _box_surface_points(box: np.ndarray, step_m: float = 0.1) -> np.ndarray:
    """(N, 4) points on the four sides of ``box`` (x, y, z, l, w, h, yaw), intensity 0.5."""
    x, y, z, length, width, h, yaw = box
    along = np.arange(-length / 2, length / 2 + 1e-9, step_m)
    across = np.arange(-width / 2, width / 2 + 1e-9, step_m)
    local = np.vstack([np.column_stack([along, np.full_like(along, s * width / 2)]) for s in (-1, 1)]
                      + [np.column_stack([np.full_like(across, s * length / 2), across]) for s in (-1, 1)])
    c, s = math.cos(yaw), math.sin(yaw)
    world = np.column_stack([x + c * local[:, 0] - s * local[:, 1], y + s * local[:, 0] + c * local[:, 1],
                             np.full(len(local), z), np.full(len(local), 0.5)])
    return world.astype(np.float32)


def test_residuals_take_a_box_onto_its_vehicle():
    rng = np.random.default_rng(0)
    gt = np.array([[10.0, -4.0, -1.0, 4.6, 1.9, 1.6, 0.3], [-20.0, 15.0, -0.8, 9.0, 2.5, 3.2, -2.8]])
    boxes = gt.copy()
    boxes[:, :2] += rng.normal(0, 0.3, (2, 2))
    boxes[:, 3:6] *= np.exp(rng.normal(0, 0.05, (2, 3)))
    boxes[:, 6] += [0.1, math.pi - 0.05]  # the second faces the other way: its heading is kept
    iou, res = residual_targets(boxes, gt)
    assert (iou > 0.3).all() and abs(res[1, 6]) < math.pi / 2
    moved = apply_residuals(boxes, res)
    assert np.allclose(moved[:, :6], gt[:, :6], atol=1e-9)
    assert np.allclose(np.cos(2 * (moved[:, 6] - gt[:, 6])), 1.0)
    assert abs(moved[1, 6] - (gt[1, 6] + math.pi)) < 1e-9 or abs(moved[1, 6] - (gt[1, 6] - math.pi)) < 1e-9
    assert residual_targets(boxes, np.zeros((0, 7)))[0].tolist() == [0.0, 0.0]


def test_box_points_are_the_points_inside_in_the_boxs_frame():
    box = np.array([5.0, 3.0, -1.0, 4.0, 2.0, 1.6, math.pi / 2])  # facing +y
    cloud = np.array([[5.0, 4.0, -1.0, 0.7],   # 1 m ahead of the centre: along +1
                      [4.0, 3.0, -1.0, 0.2],   # 1 m to its right (x smaller): across -1
                      [5.0, 5.4, -1.0, 0.1],   # 2.4 m ahead: inside the 0.5 m margin
                      [5.0, 6.0, -1.0, 0.1],   # 3 m ahead: outside
                      [5.0, 3.0, 2.0, 0.1]], dtype=np.float32)  # above the margin
    feats, mask = box_points(box[None], cloud)
    assert feats.shape == (1, POINTS, 7) and mask[0].sum() == 3
    assert np.allclose(feats[0, 0, :3], [1.0, 0.0, 0.0], atol=1e-6)
    assert np.allclose(feats[0, 1, :3], [0.0, 1.0, 0.0], atol=1e-6)  # x smaller is the box's left when facing +y
    assert np.allclose(feats[0, 0, 3:6], [0.5, 0.0, 0.0], atol=1e-6) and feats[0, 0, 6] == pytest.approx(0.7)
    many = _box_surface_points(box)
    f1, m1 = box_points(box[None], many)
    f2, m2 = box_points(box[None], many)
    assert m1.sum() == POINTS and np.array_equal(f1, f2)  # more than POINTS inside: the same ones every time
    empty, none = box_points(box[None], np.zeros((0, 4), np.float32))
    assert not none.any() and not empty.any()


def test_a_stage_without_points_or_residuals_leaves_the_box():
    torch.manual_seed(0)
    stage = PointStage().eval()
    with torch.no_grad():
        stage.head[-1].weight.zero_()
        stage.head[-1].bias.zero_()  # residuals 0, IoU logit 0 (IoU 0.5)
    boxes = np.array([[10.0, 0.0, -1.0, 4.6, 1.9, 1.6, 0.2]])
    scores = np.array([0.81])
    out, s = refine(stage, boxes, scores, np.zeros((0, 4), np.float32), rescore_power=0.5)
    assert np.allclose(out, boxes) and s == pytest.approx([0.9 * math.sqrt(0.5)])
    out, s = refine(stage, boxes, scores, _box_surface_points(boxes[0]), rescore_power=0.0)
    assert np.allclose(out, boxes) and s.tolist() == [0.81]
    nothing = refine(stage, np.zeros((0, 7)), np.zeros(0), np.zeros((0, 4), np.float32), 0.5)
    assert nothing[0].shape == (0, 7)


@pytest.fixture(scope="module")
def held_out_frames(tmp_path_factory):
    """8 frames of a town no detector trained on (roundabout, 20 s of normal traffic)."""
    from asg.perception.data import Sample
    from asg.scene.from_log import ExtractParams, extract_scenes
    from asg.scene.neighbours import with_nearest_collaborators
    from asg.sensors import load_lidar_spec, simulate_frame
    from sumo_scenarios.simulate import SimulationRequest, simulate_sumo

    log = tmp_path_factory.mktemp("stage") / "log"
    simulate_sumo(SimulationRequest(out_dir=log, town="roundabout", seed=78, duration_s=20.0, density="normal"))
    spec = load_lidar_spec()
    scenes = [with_nearest_collaborators(s, 2) for s in extract_scenes(log, ExtractParams(every=5, min_vehicles=5))][:8]
    return [Sample(s.scene_id, simulate_frame(s, spec)) for s in scenes]


@pytest.mark.parametrize("fusion", ["none", "attfuse"])
def test_the_shipped_stage_sharpens_the_boxes_on_held_out_frames(fusion, held_out_frames):
    """The shipped stage, on frames of a town no detector trained on: the boxes that overlap a
    vehicle fit it better than without the stage (the measured gain is in docs/results)."""
    from dataclasses import replace

    from asg.perception import build_detector
    from asg.training.point_stage_fit import mean_iou

    with_stage = build_detector(fusion)
    assert with_stage.point_stage is not None
    without = build_detector(fusion, cfg=replace(with_stage.cfg, point_stage=False))
    assert without.point_stage is None
    frames = {key: [(*det.detect(s.frame), s.gt_eval()) for s in held_out_frames]
              for key, det in (("with", with_stage), ("without", without))}
    assert sum(len(f[2]) for f in frames["with"]) >= 20  # enough vehicles to compare
    assert mean_iou(frames["with"]) > mean_iou(frames["without"]) + 0.04


def test_point_stage_fit_resumes_to_the_same_stage_and_records_it(sumo_log, tmp_path):
    """`asg train --fusion none --point-stage` on a tiny set: interrupted after its first epoch and
    run again, the same stage as an uninterrupted fit (a rerun with other settings is refused); the
    card records it; nothing left behind."""
    from dataclasses import replace

    from sumo_scenarios.errors import InputError

    from asg.perception.weights_io import WEIGHTS_DIR
    from asg.training.point_stage_fit import BOXES_CACHE, CHECKPOINT, PointStageFitConfig, fit_point_stage
    from test_train import tiny_dataset

    data = tiny_dataset(sumo_log, tmp_path / "tiny")
    fcfg = PointStageFitConfig(dataset=str(data), jitters=1, epochs=2, batch_size=16)

    def weights_dir(tag):
        folder = tmp_path / f"weights-{tag}"
        folder.mkdir()
        for suffix in (".pt", ".json"):
            shutil.copy(WEIGHTS_DIR / f"single{suffix}", folder / f"single{suffix}")
        return folder

    class Stop(Exception):
        pass

    def stop_after_first_epoch(message):
        if message.startswith("point stage epoch 1/"):
            raise Stop

    whole = fit_point_stage("none", lambda *_: None, 1, fit_config=fcfg, weights_dir=weights_dir("whole"),
                            out_dir=tmp_path / "run-whole")
    split_dir = weights_dir("split")
    with pytest.raises(Stop):
        fit_point_stage("none", stop_after_first_epoch, 1, fit_config=fcfg, weights_dir=split_dir,
                        out_dir=tmp_path / "run-split")
    assert (tmp_path / "run-split" / CHECKPOINT).is_file() and not (split_dir / "single.stage.pt").exists()
    with pytest.raises(InputError, match="other settings"):  # a rerun with other settings is refused
        fit_point_stage("none", lambda *_: None, 1, fit_config=replace(fcfg, epochs=3), weights_dir=split_dir,
                        out_dir=tmp_path / "run-split")
    resumed = fit_point_stage("none", lambda *_: None, 1, fit_config=fcfg, weights_dir=split_dir,
                              out_dir=tmp_path / "run-split")
    a, b = torch.load(whole, weights_only=True), torch.load(resumed, weights_only=True)
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    card = json.loads((split_dir / "single.json").read_text())
    assert card["point_stage"]["weights"] == "single.stage.pt" and card["point_stage"]["epochs"] == 2
    assert card["chunks"]  # the detector's own record kept
    assert not (tmp_path / "run-split" / CHECKPOINT).exists() and not (tmp_path / "run-split" / BOXES_CACHE).exists()


def _zip_bomb() -> bytes:
    """An .npz of one deflated member: 64 MB of zeros in about 64 kB."""
    import io
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("boxes.npy", bytes(64 << 20))
    return buf.getvalue()


@pytest.mark.parametrize("content", [b"PK\x03\x04garbage", b"", b"\x93NUMPY garbage", _zip_bomb()],
                         ids=["zip", "empty", "npy", "bomb"])
def test_a_damaged_box_cache_is_one_line(tmp_path, content):
    """The point-stage fit's cache of boxes, damaged (a crash of the disk, an edit) or hostile (a
    member that unpacks to far more than it holds), is one line saying to delete it, not a traceback."""
    from sumo_scenarios.errors import InputError

    from asg.training.point_stage_fit import BOXES_CACHE, collect

    (tmp_path / BOXES_CACHE).write_bytes(content)
    with pytest.raises(InputError, match="cached boxes are damaged"):
        collect("none", lambda: [], "frames", tmp_path, lambda *_: None)


def test_the_box_cache_is_read_once_not_once_a_frame(tmp_path):
    """A resumed fit reads its cache of boxes and clouds: each frame a slice of one array read once.
    Read once a frame, every frame's slice kept its own copy of the whole array alive: at
    detector-train's 480 frames (a 276 MB cloud array) 132 GB, killed for want of memory."""
    from asg.training.point_stage_fit import BOXES_CACHE, collect

    counts = {"boxes": [2, 0, 3], "scores": [2, 0, 3], "gt": [1, 1, 2], "cloud": [5, 4, 6]}
    widths = {"boxes": 7, "scores": None, "gt": 7, "cloud": 4}
    arrays = {k: np.arange(sum(n) * (w or 1), dtype=np.float32).reshape(-1, w) if w else np.arange(sum(n), dtype=float)
              for (k, n), w in zip(counts.items(), widths.values())}
    offsets = {"n" + k: np.cumsum([0, *n]) for k, n in counts.items()}
    np.savez(tmp_path / BOXES_CACHE, **arrays, **offsets, settings=np.array("s"))
    frames = collect("none", lambda: [], "frames", tmp_path, lambda *_: None, settings="s")
    assert [len(f[3]) for f in frames] == counts["cloud"]
    assert np.array_equal(np.concatenate([f[3] for f in frames]), arrays["cloud"])
    assert len({id(f[3].base) for f in frames}) == 1  # views of one array


def test_point_stage_settings_are_checked():
    from sumo_scenarios.errors import InputError

    from asg.training.point_stage_fit import PointStageFitConfig, load_point_stage_config

    assert load_point_stage_config().epochs >= 1  # the shipped block loads
    with pytest.raises(InputError, match="jitter_yaw_deg"):
        PointStageFitConfig(jitter_yaw_deg=90.0)


def test_box_points_from_the_grid_are_every_point_inside():
    """The BEV grid only narrows which points each box tests, and the boxes are tested together:
    the same features, to the bit, as one box at a time against the whole cloud, for boxes anywhere
    (cells' edges, turned boxes, far from every point, more than POINTS points inside), NaN points
    left out."""
    from asg.perception.point_stage import GROW_M

    rng = np.random.default_rng(5)
    cloud = np.column_stack([rng.uniform(-30, 30, (4000, 2)), rng.uniform(-2, 1, 4000), rng.random(4000)]).astype(np.float32)
    dense = np.column_stack([rng.normal([4.0, -8.0], 1.5, (1500, 2)), rng.uniform(-2, 1, 1500), rng.random(1500)])
    cloud = np.vstack([cloud, dense.astype(np.float32)])[rng.permutation(5500)]
    cloud[::97, 0] = np.nan
    boxes = np.column_stack([np.concatenate([rng.uniform(-32, 32, (60, 2)), [[4.0, -8.0], [100.0, 100.0]]]),
                             rng.uniform(-1.5, 0.5, 62), rng.uniform(3, 6, 62), rng.uniform(1.5, 2.5, 62),
                             rng.uniform(1.4, 2, 62), rng.uniform(-3.2, 3.2, 62)])
    feats, mask = box_points(boxes, cloud)
    for k, b in enumerate(boxes):
        d = cloud[:, :3] - b[:3].astype(np.float32)
        c, s = np.cos(np.float32(b[6])), np.sin(np.float32(b[6]))
        along, across = c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]
        inside = np.flatnonzero((np.abs(along) <= np.float32(b[3]) / 2 + GROW_M) & (np.abs(across) <= np.float32(b[4]) / 2 + GROW_M)
                                & (np.abs(d[:, 2]) <= np.float32(b[5]) / 2 + GROW_M))
        if len(inside) > POINTS:
            inside = inside[np.linspace(0, len(inside) - 1, POINTS).astype(int)]
        local = np.stack([along[inside], across[inside], d[inside, 2]], axis=1)
        expected = np.zeros((POINTS, 7), np.float32)
        expected[:len(inside)] = np.column_stack([local, local / (b[3:6].astype(np.float32) / 2), cloud[inside, 3]])
        assert mask[k].sum() == len(inside) and mask[k, :len(inside)].all()
        assert feats[k].tobytes() == expected.tobytes()
    assert mask.any(axis=1).sum() > 40 and not mask[-1].any() and mask[-2].all()
