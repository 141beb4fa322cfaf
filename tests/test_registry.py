"""Every registry entry builds and answers through its interface."""
import numpy as np

import pytest

from asg.collaborators import ACS_STRATEGIES
from asg.executors import EXECUTORS
from asg.io.export import EXPORT_FORMATS
from asg.perception.fusion import FUSIONS
from asg.search import SEARCHES
from asg.search.spaces import SPACES
from asg.workflows.trainers import ROUND_TRAINERS

#: the shipped set of each registry, pinned (every other test walks the registries themselves)
SHIPPED = {"fusion": ["attfuse", "attfuse-ft", "attfuse-wide", "early", "fcooper", "late", "none", "v2vnet", "v2xvit",
                      "v2xvit-noisy", "where2comm"],
           "search": ["bo", "ga", "ls", "ng", "rs"], "space": ["dropout", "insert", "latency", "pose-error", "poses"],
           "acs": ["attention", "random"], "executor": ["local", "ray"],
           "export": ["kitti", "openscenario", "opv2v", "rosbag2", "sumo"], "round trainer": ["asg", "opencood"]}
REGISTRIES = {"fusion": FUSIONS, "search": SEARCHES, "space": SPACES, "acs": ACS_STRATEGIES, "executor": EXECUTORS,
              "export": EXPORT_FORMATS, "round trainer": ROUND_TRAINERS}


@pytest.mark.parametrize("kind", sorted(SHIPPED))
def test_each_registry_holds_the_shipped_set_once_its_package_is_imported(kind):
    assert REGISTRIES[kind].names() == SHIPPED[kind]


def test_every_target_kind_that_is_trained_here_has_a_round_trainer():
    """A target kind whose ``training`` is not NONE has the round trainer of that training kind (so
    ``asg harden`` takes it); one that brings its own weights is refused in its one line."""
    from asg.perception.targets import TARGET_KINDS, Training
    from asg.workflows.trainers import round_trainer
    from sumo_scenarios.errors import InputError

    trained = {k.training.value for k in TARGET_KINDS.entries() if k.training is not Training.NONE}
    assert trained == set(ROUND_TRAINERS.names())

    class Brought:
        training, name = Training.NONE, "x"

        def not_trained_here(self):
            return "brings its own weights"

    with pytest.raises(InputError, match="brings its own weights"):
        round_trainer(Brought(), None)


#: a flag's choices as the docs write them, ``--flag a|b|c``; the words a list may add to its
#: registry's names (a plugin, an OpenCOOD folder, ACS off)
DOC_FLAGS = {"--fusion": ("fusion", {"PLUGIN", "opencood:DIR"}), "--search": ("search", set()),
             "--format": ("export", set()), "--acs": ("acs", {"off"}), "--executor": ("executor", set())}


def test_the_docs_list_every_name_of_a_registry():
    """Every ``--flag a|b|c`` the README and docs/ write names the whole registry of that flag (and
    nothing it lacks): a part added or removed shows in the docs or fails here."""
    import re
    from pathlib import Path

    root = Path(__file__).parents[1]
    pages = [root / "README.md", *sorted((root / "docs").glob("*.md"))]
    seen = 0
    for page in pages:
        # (a list in a markdown table escapes its bars: a\|b)
        for flag, words in re.findall(r"(--[a-z]+)[ =]`?([A-Za-z0-9:_-]+(?:\\?\|[A-Za-z0-9:_-]+)+)", page.read_text()):
            if flag not in DOC_FLAGS:
                continue
            kind, extra = DOC_FLAGS[flag]
            names = set(words.replace("\\|", "|").split("|")) - extra
            assert names == set(REGISTRIES[kind].names()), (page.name, flag, words)
            seen += 1
    assert seen >= 4  # the lists this test exists for are there


def test_the_export_formats_register_without_loading_the_lidar_or_torch():
    """``asg export --help`` stays quick: the writers' modules import the LiDAR and torch inside
    their methods."""
    import subprocess
    import sys

    code = "import sys, asg.io.export as e; e.EXPORT_FORMATS.entry('kitti'); print('torch' in sys.modules, 'trimesh' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split() == ["False", "False"]


def test_the_paper_tables_keep_the_papers_order():
    """``--table all`` runs the tables in the paper's order (an ordered registry), not sorted."""
    from asg.benchmarks.tables import TABLE_KINDS

    assert TABLE_KINDS.names() == ["main", "finetune", "transfer", "acs", "ablation", "blackbox", "spaces"]
    assert TABLE_KINDS.entry("main").registry_name == "main"


def test_an_unknown_name_is_one_line_naming_the_known_ones():
    from sumo_scenarios.errors import InputError

    with pytest.raises(InputError) as exc:
        SEARCHES.entry("b\no")
    assert "\n" not in str(exc.value) and "'b\\no'" in str(exc.value) and ", ".join(SEARCHES.names()) in str(exc.value)


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
    for name in FUSIONS.names():
        entry = FUSIONS.entry(name)
        det = entry(cfg=tiny, load=False)
        boxes, scores = det.detect(frame)
        assert boxes.shape[1:] == (7,) and scores.shape == (len(boxes),)
        w = det.attention_weights(frame)
        assert (w is None) == (not entry.has_attention), name  # the entry says whether it has attention
        if w is not None:
            assert set(w) == {"r", "a"} and abs(sum(w.values()) - 1.0) < 1e-5


def test_every_search_entry_asks_inside_the_box():
    for name in SEARCHES.names():
        params = {"n_initial": 2} if name == "bo" else {}
        opt = SEARCHES.entry(name)(6, 5, np.random.default_rng(0), **params)
        candidates = np.random.default_rng(1).uniform(-1, 1, (20, 6))
        for i in range(4):
            x = opt.ask(candidates)
            assert x.shape == (6,) and np.all(np.abs(x) <= 1.0)
            if name in ("rs", "bo"):  # RS and BO pick among the candidates
                assert np.any(np.all(candidates == x, axis=1))
            opt.tell(x, float(i))


@pytest.mark.parametrize("name", ["ng", "ls"])
def test_the_searches_that_step_freely_are_seeded_and_learn(name):
    """nevergrad and local search ask points of their own (not Q's members): the same generator
    seed gives the same asks, each inside the box, and on a quadratic they end nearer the minimum
    than they started."""
    def run(seed):
        opt = SEARCHES.entry(name)(4, 40, np.random.default_rng(seed))
        xs = []
        for _ in range(40):
            x = opt.ask(np.zeros((1, 4)))
            assert np.all(np.abs(x) <= 1.0)
            xs.append(x)
            opt.tell(x, float(np.sum((x - 0.5) ** 2)))
        return np.array(xs)

    a, b = run(3), run(3)
    assert np.array_equal(a, b)
    loss = np.sum((a - 0.5) ** 2, axis=1)
    assert loss[-10:].min() < loss[:5].min()


def test_nevergrad_drives_a_generator_run(capsys, tmp_path):
    import json

    from test_robustness import oracle_run

    runs = []
    for out in ("a", "b"):
        folder = oracle_run(tmp_path, 1, "--search", "ng", "--budget", "6", out=out)
        runs.append(json.loads((folder / "summary.json").read_text())["scenes"][0])
    assert runs[0]["evaluations"] == runs[1]["evaluations"] and runs[0]["delta"] == runs[1]["delta"]
    assert (tmp_path / "a" / "scenes" / "s0" / "history.csv").read_text().count("\n") == 7  # header + 6
    capsys.readouterr()
