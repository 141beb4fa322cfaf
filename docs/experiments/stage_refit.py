"""A point stage fitted to hardened weights: does it take back what a round loses on an unseen town
and give the round an edge under a new attack?

Every shipped model refines its boxes with the single-agent detector's point stage
(``single.stage.pt``), and `asg harden` fine-tunes the detector but not the stage. For each
``LABEL=WEIGHTS`` this copies the weights to ``WORK_DIR/LABEL/weights.pt``, fits a stage to them
there (asg.workflows.harden_stage.stage_of_round, as `asg harden` fits a round's: train.yaml's
``point_stage`` block, on its data set's train split), and scores on each SET the
start (its shipped stage), the weights with the shipped stage ("LABEL") and with their own
("LABEL+stage"): AP@0.7 by both yardsticks and each gap over the start with its 95 % paired
interval (asg.objective.paired, the code of `asg harden`'s guard). With ``--reattack``, each
``LABEL+stage`` is attacked anew on normal-val (asg.workflows.challenging.build_challenging, the
code of `asg harden`'s re-attack) into ``WORK_DIR/LABEL/reattack`` and paired with the start on its
own attack (challenging-FUSION-val) by harden_curve.py's code, by source scene.

Resumable: the fit checkpoints, the evaluations are cached in WORK_DIR (weight_average.py's cache).

usage: ASG_DATA=... .venv/bin/python docs/experiments/stage_refit.py FUSION START WORK_DIR OUT.json
           SET[,SET] LABEL=WEIGHTS [LABEL=WEIGHTS ...] [--reattack]
"""
from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

from harden_curve import gaps, measured

from asg.datasets import scenes_of
from asg.executors import build_executor
from asg.generator.run import file_digest
from asg.objective.ap import Yardstick
from asg.perception.weights_io import stage_path_of
from asg.perception.targets import resolve_target
from asg.training.point_stage_fit import load_point_stage_config
from asg.workflows.challenging import build_challenging
from asg.workflows.harden_stage import stage_of_round


def refit(fusion: str, label: str, weights: Path, work: Path) -> tuple[Path, dict]:
    """``weights`` copied to WORK/LABEL/weights.pt with a stage of their own beside them, fitted
    (once) as `asg harden` fits a round's (its record in WORK/LABEL/weights.stage.json)."""
    folder = work / label
    folder.mkdir(parents=True, exist_ok=True)
    copy = folder / "weights.pt"
    if not copy.is_file() or file_digest(copy) != file_digest(weights):
        shutil.copyfile(weights, copy)
        stage_path_of(copy).unlink(missing_ok=True)
    return copy, stage_of_round(resolve_target(fusion), copy, folder, load_point_stage_config(), print)


def main(fusion: str, start: str, work_dir: str, out: str, sets: str, *rest: str) -> None:
    models = dict(m.split("=", 1) for m in rest if "=" in m)
    work = Path(work_dir)
    result = {"fusion": fusion, "start": {"path": start, "sha256": file_digest(Path(start))},
              "models": {}, "sets": {}}
    refitted = {}
    for label, path in models.items():
        refitted[label], stage = refit(fusion, label, Path(path), work)
        result["models"][label] = {"path": path, "sha256": file_digest(Path(path)), "stage": stage}
    for set_name in sets.split(","):
        runs = {"start": measured(fusion, start, set_name, set_name, work / "cache" / "start")}
        for label, path in models.items():
            runs[label] = measured(fusion, path, set_name, set_name, work / "cache" / label)
            runs[f"{label}+stage"] = measured(fusion, str(refitted[label]), set_name, set_name,
                                              work / "cache" / f"{label}+stage")
        result["sets"][set_name] = {"frames": runs["start"][0]["frames"], **gaps(runs, "start")}
        print(set_name, json.dumps({y: {k: v if isinstance(v, float) else {"after": v.get("after"), "gap": v.get("gap"),
                                                                           "low": v.get("low"), "high": v.get("high")}
                                        for k, v in row.items()} for y, row in result["sets"][set_name].items()
                                    if y != "frames"}), flush=True)
        Path(out).write_text(json.dumps(result, indent=1))
    if "--reattack" in rest:
        own = f"challenging-{fusion}-val"
        result["reattack"] = {}
        for label in models:
            attacked = work / label / "reattack"
            with build_executor("local", 2) as executor:
                build_challenging(resolve_target(fusion), "val", executor, weights_file=str(refitted[label]), out=attacked)
            if [s.scene_id for s in scenes_of(own)] != [s.scene_id for s in scenes_of(str(attacked))]:
                raise SystemExit(f"{own} and {attacked} were not attacked from the same normal-val scenes in order")
            pair = {"start": measured(fusion, start, "own-attack", own, work / "cache" / "start"),
                    f"{label}+stage": measured(fusion, str(refitted[label]), "reattack", str(attacked),
                                               work / "cache" / f"{label}+stage")}
            result["reattack"][label] = {"sets": {"start": own, label: str(attacked)}, **gaps(pair, "start")}
            for y in Yardstick:
                row = result["reattack"][label][y.value]
                print(f"re-attack {label}+stage {y.value}: start on its own attack {100 * row['start']:.1f}, "
                      f"{label}+stage on its new attack {100 * row[f'{label}+stage']['after']:.1f}, gap "
                      f"{100 * row[f'{label}+stage']['gap']:+.1f} [{100 * row[f'{label}+stage']['low']:+.1f}, "
                      f"{100 * row[f'{label}+stage']['high']:+.1f}]", flush=True)
            Path(out).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    if len(sys.argv) < 7:
        raise SystemExit(__doc__)
    main(*sys.argv[1:])
