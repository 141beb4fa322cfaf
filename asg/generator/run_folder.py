"""The run folder of ``asg generate`` and its summary.json (schema: docs/generate.md).

    OUT/summary.json                         scenes + aggregate (rewritten after every scene)
    OUT/scenes/SCENE_ID/normal.yaml          the normal scene (its collaborators set)
    OUT/scenes/SCENE_ID/after_acs.yaml       after the collaborator search
    OUT/scenes/SCENE_ID/final.yaml           after the perturbation search
    OUT/scenes/SCENE_ID/history.csv          step, the member in units (per space: columns named VEHICLE_dx_m, ...), loss, AP
    OUT/scenes/SCENE_ID/clouds/AGENT.pcd     final per-agent clouds (sensor frame), also .npy
    OUT/scenes/SCENE_ID/{normal,after_acs,final}.png    bird's-eye pictures (perturbed vehicles circled)
    OUT/scenes/SCENE_ID/result.json          this scene's summary entry: written last, marks it done
    OUT/log/                                 the SUMO log of a town or net source, kept when a space
                                             reads the past (latency); scene files name it ../../log

A scene folder is written under a temporary name and renamed when complete, so a run stopped
midway resumes from the first scene without a result.json. A folder written before each stage had
one name holds the normal stage as ``initial`` (``initial.yaml``, its detections): read the same.
"""
from __future__ import annotations

import csv
import io
import json
import os
import zipfile
from pathlib import Path

import numpy as np

from sumo_scenarios.atomic import atomic_dir, atomic_path, write_text_atomic
from sumo_scenarios.checks import inside
from sumo_scenarios.errors import InputError
from sumo_scenarios.npz import load_npz

from ..objective import AP_KEYS, ap_text
from ..objective.pooled import PooledAP
from ..objective.ap import (AP_METHODS, DEFAULT_AP_METHOD, Yardstick, FrameMatches, ap_by_method_from_matches,
                            check_ap_method, frame_matches)
from .pipeline import SceneResult
from .stages import Stage
from ..scene import save_scene
from ..schemas import SchemaFile, schema_of, stamped
from ..io.figures import bev_figure
from ..sensors.agreement import cloud_changes
from ..io.pcd import write_pcd


def scene_entry(r: SceneResult) -> dict:
    return {
        "scene_id": r.scene_id,
        **{stage.ap_key: r.ap(stage) for stage in Stage},
        "loss_normal": round(r.loss_normal, 6), "loss_final": round(r.loss_final, 6),
        "evaluations": r.evaluations, "seconds": round(r.seconds, 3),
        "collaborators": {Stage.NORMAL: list(r.normal.collaborators), Stage.FINAL: list(r.after_acs.collaborators)},
        "perturbed": list(r.perturbed), "moved": list(r.moved), "delta": r.delta,
        "plausibility": r.plausibility.to_dict(), "notes": r.notes,
    } | ({"space": r.space} if r.space and r.space.get("kinds") != ["poses"] else {})


def write_scene(out_dir: Path, r: SceneResult, artifacts: bool = True) -> dict:
    """Write scene folder ``OUT/scenes/SCENE_ID`` atomically (its id must be a safe name) and
    return its summary entry. ``artifacts``: also the final clouds and the pictures (a data set of
    challenging scenes keeps only the scenes, history and detections)."""
    entry = scene_entry(r)
    folder = inside(out_dir / "scenes", out_dir / "scenes" / r.scene_id)
    with atomic_dir(folder) as work:
        for stage in Stage:
            save_scene(_log_relative(r.scene(stage), out_dir, folder), work / f"{stage}.yaml")
        buf = io.StringIO()
        w = csv.writer(buf)
        w.writerow(["step", *r.history_columns, "loss", "ap_0.3", "ap_0.5", "ap_0.7"])
        for e, values in zip(r.history, r.history_values):
            w.writerow([e.step, *values, round(e.loss, 6), *[round(e.ap.get(k, 0.0), 6) for k in AP_KEYS]])
        (work / "history.csv").write_text(buf.getvalue())
        if artifacts:
            _write_artifacts(work, r)
        arrays = {f"{k}_{n}": a for k, det in r.detections.items() for n, a in zip(("boxes", "scores", "gt"), det)}
        np.savez_compressed(work / "detections.npz", **arrays)
        (work / "result.json").write_text(json.dumps(entry, indent=1))
    return entry


