"""`asg train`: an interrupted run resumes to exactly the weights of an uninterrupted one."""
import gzip
import itertools
import json
import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from asg.training.train import train
from asg.training.config import TrainConfig
from asg.scene.from_log import ExtractParams, extract_scenes
from asg.scene.neighbours import with_nearest_collaborators

from conftest import car, make_scene
from test_perception import TINY

#: torch's kernels decide these outcomes: CI runs this file again on AVX2 and default kernels
pytestmark = pytest.mark.numeric


def tiny_dataset(log, folder):
    scenes = [with_nearest_collaborators(s, 2) for s in itertools.islice(extract_scenes(log, ExtractParams(every=50)), 3)]
    folder.mkdir()
    with gzip.open(folder / "frames.jsonl.gz", "wt", encoding="utf-8") as fh:
        for s in scenes:
            fh.write(json.dumps(s.to_dict()) + "\n")
    (folder / "index.json").write_text(json.dumps({"name": "tiny", "frames": len(scenes),
                                                   "splits": {"train": [s.scene_id for s in scenes]}}))
    return folder


class Crash(Exception):
    pass


def run(tmp_path, tag, tcfg, crash_at=None):
    weights_dir = tmp_path / f"weights-{tag}"
    weights_dir.mkdir(exist_ok=True)

    def progress(step, total, loss):
        if step == crash_at:
            raise Crash

    return train("attfuse", out_dir=tmp_path / f"run-{tag}", log=lambda *_: None, progress=progress, threads=1,
                 train_config=tcfg, detector_config=TINY, weights_dir=weights_dir, validate=False)


@pytest.mark.slow
def test_interrupted_training_resumes_to_the_same_weights(sumo_log, tmp_path):
    data = tiny_dataset(sumo_log, tmp_path / "tiny")
    for schedule in ("step", "onecycle"):
        tcfg = TrainConfig(dataset=str(data), steps=6, batch_size=1, lr=0.01, schedule=schedule, seed=5,
                           checkpoint_every=3)
        whole = run(tmp_path, f"whole-{schedule}", tcfg)
        # a crash in step 5: the checkpoint of step 3 is on disk; then the same command again
        with pytest.raises(Crash):
            run(tmp_path, f"split-{schedule}", tcfg, crash_at=5)
        assert not (tmp_path / f"weights-split-{schedule}" / "attfuse.pt").exists()
        resumed = run(tmp_path, f"split-{schedule}", tcfg)
        a = torch.load(whole, weights_only=True)
        b = torch.load(resumed, weights_only=True)
        assert a.keys() == b.keys()
        assert all(torch.equal(a[k], b[k]) for k in a), schedule
        card = json.loads(resumed.with_suffix(".json").read_text())
        assert card["steps"] == 6 and card["chunks"][0]["schedule"] == schedule
        assert not (tmp_path / f"run-split-{schedule}" / "last.pt").exists()
    # the same command after a finished chunk: one more chunk from those weights, history kept
    again = run(tmp_path, "split-onecycle", tcfg)
    card = json.loads(again.with_suffix(".json").read_text())
    assert card["steps"] == 12 and [c["seed"] for c in card["chunks"]] == [[5, 0], [5, 1]]
    assert not all(torch.equal(b[k], v) for k, v in torch.load(again, weights_only=True).items())


