"""Challenging data sets: generated once from a split of the normal set, resumable, readable by
``asg evaluate --set challenging-NAME-SPLIT``. A tiny stand-in normal set and the fake detector."""
import gzip
import json

import pytest

from asg.workflows.challenging import build_challenging
from asg.cli import main
from asg.scene import Scene

from test_cli import assert_one_line_error, run
from test_tables import write_set


@pytest.fixture
def data_root(tmp_path, monkeypatch):
    """ASG_DATA with a 'normal' set of 3 synthetic val scenes."""
    root = tmp_path / "data"
    write_set(root, "normal", {"train": [], "val": ["n0", "n1", "n2"]})
    monkeypatch.setenv("ASG_DATA", str(root))
    return root


def test_build_resume_and_evaluate(capsys, data_root):
    out = build_challenging("none", "val", count=2, detector_factory="fakes:oracle_factory")
    index = json.loads((out / "index.json").read_text())
    assert out.name == "challenging-none-val" and index["frames"] == 2 and index["splits"] == {"val": ["n0", "n1"]}
    first = (out / "run" / "scenes" / "n0" / "result.json").read_text()
    assert not (out / "run" / "scenes" / "n0" / "clouds").exists()  # a data set keeps no clouds or pictures
    # a larger --count resumes: the finished scenes stay as they are
    out = build_challenging("none", "val", detector_factory="fakes:oracle_factory")
    assert json.loads((out / "index.json").read_text())["frames"] == 3
    assert (out / "run" / "scenes" / "n0" / "result.json").read_text() == first
    finals = [Scene.from_dict(json.loads(line)) for line in gzip.open(out / "frames.jsonl.gz", "rt")]
    assert [s.scene_id for s in finals] == ["n0", "n1", "n2"] and all(len(s.collaborators) == 2 for s in finals)
    assert main(["evaluate", "--fusion", "none", "--set", "challenging-none-val", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 3


def test_bad_challenging_requests_are_one_line(capsys, data_root):
    for argv, needle in ((["dataset", "build", "challenging", "--fusion", "attfuse"], "--split"),
                         (["dataset", "build", "challenging", "--fusion", "attfuse", "--split", "test"], "--split"),
                         (["dataset", "build", "challenging", "--fusion", "nope", "--split", "val"], "unknown fusion"),
                         (["dataset", "build", "normal", "--fusion", "attfuse"], "challenging"),
                         (["evaluate", "--fusion", "none", "--set", "challenging-early-val"], "is not built")):
        code, err = run(capsys, *argv)
        assert code == 2, argv
        assert_one_line_error(err, needle)