def _log_relative(scene, out_dir: Path, folder: Path):
    """``scene`` naming a log inside the run folder by its path from ``folder`` (where the scene
    file goes; load_scene resolves it from there), so that run folders move and compare whole."""
    from dataclasses import replace

    if not scene.log or not Path(scene.log).is_absolute():
        return scene
    log = Path(scene.log)
    if not log.is_relative_to(out_dir.resolve()):
        return scene
    return replace(scene, log=os.path.relpath(log, folder.resolve()))


def _write_artifacts(work: Path, r: SceneResult) -> None:
    """The final per-agent clouds (PCD and .npy, sensor frames) and the three bird's-eye pictures."""
    for aid, cloud in r.frames[Stage.FINAL].clouds.items():
        inside(work / "clouds", work / "clouds" / aid)
        write_pcd(work / "clouds" / f"{aid}.pcd", cloud)
        with atomic_path(work / "clouds" / f"{aid}.npy") as tmp:
            np.save(tmp, cloud)
    for stage in Stage:
        final = stage == Stage.FINAL
        bev_figure(r.scene(stage), r.frames[stage], work / f"{stage}.png",
                   title=f"{r.scene_id} {stage}: AP@0.7 {r.ap(stage).get('0.7', 0):.2f}",
                   marked_ids=r.perturbed if final else (),
                   changes=cloud_changes(r.frames[Stage.AFTER_ACS], r.frames[stage]) if final and r.moved else None)


#: the largest array a scene's detections.npz holds, unpacked (bytes): a frame's boxes and ground
#: truth are at most a thousand rows of 7 numbers; a larger one is not asg's (a small archive can
#: unpack to gigabytes)
MAX_DETECTION_ARRAY_BYTES = 8 << 20


def stage_scene_path(folder: Path, stage: Stage) -> Path:
    """The scene file of ``stage`` in a scene folder: ``STAGE.yaml``, or its old spelling's in a
    folder written before each stage had one name (:attr:`Stage.old_value`)."""
    path = folder / f"{stage}.yaml"
    old = folder / f"{stage.old_value}.yaml"
    return old if not path.is_file() and old.is_file() else path


def load_detections(out_dir: Path, scene_id: str) -> dict[str, tuple]:
    """Each stage's (boxes (K, 7), scores (K,), ground truth (M, 7)) of a scene, ego frame (a stage
    under its old spelling in an older folder: :attr:`Stage.old_value`)."""
    path = out_dir / "scenes" / scene_id / "detections.npz"
    try:
        z = load_npz(path, MAX_DETECTION_ARRAY_BYTES)
        found = {k: name for k in Stage for name in (k.value, k.old_value) if f"{name}_boxes" in z}
        return {k: (z[f"{n}_boxes"], z[f"{n}_scores"], z[f"{n}_gt"]) for k, n in found.items()}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as exc:
        raise InputError(f"{path}: not a scene's detections as asg writes them ({exc}); "
                         "regenerate the scene") from None


def load_done(out_dir: Path) -> dict[str, dict]:
    """The finished scenes of a run folder by id: those whose result.json reads back whole and whose
    detections.npz is there. Any other scene folder (damaged after the fact) is generated again."""
    done = {}
    for p in sorted((out_dir / "scenes").glob("*/result.json")):
        try:
            entry = json.loads(p.read_text(encoding="utf-8"))
            with np.load(p.parent / "detections.npz") as z:
                z.files  # noqa: B018  (opens the archive's index: a truncated file fails here)
        except (OSError, ValueError, EOFError, zipfile.BadZipFile):
            continue
        if isinstance(entry, dict) and entry.get("scene_id") == p.parent.name:
            done[p.parent.name] = entry_in_todays_form(entry)
    return done


def entry_in_todays_form(entry: dict) -> dict:
    """A scene entry (result.json, a summary's scene) written before each stage had one name, in
    today's form: its ``collaborators`` name the normal stage ``normal``, not ``initial``."""
    collaborators, old = entry.get("collaborators"), Stage.NORMAL.old_value
    if isinstance(collaborators, dict) and old in collaborators and Stage.NORMAL.value not in collaborators:
        entry["collaborators"] = {(Stage.NORMAL.value if k == old else k): v for k, v in collaborators.items()}
    return entry


