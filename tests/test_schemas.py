"""Versioned files: summary.json, run.json and a data set's index.json carry their schema version; a
file from before versions were written still reads (in today's shape, its version told); a file from
a newer asg is one line."""
from __future__ import annotations

import json

import pytest

from asg.generator.run_folder import read_summary
from asg.io.run_record import RUN_RECORD, claim
from asg.schemas import CURRENT, SCHEMA_KEY, SchemaFile, schema_of
from sumo_scenarios.errors import InputError

V1_SUMMARY = {"config": {}, "scenes": [{"scene_id": "s0", "ap_normal": {"0.7": 0.9}, "ap_challenging": {"0.7": 0.5}}],
              "aggregate": {"scenes": 1, "ap_normal": {"0.7": 0.9}, "ap_challenging": {"0.7": 0.5},
                            "mean_scene_ap_challenging": {"0.7": 0.5},
                            "by_method": {"per-frame": {"ap_normal": {"0.7": 0.8}, "ap_challenging": {"0.7": 0.4}}}}}


def test_a_summary_of_schema_1_reads_in_todays_shape_and_says_so(tmp_path):
    (tmp_path / "summary.json").write_text(json.dumps(V1_SUMMARY))
    summary, version = read_summary(tmp_path / "summary.json")
    assert version == 1
    assert summary["aggregate"]["ap_final"] == {"0.7": 0.5} and "ap_challenging" not in summary["aggregate"]
    assert summary["aggregate"]["mean_scene_ap_final"] == {"0.7": 0.5}
    assert summary["aggregate"]["by_method"]["per-frame"]["ap_final"] == {"0.7": 0.4}
    assert summary["scenes"][0]["ap_final"] == {"0.7": 0.5}
    today = {**V1_SUMMARY, "aggregate": {"ap_final": {}}}
    assert schema_of(SchemaFile.SUMMARY, today, "x") == 2  # today's shape before the version was written
    assert schema_of(SchemaFile.SUMMARY, {SCHEMA_KEY: 2, **today}, "x") == 2


def test_a_run_folder_of_schema_2_reads_its_normal_stage_spelled_initial(tmp_path):
    """Before each stage had one name the normal stage was ``initial`` in a scene folder (its scene
    file, its detections) and in a scene entry's collaborators: such a folder reads as today's."""
    import numpy as np

    from asg.generator.run_folder import load_detections, load_done, stage_scene_path
    from asg.generator.stages import Stage

    folder = tmp_path / "scenes" / "s0"
    folder.mkdir(parents=True)
    (folder / "initial.yaml").write_text("x")
    (folder / "final.yaml").write_text("x")
    boxes = np.ones((1, 7), np.float32)
    np.savez(folder / "detections.npz", **{f"{k}_{n}": boxes for k in ("initial", "final") for n in ("boxes", "scores", "gt")})
    entry = {"scene_id": "s0", "ap_normal": {"0.7": 0.9}, "collaborators": {"initial": ["1"], "final": ["2"]}}
    (folder / "result.json").write_text(json.dumps(entry))
    assert stage_scene_path(folder, Stage.NORMAL) == folder / "initial.yaml"
    assert stage_scene_path(folder, Stage.FINAL) == folder / "final.yaml"
    assert set(load_detections(tmp_path, "s0")) == {Stage.NORMAL, Stage.FINAL}
    assert load_done(tmp_path)["s0"]["collaborators"] == {"normal": ["1"], "final": ["2"]}
    v2 = {SCHEMA_KEY: 2, "config": {}, "scenes": [entry], "aggregate": {"scenes": 1, "ap_final": {}}}
    (tmp_path / "summary.json").write_text(json.dumps(v2))
    summary, version = read_summary(tmp_path / "summary.json")
    assert version == 2 and summary["scenes"][0]["collaborators"] == {"normal": ["1"], "final": ["2"]}
    (folder / "normal.yaml").write_text("x")  # today's spelling wins where both are there
    assert stage_scene_path(folder, Stage.NORMAL) == folder / "normal.yaml"


@pytest.mark.parametrize("kind", list(SchemaFile))
@pytest.mark.parametrize("version", [CURRENT[SchemaFile.SUMMARY] + 5, "2", True, 0])
def test_a_version_this_asg_does_not_know_is_one_line(kind, version):
    with pytest.raises(InputError, match="does not know") as err:
        schema_of(kind, {SCHEMA_KEY: version}, "f.json")
    assert "\n" not in str(err.value)


def test_run_json_is_versioned_and_an_unversioned_one_resumes(tmp_path):
    out = tmp_path / "run"
    settings = {"config": {"fusion": "attfuse"}, "seed": 1}
    claim(out, settings)
    record = json.loads((out / RUN_RECORD).read_text())
    assert record[SCHEMA_KEY] == CURRENT[SchemaFile.RUN]
    del record[SCHEMA_KEY]  # a folder claimed before run.json carried its version
    (out / RUN_RECORD).write_text(json.dumps(record))
    assert claim(out, settings) == settings
    (out / RUN_RECORD).write_text(json.dumps({**record, SCHEMA_KEY: 99}))
    with pytest.raises(InputError, match="does not know"):
        claim(out, settings)


def test_a_data_sets_index_of_a_newer_asg_is_refused(tmp_path):
    from asg.datasets import iter_frames

    folder = tmp_path / "set"
    folder.mkdir()
    (folder / "index.json").write_text(json.dumps({SCHEMA_KEY: 99, "name": "set", "frames": 0, "splits": {"val": []}}))
    with pytest.raises(InputError, match="does not know"):
        list(iter_frames(folder))
