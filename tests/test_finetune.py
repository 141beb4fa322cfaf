"""``asg finetune``: a few steps on a tiny challenging set change the weights, write a card with the
before/after table, resume after an interruption to the same weights, and never touch the shipped
weights; ``--weights`` on evaluate and generate refuses a missing, corrupt or foreign file."""
import hashlib
import json
from dataclasses import replace

import pytest
import torch

from asg.perception.targets import resolve_target
from asg.workflows.challenging import build_challenging
from asg.workflows.finetune import finetune
from asg.training.config import load_finetune_config
from asg.perception.weights_io import WEIGHTS_DIR
from sumo_scenarios.errors import InputError

from test_cli import assert_one_line_error, run
from test_robustness import _scene_dict
from test_tables import write_set

ATTFUSE = resolve_target("attfuse")

#: two steps of one example, mixed with the normal set only, evaluated on normal-val only
TINY = replace(load_finetune_config(), mix_with=("normal",), eval_sets=("normal-val",)).with_trainer(
    "asg", steps=2, batch_size=1, checkpoint_every=1)


@pytest.fixture
def data_root(tmp_path, monkeypatch):
    """ASG_DATA with a 'normal' set (train n0, n1; val n2) and its challenging sets made against
    the fake oracle (so that they build in seconds)."""
    root = tmp_path / "data"
    write_set(root, "normal", {"train": ["n0", "n1"], "val": ["n2"]})
    monkeypatch.setenv("ASG_DATA", str(root))
    for split in ("train", "val"):
        build_challenging(ATTFUSE, split, detector_factory="fakes:oracle_factory")
    return root


def _sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.slow
def test_finetune_trains_evaluates_and_keeps_the_shipped_weights(tmp_path, data_root):
    shipped = _sha(WEIGHTS_DIR / "attfuse.pt")
    out = tmp_path / "ft"
    card = finetune(ATTFUSE, "challenging-attfuse-train", out, config=TINY, stages=("train", "evaluate"),
                    log=lambda m: None)
    assert _sha(WEIGHTS_DIR / "attfuse.pt") == shipped
    before = torch.load(WEIGHTS_DIR / "attfuse.pt", weights_only=True)
    after = torch.load(out / "attfuse-ft.pt", weights_only=True)
    assert before.keys() == after.keys()
    assert any(not torch.equal(before[k], after[k]) for k in before if before[k].is_floating_point())
    written = json.loads((out / "attfuse-ft.json").read_text())
    assert written == card
    assert card["trained"]["steps"] == 2 and card["trained"]["examples"] == {"challenging-attfuse-train": 6, "normal": 6}
    assert set(card["evaluation"]) == {"normal-val", "challenging-attfuse-val"}
    for row in card["evaluation"].values():
        assert row["frames"] == 1 and set(row["before"]["ap"]) == set(row["after"]["ap"]) == {"0.3", "0.5", "0.7"}
        # the paper's yardstick beside ours (one frame: the same ranking, so the same AP)
        assert all(row[when]["ap_per_frame"] == row[when]["ap"] for when in ("before", "after"))
    assert not (out / "last.pt").exists()
    # a rerun finds everything done and changes nothing; other settings are refused
    assert finetune(ATTFUSE, "challenging-attfuse-train", out, config=TINY, stages=("train", "evaluate"),
                    log=lambda m: None) == card
    with pytest.raises(InputError, match="other settings"):
        finetune(ATTFUSE, "challenging-attfuse-train", out, config=TINY.with_trainer("asg", lr=0.001), log=lambda m: None)