def test_a_sequence_of_chunks_continues_from_committed_weights_alone(sumo_log, tmp_path):
    """A long training run survives the end of a sitting through its chunk weights: what a
    repository holds of it (each finished chunk's weights and card), copied to an empty machine (no
    run folder, no checkpoint), continues to exactly the weights of the same chunks run in one go."""
    import shutil

    data = tiny_dataset(sumo_log, tmp_path / "tiny")
    tcfg = TrainConfig(dataset=str(data), steps=4, batch_size=1, lr=0.01, schedule="onecycle", seed=7,
                       checkpoint_every=2)
    run(tmp_path, "one-go", tcfg)
    one_go = run(tmp_path, "one-go", tcfg)  # the second chunk, same machine
    first = run(tmp_path, "sitting-1", tcfg)
    committed = tmp_path / "weights-sitting-2"
    committed.mkdir()
    for f in (first, first.with_suffix(".json")):  # what a commit holds; the run folder stays behind
        shutil.copy(f, committed / f.name)
    shutil.rmtree(tmp_path / "run-sitting-1")
    second = run(tmp_path, "sitting-2", tcfg)
    a, b = torch.load(one_go, weights_only=True), torch.load(second, weights_only=True)
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    card = json.loads(second.with_suffix(".json").read_text())
    assert card["steps"] == 8 and [c["seed"] for c in card["chunks"]] == [[7, 0], [7, 1]]


def _world_xy(boxes, pose):
    from asg.sensors.frame import boxes_to_world

    return sorted(map(tuple, np.round(boxes_to_world(boxes, pose)[:, :2], 3)))


def test_fused_views_show_the_frame_from_each_sensing_agent(cross_map):
    """views='all': one example per sensing agent, in its own frame, its cloud first, labelled
    with every vehicle the agents see together except its own body."""
    from asg.perception.data import Sample
    from asg.sensors import simulate_frame
    from asg.sensors.lidar_spec import LidarSpec

    spec = LidarSpec(name="t", channels=16, points_per_s=16 * 360 * 10, rotation_hz=10.0, range_m=40.0)
    agents = [car("e", -8.0, -1.6), car("c", 10.0, 1.6, math.pi), car("x", 2.0, -1.6), car("y", 20.0, -1.6)]
    s = Sample("t", simulate_frame(make_scene(cross_map, agents, ego="e", collaborators=("c",)), spec))
    f = s.frame
    (ego_clouds, ego_boxes), = s.fused_views("ego")
    assert all(np.array_equal(a, b) for a, b in zip(ego_clouds, s.clouds_in_ego()))
    assert np.array_equal(ego_boxes, s.gt_visible_ego())
    views = s.fused_views("all")
    assert len(views) == len(f.sensing_ids) == 2
    world = {a.agent_id: (round(a.x_m, 3), round(a.y_m, 3)) for a in agents}
    for agent_id, (clouds, boxes) in zip(f.sensing_ids, views):
        assert len(clouds) == 2 and np.array_equal(clouds[0], f.clouds[agent_id])
        # the same world seen from agent_id: every other car, the ego vehicle included, none twice
        assert _world_xy(boxes, f.poses[agent_id]) == sorted(v for k, v in world.items() if k != agent_id)
    # the other agent's cloud, moved into the collaborator's frame, lands on the same world points
    from asg.sensors.frame import transform_points

    moved = views[1][0][1]
    back = transform_points(moved, f.poses["c"], f.poses["e"])
    assert np.allclose(back[:, :3], f.clouds["e"][:, :3], atol=1e-4)
    with pytest.raises(ValueError):
        s.fused_views("some")


def test_init_from_single_weights(tmp_path):
    """AttFuse and Early Fusion start from PointPillars weights: every shared tensor copied, the
    attention an average (v = identity); wrong weights are one clear error."""
    from dataclasses import replace

    from asg.perception.model import AttFuse, PointPillars
    from asg.training.loop import init_from_weights
    from asg.perception.weights_io import save_state
    from sumo_scenarios.errors import InputError

    torch.manual_seed(0)
    single = PointPillars(TINY)
    save_state(single, tmp_path / "single.pt")
    att = AttFuse(TINY)
    init_from_weights(att, tmp_path / "single.pt")
    mine = att.state_dict()
    assert all(torch.equal(mine[k], v) for k, v in single.state_dict().items())
    assert torch.equal(att.fusion.v.weight, torch.eye(att.fusion.v.weight.shape[0]))
    staged = AttFuse(replace(TINY, attfuse_fusion="stages"))
    init_from_weights(staged, tmp_path / "single.pt")
    assert len(staged.attentions()) == 3
    assert all(torch.equal(a.v.weight, torch.eye(a.v.weight.shape[0])) for a in staged.attentions())
    early = PointPillars(TINY)
    init_from_weights(early, tmp_path / "single.pt")
    assert all(torch.equal(early.state_dict()[k], v) for k, v in single.state_dict().items())

    with pytest.raises(InputError, match="do not match"):
        init_from_weights(AttFuse(replace(TINY, filters=(16, 32, 64))), tmp_path / "single.pt")
    with pytest.raises(InputError, match="not found"):
        init_from_weights(att, tmp_path / "none.pt")


