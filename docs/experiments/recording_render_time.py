"""What rendering a move costs on a recording beside the simulator: scenes of a set exported to OPV2V
and imported back, the same 20 plausible moves a scene (members of the feasible set of the movers
recording_fidelity.py picks) rendered by the scan editor on the imported scene and by the World on
the native one, each in one world a scene as a search renders them; milliseconds a frame (all its
sensing views), ROUNDS rounds alternating. Also checks that the editor's world gives the same bits
as a fresh world for every move.

    python docs/experiments/recording_render_time.py SET COUNT ROUNDS OUT.json
"""
from __future__ import annotations

import json
import sys
import tempfile
import time
from dataclasses import replace
from itertools import islice
from pathlib import Path

import numpy as np

from asg.datasets import scenes_of
from asg.generator.config import GenerateConfig
from asg.scene.neighbours import with_nearest_collaborators
from asg.search import FeasibleSet, SearchSpace
from asg.sensors import load_lidar_spec, render_frame, world_for
from asg.sensors.recorded import RecordedWorld
from recording_fidelity import one_move, round_trip

SPEC = load_lidar_spec()
MOVES = 20


def cases(set_name: str, count: int, folder: Path) -> list[tuple]:
    """(recorded world, imported scene, its moves, native world, native scene, its moves) a scene."""
    rng, out = np.random.default_rng(0), []
    for i, scene in enumerate(islice(scenes_of(set_name), count)):
        native = with_nearest_collaborators(scene, 2)
        imported, ids = round_trip(native, folder / str(i))
        movers = list(one_move(native, rng))
        if not movers:
            continue
        space = SearchSpace(native, movers, GenerateConfig().space)
        members = FeasibleSet(space, rng).members
        native_moves = [dict(space.decode(members[k]).moved) for k in range(1, min(MOVES + 1, len(members)))]
        moves = [{ids[k]: replace(v, agent_id=ids[k]) for k, v in m.items()} for m in native_moves]
        recorded = world_for(imported, SPEC, movable_ids=set(moves[0]))
        simulated = world_for(native, SPEC, movable_ids=set(native_moves[0]))
        out.append((recorded, imported, moves, simulated, native, native_moves))
    return out


def frame_ms(worlds: list[tuple], recorded: bool) -> float:
    frames, t = 0, time.perf_counter()
    for rec, imported, moves, sim, native, native_moves in worlds:
        world, scene = (rec, imported) if recorded else (sim, native)
        for m in moves if recorded else native_moves:
            render_frame(world, scene.sensing_ids, moved=m)
            frames += 1
    return 1e3 * (time.perf_counter() - t) / frames


def main(set_name: str, count: int, rounds: int, out: Path) -> None:
    with tempfile.TemporaryDirectory(prefix="asg-render-") as tmp:
        worlds = cases(set_name, count, Path(tmp))
        frame_ms(worlds, True), frame_ms(worlds, False)  # warm-up: clouds read, meshes and planes built
        times = [(frame_ms(worlds, True), frame_ms(worlds, False)) for _ in range(rounds)]
        same = [np.array_equal(a, b) for rec, imported, moves, *_ in worlds for m in moves
                for a, b in zip(rec.render_many(imported.sensing_ids, m).values(),
                                RecordedWorld(imported, SPEC).render_many(imported.sensing_ids, m).values())]
    result = {"set": set_name, "scenes": len(worlds), "frames_a_round": sum(len(w[2]) for w in worlds),
              "command": " ".join(sys.argv),
              "edited_ms_median": round(float(np.median([a for a, _ in times])), 2),
              "simulated_ms_median": round(float(np.median([b for _, b in times])), 2),
              "rounds": [[round(a, 2), round(b, 2)] for a, b in times],
              "views_same_as_a_fresh_world": f"{sum(same)}/{len(same)}"}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), Path(sys.argv[4]))
