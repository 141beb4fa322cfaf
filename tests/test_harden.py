"""``asg harden``: rounds of attack, fine-tuning and evaluation on a tiny synthetic data root (the
attacks by the fake oracle, the training real AttFuse steps); resume without repeating a finished
round; the controls draw the scenes they claim; bad input is one line with exit 2."""
import json
from dataclasses import replace

import pytest

from asg.perception.targets import resolve_target
from asg.workflows.challenging import build_challenging
from asg.scene.recheck import recheck
from asg.perception.weights_io import WEIGHTS_DIR
from asg.workflows.harden import harden, load_harden_config
from asg.workflows.trainers import shipped as shipped_trainer
from sumo_scenarios.errors import InputError

from test_cli import assert_one_line_error, run
from test_tables import write_set

ATTFUSE = resolve_target("attfuse")

#: two steps a round, one scene a round from the normal train split, mixed with normal
TINY = replace(load_harden_config(), mix_with=("normal",), eval_sets=("normal-val",), scenes_per_round=1,
               pool=("normal",), noisy=False, reattack=False, guard_set=None).with_trainer(
    "asg", steps=2, batch_size=1, checkpoint_every=1, fit_stage=False)
ORACLE = "fakes:oracle_factory"


@pytest.fixture
def data_root(tmp_path, monkeypatch):
    """ASG_DATA with a 'normal' set (train n0, n1; val n2) and its val challenging set (oracle)."""
    root = tmp_path / "data"
    write_set(root, "normal", {"train": ["n0", "n1"], "val": ["n2"]})
    monkeypatch.setenv("ASG_DATA", str(root))
    build_challenging(ATTFUSE, "val", detector_factory=ORACLE)
    return root


def _trainer(fusion: str = "attfuse"):
    """asg's round trainer of ``fusion`` with the tiny settings."""
    from asg.perception.targets import resolve_target
    from asg.workflows.trainers import round_trainer

    return round_trainer(resolve_target(fusion), TINY.with_trainer("asg", fit_stage=False))


def _start_cache(weights):
    """Where a run starting from ``weights`` caches round 0's evaluations."""
    trainer = _trainer()
    return trainer.start_cache(trainer.model_at(weights))


def _quiet(*_):
    pass


@pytest.mark.slow
def test_two_rounds_write_weights_and_a_card_and_resume(tmp_path, data_root):
    out = tmp_path / "h"

    def stop_in_round_two(step, total, loss):
        if (out / "round-1" / "weights.pt").is_file() and step == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        harden(ATTFUSE, 2, out, config=TINY, detector_factory=ORACLE, log=_quiet, progress=stop_in_round_two)
    card = json.loads((out / "card.json").read_text())
    assert [r["round"] for r in card["rounds"]] == [0, 1]  # round 2 stopped: not in the card
    first = (out / "round-1" / "weights.pt").stat().st_mtime_ns
    card = harden(ATTFUSE, 2, out, config=TINY, detector_factory=ORACLE, log=_quiet)
    assert (out / "round-1" / "weights.pt").stat().st_mtime_ns == first  # round 1 not run again
    assert [r["round"] for r in card["rounds"]] == [0, 1, 2]
    for row in card["rounds"]:
        assert set(row["evaluation"]) == {"normal-val", "challenging-attfuse-val"}
        assert all(0.0 <= row["evaluation"][s]["ap"]["0.7"] <= 1.0 for s in row["evaluation"])
        # the paper's yardstick recorded beside ours (one frame a set: the same ranking, the same AP)
        assert all(set(row["evaluation"][s]) == {"ap", "ap_per_frame", "frames"}
                   and row["evaluation"][s]["ap_per_frame"] == row["evaluation"][s]["ap"] for s in row["evaluation"])
    r1, r2 = card["rounds"][1:]
    assert r1["data"]["kind"] == "adversarial" and r1["data"]["scenes"] == 1
    assert r2["trained"]["examples"] == {"round-1": 3, "round-2": 3, "normal": 6}  # keep_previous, 3 views a scene
    assert r2["weights"] == "round-2/weights.pt" and (out / "round-2" / "weights.pt").is_file()
    assert r1["trained"]["steps"] == 2  # the training record survives a round resumed after its training
    assert not list(out.rglob("last.pt"))
    # the two rounds drew different scenes of the pool
    ids = [sorted(p.stem for p in (out / f"round-{k}" / "scenes").glob("*.yaml")) for k in (1, 2)]
    assert len(ids[0]) == len(ids[1]) == 1 and ids[0] != ids[1]
    with pytest.raises(InputError, match="other settings"):
        harden(ATTFUSE, 2, out, config=TINY.with_trainer("asg", lr=TINY.asg.lr * 2), detector_factory=ORACLE, log=_quiet)
    # a card starts a new run from its last round's weights
    follow = harden(ATTFUSE, 1, tmp_path / "next", weights=out / "card.json", config=replace(TINY, seed=9),
                    detector_factory=ORACLE, log=_quiet)
    assert follow["start"]["weights"].endswith("round-2/weights.pt")


