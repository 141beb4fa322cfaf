"""Challenging data sets: ``asg dataset build challenging --fusion NAME --split train|val``.

The paper's protocol (the generator's defaults: ACS-A + BO, budget 50, m = 3; ``configs/generate.yaml``)
run once over a split of the ``normal`` set against a shipped model, stored as a data set that
every table reuses and that ``asg evaluate --set challenging-NAME-SPLIT`` reads like any other::

    DATA/challenging-NAME-SPLIT/frames.jsonl.gz   the final scenes (collaborators after ACS), one per line
    DATA/challenging-NAME-SPLIT/index.json        {"name", "frames", "splits": {SPLIT: ids}, "source": {...}}
    DATA/challenging-NAME-SPLIT/run/              the generator's run folder (resumable; no clouds or pictures)

A stopped build resumes with the same command (the run folder keeps every finished scene).
"""
from __future__ import annotations

import gzip
import json
from pathlib import Path

from sumo_scenarios.atomic import atomic_path, write_text_atomic
from sumo_scenarios.errors import InputError

from ..datasets import challenging_scenes, data_root, iter_frames  # noqa: F401  (challenging_scenes: this module's API)
from ..objective.ap import DEFAULT_AP_METHOD
from ..objective.pooled import pair_json
from ..perception.targets import Target
from ..schemas import SchemaFile, stamped
from ..scene import load_scene

#: the split of the normal set each challenging set is generated from
SPLITS = ("train", "val")
#: the seed of the generator for every challenging set
SEED = 1


def set_name(target: Target, split: str) -> str:
    """``challenging-LABEL-SPLIT``, LABEL the target's (a shipped model's name; an OpenCOOD model
    folder's name and digest)."""
    return f"challenging-{target.label}-{split}"


def build_challenging(target: Target, split: str, executor=None, count: int | None = None,
                      detector_factory: str | None = None, on_scene=None, weights_file: str | None = None,
                      out: Path | None = None, log=print) -> Path:
    """Generate (or resume) the challenging set of ``target`` on the ``split`` of ``normal``;
    ``count``: only the first scenes (a quick build); ``weights_file``: attack these weights of
    ``target`` instead of the shipped ones (then give ``out``: the set is not the shipped model's).
    Returns the data set's folder (``out``, default DATA/challenging-FUSION-SPLIT). A set attacked
    against shipped weights that have changed since is generated again."""
    from ..generator.run import SceneSource, made_with_other_shipped_weights, open_run
    from ..generator.run_folder import aggregate_pooled, load_done
    from ..generator.stages import Stage
    from ..generator.config import load_generate_config

    if split not in SPLITS:
        raise InputError(f"--split must be one of {', '.join(SPLITS)}, got {split!r}")
    if detector_factory is None:
        target.check()
    if weights_file and out is None:
        raise InputError("a challenging set of other weights needs its own folder (out)")
    cfg = load_generate_config(fusion=target.name, weights=None if weights_file is None else str(weights_file))
    source = SceneSource(scenes=Path("normal-val" if split == "val" else "normal"))
    out = Path(out) if out is not None else data_root() / set_name(target, split)
    run_dir = out / "run"

    def wanted(every: list) -> list:
        """The first ``count`` scenes, and every scene an earlier, larger build finished (kept)."""
        ids = {s.scene_id for s in (every[:count] if count else every)} | set(load_done(run_dir))
        return [s for s in every if s.scene_id in ids]

    changed = made_with_other_shipped_weights(run_dir, cfg)
    if changed:
        log(f"{out.name}: attacked against shipped weights '{changed}' that have changed since; generating it again")
        (out / "index.json").unlink(missing_ok=True)  # not a built set until the new attack is done
    # the split's size, not --count, is the setting: a later build with a larger --count resumes
    run = open_run(cfg, run_dir, source=source, pick=wanted, record={"detector": detector_factory}, seed=SEED,
                   force=changed is not None).run(
        detector_factory=detector_factory, executor=executor, on_scene=on_scene, artifacts=False)
    ids = [e["scene_id"] for e in run.summary["scenes"]]
    with atomic_path(out / "frames.jsonl.gz") as tmp:
        with gzip.open(tmp, "wt", encoding="utf-8") as fh:
            for scene_id in ids:
                final = load_scene(run_dir / "scenes" / scene_id / "final.yaml")
                fh.write(json.dumps(final.to_dict(), separators=(",", ":")) + "\n")
    agg = run.summary["aggregate"]
    # the attacked detector: the shipped FUSION, its WEIGHTS, or a detector factory's target
    attacked = {"fusion": target.name, "weights": cfg.weights, **({"detector": detector_factory} if detector_factory else {})}
    source = {"set": "normal", "split": split, **attacked, "seed": SEED, "skipped": [sid for sid, _ in run.skipped]}
    pooled = {"normal": aggregate_pooled(agg, Stage.NORMAL), "challenging": aggregate_pooled(agg, Stage.FINAL)}
    index = stamped(SchemaFile.INDEX, {"name": out.name, "frames": len(ids), "splits": {split: ids}, "source": source,
                                       **pair_json(pooled)})
    write_text_atomic(out / "index.json", json.dumps(index, indent=1))
    return out


def own_val_set(target: Target, executor=None, log=print) -> str:
    """The name of ``target``'s challenging val set (normal-val attacked against the shipped
    model), built first if missing: the fixed yardstick of fine-tuning and hardening."""
    own_val = set_name(target, "val")
    if not (data_root() / own_val / "index.json").is_file():
        log(f"building {own_val} (the original model attacked on normal-val) ...")
        build_challenging(target, "val", executor=executor)
    return own_val


def first_scenes_ap(out: Path, count: int | None, ap_method: str = DEFAULT_AP_METHOD) -> dict[str, dict[str, float]]:
    """Pooled AP (normal and challenging) over the first ``count`` scenes of a built challenging
    set (all when None), from the detections its run folder stored, ranked by ``ap_method``
    (asg.objective.ap.AP_METHODS; per-frame in the set's scene order)."""
    from ..generator.run_folder import load_detections, pooled_ap
    from ..generator.stages import Stage

    index = json.loads((out / "index.json").read_text())
    ids = [i for ids in index["splits"].values() for i in ids][:count]
    per_scene = [load_detections(out / "run", i) for i in ids]
    return {"scenes": len(ids), "normal": pooled_ap(per_scene, Stage.NORMAL, ap_method),
            "challenging": pooled_ap(per_scene, Stage.FINAL, ap_method)}
