"""Challenging data sets: generated once from a split of the normal set, resumable, readable by
``asg evaluate --set challenging-NAME-SPLIT``. A tiny stand-in normal set and the fake detector."""
import gzip
import json

import pytest
from sumo_scenarios.errors import InputError

from asg.perception.targets import resolve_target
from asg.workflows.challenging import build_challenging
from asg.workflows.finetune import attacked_model
from asg.cli import main
from asg.scene import Scene

from test_cli import assert_one_line_error, run
from test_tables import write_set

NONE = resolve_target("none")


@pytest.fixture
def data_root(tmp_path, monkeypatch):
    """ASG_DATA with a 'normal' set of 3 synthetic val scenes."""
    root = tmp_path / "data"
    write_set(root, "normal", {"train": [], "val": ["n0", "n1", "n2"]})
    monkeypatch.setenv("ASG_DATA", str(root))
    return root


@pytest.mark.slow
def test_build_resume_and_evaluate(capsys, data_root):
    out = build_challenging(NONE, "val", count=2, detector_factory="fakes:oracle_factory")
    index = json.loads((out / "index.json").read_text())
    assert out.name == "challenging-none-val" and index["frames"] == 2 and index["splits"] == {"val": ["n0", "n1"]}
    assert index["source"]["detector"] == "fakes:oracle_factory"  # the set names the detector it attacked
    # and a re-attack's record of the original model names it too
    assert attacked_model(index["source"]) == {"weights": "shipped", "detector": "fakes:oracle_factory"}
    assert attacked_model({"fusion": "none", "weights": "w.pt"}) == {"weights": "w.pt"}
    first = (out / "run" / "scenes" / "n0" / "result.json").read_text()
    assert not (out / "run" / "scenes" / "n0" / "clouds").exists()  # a data set keeps no clouds or pictures
    # a larger --count resumes: the finished scenes stay as they are
    out = build_challenging(NONE, "val", detector_factory="fakes:oracle_factory")
    assert json.loads((out / "index.json").read_text())["frames"] == 3
    assert (out / "run" / "scenes" / "n0" / "result.json").read_text() == first
    finals = [Scene.from_dict(json.loads(line)) for line in gzip.open(out / "frames.jsonl.gz", "rt")]
    assert [s.scene_id for s in finals] == ["n0", "n1", "n2"] and all(len(s.collaborators) == 2 for s in finals)
    assert main(["evaluate", "--fusion", "none", "--set", "challenging-none-val", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 3


@pytest.mark.slow
def test_a_set_attacked_against_other_shipped_weights_is_generated_again(capsys, data_root):
    """challenging-F-SPLIT is the split attacked against the shipped F: after those weights change
    (a new install), building it again attacks anew instead of resuming the old attack."""
    out = build_challenging(NONE, "val", count=2, detector_factory="fakes:oracle_factory")
    record_path = out / "run" / "run.json"
    today = json.loads(record_path.read_text())["shipped_weights_sha256"]
    stale = dict(today, single="0" * 64)
    record_path.write_text(json.dumps(json.loads(record_path.read_text()) | {"shipped_weights_sha256": stale}))
    marker = out / "run" / "scenes" / "n0" / "result.json"
    marker.write_text(marker.read_text().replace('"scene_id"', '"old": 1, "scene_id"', 1))  # the old attack's
    capsys.readouterr()
    out = build_challenging(NONE, "val", count=2, detector_factory="fakes:oracle_factory")
    assert "generating it again" in capsys.readouterr().out
    assert json.loads(record_path.read_text())["shipped_weights_sha256"] == today
    assert '"old"' not in marker.read_text() and json.loads((out / "index.json").read_text())["frames"] == 2
    # the same weights: resumed, nothing generated again
    marker.write_text(marker.read_text().replace('"scene_id"', '"kept": 1, "scene_id"', 1))
    build_challenging(NONE, "val", count=2, detector_factory="fakes:oracle_factory")
    assert '"kept"' in marker.read_text()


def test_bad_challenging_requests_are_one_line(capsys, data_root):
    for argv, needle in ((["dataset", "build", "challenging", "--fusion", "attfuse"], "--split"),
                         (["dataset", "build", "challenging", "--fusion", "attfuse", "--split", "test"], "--split"),
                         (["dataset", "build", "challenging", "--fusion", "nope", "--split", "val"], "unknown fusion"),
                         (["dataset", "build", "normal", "--fusion", "attfuse"], "challenging"),
                         (["evaluate", "--fusion", "none", "--set", "challenging-early-val"], "is not built")):
        code, err = run(capsys, *argv)
        assert code == 2, argv
        assert_one_line_error(err, needle)


def test_a_missing_set_names_the_command_that_builds_it(data_root):
    """The hint of a set not built: the shipped model's name, or the prefixed target's form (an
    OpenCOOD set's name holds its folder's name and digest, not the folder)."""
    from asg.datasets import challenging_scenes

    for name, hint in (("challenging-attfuse-wide-val", "--fusion attfuse-wide --split val"),
                       ("challenging-opencood-m-ab12cd34-train", "--fusion opencood:DIR --split train")):
        with pytest.raises(InputError, match=f"run 'asg dataset build challenging {hint}'"):
            challenging_scenes(name)


def test_evaluate_loads_a_weights_file_once(capsys, data_root, tmp_path, monkeypatch):
    """``asg evaluate --weights FILE`` in one process: the detector that checked the file is the one
    scored (the file read once), and its AP is the shipped weights' own."""
    import shutil

    from asg.perception import weights_io

    copy = tmp_path / "mine.pt"
    shutil.copy(weights_io.weights_path(NONE.shipped_weights), copy)
    reads = []
    load_state = weights_io.load_state
    monkeypatch.setattr(weights_io, "load_state",
                        lambda model, path, *a, **k: reads.append(str(path)) or load_state(model, path, *a, **k))

    def ap(*extra: str) -> dict:
        assert main(["evaluate", "--fusion", "none", "--set", "normal-val", "--json", *extra]) == 0
        return json.loads(capsys.readouterr().out.strip().splitlines()[-1])

    mine = ap("--weights", str(copy))
    assert reads.count(str(copy)) == 1
    assert ap() == mine