@pytest.mark.slow
def test_the_report_shows_a_hardening_run_round_by_round(capsys, tmp_path, data_root):
    """asg report on a harden folder: a row a round and the training curves (each round's loss.csv,
    written as it trains); a card someone edited is one line."""
    from asg.cli import main

    out = tmp_path / "h"
    harden(ATTFUSE, 2, out, config=TINY, detector_factory=ORACLE, log=_quiet)
    for k in (1, 2):
        lines = (out / f"round-{k}" / "loss.csv").read_text().splitlines()
        assert lines[0] == "step,loss" and lines[-1].startswith("2,")
    assert main(["report", str(out)]) == 0
    page = (out / "report.html").read_text()
    assert "asg harden --fusion attfuse" in page and "challenging-attfuse-val" in page
    assert page.count("<tr><td>") == 3 and page.count("<img") == 1  # rounds 0, 1, 2; AP by round and the curves
    capsys.readouterr()
    card = json.loads((out / "card.json").read_text())
    card["rounds"][1]["evaluation"]["normal-val"]["ap"]["0.7"] = "<script>alert(1)</script>"
    (out / "card.json").write_text(json.dumps(card))
    code, err = run(capsys, "report", str(out))
    assert code == 2
    assert_one_line_error(err, "the training card")


@pytest.mark.slow
@pytest.mark.parametrize("data", ["random", "normal"])
def test_the_controls_draw_the_scenes_they_claim(tmp_path, data_root, data):
    from asg.datasets import iter_frames
    from asg.scene import load_scene

    cfg = replace(TINY, data=data, scenes_per_round=2).with_trainer("asg", steps=1)
    card = harden(ATTFUSE, 1, tmp_path / data, config=cfg, log=_quiet)
    made = {p.stem: load_scene(p) for p in (tmp_path / data / "round-1" / "scenes").glob("*.yaml")}
    pool = {s.scene_id: s for s in iter_frames("normal", "train")}
    assert set(made) == set(pool) and card["rounds"][1]["data"]["scenes"] == 2
    for sid, scene in made.items():
        moved = [a.agent_id for a, b in zip(scene.agents, pool[sid].agents) if (a.x_m, a.y_m, a.yaw_rad) != (b.x_m, b.y_m, b.yaw_rad)]
        if data == "normal":
            assert scene.to_dict() == pool[sid].to_dict()
        else:
            assert moved and len(moved) <= 3  # one draw moving the heuristic's movers (m = 3)
            assert scene.collaborators == pool[sid].collaborators
            assert recheck(pool[sid], scene, "paper", 30.0).ok  # the space's plausibility level


def test_bad_rounds_and_weights_are_one_line(capsys, tmp_path, data_root):
    for argv, what in ((["--rounds", "0"], "--rounds"), (["--rounds", "x"], "--rounds"), (["--rounds", "\u0663"], "--rounds"),
                       (["--rounds", "\uff13"], "--rounds"),
                       (["--rounds", "1", "--weights", str(tmp_path / "missing.pt")], "no such file")):
        code, err = run(capsys, "harden", "--fusion", "attfuse", *argv, "--out", str(tmp_path / "o"))
        assert code == 2
        assert_one_line_error(err, what)
    foreign = tmp_path / "foreign.pt"
    foreign.write_bytes(b"not torch")
    code, err = run(capsys, "harden", "--fusion", "attfuse", "--rounds", "1", "--weights", str(foreign),
                    "--out", str(tmp_path / "o"))
    assert code == 2
    assert_one_line_error(err, "foreign.pt")
    config = tmp_path / "train.yaml"
    config.write_text("harden: {pool: [normal], scenes_per_round: 1}\n")
    too_many = run(capsys, "harden", "--fusion", "attfuse", "--rounds", "3", "--config", str(config),
                   "--out", str(tmp_path / "o"))
    assert too_many[0] == 2 and "fresh scenes" in too_many[1]


def test_the_pool_gives_every_scene_its_own_id(data_root):
    from asg.workflows.harden import _pool

    write_set(data_root, "other", {"train": ["n0", "n1", "x"]})  # ids that repeat the normal set's
    ids = [s.scene_id for s in _pool(replace(TINY, pool=("normal", "other")))]
    assert sorted(ids) == ["n0", "n0_2", "n1", "n1_2", "x"]


def _stopped_before_round_one_is_evaluated(out, cfg, monkeypatch) -> None:
    """Run one round of ``cfg`` into ``out`` and stop it (Ctrl-C) once its training is written."""
    import asg.workflows.harden as h

    real = h.evaluate_round

    def stop_in_round_one(model, *args, **kw):
        if "round-1" in str(model.path):
            raise KeyboardInterrupt
        return real(model, *args, **kw)

    with monkeypatch.context() as m:
        m.setattr(h, "evaluate_round", stop_in_round_one)
        with pytest.raises(KeyboardInterrupt):
            harden(ATTFUSE, 1, out, config=cfg, detector_factory=ORACLE, log=_quiet)


