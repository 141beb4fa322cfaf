"""Every registry entry builds and answers through its interface."""
import numpy as np

from asg import perception, search  # noqa: F401  (fill the registries)
from asg.registry import lookup, names


def test_every_fusion_entry_builds_untrained(cross_map):
    from asg.perception.config import DetectorConfig
    from asg.sensors import simulate_frame
    from asg.sensors.lidar_spec import LidarSpec

    from conftest import car, make_scene, rsu

    spec = LidarSpec(name="t", channels=8, points_per_s=8 * 90 * 10, rotation_hz=10.0)
    scene = make_scene(cross_map, [rsu("r", 8.0, 8.0), car("a", -10.0, -1.6), car("b", 15.0, 1.6, np.pi)],
                       collaborators=["a"])
    frame = simulate_frame(scene, spec)
    tiny = DetectorConfig(range_m=16.0, pfn_channels=8, layers=(1, 1, 1), filters=(8, 8, 8), upsample_channels=8,
                          score_threshold=0.99, iou_rescore=0.0, iou_patch=1, box_refine=False,
                          attfuse_fusion="output")
    assert names("fusion") == ["attfuse", "attfuse-ft", "early", "late", "none"]
    for name in names("fusion"):
        det = lookup("fusion", name)(cfg=tiny, load=False)
        boxes, scores = det.detect(frame)
        assert boxes.shape[1:] == (7,) and scores.shape == (len(boxes),)
        w = det.attention_weights(frame)
        assert (w is None) == (not name.startswith("attfuse"))
        if w is not None:
            assert set(w) == {"r", "a"} and abs(sum(w.values()) - 1.0) < 1e-5


def test_every_search_entry_asks_inside_the_box():
    assert names("search") == ["bo", "ga", "rs"]
    for name in names("search"):
        params = {"n_initial": 2} if name == "bo" else {}
        opt = lookup("search", name)(6, 5, np.random.default_rng(0), **params)
        candidates = np.random.default_rng(1).uniform(-1, 1, (20, 6))
        for i in range(4):
            x = opt.ask(candidates)
            assert x.shape == (6,) and np.all(np.abs(x) <= 1.0)
            if name != "ga":  # RS and BO pick among the candidates
                assert np.any(np.all(candidates == x, axis=1))
            opt.tell(x, float(i))
