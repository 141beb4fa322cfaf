"""``asg bench paper --table ...``: every table end to end on 2 scenes with the fake detector, in
the documented schema (docs/results/tables.md), with the paper's numbers beside ours."""
import csv
import gzip
import io
import json
from dataclasses import replace
from pathlib import Path

import pytest

from asg.benchmarks.tables import TABLE_KINDS
from asg.cli import main
from sumo_scenarios.errors import InputError

from test_cli import assert_one_line_error, run
from test_robustness import _scene_dict

AP_KEYS = {"0.3", "0.5", "0.7"}


def write_set(root, name, splits):
    """A data set folder ``root/name`` of synthetic scenes with these splits ({split: [ids]})."""
    folder = root / name
    folder.mkdir(parents=True)
    ids = [i for ids in splits.values() for i in ids]
    with gzip.open(folder / "frames.jsonl.gz", "wt", encoding="utf-8") as fh:
        for sid in ids:
            fh.write(json.dumps(_scene_dict(sid)) + "\n")
    (folder / "index.json").write_text(json.dumps({"name": name, "frames": len(ids), "splits": splits}))


@pytest.fixture
def data_root(tmp_path, monkeypatch):
    """A tiny 'normal' set (3 train, 3 val scenes) and 'heuristic' set (2 scenes)."""
    root = tmp_path / "data"
    write_set(root, "normal", {"train": ["t0", "t1", "t2"], "val": ["v0", "v1", "v2"]})
    write_set(root, "heuristic", {"test": ["h0", "h1"]})
    monkeypatch.setenv("ASG_DATA", str(root))
    return root


def _is_ap(d):
    return isinstance(d, dict) and set(d) == AP_KEYS and all(0.0 <= v <= 1.0 for v in d.values())


@pytest.mark.slow
def test_every_table_end_to_end(capsys, tmp_path, data_root):
    out = tmp_path / "tables"
    argv = ["bench", "paper", "--table", "all", "--scenes", "2", "--detector", "fakes:oracle_factory",
            "--workers", "1", "--out", str(out), "--json"]
    assert main(argv) == 0
    printed = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.strip()]
    assert [p["table"] for p in printed] == TABLE_KINDS.names()
    for name in TABLE_KINDS.names():
        result = json.loads((out / f"{name}.json").read_text())
        assert {"command", "scenes", "seconds", "commit", "rows"} <= set(result)
        assert result["command"] == "asg " + " ".join(argv) and result["scenes"] == 2
        rows = list(csv.DictReader(io.StringIO((out / f"{name}.csv").read_text())))
        assert len(rows) == len(result["rows"]) > 0
        md = (out / f"{name}.md").read_text()
        assert result["command"] in md and md.count("\n|") >= 3
    tables = {name: json.loads((out / f"{name}.json").read_text())["rows"] for name in TABLE_KINDS.names()}
    main_rows = tables["main"]
    assert [r["model"] for r in main_rows] == ["none", "late", "early", "attfuse"]
    assert all(_is_ap(r["normal"]) and _is_ap(r["challenging"]) for r in main_rows)
    assert main_rows[3]["paper"]["challenging"]["0.7"] == pytest.approx(0.405)
    ft = tables["finetune"]
    assert {(r["model"], r["set"]) for r in ft} == {(m, s) for m in ("attfuse", "attfuse-ft")
                                                    for s in ("normal-val", "heuristic", "challenging-val", "own-attack-val")}
    assert all(_is_ap(r["ap"]) for r in ft)
    transfer = tables["transfer"]
    assert {(r["source"], r["target"]) for r in transfer} == {(s, t) for s in ("normal", "none", "late", "early", "attfuse")
                                                              for t in ("none", "late", "early", "attfuse")}
    # the target scored on its own challenging scenes is what the generator measured on them
    own = {r["target"]: r["ap"] for r in transfer if r["source"] == r["target"]}
    assert all(own[r["model"]] == pytest.approx(r["challenging"], abs=1e-6) for r in main_rows)
    assert all({"model", "normal", "acs_random", "acs_attention"} <= set(r) for r in tables["acs"])
    assert [(r["acs"], r["aps"]) for r in tables["ablation"]] == [(False, False), (True, False), (False, True), (True, True)]
    assert [r["search"] for r in tables["blackbox"]] == ["normal", "rs", "ga", "bo"]
    spaces = tables["spaces"]
    levels = {("paper", s) for s in ("poses", "insert", "pose-error", "latency", "dropout", "union")}
    levels |= {("traffic", s) for s in ("poses", "insert", "union")}  # the spaces that place vehicles
    levels = {(p, s, 3) for p, s in levels} | {("paper", "union", 6)}  # and the union with six movers
    assert len(spaces) == len(levels) * 3
    assert {(r["model"], r["plausibility"], r["space"], r["movers"], r["search"]) for r in spaces} == {
        ("attfuse", p, s, m, q) for p, s, m in levels for q in ("rs", "bo", "ng")}
    for r in spaces:  # the synthetic scenes have no traffic log: latency (alone or in the union) says so
        if "latency" in r["kinds"]:
            assert "SUMO log" in r["error"]
        else:
            assert _is_ap(r["ap"]) and r["implausible_scenes"] == 0
            assert r["drop"]["0.7"] == pytest.approx(r["normal"]["0.7"] - r["ap"]["0.7"], abs=1e-6)
    # a rerun reuses every challenging set and generator run: the same numbers
    assert main(argv) == 0
    capsys.readouterr()
    again = {name: json.loads((out / f"{name}.json").read_text())["rows"] for name in TABLE_KINDS.names()}
    assert again == tables