@pytest.mark.slow
def test_a_round_stopped_after_its_training_keeps_the_training_record(tmp_path, data_root, monkeypatch):
    _stopped_before_round_one_is_evaluated(tmp_path / "h", TINY, monkeypatch)
    card = harden(ATTFUSE, 1, tmp_path / "h", config=TINY, detector_factory=ORACLE, log=_quiet)
    assert card["rounds"][1]["trained"]["steps"] == 2


@pytest.mark.slow
def test_a_round_with_its_scenes_on_disk_resumes_at_its_training_without_attacking(tmp_path, data_root, monkeypatch):
    """A run folder copied without its attack folder (a committed one on an empty machine) resumes
    at the training checkpoint: the scenes and their record are read back, nothing is attacked."""
    import shutil

    import asg.workflows.harden as h

    out = tmp_path / "h"

    def stop_at_step_two(step, total, loss):
        if step == 2:  # step 1's checkpoint is written
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        harden(ATTFUSE, 1, out, config=TINY, detector_factory=ORACLE, log=_quiet, progress=stop_at_step_two)
    made = json.loads((out / "round-1" / "data.json").read_text())
    assert made["kind"] == "adversarial" and (out / "round-1" / "last.pt").is_file()
    shutil.rmtree(out / "round-1" / "attack")

    def no_attack(*_args, **_kw):
        raise AssertionError("the round's scenes were made again")

    monkeypatch.setattr(h, "round_data", no_attack)
    card = harden(ATTFUSE, 1, out, config=TINY, detector_factory=ORACLE, log=_quiet)
    assert card["rounds"][1]["data"] == made and card["rounds"][1]["trained"]["steps"] == 2


@pytest.mark.slow
def test_the_finetune_table_gains_a_row_per_round_of_each_kind_of_data(tmp_path, data_root):
    from asg.benchmarks.tables import TableRun, run_table

    write_set(data_root, "heuristic", {"test": ["h0"]})
    run = TableRun(out=tmp_path / "tables", scenes=1, detector_factory=ORACLE, harden_rounds=1,
                   harden_config=replace(TINY, reattack=True))
    rows = run_table("finetune", run, log=_quiet)["rows"]
    added = [r for r in rows if r["model"].startswith("harden-")]
    assert {(r["model"], r["set"]) for r in added} == {
        (f"harden-{d}-r1", s) for d in ("adversarial", "random", "normal")
        for s in ("normal-val", "challenging-val", "own-attack-val")}
    for data in ("adversarial", "random", "normal"):  # each row is its run's card
        card = json.loads((tmp_path / "tables" / "harden" / data / "card.json").read_text())
        assert card["data"] == data
        row = next(r for r in added if r["model"] == f"harden-{data}-r1" and r["set"] == "normal-val")
        assert row["ap"] == card["rounds"][1]["evaluation"]["normal-val"]["ap"]
    assert "harden-random-r1" in (tmp_path / "tables" / "finetune.md").read_text()
    # the paper's yardstick: the same runs (resumed, nothing run again), the rows from each card's per-frame AP
    per_frame = run_table("finetune", replace(run, ap_method="per-frame"), log=_quiet)["rows"]
    card = json.loads((tmp_path / "tables" / "harden" / "adversarial" / "card.json").read_text())
    row = next(r for r in per_frame if r["model"] == "harden-adversarial-r1" and r["set"] == "own-attack-val")
    assert row["ap"] == card["rounds"][1]["reattack"]["challenging"]["ap_per_frame"]
    assert (tmp_path / "tables" / "finetune.per-frame.md").is_file()


def test_harden_rounds_need_the_finetune_table(capsys):
    code, err = run(capsys, "bench", "paper", "--table", "main", "--harden-rounds", "1")
    assert code == 2
    assert_one_line_error(err, "--table finetune")


@pytest.mark.slow
def test_challenging_views_ego_trains_the_rounds_scenes_from_the_attacked_view_only(tmp_path, data_root):
    card = harden(ATTFUSE, 1, tmp_path / "ego", config=TINY.with_trainer("asg", challenging_views="ego"),
                  detector_factory=ORACLE, log=_quiet)
    trained = card["rounds"][1]["trained"]
    assert trained["examples"] == {"round-1": 1, "normal": 6}  # one view of the round's scene, all of normal's
    assert trained["challenging_views"] == "ego" and trained["views"] == "all"


def test_round_zeros_cache_is_not_reused_by_other_scoring_code(tmp_path, monkeypatch):
    """Round 0's cached evaluation is keyed by the weights and by what scores them: another detector
    config (or LiDAR code or preset) gives another folder."""
    import shutil

    import asg.workflows.harden as harden_mod
    from sumo_scenarios import paths

    weights = WEIGHTS_DIR / "attfuse.pt"
    before = _start_cache(weights)
    assert _start_cache(weights) == before  # stable
    configs = tmp_path / "configs"
    shutil.copytree(paths.configs_dir(), configs)
    (configs / "detectors" / "pointpillars.yaml").write_text(
        (configs / "detectors" / "pointpillars.yaml").read_text().replace("nms_iou: 0.15", "nms_iou: 0.2"))
    monkeypatch.setattr(paths, "configs_dir", lambda: configs)
    after = _start_cache(weights)
    assert after.parent == before.parent and after != before
    trainer = _trainer()
    start = trainer.model_at(weights)
    assert harden_mod._eval_cache(tmp_path, 1, start, trainer.start_cache(start)) == tmp_path / "round-1" / "eval"
    assert harden_mod._eval_cache(tmp_path, 0, start, trainer.start_cache(start)) == after


