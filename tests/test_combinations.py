"""Every option with every other: scene source x perturbation space x plausibility level x executor.

Each combination of ``asg generate`` either writes its scene, whose final state the independent
re-check finds plausible at the asked level, or is refused in one line with exit 2 before any
scene is computed (and then only where the combination cannot work: latency on a log recorded
less often than its delays or on a recording, whose past is not imported; lanes read from a
recording imported without its town's map).
The sources: a town, a net, scene folders of a SUMO and of a highway-env log, and the SUMO scene
exported to OPV2V's layout and imported back as a recording, without and with its town's map.
``-m slow`` (CI) runs a pairwise cover (every pair of values of two options appears in some run)
on one and two workers, and a run of Ray with every value of each other option;
``-m exhaustive`` runs the whole product, Ray included.
"""
import itertools
import json

import pytest

from asg.cli import main
from asg.scene import load_scene, save_scene
from asg.scene.recheck import recheck
from sumo_scenarios.paths import nets_dir

from test_cli import assert_one_line_error

SOURCES = ("town", "net", "sumo-scenes", "highway-scenes", "recording", "recording-map")
SPACES = ("poses", "insert", "pose-error", "latency", "dropout", "poses,insert,pose-error,latency,dropout")
LEVELS = ("paper", "traffic")
EXECUTORS = ("one", "two")


def _pairwise() -> list[tuple[str, str, str, str]]:
    """A small set of (source, space, level, executor) in which every pair of values of any two
    options appears (greedy cover over the full product, deterministic)."""
    full = list(itertools.product(SOURCES, SPACES, LEVELS, EXECUTORS))
    pairs = lambda c: {(i, j, c[i], c[j]) for i, j in itertools.combinations(range(4), 2)}
    todo, picked = set().union(*(pairs(c) for c in full)), []
    while todo:
        best = max(full, key=lambda c: len(pairs(c) & todo))
        picked.append(best)
        todo -= pairs(best)
    return picked


@pytest.fixture(scope="module")
def scene_folders(tmp_path_factory, highway_log):
    """Scenes of a SUMO log recorded every 0.1 s (a later frame: latency reaches back) and of the
    highway-env log (recorded every 0.5 s), each one scene with an RSU ego and two collaborators;
    the SUMO scene as a recording in OPV2V's layout, imported without and with its town's map."""
    from sumo_scenarios.simulate import SimulationRequest, simulate_sumo
    from asg.io.export import export
    from asg.scene.from_log import ExtractParams, extract_scenes
    from asg.scene.from_opv2v import ImportParams, import_scenes

    root = tmp_path_factory.mktemp("combos")
    log = root / "log"
    simulate_sumo(SimulationRequest(out_dir=log, town="grid_small", seed=3, duration_s=4.0, warmup_s=40.0,
                                    record_period_s=0.1, density="dense"))
    folders = {}
    for name, logs, every in (("sumo-scenes", log, 10), ("highway-scenes", highway_log, 20)):
        scenes = list(extract_scenes(logs, ExtractParams(every=every, min_vehicles=3, collaborators=2)))
        folders[name] = root / name
        save_scene(scenes[-1], folders[name] / f"{scenes[-1].scene_id}.yaml")
    assert export(folders["sumo-scenes"], "opv2v", root / "opv2v") == 1
    for name, town_map in (("recording", None), ("recording-map", nets_dir() / "grid_small.net.xml")):
        (recorded,) = import_scenes(root / "opv2v", ImportParams(map=town_map))
        folders[name] = root / name
        save_scene(recorded, folders[name] / f"{recorded.scene_id}.yaml")
    return folders


def _refusal(source: str, space: str, level: str) -> str | None:
    """What the one line says where a combination cannot work (None: it runs)."""
    if source == "recording" and ("insert" in space or level == "traffic"):
        return "has no lanes (a recording imported without --map)"
    if source.startswith("recording") and "latency" in space:
        return "earlier frames are not imported"
    if source == "highway-scenes" and "latency" in space:  # its log records every 0.5 s > the 0.4 s delays
        return "records every 0.5 s"
    return None


def _argv(source, space, level, executor, folders, out):
    where = {"town": ["--town", "grid_small"], "net": ["--net", str(nets_dir() / "grid_wide.net.xml")]}.get(
        source, ["--scenes", str(folders.get(source))])
    executor_args = {"one": ["--workers", "1"], "two": ["--workers", "2"], "ray": ["--executor", "ray", "--workers", "2"]}
    return ["generate", *where, "--count", "1", "--budget", "3", "--space", space, "--plausibility", level,
            "--detector", "fakes:oracle_factory", *executor_args[executor], "--out", str(out)]


def _check(capsys, tmp_path, folders, source, space, level, executor):
    out = tmp_path / "run"
    code = main(_argv(source, space, level, executor, folders, out))
    err = capsys.readouterr().err
    refusal = _refusal(source, space, level)
    if refusal:
        assert code == 2 and not out.exists(), err  # refused before any scene, nothing left behind
        assert_one_line_error(err, refusal)
        return
    assert code == 0, err
    entry = json.loads((out / "summary.json").read_text())["scenes"][0]
    folder = out / "scenes" / entry["scene_id"]
    initial, final = load_scene(folder / "normal.yaml"), load_scene(folder / "final.yaml")
    assert recheck(initial, final, level).ok
    assert sorted(entry["space"]["kinds"] if "space" in entry else ["poses"]) == sorted(space.split(","))


@pytest.mark.slow
@pytest.mark.parametrize("source,space,level,executor", _pairwise())
def test_every_pair_of_options_works_together(capsys, tmp_path, scene_folders, source, space, level, executor):
    _check(capsys, tmp_path, scene_folders, source, space, level, executor)


def _ray_cover() -> list[tuple[str, str, str, str]]:
    """Ray with every value of each other option: run i takes the i-th source, space and level (cycling)."""
    n = max(len(SOURCES), len(SPACES), len(LEVELS))
    return [(SOURCES[i % len(SOURCES)], SPACES[i % len(SPACES)], LEVELS[i % len(LEVELS)], "ray") for i in range(n)]


@pytest.mark.slow
@pytest.mark.parametrize("source,space,level,executor", _ray_cover())
def test_ray_runs_with_every_value_of_the_other_options(capsys, tmp_path, scene_folders, source, space, level, executor):
    pytest.importorskip("ray")
    _check(capsys, tmp_path, scene_folders, source, space, level, executor)


@pytest.mark.exhaustive
@pytest.mark.parametrize("source,space,level,executor",
                         [c for c in itertools.product(SOURCES, SPACES, LEVELS, EXECUTORS + ("ray",))
                          if c not in _pairwise() and c not in _ray_cover()])
def test_every_combination_works(capsys, tmp_path, scene_folders, source, space, level, executor):
    if executor == "ray":
        pytest.importorskip("ray")
    _check(capsys, tmp_path, scene_folders, source, space, level, executor)