@pytest.mark.slow
def test_the_spaces_table_with_a_row_per_model_and_chosen_searches(capsys, tmp_path, data_root):
    """--models gives the spaces table a block of rows per model, --searches the searches compared;
    each model's rows are its own generator runs (the runs of one model are not reused for another)."""
    out = tmp_path / "tables"
    argv = ["bench", "paper", "--table", "spaces", "--models", "late,fcooper", "--searches", "bo", "--scenes", "1",
            "--detector", "fakes:oracle_factory", "--workers", "1", "--out", str(out)]
    assert main(argv) == 0
    capsys.readouterr()
    rows = json.loads((out / "spaces.json").read_text())["rows"]
    per_model = {m: {(r["plausibility"], r["space"], r["movers"]) for r in rows if r["model"] == m}
                 for m in ("late", "fcooper")}
    assert per_model["late"] == per_model["fcooper"] and len(per_model["late"]) == 10
    assert {r["search"] for r in rows} == {"bo"} and len(rows) == 20
    runs = sorted(p.name for p in (out / "runs").iterdir())
    measured = sum("error" not in r for r in rows if r["model"] == "late")  # latency needs a SUMO log
    assert measured == 6 and sum("-late-" in n for n in runs) == sum("-fcooper-" in n for n in runs) == measured
    md = (out / "spaces.md").read_text()
    assert "| model | space |" in md and "| fcooper | union |" in md
    by_model = [line for line in md.splitlines() if line.startswith("| late |") or line.startswith("| fcooper |")]
    assert by_model[0].count("|") == 2 + 1 + 10  # the summary: model, normal AP, a column a configuration
    poses = next(r for r in rows if r["model"] == "late" and r["space"] == "poses" and r["plausibility"] == "paper")
    assert by_model[0].split("|")[3].strip() == f"{100 * poses['drop']['0.7']:.1f}"
    code, err = run(capsys, "bench", "paper", "--table", "main", "--searches", "bo", "--out", str(tmp_path / "o"))
    assert code == 2 and "--table spaces" in err
    code, err = run(capsys, "bench", "paper", "--table", "spaces", "--searches", "bo,bo", "--out", str(tmp_path / "o"))
    assert code == 2
    assert_one_line_error(err, "--searches takes distinct searches")