def test_train_init_from_starts_a_new_sequence(sumo_log, tmp_path):
    from asg.perception.model import PointPillars
    from asg.perception.weights_io import save_state
    from sumo_scenarios.errors import InputError

    data = tiny_dataset(sumo_log, tmp_path / "tiny")
    weights_dir = tmp_path / "weights"
    weights_dir.mkdir()
    save_state(PointPillars(TINY), weights_dir / "single.pt")
    (weights_dir / "single.json").write_text(json.dumps({"steps": 40, "train_wall_s": 12.5}))
    tcfg = TrainConfig(dataset=str(data), steps=2, batch_size=1, schedule="onecycle", seed=5, checkpoint_every=1,
                       views="all")
    kw = dict(log=lambda *_: None, threads=1, train_config=tcfg, detector_config=TINY, weights_dir=weights_dir,
              validate=False)
    out = train("early", out_dir=tmp_path / "run", init_from="single", **kw)
    card = json.loads(out.with_suffix(".json").read_text())
    assert card["init_from"] == {"weights": "single.pt", "steps": 40, "train_wall_s": 12.5}
    assert card["steps"] == 2 and card["examples"] == 3 * 3  # each of 3 sensing agents' views of 3 frames
    # the next plain run continues this sequence and keeps its origin
    again = json.loads(train("early", out_dir=tmp_path / "run", **kw).with_suffix(".json").read_text())
    assert again["steps"] == 4 and again["init_from"]["weights"] == "single.pt"
    # an AttFuse card names where its weights fuse (weights of one placement do not load in another)
    att = json.loads(train("attfuse", out_dir=tmp_path / "run-att", init_from="single", **kw).with_suffix(".json").read_text())
    assert att["attfuse_fusion"] == TINY.attfuse_fusion and "attfuse_fusion" not in again
    with pytest.raises(InputError, match="choose one of"):
        train("early", out_dir=tmp_path / "run", init_from="nope", **kw)


def test_an_interrupted_init_from_chunk_resumes_when_the_same_command_is_rerun(sumo_log, tmp_path):
    """Ctrl-C in a chunk started with --init-from: the same command resumes it (the card keeps its
    origin and the chunk's length); --init-from on a chunk that continues the model's own weights,
    or that started from other weights, is refused in one line."""
    from asg.perception.model import PointPillars
    from asg.perception.weights_io import save_state
    from sumo_scenarios.errors import InputError

    data = tiny_dataset(sumo_log, tmp_path / "tiny")
    weights_dir = tmp_path / "weights"
    weights_dir.mkdir()
    save_state(PointPillars(TINY), weights_dir / "single.pt")
    tcfg = TrainConfig(dataset=str(data), steps=3, batch_size=1, schedule="onecycle", seed=5, checkpoint_every=1)

    def stop_at_2(step, total, loss):
        if step == 2:
            raise KeyboardInterrupt

    kw = dict(log=lambda *_: None, threads=1, train_config=tcfg, detector_config=TINY, weights_dir=weights_dir,
              validate=False)
    with pytest.raises(KeyboardInterrupt):
        train("early", out_dir=tmp_path / "run", init_from="single", progress=stop_at_2, **kw)
    steps_seen = []
    out = train("early", out_dir=tmp_path / "run", init_from="single",
                progress=lambda step, total, loss: steps_seen.append(step), **kw)
    card = json.loads(out.with_suffix(".json").read_text())
    assert steps_seen == [2, 3] and card["steps"] == 3 and card["init_from"]["weights"] == "single.pt"
    assert not (tmp_path / "run" / "last.pt").exists()
    # a continuation chunk of early's own weights, interrupted: --init-from single is not its command
    with pytest.raises(KeyboardInterrupt):
        train("early", out_dir=tmp_path / "run", progress=stop_at_2, **kw)
    with pytest.raises(InputError, match="did not start from single"):
        train("early", out_dir=tmp_path / "run", init_from="single", **kw)


