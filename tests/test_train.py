"""`asg train`: an interrupted run resumes to exactly the weights of an uninterrupted one."""
import gzip
import itertools
import json

import pytest
import torch

from asg.perception.train import TrainConfig, train
from asg.scene.from_log import ExtractParams, extract_scenes
from asg.scene.neighbours import with_nearest_collaborators

from test_perception import TINY


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
