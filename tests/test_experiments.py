"""docs/experiments: each script still compiles, and every name it imports from the package exists
and is public (no leading underscore: a script uses what a user could, so a refactoring of the
internals does not break it silently)."""
import ast
import importlib.util
import json
from pathlib import Path

import pytest

SCRIPTS = sorted((Path(__file__).resolve().parent.parent / "docs" / "experiments").glob("*.py"))


def _script(name: str):
    """docs/experiments/NAME.py loaded as a module (its imports of sibling scripts need the folder on
    sys.path: a test that loads such a script prepends it)."""
    spec = importlib.util.spec_from_file_location(name, SCRIPTS[0].parent / f"{name}.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    return script


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_experiment_imports_resolve(script):
    tree = ast.parse(script.read_text(), str(script))
    compile(tree, str(script), "exec")
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in ("asg", "sumo_scenarios"):
            module = importlib.import_module(node.module)
            for alias in node.names:
                assert not alias.name.startswith("_"), f"{script.name}: imports the private {node.module}.{alias.name}"
                assert hasattr(module, alias.name) or importlib.util.find_spec(f"{node.module}.{alias.name}"), \
                    f"{script.name}: {node.module}.{alias.name} is gone"


def test_every_experiment_backs_a_statement_of_the_docs():
    """Each script and record of docs/experiments is named by a page outside the lab (the docs, the
    README, a docstring of the package): one whose figures no page cites any more is superseded and
    leaves the tree with its records."""
    import subprocess

    root = SCRIPTS[0].parent
    repo = root.parent.parent
    tracked = subprocess.run(["git", "ls-files", "docs/experiments"], cwd=repo, capture_output=True, text=True,
                             check=True).stdout.split()
    if not tracked:
        pytest.skip("not a git checkout")
    pages = [p for p in (*repo.joinpath("docs").rglob("*.md"), repo / "README.md", *repo.joinpath("asg").rglob("*.py"))
             if root not in p.parents]
    text = "\n".join(p.read_text(encoding="utf-8") for p in pages)
    lab_files = {Path(t).relative_to("docs/experiments").parts[0] for t in tracked}
    lab_files -= {"README.md", "removed.json"}
    uncited = sorted(n for n in lab_files if n not in text)
    assert not uncited, f"named by no page outside docs/experiments (superseded?): {uncited}"


def test_ap_bootstrap_builds_any_shipped_fusion_named_before_a_weights_path(monkeypatch):
    """``NAME=FUSION:weights.pt`` loads the weights into that shipped network (attfuse-wide too);
    ``NAME=weights.pt`` into AttFuse's; a bare name is the shipped model."""
    script = _script("ap_bootstrap")
    monkeypatch.setattr(script, "build_detector", lambda fusion, weights_file=None: (fusion, weights_file))
    built = script.build_models(["hw=attfuse-wide:run/round-1/weights.pt", "ft=run/weights.pt",
                                 "e=early:w.pt", "late"])
    assert built == {"hw": ("attfuse-wide", "run/round-1/weights.pt"), "ft": ("attfuse", "run/weights.pt"),
                     "e": ("early", "w.pt"), "late": ("late", None)}


def test_the_tables_index_lists_every_table_file():
    """docs/results/tables/README.md names every JSON of the folder (an index that cannot drift)."""
    root = Path(__file__).resolve().parent.parent / "docs" / "results" / "tables"
    index = (root / "README.md").read_text()
    missing = [str(f.relative_to(root)) for f in root.rglob("*.json") if f"]({f.relative_to(root)})" not in index]
    assert not missing, missing


def test_opencood_from_asg_folds_the_value_projection_exactly():
    """asg's fused first-stage map V x + b through the second stage's first convolution and norm,
    and through the first upsampling and its norm, equals OpenCOOD's unprojected x through the
    folded layers (away from the zero-padded border, where b has no neighbours to sum)."""
    import torch
    from torch import nn

    script = _script("opencood_from_asg")
    torch.manual_seed(0)
    c, c2, cu = 8, 12, 6
    v = nn.Linear(c, c)
    conv, up = nn.Conv2d(c, c2, 3, padding=1, bias=False), nn.ConvTranspose2d(c, cu, 1, bias=False)
    norm, up_norm = nn.BatchNorm2d(c2).eval(), nn.BatchNorm2d(cu).eval()
    for n in (norm, up_norm):
        n.running_mean.uniform_(-1, 1)
        n.running_var.uniform_(0.5, 2)
    state = {"backbone.blocks.1.1.weight": conv.weight.detach(), "backbone.blocks.1.2.running_mean": norm.running_mean.clone(),
             "backbone.deblocks.0.0.weight": up.weight.detach(), "backbone.deblocks.0.1.running_mean": up_norm.running_mean.clone()}
    script.fold_value_projection({"fusion.v.weight": v.weight.detach(), "fusion.v.bias": v.bias.detach()}, state)
    x = torch.randn(1, c, 9, 9)
    projected = v(x.permute(0, 2, 3, 1)).permute(0, 3, 1, 2)
    with torch.no_grad():
        asg_stage, asg_up = norm(conv(projected)), up_norm(up(projected))
        conv.weight.copy_(state["backbone.blocks.1.1.weight"])
        up.weight.copy_(state["backbone.deblocks.0.0.weight"])
        norm.running_mean.copy_(state["backbone.blocks.1.2.running_mean"])
        up_norm.running_mean.copy_(state["backbone.deblocks.0.1.running_mean"])
        oc_stage, oc_up = norm(conv(x)), up_norm(up(x))
    assert torch.allclose(asg_stage[..., 1:-1, 1:-1], oc_stage[..., 1:-1, 1:-1], atol=1e-5)
    assert torch.allclose(asg_up, oc_up, atol=1e-5)
    assert not torch.allclose(asg_stage[..., 0, :], oc_stage[..., 0, :], atol=1e-3)  # the border differs


def test_opencood_from_asg_gives_opencood_asgs_anchors(tmp_path):
    """The folder's config makes OpenCOOD's post-processor lay out asg's anchors: the same centres,
    sizes (OpenCOOD's h, w, l order) and yaws, four a cell in asg's order."""
    import numpy as np
    pytest.importorskip("opencood")
    from asg.perception.boxes import make_anchors
    from asg.perception.config import load_detector_config
    from asg.perception.opencood.folder import read_hypes
    from asg.perception.opencood.runtime import module

    script = _script("opencood_from_asg")
    script.write_config(tmp_path, tmp_path, tmp_path, "pointpillars-wide.yaml", epochs=1, lr=5e-4)
    hypes = read_hypes(tmp_path)
    post = module("data_utils.post_processor").build_postprocessor(hypes["postprocess"], train=False)
    theirs = post.generate_anchor_box().reshape(-1, 7)  # x, y, z, h, w, l, yaw
    ours = make_anchors(load_detector_config(SCRIPTS[0].parents[2] / "configs" / "detectors" / "pointpillars-wide.yaml"))
    assert theirs.shape == ours.shape == (96 * 96 * 4, 7)
    assert np.allclose(theirs[:, list(script.ORDER)], ours, atol=1e-9)


def test_opencood_train_backbone_from_keeps_the_sources_grid(tmp_path):
    """``opencood_train.py --backbone-from``: the new fusion's folder takes the trained folder's grid,
    range and anchors (its stock ones would differ), its own model from its stock hypes, and every
    pillar-net and backbone tensor of the source, the fusion's own layers left as initialised."""
    import torch
    import yaml
    pytest.importorskip("opencood")
    from opencood_models import make_model_dir

    from asg.perception.opencood.folder import read_hypes
    from asg.perception.opencood.runtime import module

    script = _script("opencood_train")
    source = make_model_dir(tmp_path / "att", "intermediate")
    raw = yaml.safe_load((source / "config.yaml").read_text())
    raw["preprocess"]["args"]["voxel_size"] = raw["model"]["args"]["voxel_size"] = [0.5, 0.5, 4]  # not F-Cooper's stock 0.4
    (source / "config.yaml").write_text(yaml.safe_dump(raw))
    new = tmp_path / "fc"
    script.config_from_source(new, "fcooper", source, tmp_path / "train", tmp_path / "val", epochs=2, lr=None)
    script.seed_backbone(new, source, epochs=2)
    hypes = read_hypes(new)
    assert hypes["model"]["core_method"] == "point_pillar_fcooper" and "shrink_header" in hypes["model"]["args"]
    assert hypes["preprocess"]["args"]["voxel_size"] == [0.5, 0.5, 4]
    assert hypes["postprocess"]["anchor_args"]["cav_lidar_range"] == raw["postprocess"]["anchor_args"]["cav_lidar_range"]
    assert hypes["train_params"]["epoches"] == 3 and hypes["optimizer"]["lr"] == 0.001  # epoch 1 given, F-Cooper's rate
    seeded = torch.load(new / "net_epoch1.pth", weights_only=True)
    given = torch.load(source / "net_epoch1.pth", weights_only=True)
    own = module("tools.train_utils").create_model(hypes).state_dict()
    shared = [k for k in own if k.startswith(("pillar_vfe.", "backbone.")) and given[k].shape == own[k].shape]
    assert shared and all(torch.equal(seeded[k], given[k]) for k in shared)
    assert not any(k.startswith("shrink_conv.") for k in seeded)


def test_opencood_rounds_puts_the_attack_beside_its_control_with_a_paired_interval(tmp_path):
    """opencood_rounds.py: each round's after and gap from its card, and the first round over the
    other by the frames both cached: a round that finds every vehicle against one that finds none
    is ahead by the whole AP, interval clear of zero."""
    import json

    import numpy as np

    from asg.objective.ap import REPORTED_THRESHOLDS
    from asg.objective.paired import save_matches

    script = _script("opencood_rounds")
    ap = {"ap": {"0.7": 0.5}, "ap_per_frame": {"0.7": 0.4}}
    gap = {"threshold": 0.7, "gap": 0.1, "low": 0.0, "high": 0.2, "frames": 20}
    for data, hit in (("adversarial", True), ("random", False)):
        out = tmp_path / data
        (out / "eval").mkdir(parents=True)
        frames = [{t: (np.array([0.9]), np.array([hit]), 1) for t in REPORTED_THRESHOLDS} for _ in range(20)]
        save_matches(out / "eval" / "after-normal-val.matches.npz", frames)
        row = {"frames": 20, "before": ap, "after": ap, "gap": {"global": gap, "per-frame": gap}}
        card = {"data": data, "epochs": 3, "evaluation": {"normal-val": row},
                "reattack": {"frames": 20, "before": {"normal": ap, "challenging": ap},
                             "after": {"normal": ap, "challenging": ap}}}
        (out / "card.json").write_text(json.dumps(card))
    result = script.compare([tmp_path / "adversarial", tmp_path / "random"])
    ahead = result["sets"]["normal-val"]["first_over"]["random"]
    assert ahead["global"]["gap"] == pytest.approx(1.0) and ahead["per-frame"]["low"] == pytest.approx(1.0)
    assert set(result["reattack"]) == {"adversarial", "random"}
    table = script.markdown(result)
    assert "adversarial - random" in table and "+100.0 [+100.0, +100.0]" in table and "re-attack" in table


def test_harden_curve_measures_the_bases_it_is_given_and_keeps_the_others(monkeypatch, tmp_path):
    """A base measured again replaces its own entry in OUT.json; one not given is kept as it was."""
    monkeypatch.syspath_prepend(str(SCRIPTS[0].parent))
    script = _script("harden_curve")
    out = tmp_path / "curve.json"
    out.write_text('{"bases": [{"label": "weak", "old": true}, {"label": "shipped", "old": true}]}')
    monkeypatch.setattr(script, "parse_base", lambda spec: {"label": spec.partition("=")[0]})
    monkeypatch.setattr(script, "measure", lambda base, work: {"label": base["label"], "old": False})
    monkeypatch.setattr(script, "markdown", lambda result: "")
    script.main(str(tmp_path / "work"), str(out), "shipped=attfuse,s.pt,adv,rand", "wide=attfuse-wide,w.pt,-,-")
    bases = json.loads(out.read_text())["bases"]
    assert bases == [{"label": "weak", "old": True}, {"label": "shipped", "old": False},
                     {"label": "wide", "old": False}]


def test_harden_curve_puts_the_attack_beside_each_control_it_was_given():
    """A base's row names every model's gain, then the attack over each control of the same kind
    (random, and plain normal data when its run was given), each with its interval."""
    script = _script("harden_curve")
    gap = {"gap": 0.01, "low": -0.02, "high": 0.03}
    row = {"start": 0.5, "adversarial": gap, "random": gap, "normal": gap,
           "adversarial_over_random": gap, "adversarial_over_normal": {"gap": 0.02, "low": 0.01, "high": 0.04}}
    cells = script.table_rows("vlp16", "normal-val", row)[0].split(" | ")
    assert cells[2:6] == ["50.0", "adversarial: +1.0 [-2.0, +3.0]", "random: +1.0 [-2.0, +3.0]", "normal: +1.0 [-2.0, +3.0]"]
    assert cells[6:] == ["adversarial - random: +1.0 [-2.0, +3.0]", "adversarial - normal: +2.0 [+1.0, +4.0] |"]


def test_harden_curve_takes_the_starts_own_attack_from_the_attack_run(monkeypatch, tmp_path):
    """The start's own attack is the attack run's round 0, though a control's run holds a copy too;
    a round the guard averaged is measured by both its weights; its re-attacks are the run's
    round-1/reattack (the averaged weights) and the one reattack_trained.py built (the trained)."""
    monkeypatch.syspath_prepend(str(SCRIPTS[0].parent))
    script = _script("harden_curve")
    start = tmp_path / "start.pt"
    start.write_bytes(b"w")

    def run_folder(name: str, averaged: bool, attacks: list[str]) -> Path:
        run = tmp_path / name
        (run / "round-1").mkdir(parents=True)
        kept = "round-1/averaged.pt" if averaged else "round-1/weights.pt"
        (run / "card.json").write_text(json.dumps({"rounds": [{"round": 0}, {"round": 1, "weights": kept}]}))
        for f in {"round-1/weights.pt", kept}:
            (run / f).write_bytes(b"w")
        for folder in attacks:
            (run / folder).mkdir(parents=True)
            (run / folder / "index.json").write_text("{}")
        return run

    adv = run_folder("adv", True, ["round-0/reattack", "round-1/reattack", "round-1/reattack-trained"])
    rand = run_folder("rand", False, ["round-0/reattack", "round-1/reattack"])
    base = script.parse_base(f"shipped=attfuse,{start},{adv},{rand}")
    assert base["reattacks"] == {"adversarial-averaged": str(adv / "round-1" / "reattack"),
                                 "adversarial": str(adv / "round-1" / "reattack-trained"),
                                 "random": str(rand / "round-1" / "reattack")}
    assert base["own_attack"] == str(adv / "round-0" / "reattack")
    assert set(base["models"]) == {"start", "adversarial", "adversarial-averaged", "random"}


def test_reattack_trained_refuses_a_round_that_kept_its_weights_or_has_not_trained(monkeypatch, tmp_path):
    """reattack_trained.py attacks nothing unless round 1 has trained, from the start the run names,
    and its guard did not keep the trained weights (whose re-attack the run made already)."""
    monkeypatch.syspath_prepend(str(SCRIPTS[0].parent))
    script = _script("reattack_trained")
    monkeypatch.setattr(script, "build_challenging", lambda *a, **k: pytest.fail("attacked"))
    run = tmp_path / "run"
    (run / "round-1").mkdir(parents=True)
    start = tmp_path / "start.pt"
    start.write_bytes(b"w")
    settings = {"fusion": "attfuse", "start_weights": str(start), "start_sha256": script.file_digest(start),
                "config": {"data": "adversarial"}}
    (run / "run.json").write_text(json.dumps(settings))
    (run / "card.json").write_text(json.dumps({"rounds": [{"round": 0}, {"round": 1, "weights": "round-1/weights.pt"}]}))
    with pytest.raises(SystemExit, match="has not trained"):
        script.main(str(run), str(tmp_path / "work"))
    (run / "round-1" / "weights.pt").write_bytes(b"t")
    (run / "round-1" / "trained.json").write_text("{}")
    with pytest.raises(SystemExit, match="kept its trained weights"):
        script.main(str(run), str(tmp_path / "work"))
    start.write_bytes(b"other")
    with pytest.raises(SystemExit, match="not the weights"):
        script.main(str(run), str(tmp_path / "work"))


def test_sensor_base_scores_every_lidar_on_the_whole_set(monkeypatch, tmp_path):
    """sensor_base.py: the base is scored on every frame of the set with each LiDAR, the second
    pass too (the set is read once: a one-pass iterator once left the shipped LiDAR's pass empty)."""
    monkeypatch.syspath_prepend(str(SCRIPTS[0].parent))
    script = _script("sensor_base")
    monkeypatch.setattr(script, "AttFuseDetector", lambda weights_file: weights_file)
    monkeypatch.setattr(script, "scenes_of", lambda name: iter(["a", "b", "c"]))
    ap = {"0.3": 0.5, "0.5": 0.4, "0.7": 0.3}
    monkeypatch.setattr(script, "evaluate_detector",
                        lambda detector, scenes, lidar: {"ap": ap, "ap_per_frame": ap, "frames": len(list(scenes))})
    result = script.score(tmp_path, "vlp16")
    assert result["vlp16"]["frames"] == result["v2xp"]["frames"] == 3


@pytest.mark.numeric
def test_a_half_precision_checkpoint_resumes_the_chunk_close_to_the_uninterrupted_weights(sumo_log, tmp_path):
    """half_checkpoint.py: the committed form of a run's checkpoint is under half its size' float32
    bytes per tensor, and the same training resumes from it to the end of the chunk, within float16's
    rounding of the uninterrupted run (not to its bits)."""
    import torch

    from asg.training.config import TrainConfig
    from test_train import Crash, run, tiny_dataset

    half = _script("half_checkpoint")
    data = tiny_dataset(sumo_log, tmp_path / "tiny")
    tcfg = TrainConfig(dataset=str(data), steps=4, batch_size=1, lr=1e-3, schedule="onecycle", seed=5, checkpoint_every=2)
    whole = torch.load(run(tmp_path, "whole", tcfg), weights_only=True)
    with pytest.raises(Crash):
        run(tmp_path, "split", tcfg, crash_at=3)
    ckpt = tmp_path / "run-split" / "last.pt"
    half.half_checkpoint(ckpt, tmp_path / "half.pt")
    state = torch.load(tmp_path / "half.pt", weights_only=True)
    assert {v.dtype for v in state["model"].values() if v.is_floating_point()} == {torch.float16}
    assert state["step"] == 2 and (tmp_path / "half.pt").stat().st_size < 0.6 * ckpt.stat().st_size
    (tmp_path / "half.pt").replace(ckpt)
    resumed = torch.load(run(tmp_path, "split", tcfg), weights_only=True)
    assert resumed.keys() == whole.keys()
    assert {v.dtype for v in resumed.values() if v.is_floating_point()} == {torch.float32}
    worst = max(float((resumed[k] - whole[k]).abs().max()) for k in whole if whole[k].is_floating_point())
    assert 0 < worst < 5e-2


def test_stage_refit_fits_a_stage_to_each_weights_once_and_never_keeps_another_weights_stage(monkeypatch, tmp_path):
    """stage_refit.py: the weights copied beside a stage fitted to them; the same weights again fit
    nothing; other weights under the same label drop the old stage and fit their own."""
    import asg.training.point_stage_fit as point_stage_fit

    monkeypatch.syspath_prepend(str(SCRIPTS[0].parent))
    script = _script("stage_refit")
    fits = []

    def fake_fit(fusion, weights, run_dir, log, fit_config=None):
        fits.append(weights.read_bytes())
        stage = weights.with_name("weights.stage.pt")
        stage.write_bytes(b"stage of " + weights.read_bytes())
        return stage, {"weights": stage.name}

    monkeypatch.setattr(point_stage_fit, "fit_stage_beside", fake_fit)
    first, second = tmp_path / "a.pt", tmp_path / "b.pt"
    first.write_bytes(b"A")
    second.write_bytes(b"B")
    copy, record = script.refit("attfuse", "h", first, tmp_path / "work")
    assert copy.read_bytes() == b"A" and record == {"weights": "weights.stage.pt"}
    script.refit("attfuse", "h", first, tmp_path / "work")
    assert fits == [b"A"]
    copy, _ = script.refit("attfuse", "h", second, tmp_path / "work")
    assert fits == [b"A", b"B"] and copy.with_name("weights.stage.pt").read_bytes() == b"stage of B"


def test_ship_staged_refuses_weights_that_are_not_the_hardened_ones_the_card_averaged(monkeypatch, tmp_path):
    monkeypatch.syspath_prepend(str(SCRIPTS[0].parent))
    script = _script("ship_staged")
    weights_dir = tmp_path / "shipped"
    weights_dir.mkdir()
    (weights_dir / "attfuse-ft.json").write_text(json.dumps({"averaged": {"hardened_sha256": "0" * 64}}))
    monkeypatch.setattr(script, "WEIGHTS_DIR", weights_dir)
    (tmp_path / "work" / "h2").mkdir(parents=True)
    (tmp_path / "work" / "h2" / "weights.pt").write_bytes(b"other")
    with pytest.raises(SystemExit, match="not the hardened weights"):
        script.main(str(tmp_path / "work"), "h2", "holdout")
