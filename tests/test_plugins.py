"""Your detector as the target: a tiny external package (tests/plugin_pkg) installed with pip
registers detectors in the ``asg.detectors`` entry point group; asg evaluates and attacks it by
name, and names a broken plugin in one line (exit 2)."""
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from asg.cli import main
from asg.perception import detector_names

from test_cli import assert_one_line_error, run
from test_robustness import _scene_dict, _write

PLUGIN_PKG = Path(__file__).parent / "plugin_pkg"


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """The toy package pip-installed into a folder put on sys.path (entry points are found there)."""
    target = tmp_path_factory.mktemp("site")
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
                    "--target", str(target), str(PLUGIN_PKG)], check=True, capture_output=True)
    sys.path.insert(0, str(target))
    yield target
    sys.path.remove(str(target))
    for name in [m for m in sys.modules if m.startswith("toy_detector")]:
        del sys.modules[name]


@pytest.fixture
def scenes(tmp_path):
    folder = tmp_path / "scenes"
    for i in range(2):
        _write(folder, _scene_dict(f"s{i}"))
    return folder


def test_shipped_and_plugin_detectors_are_listed(installed):
    from asg.perception.fusion import FUSIONS
    from asg.perception.plugins import plugin_names

    assert not set(FUSIONS.names()) & set(plugin_names())  # the entry point group holds plugins only
    assert set(FUSIONS.names()) | {"toy"} <= set(detector_names())


def test_every_shipped_model_is_registered_in_each_place_it_needs():
    """A shipped model is its module in asg/perception/fusion/ (imported by the package without an
    import line) and, unless its weights fine-tune another model's (``fine_tuned_from``), its
    train.yaml block; it is in the registry only (the entry point group is for plugins)."""
    import tomllib

    from asg.perception.fusion import FUSIONS
    from asg.training.config import load_train_config

    project = tomllib.loads((Path(__file__).parent.parent / "pyproject.toml").read_text())
    assert "asg.detectors" not in project["project"].get("entry-points", {})
    for fusion in FUSIONS.names():
        cls = FUSIONS.entry(fusion)
        if not cls.fine_tuned_from:
            assert load_train_config(cls.weights).steps > 0, fusion


def test_a_plugin_is_evaluated_and_attacked_by_name(capsys, installed, scenes, tmp_path):
    assert main(["evaluate", "--fusion", "toy", "--set", str(scenes), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["frames"] == 2 and set(result["ap"]) == {"0.3", "0.5", "0.7"}
    out = tmp_path / "gen"
    assert main(["generate", "--scenes", str(scenes), "--fusion", "toy", "--budget", "3", "--count", "2",
                 "--workers", "1", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["config"]["fusion"] == "toy" and summary["aggregate"]["scenes"] == 2


@pytest.mark.parametrize("command", [["train"], ["finetune", "--out", "OUT"], ["harden", "--rounds", "1", "--out", "OUT"]],
                         ids=["train", "finetune", "harden"])
def test_training_a_plugin_says_why_not_in_one_line(capsys, installed, tmp_path, command):
    """Every command that takes --fusion knows a plugin: the ones that train say it brings its own
    weights (not "unknown fusion"), before any work."""
    out = tmp_path / "out"
    code, err = run(capsys, *[str(out) if a == "OUT" else a for a in command], "--fusion", "toy")
    assert code == 2
    assert_one_line_error(err, "'toy' is a detector plugin")
    assert not out.exists()


def test_bad_plugins_are_one_line_naming_them(capsys, installed, scenes, tmp_path):
    for name, needle in (("toy-broken", "could not be loaded"), ("toy-bad-shape", "(K, 7)"), ("toy-nan", "non-finite")):
        code, err = run(capsys, "evaluate", "--fusion", name, "--set", str(scenes))
        assert code == 2, name
        assert_one_line_error(err, f"detector plugin '{name}'", needle)
    code, err = run(capsys, "evaluate", "--fusion", "toy", "--set", str(scenes), "--weights", str(tmp_path / "w.pt"))
    assert code == 2
    assert_one_line_error(err, "--weights applies to the shipped models")


def test_a_factory_without_attention_under_the_default_acs(capsys, tmp_path):
    """The default --acs attention with a --detector that gives no ACS model borrows the shipped
    AttFuse's attention (as a shipped model without attention does); one whose ACS model returns
    no attention is one line, exit 2, and leaves no run behind."""
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict("s0"))
    common = ["generate", "--scenes", str(scenes), "--count", "1", "--budget", "2", "--search", "rs"]
    code, err = run(capsys, *common, "--detector", "fakes:no_acs_model_factory", "--out", str(tmp_path / "borrow"))
    assert code == 0, err
    code, err = run(capsys, *common, "--detector", "fakes:none_attention_factory", "--out", str(tmp_path / "none"))
    assert code == 2
    assert_one_line_error(err, "no attention weights", "--acs random")
    assert not list((tmp_path / "none").glob("scenes/*/result.json"))


@pytest.mark.parametrize("boxes, scores, needle", [
    (np.array([[5.0, 0, 0, 4.0, 2.0, 1.5, 0]]) + 1j, np.ones(1), "not real numbers"),
    (np.array([[5.0, 0, 0, 4.0, 2.0, 1.5, 0]]), np.ones(1, dtype=complex), "not real numbers"),
    (np.array([[5.0, 0, 0, 1e300, 2.0, 1.5, 0]]), np.ones(1), "at most 100 m long"),
    (np.array([[1e300, 0, 0, 4.0, 2.0, 1.5, 0]]), np.ones(1), "within 10000 m"),
    (np.array([[5.0, 0, 0, 4.0, 2.0, 1.5, 1e300]]), np.ones(1), "|yaw|"),
    (np.array([[5.0, 0, 0, 4.0, 2.0, 1.5, 0]], dtype=object), np.ones(1), "not real numbers"),
])
def test_detections_that_are_not_boxes_are_one_line(boxes, scores, needle):
    """Complex numbers (their imaginary part would be dropped) and numbers no box has (1e300
    overflows the IoU) are refused, naming the plugin."""
    from asg.perception.plugins import check_detections
    from sumo_scenarios.errors import InputError

    with pytest.raises(InputError, match=re.escape(needle)) as exc:
        check_detections("mine", (boxes, scores))
    assert "'mine'" in str(exc.value) and "\n" not in str(exc.value)
    good = check_detections("mine", (np.array([[5.0, 0, 0, 4.0, 2.0, 1.5, 0.3]]), np.array([0.9])))
    assert good[0].dtype == np.float64 and good[0][0, 6] == 0.3