def test_round_zeros_reattack_is_scored_by_todays_code(data_root):
    """The original's re-attack is its own challenging set: round 0 takes that set's AP from the
    round's evaluation, not the figure the set's index recorded when it was built (by older code)."""
    from asg.workflows.harden import reattack_round

    index_path = data_root / "challenging-attfuse-val" / "index.json"
    index = json.loads(index_path.read_text())
    index["challenging"]["ap"] = {"0.3": 0.11, "0.5": 0.11, "0.7": 0.11}  # as scored by older meshes
    index_path.write_text(json.dumps(index))
    normal, attacked = {"0.3": 0.9, "0.5": 0.8, "0.7": 0.7}, {"0.3": 0.6, "0.5": 0.5, "0.7": 0.4}
    evaluation = {"normal-val": {"ap": normal, "ap_per_frame": normal, "frames": 1},
                  "challenging-attfuse-val": {"ap": attacked, "ap_per_frame": attacked, "frames": 1}}
    got = reattack_round(None, "challenging-attfuse-val", data_root / "unused", None, None, _quiet, evaluation)
    assert got == {"frames": 1, "normal": {"ap": normal, "ap_per_frame": normal},
                   "challenging": {"ap": attacked, "ap_per_frame": attacked}}
    assert not (data_root / "unused").exists()  # nothing attacked


@pytest.mark.slow
def test_round_zero_of_other_start_weights_is_attacked_itself(tmp_path, data_root):
    """From other ``--weights`` (a card's last round), round 0's re-attack attacks those weights;
    from the shipped ones it is the shipped model's own challenging set (nothing attacked)."""
    first = harden(ATTFUSE, 1, tmp_path / "first", config=replace(TINY, reattack=True), detector_factory=ORACLE,
                   log=_quiet)
    assert not (tmp_path / "first" / "round-0" / "reattack").exists()
    assert first["rounds"][0]["reattack"]["challenging"]["ap"] == first["rounds"][0]["evaluation"]["challenging-attfuse-val"]["ap"]
    # round 1's re-attack scenes scored by the weights it started from too, and the round's gap over them there
    from asg.evaluation import evaluate

    scenes = str(tmp_path / "first" / "round-1" / "reattack")
    start = evaluate(ATTFUSE, scenes, weights_file=str(WEIGHTS_DIR / "attfuse.pt"))
    attacked = evaluate(ATTFUSE, scenes, weights_file=str(tmp_path / "first" / first["rounds"][1]["weights"]))
    started = first["rounds"][1]["reattack"]["started_from"]
    assert started["frames"] == 1 and started["ap"] == pytest.approx(start["ap"])
    for y, key in (("global", "ap"), ("per-frame", "ap_per_frame")):
        assert started["gap"][y]["gap"] == pytest.approx(attacked[key]["0.7"] - start[key]["0.7"])
    card = harden(ATTFUSE, 1, tmp_path / "next", weights=tmp_path / "first" / "card.json",
                  config=replace(TINY, reattack=True, pool=("normal",)), detector_factory=ORACLE, log=_quiet)
    assert (tmp_path / "next" / "round-0" / "reattack" / "index.json").is_file()
    assert card["rounds"][0]["reattack"]["frames"] == 1


@pytest.mark.slow
@pytest.mark.parametrize("text, needle", [
    ("harden: null\n", "must be a mapping"), ("harden: [1, 2]\n", "must be a mapping"),
    ("harden: just text\n", "must be a mapping"), ("", "an empty file"), ("- a\n- b\n", "list"),
    ("a: &a [1, 1]\nb: &b [*a, *a]\nharden: [*b, *b]\n", "aliases"),
    ("harden: {seed: 1}\nharden: {seed: 2}\n", "written twice"),
    # the form before each trainer's settings had a part of their own
    ("harden: {pool: [normal], steps: 10, lr: 1.0e-3}\n", "lr, steps set asg's own trainer; they sit under the block's asg part"),
    ("harden: {pool: [normal]}\nopencood: {epochs: 2}\n", "sit in the harden block's opencood part now")])
def test_a_hostile_training_config_is_one_line_and_writes_nothing(capsys, tmp_path, data_root, text, needle):
    config = tmp_path / "train.yaml"
    config.write_text(text)
    code, err = run(capsys, "harden", "--fusion", "attfuse", "--rounds", "1", "--config", str(config),
                    "--out", str(tmp_path / "o"))
    assert code == 2
    assert_one_line_error(err, needle)
    assert not (tmp_path / "o").exists()


def test_yaml_12_floats_are_numbers_in_a_training_config(tmp_path):
    """lr: 1e-3 (no dot) is a number, as YAML 1.2 and every user read it, not the string YAML 1.1 made of it."""
    config = tmp_path / "train.yaml"
    config.write_text("harden: {pool: [normal], scenes_per_round: 4, asg: {lr: 1e-3}}\n")
    assert load_harden_config(config).asg.lr == pytest.approx(1e-3)


