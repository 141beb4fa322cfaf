"""The standard noisy V2X setting: each collaborator's shared pose off by Gaussian noise and its
message one 0.1 s log step late; the ego untouched; the same seed gives the same noise."""
import math

import numpy as np
import pytest

from asg.scene.from_log import ExtractParams, extract_scenes
from asg.scene.neighbours import with_nearest_collaborators
from asg.scene.noisy import STANDARD, noisy_scene, write_noisy_set


@pytest.fixture(scope="module")
def fine_log(tmp_path_factory):
    """A log recorded every 0.1 s (the data sets' logs are re-simulated at that rate for latency)."""
    from sumo_scenarios.simulate import SimulationRequest, simulate_sumo

    out = tmp_path_factory.mktemp("logs") / "grid_fine"
    simulate_sumo(SimulationRequest(out_dir=out, town="grid_small", seed=3, duration_s=6.0, density="normal",
                                    warmup_s=60.0, record_period_s=0.1))
    return out


@pytest.fixture(scope="module")
def scenes(fine_log):
    found = [with_nearest_collaborators(s, 2) for s in extract_scenes(fine_log, ExtractParams(every=20, min_vehicles=5))]
    return [s for s in found if len(s.collaborators) == 2 and s.time_s > 61.0][:3]


def test_a_log_too_coarse_for_the_delay_is_one_line(sumo_log):
    from sumo_scenarios.errors import InputError

    scene = next(with_nearest_collaborators(s, 2) for s in extract_scenes(sumo_log, ExtractParams(every=10, min_vehicles=5))
                 if s.time_s > 62.0)
    with pytest.raises(InputError, match="records every 0.5 s"):
        noisy_scene(scene, np.random.default_rng(0))


def test_collaborators_are_late_and_off_the_ego_is_not(scenes):
    assert scenes
    errors = []
    for scene in scenes:
        noisy = noisy_scene(scene, np.random.default_rng(0))
        assert set(noisy.link) == set(scene.collaborators)  # the ego's own message is not on the link
        for cid, state in noisy.link.items():
            assert state.delay_s == pytest.approx(STANDARD.delay_s)  # the previous 0.1 s step of the log
            assert state.earlier_self(cid).agent_id == cid
            errors += [state.dx_m, state.dy_m, math.degrees(state.dyaw_rad)]
        assert noisy.to_dict()["agents"] == scene.to_dict()["agents"]  # the world itself is not moved
    assert max(abs(e) for e in errors) < 1.0 and any(e != 0 for e in errors)


def test_the_noisy_set_is_seeded_per_scene(scenes, tmp_path):
    a = write_noisy_set(scenes, tmp_path / "a", seed=1)
    b = write_noisy_set(scenes[::-1], tmp_path / "b", seed=1)  # another order, the same noise per scene
    for scene in scenes:
        assert (a / f"{scene.scene_id}.yaml").read_text() == (b / f"{scene.scene_id}.yaml").read_text()
    assert (a / ".complete").is_file()


def test_training_over_noisy_links_adds_each_frames_late_ego_view(scenes, tmp_path):
    """train.yaml's ``noisy_links``: each frame of the data set once more as its ego receives it over
    the standard noisy link (the noise of the seed and the frame's id), one example a frame, each
    collaborator's cloud 0.1 s old; the perfect frames keep their views."""
    import gzip
    import json

    from asg.perception.feeds import KINDED_AGENT_CLOUDS
    from asg.scene.noisy import noise_rng
    from asg.training.loop import Batches, render_samples

    folder = tmp_path / "set"
    folder.mkdir()
    with gzip.open(folder / "frames.jsonl.gz", "wt", encoding="utf-8") as fh:
        for scene in scenes[:2]:
            fh.write(json.dumps(scene.to_dict()) + "\n")
    (folder / "index.json").write_text(json.dumps({"name": "set", "frames": 2,
                                                   "splits": {"train": [s.scene_id for s in scenes[:2]]}}))
    batches = Batches(KINDED_AGENT_CLOUDS, render_samples(str(folder), "train"), "all")
    assert len(batches.items) == 6 and all(e.delays_s == (0.0, 0.0, 0.0) for e in batches.items)
    noisy = render_samples(str(folder), "train", noise_seed=3)
    perfect = render_samples(str(folder), "train")
    for sample, clean, scene in zip(noisy, perfect, scenes):
        expected = noisy_scene(scene, noise_rng(3, scene.scene_id)).link
        assert dict(sample.frame.agent_delays_s) == {c: s.delay_s for c, s in expected.items()}
        assert sample.frame.poses[scene.ego_id] == clean.frame.poses[scene.ego_id]  # the ego's own is exact
        assert all(sample.frame.poses[c] != clean.frame.poses[c] for c in scene.collaborators)
    batches.add(noisy, "ego")
    assert len(batches.items) == 8
    assert [e.delays_s for e in batches.items[6:]] == [(0.0, STANDARD.delay_s, STANDARD.delay_s)] * 2