def test_resumed_onecycle_follows_the_configured_length():
    """A chunk resumed with another configured length anneals on that length (peak and end move)."""
    from asg.training.loop import keep_configured_length, make_scheduler

    def lrs(sched, n):
        out = []
        for _ in range(n):
            sched.optimizer.step()
            sched.step()
            out.append(sched.get_last_lr()[0])
        return out

    def fresh(steps):
        opt = torch.optim.SGD([torch.zeros(1, requires_grad=True)], lr=0.001)
        return make_scheduler(opt, TrainConfig(dataset="x", steps=steps, schedule="onecycle", lr=0.001), steps)

    long = fresh(40)
    lrs(long, 10)  # a checkpoint of a 40-step chunk at step 10 ...
    resumed = fresh(30)
    resumed.load_state_dict(long.state_dict())
    keep_configured_length(resumed, TrainConfig(dataset="x", steps=30, schedule="onecycle", lr=0.001), 30)
    short = fresh(30)
    lrs(short, 10)
    tail = lrs(resumed, 20)
    assert tail == pytest.approx(lrs(short, 20))  # ... resumed as a 30-step one
    assert lrs(long, 20)[-1] > 10 * tail[-1]  # the saved 40-step phases would still be annealing


@pytest.mark.slow
def test_branch_fit_changes_the_branches_alone_and_resumes(sumo_log, tmp_path, monkeypatch):
    """`asg train --iou-branch`: the frozen detector's tensors (batch-norm statistics included)
    stay as they were, both branches are fitted, the card records the fit apart from the
    detector's steps, an interruption after the collection resumes from the cached candidates to
    the same weights, and the same seed gives the same weights. Weights made before the branches
    existed get them."""
    from asg.training import branch_fit
    from asg.training.branch_fit import CACHE_NAME, BranchFitConfig
    from asg.perception.model import PointPillars
    from sumo_scenarios.errors import InputError

    data = tiny_dataset(sumo_log, tmp_path / "tiny")
    torch.manual_seed(0)
    base = PointPillars(TINY)
    branches = ("head.iou.", "head.refine.")

    def weights_dir(tag):
        folder = tmp_path / f"weights-{tag}"
        folder.mkdir()
        torch.save({k: v for k, v in base.state_dict().items() if not k.startswith(branches)}, folder / "early.pt")
        (folder / "early.json").write_text(json.dumps({"steps": 40, "train_wall_s": 12.5, "dataset": "x"}))
        return folder

    # every anchor a candidate: the untrained tiny detector scores them all alike
    fcfg = BranchFitConfig(dataset=str(data), passes=2, min_score=0.0, top_k=100000, epochs=2, batch_size=64, seed=3)
    kw = dict(log=lambda *_: None, threads=1, detector_config=TINY, validate=False, iou_branch=True, branch_config=fcfg)
    out = train("early", out_dir=tmp_path / "run", weights_dir=weights_dir("a"), **kw)
    after = torch.load(out, weights_only=True)
    fresh = PointPillars(TINY).state_dict()
    for k, v in base.state_dict().items():
        if k.startswith(branches):
            assert not torch.equal(after[k], fresh[k]), k
        else:
            assert torch.equal(after[k], v), k
    card = json.loads(out.with_suffix(".json").read_text())
    fit = card["branch_fit"]
    assert card["steps"] == 40 and card["chunks"][-1] == fit and fit["part"] == "branches"
    assert fit["candidates"] > fit["refine_examples"] > 0
    assert fit["mean_iou_after"] > fit["mean_iou_before"]  # the refinement moved boxes onto their vehicles
    assert not (tmp_path / "run" / CACHE_NAME).exists()

    # interrupted after the collection: the rerun fits from the cache, to the same weights
    real_fit = branch_fit.fit_branches

    def crash(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("asg.training.train.fit_branches", crash)
    with pytest.raises(KeyboardInterrupt):
        train("early", out_dir=tmp_path / "run-b", weights_dir=weights_dir("b"), **kw)
    assert (tmp_path / "run-b" / CACHE_NAME).is_file()
    monkeypatch.setattr("asg.training.train.fit_branches", real_fit)
    collected = []
    monkeypatch.setattr("asg.training.branch_fit.collect", lambda *a, **k: collected.append(1))
    resumed = torch.load(train("early", out_dir=tmp_path / "run-b", weights_dir=tmp_path / "weights-b", **kw),
                         weights_only=True)
    assert not collected and all(torch.equal(after[k], resumed[k]) for k in after)

    with pytest.raises(InputError, match="no trained attfuse weights"):
        train("attfuse", out_dir=tmp_path / "run-att", weights_dir=tmp_path / "weights-a", **kw)
    with pytest.raises(InputError, match="cannot be combined"):
        train("early", out_dir=tmp_path / "run2", weights_dir=tmp_path / "weights-a", init_from="single", **kw)


def test_whole_network_chunk_trains_the_branches_alongside(sumo_log, tmp_path):
    """A detector chunk trains the branches with the rest (on detached features) and counts its
    steps as detector steps."""
    from asg.perception.model import PointPillars
    from asg.perception.weights_io import save_state

    data = tiny_dataset(sumo_log, tmp_path / "tiny")
    weights_dir = tmp_path / "weights"
    weights_dir.mkdir()
    torch.manual_seed(0)
    save_state(PointPillars(TINY), weights_dir / "early.pt")
    before = torch.load(weights_dir / "early.pt", weights_only=True)
    (weights_dir / "early.json").write_text(json.dumps({"steps": 40, "train_wall_s": 12.5, "dataset": "x"}))
    tcfg = TrainConfig(dataset=str(data), steps=4, batch_size=2, lr=0.01, schedule="onecycle", seed=5,
                       checkpoint_every=2, views="all")
    whole = train("early", out_dir=tmp_path / "run", train_config=tcfg, log=lambda *_: None, threads=1,
                  detector_config=TINY, weights_dir=weights_dir, validate=False)
    again = torch.load(whole, weights_only=True)
    for key in ("head.cls.weight", "head.iou.2.weight", "head.refine.2.weight"):
        assert not torch.equal(again[key], before[key]), key
    card = json.loads(whole.with_suffix(".json").read_text())
    assert card["steps"] == 44 and "branch_fit" not in card


def test_candidates_are_matched_with_their_own_views_ground_truth():
    from asg.training.branch_fit import Candidates

    box = np.array([[0.0, 0, 0, 4, 2, 1.5, 0]])
    far = box + [[10, 0, 0, 0, 0, 0, 0]]  # view 0's only vehicle
    near = box + [[0.5, 0, 0, 0, 0, 0, 0]]  # view 1's only vehicle
    cands = Candidates(features=np.zeros((2, 3), np.float16), slot=np.zeros(2, np.int16), boxes=np.vstack([box, box]),
                       view=np.array([1, 0], np.int32), gt=np.vstack([far, near]), gt_start=np.array([0, 1, 2]))
    best, match = cands.best_iou(cands.boxes)
    # a 4 x 2 box shifted 0.5 m along its length: IoU 7 / 9
    assert best[0] == pytest.approx(7 / 9) and np.allclose(match[0], near[0])
    assert best[1] == 0  # not view 1's vehicle


def test_branch_fit_settings_are_checked(tmp_path):
    from sumo_scenarios.errors import InputError

    from asg.training.config import load_branch_config

    assert load_branch_config().epochs >= 1  # the shipped block loads
    bad = tmp_path / "train.yaml"
    for line, match in (("epochs: 0", "epochs"), ("views: some", "views"), ("passes: 2\n  extra: 1", "extra")):
        bad.write_text("iou_branch:\n  " + line + "\n")
        with pytest.raises(InputError, match=match):
            load_branch_config(bad)


@pytest.mark.slow
def test_bench_train_reports_a_step_and_its_phases(monkeypatch):
    """``asg bench train``'s measurement on synthetic frames: one JSON-able dict whose phase shares
    cover the step (the time itself is a benchmark's business, never asserted)."""
    import asg.datasets
    from asg.benchmarks.train import bench_train
    from asg.scene import Scene

    from test_robustness import _scene_dict

    monkeypatch.setattr(asg.datasets, "iter_frames",
                        lambda name, split=None: iter([Scene.from_dict(_scene_dict(f"s{i}")) for i in range(2)]))
    out = bench_train(steps=2, frames=2)
    assert out["model"] == "attfuse" and out["steps"] == 2 and out["examples"] == 6 and out["seconds_per_step"] > 0
    shares = out["phase_share"]
    assert set(shares) == {"draw", "targets", "voxelise", "forward", "loss", "backward", "optimiser"}
    assert all(v >= 0 for v in shares.values()) and 0.8 < sum(shares.values()) < 1.2


def test_bench_train_needs_no_data_set_built(tmp_path, monkeypatch):
    """On a fresh machine (detector-train not built) the benchmark takes a minute of its first
    town's traffic instead of refusing."""
    from asg.benchmarks.train import bench_frames
    from asg.dataset_spec import load_spec

    monkeypatch.setenv("ASG_DATA", str(tmp_path / "empty"))
    scenes, source = bench_frames(3)
    assert len(scenes) == 3 and "not built" in source
    assert all(s.town == load_spec("detector-train").towns[0] and s.collaborators for s in scenes)


def test_a_detector_builds_and_trains_with_its_own_config_file(monkeypatch, tmp_path):
    """A variant of a model (another size) is an entry with its own config file: its detector,
    training and card read that file, not the shipped default."""
    import asg.perception.fusion.base as base
    from asg.perception.fusion import card_settings_of, detector_config_of
    from asg.perception.fusion.single import _Single

    (tmp_path / "detectors").mkdir()
    (tmp_path / "detectors" / "wide.yaml").write_text("filters: [64, 128, 256]\nupsample_channels: 64\n")
    monkeypatch.setattr(base, "configs_dir", lambda: tmp_path)
    monkeypatch.setattr(_Single, "config_file", "wide.yaml")
    cfg = detector_config_of("single")
    assert cfg.filters == (64, 128, 256) and cfg.upsample_channels == 64
    detector = _Single.__subclasses__()[0](load=False)
    assert detector.cfg == cfg and detector.model.backbone.stage_channels == (64, 128, 256)
    card = card_settings_of("single", cfg)
    assert card["detector_config"] == "configs/detectors/wide.yaml"
    assert card["network"]["filters"] == (64, 128, 256) and card["network"]["upsample_channels"] == 64
    # settings a caller gives apart from the file (as the size experiments do) are what the card says
    assert card_settings_of("single", replace(cfg, filters=(16, 32, 64)))["network"]["filters"] == (16, 32, 64)


def test_training_reads_and_writes_its_run_folder_and_installs_only_on_request(tmp_path, monkeypatch, capsys):
    """The first run copies the weights it continues from into runs/train/NAME/; the package is never
    written; --install makes the run's weights the ones every command loads (ASG_HOME/weights)."""
    import asg.training.command as train_mod
    from asg.cli import main
    from asg.perception.weights_io import WEIGHTS_DIR, seed_run_folder, weights_path

    monkeypatch.setenv("ASG_HOME", str(tmp_path / "home"))
    monkeypatch.setattr(train_mod, "runs_dir", lambda: tmp_path / "runs")
    shipped = {p.name: p.stat().st_mtime_ns for p in WEIGHTS_DIR.iterdir()}
    run_dir = tmp_path / "runs" / "train" / "single"
    assert weights_path("single") == WEIGHTS_DIR / "single.pt"
    assert main(["train", "--fusion", "late", "--install"]) == 2  # nothing trained yet
    seed_run_folder(run_dir, "single")
    assert (run_dir / "single.pt").read_bytes() == (WEIGHTS_DIR / "single.pt").read_bytes()
    assert (run_dir / "single.json").is_file()
    assert main(["train", "--fusion", "late", "--install"]) == 0
    assert weights_path("single") == tmp_path / "home" / "weights" / "single.pt"
    assert {p.name: p.stat().st_mtime_ns for p in WEIGHTS_DIR.iterdir()} == shipped
    capsys.readouterr()


def test_a_chunk_for_another_sensor_renders_its_frames_with_it_and_its_card_says_so(sumo_log, tmp_path, monkeypatch):
    """``lidar`` in a training block: every training frame is cast with that preset (the points
    of another sensor), the chunk and the card record it, and a branch fit (which renders with the
    shipped LiDAR) is refused for those weights."""
    import asg.training.loop as loop
    from sumo_scenarios.errors import InputError

    from asg.perception.data import make_sample

    data = tiny_dataset(sumo_log, tmp_path / "tiny")
    cast = []
    monkeypatch.setattr(loop, "make_sample", lambda scene, spec: cast.append(spec) or make_sample(scene, spec))
    tcfg = TrainConfig(dataset=str(data), steps=2, batch_size=1, lr=0.01, seed=5, checkpoint_every=2, lidar="vlp16")
    weights = run(tmp_path, "vlp16", tcfg)
    assert cast and {(s.name, s.channels) for s in cast} == {("vlp16", 16)}
    card = json.loads(weights.with_suffix(".json").read_text())
    assert card["lidar"] == "vlp16" and card["chunks"][-1]["lidar"] == "vlp16"
    with pytest.raises(InputError, match="trained for the vlp16 LiDAR"):
        train("attfuse", out_dir=tmp_path / "run-vlp16", log=lambda *_: None, threads=1, detector_config=TINY,
              weights_dir=tmp_path / "weights-vlp16", validate=False, iou_branch=True)
    # a chunk of the shipped sensor after it: the card follows the last whole-network chunk
    cast.clear()
    weights = run(tmp_path, "vlp16", replace(tcfg, lidar="v2xp"))
    card = json.loads(weights.with_suffix(".json").read_text())
    assert {s.name for s in cast} == {"v2xp"} and card["lidar"] == "v2xp" and "lidar" not in card["chunks"][-1]


def test_the_training_lidar_is_checked_and_fine_tuning_keeps_the_shipped_one(tmp_path):
    from sumo_scenarios.errors import InputError

    from asg.training.config import check_train_config, load_finetune_config
    from asg.workflows.harden import load_harden_config

    assert check_train_config(TrainConfig(lidar="dense64"), "t").lidar == "dense64"
    with pytest.raises(InputError, match="unknown lidar preset 'hdl32'; presets: dense64, v2xp, vlp16"):
        check_train_config(TrainConfig(lidar="hdl32"), "t")
    with pytest.raises(InputError, match="t.lidar"):
        check_train_config(TrainConfig(lidar="../v2xp"), "t")
    with pytest.raises(InputError, match="fine-tuning renders with the LiDAR its scenes are attacked and evaluated with"):
        check_train_config(replace(load_finetune_config().asg, lidar="vlp16"), "t")
    with pytest.raises(InputError, match="train.yaml:harden.asg.lidar"):
        load_harden_config(asg={"lidar": "vlp16"})
