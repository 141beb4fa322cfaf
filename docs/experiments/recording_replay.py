"""Does an attack on a recording find scenes that are hard, or edits that are? The final scenes an
attack found on imported recordings (a ``recording_attack.py`` work folder), their moves applied to
the native scenes they came from and rendered by the simulator: the target's pooled AP@0.3/0.5/0.7
(both yardsticks) on the edited final frames beside the re-simulated ones. A search that exploited
a flaw of the scan editor would score lower on its edited frames than on the simulator's.

    python docs/experiments/recording_replay.py WORK_DIR TARGET OUT.json

WORK_DIR holds native/, export-TOWN/ (the ids.yaml of each scenario) and gen-LABEL-recording/scenes/.
"""
from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import yaml

from asg.generator.run_folder import stage_scene_path
from asg.generator.stages import Stage
from asg.objective.ap import ap_by_method
from asg.perception import build_detector, resolve_target
from asg.scene.scene import load_scene
from asg.sensors import render_frame, world_for
from recording_fidelity import SPEC, detections


def native_of(final, initial, native, ids: dict[str, str]):
    """``native`` with the vehicles the attack moved in ``final`` (against ``initial``, both imported
    scenes) at their final poses; ``ids``: native id -> OPV2V id."""
    back = {v: k for k, v in ids.items()}
    before = {a.agent_id: a for a in initial.agents}
    moved = {back[a.agent_id]: a for a in final.agents
             if a.agent_id in before and (a.x_m, a.y_m, a.yaw_rad) != (before[a.agent_id].x_m, before[a.agent_id].y_m,
                                                                       before[a.agent_id].yaw_rad)}
    agents = tuple(replace(a, x_m=moved[a.agent_id].x_m, y_m=moved[a.agent_id].y_m, z_m=moved[a.agent_id].z_m,
                           yaw_rad=moved[a.agent_id].yaw_rad) if a.agent_id in moved else a for a in native.agents)
    return replace(native, agents=agents), len(moved)


def main(work: Path, target_name: str, out: Path) -> None:
    target = build_detector(target_name)
    runs = work / f"gen-{resolve_target(target_name).label}-recording" / "scenes"
    rows = {"edited": [], "re-simulated": []}
    moved_counts = []
    for folder in sorted(p for p in runs.iterdir() if (p / "final.yaml").is_file()):
        final, initial = load_scene(folder / "final.yaml"), load_scene(stage_scene_path(folder, Stage.NORMAL))
        scene_id = folder.name.rsplit("-", 1)[0]
        ids_file = next(work.glob(f"export-*/{scene_id}/ids.yaml"))
        ids = {str(k): str(v) for k, v in yaml.safe_load(ids_file.read_text())["ids"].items()}
        native, count = native_of(final, initial, load_scene(work / "native" / f"{scene_id}.yaml"), ids)
        moved_counts.append(count)
        rows["edited"].append(detections(target, render_frame(world_for(final, SPEC))))
        rows["re-simulated"].append(detections(target, render_frame(world_for(native, SPEC))))
    result = {"work": str(work), "target": target_name, "scenes": len(moved_counts), "command": " ".join(sys.argv),
              "scenes_by_vehicles_moved": {str(k): moved_counts.count(k) for k in sorted(set(moved_counts))},
              "ap": {k: ap_by_method(v) for k, v in rows.items()}}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2], Path(sys.argv[3]))
