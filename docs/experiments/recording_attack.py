"""The attack on recordings beside the same frames attacked natively: scenes of a set exported to OPV2V
and imported back with their town's map (``asg scenes import --map``, so that both runs move vehicles
under the same lane rule), then ``asg generate`` with the same settings on the native scenes and on
the imported ones; the pooled AP@0.3/0.5/0.7 before and after by both yardsticks, and the drop.

ACS is off in both (``--acs off``): a recording's collaborators can only be agents whose scans were
recorded, the two of each scene here, while natively ACS picks among every vehicle in range; the
perturbation search (the paper's BO, 50 evaluations, 3 movers) is what the scan editor renders.

    python docs/experiments/recording_attack.py SET COUNT WORK_DIR OUT.json TARGET [WORKERS]

Resumable (each ``asg generate`` run resumes its folder). Results: recording-attack/.
"""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from itertools import islice
from pathlib import Path

from asg.datasets import scenes_of
from asg.io.export import export
from asg.scene import save_scene
from asg.scene.neighbours import with_nearest_collaborators
from asg.perception import resolve_target
from sumo_scenarios.paths import nets_dir

SETTINGS = ("--acs", "off", "--search", "bo", "--budget", "50")


def prepare(set_name: str, count: int, work: Path) -> tuple[Path, Path]:
    """(native scenes folder, imported scenes folder) of the set's first ``count`` scenes."""
    native, exported, imported = work / "native", work / "export", work / "imported"
    if not imported.is_dir():
        scenes = [with_nearest_collaborators(s, 2) for s in islice(scenes_of(set_name), count)]
        for s in scenes:
            save_scene(s, native / f"{s.scene_id}.yaml")
        export(native, "opv2v", exported)
        towns = {s.town for s in scenes}
        parts = []
        for town in sorted(towns):  # one import per town: its own map
            folder = work / f"export-{town}"
            folder.mkdir(parents=True, exist_ok=True)
            for s in scenes:
                if s.town == town and not (folder / s.scene_id).exists():
                    shutil.copytree(exported / s.scene_id, folder / s.scene_id)  # an import refuses links out
            parts.append(folder)
        for folder, town in zip(parts, sorted(towns)):
            subprocess.run([sys.executable, "-m", "asg", "scenes", "import", str(folder.resolve()), "--map",
                            str(nets_dir() / f"{town}.net.xml"), "--out", str(imported)], check=True)
    return native, imported


def attack(scenes: Path, out: Path, target: str, count: int, workers: int) -> dict:
    subprocess.run([sys.executable, "-m", "asg", "generate", "--scenes", str(scenes), "--fusion", target, *SETTINGS,
                    "--count", str(count), "--workers", str(workers), "--out", str(out)], check=True)
    summary = json.loads((out / "summary.json").read_text())
    agg = summary["aggregate"]
    return {"scenes": agg["scenes"], "seconds_per_scene_median": agg["seconds_per_scene_median"],
            "by_method": agg["by_method"]}


def main(set_name: str, count: int, work: Path, out: Path, target: str, workers: int) -> None:
    native, imported = prepare(set_name, count, work)
    label = resolve_target(target).label
    result = {"set": set_name, "scenes": count, "target": target, "settings": list(SETTINGS),
              "command": " ".join(sys.argv)}
    for name, folder in (("native", native), ("recording", imported)):
        result[name] = attack(folder, work / f"gen-{label}-{name}", target, count, workers)
        for method, ap in result[name]["by_method"].items():
            result[name].setdefault("drop_0.7", {})[method] = round(ap["ap_normal"]["0.7"] - ap["ap_final"]["0.7"], 4)
    result["drop_gap_0.7"] = {m: round(result["recording"]["drop_0.7"][m] - result["native"]["drop_0.7"][m], 4)
                              for m in result["native"]["drop_0.7"]}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(json.dumps({k: v for k, v in result.items() if k != "command"}, indent=1))


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), Path(sys.argv[3]), Path(sys.argv[4]), sys.argv[5],
         int(sys.argv[6]) if len(sys.argv) > 6 else 2)