@pytest.mark.parametrize("extra, config_text, needle", [
    (["--space", "evil,../x"], None, "unknown perturbation space"),
    ([], "harden: {pool: [normal], scenes_per_round: 1, eval_sets: [nosuchset]}\n", "unknown set 'nosuchset'"),
    # a set to train on that does not exist, or has no train split, used to surface only at the
    # round's training, after its attack (hours at the paper's size)
    ([], "harden: {pool: [normal], scenes_per_round: 1, mix_with: [nosuchset]}\n", "mix_with: unknown data set 'nosuchset'"),
    ([], "harden: {pool: [normal], scenes_per_round: 1, mix_with: [heuristic]}\n", "'heuristic' has no train split"),
    ([], "harden: {pool: [nosuchset], scenes_per_round: 1}\n", "pool: unknown data set 'nosuchset'"),
    ([], "harden: {pool: [holdout], scenes_per_round: 1}\n", "'holdout' has no train split")])
def test_a_bad_space_or_set_is_refused_before_the_run_starts(capsys, tmp_path, data_root, extra, config_text, needle):
    """Refused up front: no round-0 evaluation, no run.json or card.json left behind (which made the
    corrected rerun a 'rerun with other settings')."""
    argv = ["harden", "--fusion", "attfuse", "--rounds", "1", "--out", str(tmp_path / "o"), *extra]
    if config_text:
        (tmp_path / "train.yaml").write_text(config_text)
        argv += ["--config", str(tmp_path / "train.yaml")]
    code, err = run(capsys, *argv)
    assert code == 2
    assert_one_line_error(err, needle)
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_a_round_worse_on_the_guard_set_is_not_kept(tmp_path, data_root, monkeypatch):
    """The guard: each round's AP@0.7 on a set no round trains on (holdout) is compared with the
    weights it started from, paired bootstrap over the frames, and recorded in the card; a round
    whose interval lies below zero is not kept: the next round starts from the weights before it,
    and the card (as --weights) gives them."""
    import asg.workflows.harden as harden_mod
    from asg.perception.weights_io import weights_path
    from test_tables import write_set

    write_set(data_root, "holdout", {"test": ["g0", "g1", "g2"]})
    cfg = replace(TINY, guard_set="holdout")
    out = tmp_path / "h"
    card = harden(ATTFUSE, 1, out, config=cfg, detector_factory=ORACLE, log=_quiet)
    g = card["rounds"][1]["guard"]  # the real guard, on the real matches of both weights
    assert g["set"] == "holdout" and g["frames"] == 3 and g["threshold"] == 0.7
    assert g["low"] <= g["gap"] <= g["high"] and g["kept"] == (g["high"] >= 0)
    assert (out / "round-1" / "eval" / "holdout.matches.npz").is_file()
    assert "holdout" in card["rounds"][0]["evaluation"] and "holdout" in card["rounds"][1]["evaluation"]

    # a round worse beyond its interval: not kept
    starts = []
    real_fit = shipped_trainer.fit_chunk
    monkeypatch.setattr(shipped_trainer, "fit_chunk", lambda name, start, *a, **k: (starts.append(start), real_fit(name, start, *a, **k))[1])
    monkeypatch.setattr(harden_mod, "guard", lambda before, after, guard_set: {
        "set": guard_set, "threshold": 0.7, "gap": -0.1, "low": -0.2, "high": -0.05, "frames": 3, "kept": False})
    lines = []
    out2 = tmp_path / "h2"
    card = harden(ATTFUSE, 2, out2, config=cfg, detector_factory=ORACLE, log=lines.append)
    start = weights_path("attfuse")
    assert [r["guard"]["kept"] for r in card["rounds"][1:]] == [False, False]
    assert starts == [start, start]  # round 2 trained from the start weights, not round 1's
    assert card["weights"] == str(start)
    assert _trainer().start(out2 / "card.json").path == start
    assert any("not kept" in l and "fell by 10.0 points" in l for l in lines)


@pytest.mark.slow
def test_a_round_resumed_on_an_empty_data_root_guards_against_its_start_evaluated_again(tmp_path, data_root, monkeypatch):
    """The start's evaluations are cached under the data root, not in the run folder: a run folder
    resumed after its training on another machine (its data sets rebuilt, that cache gone) evaluates
    the start on the guard set again instead of failing on the missing matches."""
    import shutil

    from asg.evaluation import start_evaluations_dir
    from test_tables import write_set

    write_set(data_root, "holdout", {"test": ["g0", "g1", "g2"]})
    cfg, out = replace(TINY, guard_set="holdout"), tmp_path / "h"
    _stopped_before_round_one_is_evaluated(out, cfg, monkeypatch)
    start_cache = start_evaluations_dir("x").parent
    assert any(start_cache.iterdir())
    shutil.rmtree(start_cache)
    card = harden(ATTFUSE, 1, out, config=cfg, detector_factory=ORACLE, log=_quiet)
    g = card["rounds"][1]["guard"]
    assert g["set"] == "holdout" and g["frames"] == 3 and g["kept"] == (g["high"] >= 0)


