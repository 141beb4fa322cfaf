"""How true is an edit of a recorded scan? Measured against our own simulator, where the right answer
is known: scenes of a set exported to OPV2V (``asg export --format opv2v``) and imported back
(``asg scenes import``), the same plausible moves (1 to 3 vehicles, a member of the generator's
feasible set) applied by the scan editor to the imported scene and by the World to the native one.

Per scene and sensing agent: the share of re-simulated points within 5 cm of an edited point, and
the reverse; per target, AP@0.3/0.5/0.7 by both yardsticks on the edited frames and on the
re-simulated ones (their intensities at the 8 bits a recorded PCD holds, as the recording's are); and one vehicle taken out and put back at its own pose (the editor's removal,
then its insertion) against the recorded scan: the share within 2 cm both ways.

    python docs/experiments/recording_fidelity.py SET COUNT OUT.json [TARGET ...]

SET a data set (normal-val), COUNT scenes, TARGET a ``--fusion`` name (default attfuse and
opencood:docs/experiments/opencood-attfuse-asg). Results: recording-fidelity/.
"""
from __future__ import annotations

import json
import sys
import tempfile
from dataclasses import replace
from itertools import islice
from pathlib import Path

import numpy as np
import yaml

from asg.datasets import scenes_of
from asg.generator.config import GenerateConfig
from asg.io.export import export
from asg.objective.ap import ap_by_method
from asg.perception import build_detector
from asg.perception.data import in_range
from asg.scene import save_scene
from asg.scene.from_opv2v import import_scenes
from asg.scene.neighbours import with_nearest_collaborators
from asg.search import EmptyFeasibleSet, FeasibleSet, SearchSpace
from asg.sensors import load_lidar_spec, occlusion_scores, render_frame, simulate_frame, world_for
from asg.sensors.agreement import share_within
from asg.sensors.opv2v import pcd_intensity_levels

DEFAULT_TARGETS = ("attfuse", "opencood:docs/experiments/opencood-attfuse-asg")
SPEC = load_lidar_spec()


def one_move(scene, rng: np.random.Generator) -> dict:
    """{vehicle id: moved agent} of 1 to 3 vehicles (the occlusion heuristic's picks), one member of
    the generator's feasible set of poses (the default plausibility, paper)."""
    cfg = GenerateConfig()
    others = [a for a in scene.vehicles if a.agent_id not in scene.sensing_ids]
    scores = occlusion_scores([scene.agent(i) for i in scene.sensing_ids], others, SPEC.range_m)
    ranked = [a.agent_id for a in sorted(others, key=lambda a: (-scores[a.agent_id], a.agent_id))]
    count = int(rng.integers(1, 4))
    movers: list[str] = []
    for vid in ranked:  # the heuristic's picks, passing over a vehicle that is boxed in
        if len(movers) == count:
            break
        try:
            FeasibleSet(SearchSpace(scene, [*movers, vid], cfg.space), rng)
            movers.append(vid)
        except EmptyFeasibleSet:
            continue
    if not movers:
        return {}
    space = SearchSpace(scene, movers, cfg.space)
    x = FeasibleSet(space, rng).project(rng.uniform(-1.0, 1.0, space.dim))
    return dict(space.decode(x).moved)


def in_world(frame, agent: str) -> np.ndarray:
    """``agent``'s cloud (N, 3) in the world frame."""
    pose = frame.poses[agent]
    return frame.clouds[agent][:, :3].astype(np.float64) @ pose.rotation().T + pose.origin


def as_recorded(frame):
    """``frame`` with each point's intensity at the 8 bits an OPV2V PCD stores (``asg export``
    quantises every recorded scan so, and the edit keeps the recorded points as they are): the
    re-simulated frame the edit is measured against, apart from the edit itself."""
    clouds = {}
    for aid, cloud in frame.clouds.items():
        c = cloud.copy()
        c[:, 3] = pcd_intensity_levels(c[:, 3]) / np.float32(255.0)
        clouds[aid] = c
    return replace(frame, clouds=clouds)


def detections(target, frame) -> tuple:
    boxes, scores = target.detect(frame)
    gt = frame.ego_boxes
    return boxes, scores, gt[in_range(gt)]