@pytest.mark.slow
def test_the_own_attack_row_is_scored_by_todays_detector(tmp_path, data_root):
    """Table II's own-attack row evaluates the model on the scenes its attack found; it does not read
    the detections the attack stored (an older build of the set, e.g. before a mesh change, leaves
    detections today's code would not make)."""
    import numpy as np

    out = tmp_path / "tables"
    argv = ["bench", "paper", "--table", "finetune", "--scenes", "2", "--detector", "fakes:oracle_factory",
            "--workers", "1", "--out", str(out)]
    assert main(argv) == 0
    stored = sorted((data_root / "challenging-attfuse-val" / "run" / "scenes").glob("*/detections.npz"))
    assert len(stored) == 2
    for npz in stored:  # the stale build: it detected nothing
        with np.load(npz) as z:
            arrays = dict(z)
        for key in ("normal", "after_acs", "final"):
            if f"{key}_boxes" in arrays:
                arrays[f"{key}_boxes"] = np.zeros((0, 7), np.float32)
                arrays[f"{key}_scores"] = np.zeros(0, np.float32)
        np.savez(npz, **arrays)
    assert main(argv) == 0
    rows = {(r["model"], r["set"]): r for r in json.loads((out / "finetune.json").read_text())["rows"]}
    own, challenging = rows[("attfuse", "own-attack-val")], rows[("attfuse", "challenging-val")]
    assert own["scenes_from"] == challenging["scenes_from"] == "challenging-attfuse-val"
    assert own["ap"] == challenging["ap"] and own["ap"]["0.7"] > 0.5 and own["frames"] == 2


def test_bad_table_requests_are_one_line(capsys, tmp_path, data_root):
    for argv, needle in ((["bench", "paper", "--table", "mian"], "unknown table"),
                         (["bench", "paper", "--table", "main", "--budget", "5"], "--budget"),
                         (["bench", "paper", "--table", "main", "--detector", "nowhere:f"], "cannot be loaded"),
                         (["bench", "paper", "--detector", "fakes:oracle_factory"], "--table")):
        code, err = run(capsys, *argv, "--out", str(tmp_path / "o"))
        assert code == 2, argv
        assert_one_line_error(err, needle)


@pytest.mark.slow
def test_tables_both_ways_from_one_measurement(capsys, tmp_path, data_root, monkeypatch):
    """--ap-method both writes every table as ours (NAME.*) and as the paper's yardstick
    (NAME.per-frame.*), each labelled; a set is detected once for both; the per-frame rows are what
    asg.objective scores per frame over the same detections."""
    from asg import evaluation as evaluate_mod

    calls = []
    real = evaluate_mod.evaluate
    monkeypatch.setattr(evaluate_mod, "evaluate", lambda *a, **k: calls.append(a[:2]) or real(*a, **k))
    out = tmp_path / "tables"
    argv = ["bench", "paper", "--table", "main,finetune", "--scenes", "2", "--detector", "fakes:oracle_factory",
            "--workers", "1", "--out", str(out), "--ap-method", "both"]
    assert main(argv) == 0
    capsys.readouterr()
    assert calls and len(calls) == len(set(calls))  # each (model, set) detected once for both yardsticks
    for name in ("main", "finetune"):
        ours, paper_way = (json.loads((out / f"{stem}.json").read_text()) for stem in (name, f"{name}.per-frame"))
        assert (ours["ap_method"], paper_way["ap_method"]) == ("global", "per-frame")
        assert "ranked globally" in (out / f"{name}.md").read_text()
        assert "no sort across frames" in (out / f"{name}.per-frame.md").read_text()
        assert len(ours["rows"]) == len(paper_way["rows"])
    from asg.generator.run_folder import load_detections, pooled_ap

    index = json.loads((data_root / "challenging-attfuse-train" / "index.json").read_text())
    per_scene = [load_detections(data_root / "challenging-attfuse-train" / "run", i) for i in index["splits"]["train"]]
    row = json.loads((out / "main.per-frame.json").read_text())["rows"][3]
    assert row["challenging"] == pooled_ap(per_scene, "final", "per-frame")


def test_per_frame_harden_rows_from_a_card_before_the_yardstick_are_refused(tmp_path, monkeypatch):
    """The harden run resumed in the table's folder has a card from before the paper's yardstick
    was recorded: per-frame rows are refused in one line, global ones still read it."""
    from asg.benchmarks.tables import TableRun, harden_rows
    from asg.workflows import harden as harden_module

    old_row = {"0.3": 0.9, "0.5": 0.8, "0.7": 0.7, "frames": 3}
    card = {"rounds": [{"round": k, "evaluation": {"normal-val": old_row}} for k in (0, 1)]}
    monkeypatch.setattr(harden_module, "harden", lambda *a, **k: card)
    run = TableRun(out=tmp_path / "o", harden_rounds=1)
    assert len(harden_rows(run)) == 3  # a row for each kind of data
    with pytest.raises(InputError, match="before asg harden recorded the paper's yardstick"):
        harden_rows(replace(run, ap_method="per-frame"))