@pytest.mark.slow
def test_a_round_the_guard_drops_is_averaged_with_its_start_and_kept_if_that_passes(tmp_path, data_root, monkeypatch):
    """The guard's cure: a round worse on the guard set is averaged with the weights it started from
    (``guard_average`` of the round's); the average, evaluated and guarded in its turn, is what the
    round keeps (its weights, evaluation and re-attack), what it trained stays under "unaveraged",
    and the next round starts from the average."""
    import torch

    import asg.workflows.harden as harden_mod
    from asg.perception.weights_io import weights_path

    write_set(data_root, "holdout", {"test": ["g0", "g1"]})
    monkeypatch.setattr(harden_mod, "guard", lambda before, after, guard_set: {
        "set": guard_set, "threshold": 0.7, "gap": -0.1, "low": -0.2, "high": -0.05, "frames": 2,
        "kept": after.name == "eval-averaged"})
    starts = []
    real_fit = shipped_trainer.fit_chunk
    monkeypatch.setattr(shipped_trainer, "fit_chunk", lambda name, start, *a, **k: (starts.append(start), real_fit(name, start, *a, **k))[1])
    out = tmp_path / "h"
    card = harden(ATTFUSE, 2, out, config=replace(TINY, guard_set="holdout", guard_average=0.25),
                  detector_factory=ORACLE, log=_quiet)
    r1 = card["rounds"][1]
    assert r1["weights"] == "round-1/averaged.pt" and r1["guard"]["kept"] and r1["guard"]["averaged"] == 0.25
    assert r1["unaveraged"]["weights"] == "round-1/weights.pt" and not r1["unaveraged"]["guard"]["kept"]
    assert (out / "round-1" / "eval-averaged" / "holdout.json").is_file()
    start, trained, averaged = (torch.load(p, weights_only=True) for p in
                                (weights_path("attfuse"), out / "round-1" / "weights.pt", out / "round-1" / "averaged.pt"))
    k = next(k for k, v in start.items() if v.is_floating_point() and not torch.equal(v, trained[k]))
    assert torch.allclose(averaged[k], 0.75 * start[k] + 0.25 * trained[k], atol=1e-6)
    assert starts == [weights_path("attfuse"), out / "round-1" / "averaged.pt"]
    assert card["weights"] == "round-2/averaged.pt"


@pytest.mark.slow
def test_a_round_fits_a_point_stage_to_its_weights_and_to_their_average(tmp_path, data_root, monkeypatch):
    """With ``fit_stage`` a round fits a point stage to its trained weights, and to their average when
    the guard averages them, beside each file before it is evaluated (so every detector built from it,
    the guard's and the next round's attack included, refines with it); the card records each fit; a
    resumed round fits nothing again; a start given with a stage beside it is cached apart from the
    same weights without it."""
    import asg.workflows.harden as harden_mod
    import asg.workflows.harden_stage as harden_stage
    from asg.perception.weights_io import stage_path_of
    from asg.training.point_stage_fit import PointStageFitConfig

    write_set(data_root, "holdout", {"test": ["g0", "g1"]})
    monkeypatch.setattr(harden_stage, "load_point_stage_config",
                        lambda: PointStageFitConfig(dataset="normal", jitters=0, epochs=1, batch_size=16))
    monkeypatch.setattr(harden_mod, "guard", lambda before, after, guard_set: {
        "set": guard_set, "threshold": 0.7, "gap": -0.1, "low": -0.2, "high": -0.05, "frames": 2,
        "kept": after.name == "eval-averaged"})
    staged_when_scored = []
    real_evaluate = harden_mod.evaluate_round
    monkeypatch.setattr(harden_mod, "evaluate_round", lambda model, *a: (
        staged_when_scored.append((model.path.name, stage_path_of(model.path).is_file())), real_evaluate(model, *a))[1])
    out = tmp_path / "h"
    cfg = replace(TINY, guard_set="holdout").with_trainer("asg", fit_stage=True)
    card = harden(ATTFUSE, 1, out, config=cfg, detector_factory=ORACLE, log=_quiet)
    assert staged_when_scored == [("attfuse.pt", False), ("weights.pt", True), ("averaged.pt", True)]
    r1 = card["rounds"][1]
    assert r1["stage"]["weights"] == "averaged.stage.pt" and r1["unaveraged"]["stage"]["weights"] == "weights.stage.pt"
    assert r1["stage"]["dataset"] == "normal" and r1["stage"]["frames"] == 2
    assert not list(out.glob("round-1/stage-fit-*"))  # the fit's cache and checkpoint gone
    fitted = {p: p.stat().st_mtime_ns for p in out.glob("round-1/*.stage.pt")}
    assert len(fitted) == 2
    del card["rounds"][1]  # the round resumed from its files: nothing fitted again, the same records
    (out / "card.json").write_text(json.dumps(card))
    again = harden(ATTFUSE, 1, out, config=cfg, detector_factory=ORACLE, log=_quiet)
    assert {p: p.stat().st_mtime_ns for p in fitted} == fitted and again["rounds"][1]["stage"] == r1["stage"]
    # the round's weights with their stage, and the same file without it, are two starts
    alone = tmp_path / "alone" / "weights.pt"
    alone.parent.mkdir()
    alone.write_bytes((out / "round-1" / "weights.pt").read_bytes())
    assert _start_cache(out / "round-1" / "weights.pt") != _start_cache(alone)