@pytest.mark.slow
def test_an_interrupted_finetune_resumes_to_the_same_weights(tmp_path, data_root):
    whole = tmp_path / "whole"
    finetune(ATTFUSE, "challenging-attfuse-train", whole, config=TINY, stages=("train",), log=lambda m: None)

    def stop_after_first(step, total, loss):  # called after each step, before its checkpoint
        if step == 2:
            raise KeyboardInterrupt

    part = tmp_path / "part"
    with pytest.raises(KeyboardInterrupt):
        finetune(ATTFUSE, "challenging-attfuse-train", part, config=TINY, stages=("train",), log=lambda m: None,
                 progress=stop_after_first)
    assert (part / "last.pt").is_file() and not (part / "attfuse-ft.pt").exists()
    finetune(ATTFUSE, "challenging-attfuse-train", part, config=TINY, stages=("train",), log=lambda m: None)
    a = torch.load(whole / "attfuse-ft.pt", weights_only=True)
    b = torch.load(part / "attfuse-ft.pt", weights_only=True)
    assert all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.slow
def test_bad_weights_are_one_line(capsys, tmp_path, data_root):
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"not a torch file")
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    (scenes / "a.yaml").write_text(json.dumps(_scene_dict("a")))
    cases = [
        (["evaluate", "--fusion", "attfuse", "--set", "normal-val", "--weights", str(tmp_path / "missing.pt")], "not found"),
        (["evaluate", "--fusion", "attfuse", "--set", "normal-val", "--weights", str(corrupt)], "not a readable weights"),
        # Early Fusion's weights are not AttFuse's
        (["evaluate", "--fusion", "attfuse", "--set", "normal-val", "--weights", str(WEIGHTS_DIR / "early.pt")],
         "do not match"),
        (["generate", "--scenes", str(scenes), "--out", str(tmp_path / "g"), "--weights", str(corrupt)],
         "not a readable weights"),
        (["finetune", "--fusion", "attfuse", "--weights", str(corrupt)], "not a readable weights"),
        (["finetune", "--fusion", "attfuse", "--on", "challenging-late-train"], "is not built"),
        (["finetune", "--fusion", "attfuse", "--on", "challenging-../../x"], "not a safe name"),
        (["finetune", "--fusion", "attfuse", "--on", "normal"], "not a challenging set"),
        (["finetune", "--fusion", "attfuse", "--stages", "train,fly"], "--stages"),
        (["finetune", "--fusion", "attfuse", "--config", str(tmp_path / "none.yaml")], "file not found"),
    ]
    for argv, needle in cases:
        code, err = run(capsys, *argv)
        assert code == 2, argv
        assert_one_line_error(err, needle)
    assert not (tmp_path / "g").exists()


@pytest.mark.parametrize("bad", ["asg: {steps: 0}", "asg: {batch_size: -1}", "asg: {lr: -0.1}", "asg: {lr: 1.0e+30}",
                                 "asg: {weight_decay: -1}", "asg: {pct_start: 5}", "asg: {checkpoint_every: 0}",
                                 "asg: {div_factor: 0}", "asg: {seed: -3}", "mix_with: ['../..']",
                                 "asg: {augment: {rotate_deg: 200}}", "asg: {augment: {scale: 0.9}}",
                                 "asg: {augment: {spin: 1}}", "asg: {corner_loss: -1}", "asg: {corner_loss: .nan}",
                                 "asg: {challenging_share: 2}", "opencood: {epochs: 0}", "opencood: {rate: 1}"])
def test_bad_finetune_settings_are_refused_when_loaded(tmp_path, bad):
    from asg.training.config import load_finetune_config
    from asg.workflows.harden import load_harden_config

    key = bad.replace("{", "").split(":")[-2].strip()
    for block, load in (("finetune", load_finetune_config), ("harden", load_harden_config)):
        config = tmp_path / f"{block}.yaml"
        config.write_text(f"{block}:\n  {bad}\n")
        with pytest.raises(InputError, match=key):
            load(config)


def test_weights_with_nan_are_refused(tmp_path):
    from asg.perception.config import load_detector_config
    from asg.perception.model import AttFuse
    from asg.perception.weights_io import load_state

    state = torch.load(WEIGHTS_DIR / "attfuse.pt", weights_only=True)
    key = next(k for k, v in state.items() if v.is_floating_point())
    state[key] = torch.full_like(state[key], float("nan"))
    path = tmp_path / "diverged.pt"
    torch.save(state, path)
    with pytest.raises(InputError, match="NaN or infinite"):
        load_state(AttFuse(load_detector_config()), path)