@pytest.mark.slow
def test_models_pick_the_rows_of_the_model_tables(capsys, tmp_path, data_root):
    """``--models``: Table I's rows are those models, in that order; one the paper lacks has no
    paper figures (empty cells in the markdown), one it has keeps them."""
    out = tmp_path / "tables"
    argv = ["bench", "paper", "--table", "main", "--models", "fcooper,attfuse", "--scenes", "2",
            "--detector", "fakes:oracle_factory", "--workers", "1", "--out", str(out), "--json"]
    assert main(argv) == 0
    rows = json.loads((out / "main.json").read_text())["rows"]
    assert [r["model"] for r in rows] == ["fcooper", "attfuse"]
    assert rows[0]["paper"] is None and rows[1]["paper"]["challenging"]["0.7"] == 0.405
    assert "| fcooper |" in (out / "main.md").read_text()


@pytest.mark.parametrize("models, factory, said", [
    (None, None, "shipped"), (("attfuse", "none"), None, "shipped"),
    (("attfuse", "opencood:/m"), None, "shipped, and OpenCOOD model folders"),
    (("opencood:/m",), None, "OpenCOOD model folders"), (("attfuse",), "fakes:oracle_factory", "fakes:oracle_factory")])
def test_a_tables_header_says_what_detected(models, factory, said):
    """A table with an OpenCOOD model among its rows does not call its detectors shipped."""
    from asg.benchmarks.tables import TableRun, _detectors

    assert _detectors(TableRun(Path("out"), models=models, detector_factory=factory)) == said


@pytest.mark.parametrize("models", ["nope", "attfuse,attfuse", ","])
def test_bad_models_are_one_line(capsys, tmp_path, models):
    code, err = run(capsys, "bench", "paper", "--table", "main", "--models", models, "--out", str(tmp_path / "o"))
    assert code == 2
    assert_one_line_error(err, "--models")


def test_every_built_set_is_read_and_exported_by_its_name(data_root, tmp_path, capsys):
    """Each name of ``datasets.SETS`` reads its built set (the split it names, or the whole set),
    and ``asg export NAME`` takes it: detector-train included, which OpenCOOD's trainer reads."""
    from asg.cli import main
    from asg.datasets import SETS, scenes_of

    write_set(data_root, "holdout", {"test": ["o0"]})
    write_set(data_root, "detector-train", {"train": ["d0", "d1"], "val": ["d2"]})
    want = {"normal": ["t0", "t1", "t2"], "normal-val": ["v0", "v1", "v2"], "normal-all": ["t0", "t1", "t2", "v0", "v1", "v2"],
            "heuristic": ["h0", "h1"], "holdout": ["o0"], "detector-train": ["d0", "d1", "d2"]}
    assert set(SETS) == set(want)
    for name, ids in want.items():
        assert [s.scene_id for s in scenes_of(name)] == ids, name
    assert main(["export", "detector-train", "--format", "opv2v", "--out", str(tmp_path / "dt")]) == 0
    assert (tmp_path / "dt").is_dir() and any((tmp_path / "dt").iterdir())


def test_a_measurement_resolves_each_model_once(tmp_path, monkeypatch):
    """Every table of a run (and the run copied per AP method) asks the run for a model's target:
    the name is resolved once, and the same object answers each time."""
    from dataclasses import replace

    from asg.benchmarks.tables import TableRun
    from asg.perception import targets

    calls = []
    resolve = targets.resolve_target
    monkeypatch.setattr(targets, "resolve_target", lambda name: calls.append(name) or resolve(name))
    run = TableRun(out=tmp_path)
    first = run.target("attfuse")
    assert replace(run, ap_method="per-frame").target("attfuse") is first is run.target("attfuse")
    assert first == resolve("attfuse") and calls == ["attfuse"]