def round_trip(native, folder: Path) -> tuple:
    """(``native`` exported to OPV2V in ``folder`` and imported back, {native id: OPV2V id})."""
    save_scene(native, folder / "native" / f"{native.scene_id}.yaml")
    export(folder / "native", "opv2v", folder / "export")
    (imported,) = import_scenes(folder / "export")
    ids = {k: str(v) for k, v in yaml.safe_load((folder / "export" / native.scene_id / "ids.yaml").read_text())["ids"].items()}
    return imported, ids


def measure_scene(native, folder: Path, targets: dict, rng: np.random.Generator) -> dict:
    imported, ids = round_trip(native, folder)
    moved = one_move(native, rng)
    edited_moves = {ids[k]: replace(v, agent_id=ids[k]) for k, v in moved.items()}
    sim = render_frame(world_for(native, SPEC, movable_ids=moved), moved=moved)
    world = world_for(imported, SPEC, movable_ids=edited_moves)
    edited = render_frame(world, moved=edited_moves)
    row = {"scene": native.scene_id, "moved": len(moved), "agents": {}}
    for agent in native.sensing_ids:  # compared in the world frame: an export lowers a high sensor's frame
        a, b = in_world(sim, agent), in_world(edited, ids[agent])
        row["agents"][agent] = {"sim_in_edit_5cm": share_within(a, b, 0.05), "edit_in_sim_5cm": share_within(b, a, 0.05),
                                "points_sim": len(a), "points_edit": len(b),
                                "kind": native.agent(agent).kind}
    car = moved and imported.agent(ids[next(iter(moved))])
    recorded = simulate_frame(imported, SPEC)
    if car:
        twin = replace(car, agent_id=car.agent_id + "-twin")
        back = render_frame(world_for(imported, SPEC), moved={car.agent_id: None, twin.agent_id: twin})
        row["put_back_2cm"] = {a: [share_within(recorded.clouds[a], back.clouds[a], 0.02),  # one frame: same pose
                                   share_within(back.clouds[a], recorded.clouds[a], 0.02)] for a in imported.sensing_ids}
    sim = as_recorded(sim)  # the re-simulated frame as a recording holds it: 8-bit intensities
    row["detections"] = {name: {"sim": detections(t, sim), "edit": detections(t, edited)} for name, t in targets.items()}
    return row


def pooled(rows: list[dict]) -> dict:
    agents = [v for r in rows for v in r["agents"].values()]
    out = {"scenes": len(rows), "agent_views": len(agents)}
    for key in ("sim_in_edit_5cm", "edit_in_sim_5cm"):
        weights = [v["points_sim" if key.startswith("sim") else "points_edit"] for v in agents]
        out[key] = float(np.average([v[key] for v in agents], weights=weights))
        out[key + "_worst_view"] = float(min(v[key] for v in agents))
        out[key + "_by_kind"] = {k: float(np.mean([v[key] for v in agents if v["kind"] == k]))
                                 for k in sorted({v["kind"] for v in agents})}
    backs = [s for r in rows for pair in r.get("put_back_2cm", {}).values() for s in pair]
    out["put_back_2cm_mean"], out["put_back_2cm_worst"] = float(np.mean(backs)), float(min(backs))
    return out


def main(set_name: str, count: int, out: Path, target_names: tuple[str, ...]) -> None:
    rng = np.random.default_rng(0)
    targets = {name: build_detector(name) for name in target_names}
    rows = []
    with tempfile.TemporaryDirectory(prefix="asg-fidelity-") as tmp:
        for i, scene in enumerate(islice(scenes_of(set_name), count)):
            scene = with_nearest_collaborators(scene, 2)
            rows.append(measure_scene(scene, Path(tmp) / str(i), targets, rng))
            print(f"{i + 1}/{count} {scene.scene_id}: " + ", ".join(
                f"{a} {v['sim_in_edit_5cm']:.3f}/{v['edit_in_sim_5cm']:.3f}" for a, v in rows[-1]["agents"].items()),
                flush=True)
    result = {"set": set_name, "scenes": count, "command": " ".join(sys.argv), "pooled": pooled(rows), "ap": {}}
    for name in targets:
        for kind in ("sim", "edit"):
            result["ap"].setdefault(name, {})[kind] = ap_by_method([r["detections"][name][kind] for r in rows])
    result["per_scene"] = [{k: v for k, v in r.items() if k != "detections"} for r in rows]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(json.dumps({"pooled": result["pooled"], "ap": result["ap"]}, indent=1))


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), Path(sys.argv[3]), tuple(sys.argv[4:]) or DEFAULT_TARGETS)
