"""What a search step costs on a recording beside the native scene it came from: the same scenes (a
``recording_attack.py`` work folder: native scenes and their imports) searched by ``asg generate``
with the same settings (BO, 50 evaluations, ACS off, one worker, one thread), the two kinds
alternating round after round; the median seconds a scene and a step of each.

    python docs/experiments/recording_speed.py WORK_DIR COUNT ROUNDS OUT.json [TARGET]
"""
from __future__ import annotations

import json
import statistics
import subprocess
import sys
from pathlib import Path

SETTINGS = ("--acs", "off", "--search", "bo", "--budget", "50", "--workers", "1")


def one_run(scenes: Path, out: Path, count: int, target: str) -> list[dict]:
    subprocess.run([sys.executable, "-m", "asg", "generate", "--scenes", str(scenes), "--fusion", target, *SETTINGS,
                    "--count", str(count), "--out", str(out), "--force"], check=True, stdout=subprocess.DEVNULL)
    return json.loads((out / "summary.json").read_text())["scenes"]


def main(work: Path, count: int, rounds: int, out: Path, target: str) -> None:
    seconds = {"native": [], "recording": []}
    steps = {"native": [], "recording": []}
    for r in range(rounds):
        for kind, folder in (("native", work / "native"), ("recording", work / "imported"))[:: 1 if r % 2 == 0 else -1]:
            for e in one_run(folder, work / f"speed-{kind}", count, target):
                seconds[kind].append(e["seconds"])
                steps[kind].append(e["seconds"] / e["evaluations"])
            print(f"round {r + 1} {kind}: median {statistics.median(seconds[kind]):.2f} s a scene", flush=True)
    result = {"target": target, "scenes": count, "rounds": rounds, "settings": list(SETTINGS), "command": " ".join(sys.argv)}
    for kind in seconds:
        result[kind] = {"scene_s_median": round(statistics.median(seconds[kind]), 3),
                        "step_ms_median": round(1e3 * statistics.median(steps[kind]), 1)}
    result["recording_over_native"] = round(result["recording"]["scene_s_median"] / result["native"]["scene_s_median"], 3)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main(Path(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), Path(sys.argv[4]),
         sys.argv[5] if len(sys.argv) > 5 else "attfuse")