def previous_wall_s(out_dir: Path) -> float:
    """Wall time recorded by the earlier runs that wrote ``out_dir`` (0 if none): a resumed run adds to it."""
    try:
        return float(json.loads((out_dir / "summary.json").read_text())["aggregate"]["wall_s"])
    except (OSError, ValueError, KeyError, TypeError):
        return 0.0


def pooled_ap(per_scene: list[dict[str, tuple]], key: str, method: str = DEFAULT_AP_METHOD) -> dict[str, float] | None:
    """AP over one stage's detections of all scenes together, as the paper's tables, ranked by
    ``method`` (asg.objective.ap.AP_METHODS; per-frame takes the scenes in the given order);
    ``per_scene`` as load_detections gives them. None if a scene lacks that stage (a folder
    written before it was stored)."""
    both = pooled_ap_by_method(per_scene, key)
    return None if both is None else both[check_ap_method(method)]


def pooled_ap_by_method(per_scene: list[dict[str, tuple]], key: str) -> dict[str, dict[str, float]] | None:
    """{method: pooled AP} of :func:`pooled_ap` for every AP method, each frame matched once."""
    if any(key not in d for d in per_scene):
        return None
    return _pooled_from_matches([{key: frame_matches(d[key])} for d in per_scene], key)


def scene_matches(detections: dict[str, tuple]) -> dict[str, FrameMatches]:
    """Each stage's frame of one scene (:func:`load_detections`) matched at the reported thresholds."""
    return {stage: frame_matches(frame) for stage, frame in detections.items()}


def _pooled_from_matches(per_scene: list[dict[str, FrameMatches]], key: str) -> dict[str, dict[str, float]] | None:
    """:func:`pooled_ap_by_method` from the scenes' matches (:func:`scene_matches`)."""
    if any(key not in m for m in per_scene):
        return None
    if not per_scene:
        return {m: dict.fromkeys(AP_KEYS, 0.0) for m in AP_METHODS}
    both = ap_by_method_from_matches([m[key] for m in per_scene])
    return {m: {k: round(v, 6) for k, v in ap.items()} for m, ap in both.items()}


def aggregate_ap(aggregate: dict, stage: Stage, method: str = DEFAULT_AP_METHOD) -> dict[str, float] | None:
    """A summary aggregate's pooled AP of ``stage`` ranked by ``method``: the global ranking at the
    top level under the stage's ``ap_key``, every AP method under "by_method" ({method: {ap_key:
    AP}}). Summaries written before the key was one (the final stage's "ap_challenging") read the
    same; None where the folder's summary holds none (the after-ACS stage of old folders)."""
    held = aggregate if check_ap_method(method) == DEFAULT_AP_METHOD else aggregate.get("by_method", {}).get(method, {})
    return held.get(stage.ap_key, held.get(stage.old_pooled_key))


def aggregate_pooled(aggregate: dict, stage: Stage) -> PooledAP | None:
    """A summary aggregate's pooled AP of ``stage`` under both yardsticks (None: not recorded)."""
    ap = aggregate_ap(aggregate, stage)
    return None if ap is None else PooledAP(ap, aggregate_ap(aggregate, stage, Yardstick.PER_FRAME))


def mean_ap(entries: list[dict], key: str) -> dict[str, float]:
    if not entries:
        return dict.fromkeys(AP_KEYS, 0.0)
    return {t: round(float(np.mean([e[key][t] for e in entries])), 6) for t in AP_KEYS}


def after_acs_ap(pooled: dict[str, float] | None, mean: dict[str, float]) -> tuple[dict[str, float], bool]:
    """The after-ACS AP to show: the pooled one and True, or, for folders written before after-ACS
    detections were stored (``pooled`` None), the mean of per-scene APs and False."""
    return (pooled, True) if pooled else (mean, False)