def test_a_point_stage_data_set_that_cannot_be_had_is_refused_before_the_run_starts(tmp_path, data_root, monkeypatch):
    """The stage's data set is checked (and a known set built) before the folder is claimed, not
    found missing after a round's training."""
    import asg.workflows.harden_stage as harden_stage
    from asg.training.point_stage_fit import PointStageFitConfig

    monkeypatch.setattr(harden_stage, "load_point_stage_config", lambda: PointStageFitConfig(dataset="nosuchset"))
    with pytest.raises(InputError, match="nosuchset"):
        harden(ATTFUSE, 1, tmp_path / "h", config=TINY.with_trainer("asg", fit_stage=True), detector_factory=ORACLE, log=_quiet)
    assert not (tmp_path / "h").exists()


@pytest.mark.parametrize("share", [0.0, 1.0, 1.5, True, "half"])
def test_a_guard_average_outside_zero_to_one_is_refused(share):
    with pytest.raises(InputError, match="guard_average"):
        load_harden_config(guard_average=share)


def test_a_guard_set_that_is_trained_on_is_refused(tmp_path, data_root):
    with pytest.raises(InputError, match="guard_set 'normal' is trained on"):
        harden(ATTFUSE, 1, tmp_path / "h", config=replace(TINY, guard_set="normal"), detector_factory=ORACLE, log=_quiet)
    assert not (tmp_path / "h").exists()


def test_paired_gap_and_matches_on_disk(tmp_path):
    """The paired gap is AP(after) - AP(before) on the same frames, its interval around it; matches
    survive the trip to disk; a damaged file is one line."""
    import numpy as np

    from asg.objective.ap import ap_by_method_from_matches, frame_matches
    from asg.objective.paired import ApGap, load_matches, paired_ap_gap, save_matches

    rng = np.random.default_rng(0)
    gts = [np.array([[x, 0, 0, 4.0, 1.8, 1.5, 0] for x in rng.uniform(-40, 40, 4)]) for _ in range(20)]
    good = [frame_matches((g + [0.1, 0, 0, 0, 0, 0, 0], np.full(len(g), 0.9), g)) for g in gts]
    bad = [frame_matches((g[:2] + [0.5, 0.5, 0, 0, 0, 0, 0], np.full(2, 0.9), g)) for g in gts]
    gap = paired_ap_gap(good, bad, 0.7)
    ap = lambda m: ap_by_method_from_matches(m)["global"]["0.7"]
    assert gap.gap == pytest.approx(ap(bad) - ap(good)) and gap.high < 0 and gap.low <= gap.gap <= gap.high
    assert paired_ap_gap(good, good, 0.7).to_dict() == {"threshold": 0.7, "gap": 0.0, "low": 0.0, "high": 0.0, "frames": 20}
    # the guard's rule lives on the gap: worse only when the whole interval is below zero
    assert not gap.not_worse and paired_ap_gap(good, good, 0.7).not_worse and paired_ap_gap(bad, good, 0.7).not_worse
    record = gap.guard_record("holdout")
    assert record["kept"] is False and record["set"] == "holdout" and ApGap.from_dict(record) == gap.from_dict(gap.to_dict())
    save_matches(tmp_path / "m.npz", bad)
    back = load_matches(tmp_path / "m.npz")
    assert ap(back) == ap(bad) and len(back) == 20
    (tmp_path / "m.npz").write_bytes(b"garbage")
    with pytest.raises(InputError, match="damaged matches"):
        load_matches(tmp_path / "m.npz")
    # a member whose header declares 10^12 counts (np.load would allocate them before reading)
    import io
    import zipfile

    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (10 ** 12,)})
    with zipfile.ZipFile(tmp_path / "m.npz", "w") as archive:
        archive.writestr("counts@0.3.npy", header.getvalue())
    with pytest.raises(InputError, match="damaged matches"):
        load_matches(tmp_path / "m.npz")


def test_a_folder_claimed_before_a_setting_existed_resumes_and_other_settings_are_refused(tmp_path, data_root, monkeypatch):
    """A run record written before a setting was added (here the training LiDAR) lacks it: the
    same command resumes the folder (the setting's default reproduces what it did); a record that
    differs in a setting it has is still refused."""
    import asg.workflows.harden as hardening

    class Claimed(Exception):
        pass

    def stop(rounds):  # the first step after the claim
        raise Claimed

    monkeypatch.setattr(hardening, "upgraded_rounds", stop)
    out = tmp_path / "h"
    with pytest.raises(Claimed):
        harden(ATTFUSE, 1, out, config=TINY, detector_factory=ORACLE, log=_quiet)
    record = json.loads((out / "run.json").read_text())
    assert record["config"]["asg"]["lidar"] == "v2xp"
    del record["config"]["asg"]["lidar"]
    (out / "run.json").write_text(json.dumps(record))
    with pytest.raises(Claimed):
        harden(ATTFUSE, 1, out, config=TINY, detector_factory=ORACLE, log=_quiet)
    # a folder from before rounds fitted their own point stage did not: it resumes without, not with
    del record["config"]["asg"]["fit_stage"], record["point_stage"]
    (out / "run.json").write_text(json.dumps(record))
    with pytest.raises(Claimed):
        harden(ATTFUSE, 1, out, config=TINY, detector_factory=ORACLE, log=_quiet)
    with pytest.raises(InputError, match="fit_stage"):
        harden(ATTFUSE, 1, out, config=TINY.with_trainer("asg", fit_stage=True), detector_factory=ORACLE, log=_quiet)
    record["config"]["asg"]["lr"] *= 2
    (out / "run.json").write_text(json.dumps(record))
    with pytest.raises(InputError, match="config.asg.lr"):
        harden(ATTFUSE, 1, out, config=TINY, detector_factory=ORACLE, log=_quiet)


def test_start_weights_trained_for_another_lidar_are_named_in_one_line(tmp_path, data_root, monkeypatch):
    """Weights whose card records another LiDAR start a run with a line saying so (every round
    casts with the shipped preset); the shipped weights start without it."""
    import shutil

    import asg.workflows.harden as hardening

    class Evaluating(Exception):
        pass

    def stop(*args, **kwargs):  # round 0's evaluation: the first step after the start is named
        raise Evaluating

    monkeypatch.setattr(hardening, "evaluate_round", stop)
    other = tmp_path / "w" / "attfuse.pt"
    other.parent.mkdir()
    shutil.copy(WEIGHTS_DIR / "attfuse.pt", other)
    other.with_suffix(".json").write_text(json.dumps({"weights": "attfuse.pt", "lidar": "vlp16"}))
    for weights, out in ((other, "other"), (None, "shipped")):
        lines = []
        with pytest.raises(Evaluating):
            harden(ATTFUSE, 1, tmp_path / out, weights=weights, config=TINY, detector_factory=ORACLE, log=lines.append)
        named = [line for line in lines if "LiDAR" in line]
        assert named == ([f"{other}: trained for the 'vlp16' LiDAR; every round casts its frames with 'v2xp', so round 0 "
                          "scores them on another sensor and the rounds tune them to it"] if weights else [])


def test_a_refused_run_builds_no_point_stage_set(tmp_path, data_root, monkeypatch):
    """The point stage's data set (minutes of traffic simulation) is built only once the run's
    settings pass and its folder is claimed: too many rounds, or a folder of other settings, are
    refused without it."""
    import asg.datasets

    monkeypatch.setattr(asg.datasets, "build_dataset", lambda *a, **k: pytest.fail("the stage's set was built"))
    staged = TINY.with_trainer("asg", fit_stage=True)
    with pytest.raises(InputError, match="fresh scenes"):
        harden(ATTFUSE, 50, tmp_path / "a", config=staged, detector_factory=ORACLE, log=_quiet)
    out = tmp_path / "b"
    out.mkdir()
    (out / "run.json").write_text(json.dumps({"schema": 1, "fusion": "attfuse"}))
    (out / "card.json").write_text("{}")
    with pytest.raises(InputError, match="other settings"):
        harden(ATTFUSE, 1, out, config=staged, detector_factory=ORACLE, log=_quiet)


def test_a_run_folder_recording_the_flat_harden_block_resumes(tmp_path):
    """A run.json written while the harden block held asg's trainer's settings beside the loop's
    (and ``opencood_epochs``, read only by an OpenCOOD round) is today's settings for an asg model:
    the folder resumes; any other change is refused. So is an OpenCOOD run's, whose trainer recorded
    its epochs beside the config."""
    from dataclasses import asdict

    import asg.workflows.harden as harden_mod
    from asg.io.run_record import claim

    today = {"fusion": "attfuse", "start_weights": "w.pt", "start_sha256": "ab", "point_stage": None,
             "config": asdict(TINY), "space": None, "detector": None}
    config = json.loads(json.dumps(today["config"]))
    old = today | {"config": {**{k: v for k, v in config.items() if k not in ("asg", "opencood")}, **config["asg"],
                              "opencood_epochs": 1}}
    claim(tmp_path / "h", old)
    claim(tmp_path / "h", today, as_today=harden_mod._as_today)  # no refusal
    with pytest.raises(InputError, match="steps"):
        claim(tmp_path / "h", today | {"config": asdict(TINY.with_trainer("asg", steps=3))}, as_today=harden_mod._as_today)
    opencood = {"fusion": "opencood:m", "start": {"config": "ab"}, "config": asdict(TINY.with_trainer("opencood", epochs=2)),
                "space": None, "detector": None}
    old = opencood | {"config": old["config"], "opencood": {"epochs": 2}}
    claim(tmp_path / "o", old)
    claim(tmp_path / "o", opencood, as_today=harden_mod._as_today)  # no refusal