def write_summary(out_dir: Path, entries: list[dict], config: dict, wall_s: float,
                  matches: dict[str, dict[str, FrameMatches]] | None = None) -> dict:
    """Write (and return) the run's summary.json of its finished scenes ``entries``. ``matches``:
    each scene's matched detections by scene id (:func:`scene_matches`), filled here with the scenes
    it lacks; a run that rewrites its summary after every scene passes the same dict each time, so
    each scene is read and matched once (reading and matching every scene again made a summary of
    699 scenes cost 12 s, each time)."""
    seconds = [e["seconds"] for e in entries]
    matches = {} if matches is None else matches
    for e in entries:
        if e["scene_id"] not in matches:
            matches[e["scene_id"]] = scene_matches(load_detections(out_dir, e["scene_id"]))
    per_scene = [matches[e["scene_id"]] for e in entries]
    pooled = {stage.ap_key: _pooled_from_matches(per_scene, stage) for stage in Stage}
    by_method = {m: {k: (None if v is None else v[m]) for k, v in pooled.items()} for m in AP_METHODS}
    summary = stamped(SchemaFile.SUMMARY, {
        "config": config,
        "scenes": entries,
        "aggregate": {
            "scenes": len(entries),
            **by_method[DEFAULT_AP_METHOD],
            "by_method": by_method,
            **{f"mean_scene_{stage.ap_key}": mean_ap(entries, stage.ap_key) for stage in Stage},
            "seconds_per_scene_median": round(float(np.median(seconds)), 3) if seconds else None,
            "scenes_per_hour": round(3600.0 * len(entries) / sum(seconds), 1) if seconds and sum(seconds) > 0 else None,
            "wall_s": round(wall_s, 1),
        },
    })
    write_text_atomic(out_dir / "summary.json", json.dumps(summary, indent=1))
    return summary


def read_summary(path: Path, what: str = "the run") -> tuple[dict, int]:
    """(a run's summary.json in today's shape, the schema version the file was written in): a file of
    schema 1 (the final stage's AP under ``ap_challenging``) or 2 (the normal stage's collaborators
    under ``initial``) has its keys renamed as today's; InputError for a damaged file or one from a
    newer asg (asg.schemas)."""
    from ..io.json_file import read_json

    summary = read_json(path, what)
    if not isinstance(summary, dict) or not isinstance(summary.get("aggregate"), dict):
        raise InputError(f"{path}: not a run's summary (no aggregate); rerun the command to write it again")
    version = schema_of(SchemaFile.SUMMARY, summary, str(path))
    if version == 1:
        old, new = Stage.FINAL.old_pooled_key, Stage.FINAL.ap_key
        for holder in (summary["aggregate"], *summary["aggregate"].get("by_method", {}).values(),
                       *(e for e in summary.get("scenes", []) if isinstance(e, dict))):
            if isinstance(holder, dict):
                for prefix in ("", "mean_scene_"):
                    if prefix + old in holder and prefix + new not in holder:
                        holder[prefix + new] = holder.pop(prefix + old)
    if version < 3:
        for entry in summary.get("scenes", []):
            if isinstance(entry, dict):
                entry_in_todays_form(entry)
    return summary, version


def print_table(summary: dict, out) -> None:
    """The before/after AP table of a run's summary on rich console ``out``."""
    from rich.table import Table

    table = Table(title="AP before / after (fractions)")
    table.add_column("scene")
    for col in ("normal 0.3/0.5/0.7", "after ACS", "final", "moved", "s"):
        table.add_column(col, justify="right")
    fmt = lambda ap: ap_text(ap, scale=1.0, digits=2)  # noqa: E731
    for e in summary["scenes"]:
        table.add_row(e["scene_id"][-32:], *(fmt(e[stage.ap_key]) for stage in Stage),
                      str(len(e.get("moved", e["perturbed"] if e["delta"] else []))), f"{e['seconds']:.1f}")
    agg = summary["aggregate"]
    after_ap, pooled = after_acs_ap(aggregate_ap(agg, Stage.AFTER_ACS), agg[f"mean_scene_{Stage.AFTER_ACS.ap_key}"])
    table.add_row("[bold]pooled", fmt(aggregate_ap(agg, Stage.NORMAL)), fmt(after_ap) + ("" if pooled else "*"),
                  fmt(aggregate_ap(agg, Stage.FINAL)), "", f"{agg['seconds_per_scene_median']:.1f}")
    if aggregate_ap(agg, Stage.NORMAL, Yardstick.PER_FRAME) is not None:
        table.add_row("pooled per frame (paper)", *(fmt(aggregate_ap(agg, s, Yardstick.PER_FRAME)) for s in Stage), "", "")
    out.print(table)
    if not pooled:
        out.print("* mean over scenes (this folder has scenes written before after-ACS detections were stored)")
