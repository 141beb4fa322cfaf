"""The perturbation spaces (asg.search.spaces): bounds, plausibility, determinism, and bad input."""
from __future__ import annotations

import json
import math
import csv
from pathlib import Path

import numpy as np
import pytest
import yaml

from asg.cli import main
from asg.scene import load_scene
from asg.scene.recheck import recheck
from asg.search import FeasibleSet, SearchSpace, SpaceConfig
from asg.search.space import EmptyFeasibleSet
from asg.search.spaces import INSERT_PREFIX, InsertConfig, LatencyConfig, PoseErrorConfig
from asg.sensors import load_lidar_spec, simulate_frame
from sumo_scenarios.errors import InputError

from test_robustness import _scene_dict, _write, oracle_run
from asg.scene import Scene

UNION = "poses,insert,pose-error,dropout"


def _scene() -> Scene:
    return Scene.from_dict(_scene_dict("s0"))


def _history(out: Path, scene_id: str) -> list[dict]:
    return list(csv.DictReader((out / "scenes" / scene_id / "history.csv").open()))


@pytest.mark.parametrize("kinds", ["insert", "pose-error", "dropout", UNION])
def test_every_member_of_q_is_within_bounds_and_plausible(kinds):
    cfg = SpaceConfig(kinds=tuple(kinds.split(",")), n_q=120)
    scene = _scene()
    space = SearchSpace(scene, ("v2", "v3", "u0") if "poses" in kinds else (), cfg)
    q = FeasibleSet(space, np.random.default_rng(4))
    assert np.all(np.abs(q.members) <= 1.0 + 1e-12) and np.array_equal(q.members[0], space.identity())
    assert len(np.unique(q.members, axis=0)) == len(q.members)
    for x in q.members[:60]:
        final = space.apply(x)
        assert recheck(scene, final).ok
        for cid, state in final.link.items():
            assert cid in scene.collaborators
            assert abs(state.dx_m) <= 0.5 + 1e-9 and abs(state.dy_m) <= 0.5 + 1e-9
            assert abs(state.dyaw_rad) <= math.radians(1.0) + 1e-9
        assert sum(s.dropped for s in final.link.values()) <= 1
        inserted = [a for a in final.vehicles if a.agent_id.startswith(INSERT_PREFIX)]
        assert len(inserted) <= 3
    if "insert" in kinds:  # some members insert, and an inserted vehicle lies along its lane
        placed = [a for x in q.members for a in space.apply(x).vehicles if a.agent_id.startswith(INSERT_PREFIX)]
        assert placed
        for a in placed[:20]:
            where = scene.lane_map.locate(a.x_m, a.y_m, include_internal=False)
            gap = abs((a.yaw_rad - where.heading_rad + math.pi) % (2 * math.pi) - math.pi)
            assert gap < 1e-6 and a.speed_mps == scene.lane_map.lane(where.lane_id).speed_mps
    again = FeasibleSet(SearchSpace(scene, space.vehicle_ids, cfg), np.random.default_rng(4))
    assert np.array_equal(q.members, again.members)


@pytest.mark.parametrize("level", ["paper", "traffic"])
def test_every_move_of_q_passes_the_recheck_at_its_level(level):
    """Q's moves (drawn by the checker's array tests) all pass the independent re-check at the
    run's level: at ``traffic``, none drives the wrong way, and Q is not left empty by it."""
    scene = _scene()
    space = SearchSpace(scene, ("v2", "v3", "u0"), SpaceConfig(n_q=150, plausibility=level))
    q = FeasibleSet(space, np.random.default_rng(7))
    assert len(q) > 100
    for x in q.members:
        assert recheck(scene, space.apply(x), level, 30.0).ok


def test_a_slot_places_its_draws_at_once_as_one_at_a_time():
    """A moved vehicle's poses and footprints computed for a whole batch of draws are the floats
    its one-at-a-time path gives (so Q does not depend on the path)."""
    from asg.scene.agent import footprint_xy, stacked_footprints_xy

    scene = _scene()
    rng = np.random.default_rng(5)
    for slot in SearchSpace(scene, ("v2", "v3"), SpaceConfig(dyaw_deg=180.0)).slots:
        draws = slot.draw(rng, 4000)
        poses = slot.poses(draws)
        agents = [slot.agent(x) for x in draws]
        assert poses.present.all()
        assert np.array_equal(poses.centres_xy, [(a.x_m, a.y_m) for a in agents])
        assert np.array_equal(poses.yaws_rad, [a.yaw_rad for a in agents])
    x, y = rng.uniform(-3000, 3000, (2, 20000))
    yaw, length, width = rng.uniform(-7, 7, 20000), rng.uniform(0.5, 20, 20000), rng.uniform(0.5, 4, 20000)
    one_at_a_time = np.stack([footprint_xy(*v) for v in zip(x, y, yaw, length, width)])
    assert np.array_equal(stacked_footprints_xy(x, y, yaw, length, width), one_at_a_time)


def test_link_changes_what_the_ego_receives_not_what_sensors_see():
    scene = _scene()
    spec = load_lidar_spec("v2xp")
    space = SearchSpace(scene, (), SpaceConfig(kinds=("pose-error", "dropout"), n_q=50))
    x = space.identity().copy()
    x[:3] = (1.0, -1.0, 0.5)   # the first collaborator's shared pose off by (+0.5 m, -0.5 m, +0.5 deg)
    x[-1] = 1.0                # the second collaborator's message lost
    final = space.apply(x)
    c1, c2 = scene.collaborators
    truth, received = simulate_frame(scene, spec), simulate_frame(final, spec)
    assert received.sensing_ids == (scene.ego_id, c1)
    assert np.array_equal(received.clouds[c1], truth.clouds[c1])
    p, q = truth.poses[c1], received.poses[c1]
    assert (q.x_m - p.x_m, q.y_m - p.y_m) == pytest.approx((0.5, -0.5))
    assert q.yaw_rad - p.yaw_rad == pytest.approx(math.radians(0.5))
    assert np.array_equal(received.ego_boxes, truth.ego_boxes)


@pytest.mark.slow
def test_a_run_in_each_space_is_plausible_and_reproducible(capsys, tmp_path):
    for kinds in ("insert", "pose-error", "dropout", UNION):
        runs = [oracle_run(tmp_path / f"{kinds}-{i}", 2, "--budget", "6", "--space", kinds) for i in range(2)]
        a, b = (json.loads((r / "summary.json").read_text()) for r in runs)
        for entry in a["scenes"]:
            assert all(v == 0 for v in entry["plausibility"].values())
            assert entry["space"]["kinds"] == kinds.split(",")
            final = load_scene(runs[0] / "scenes" / entry["scene_id"] / "final.yaml")
            initial = load_scene(runs[0] / "scenes" / entry["scene_id"] / "after_acs.yaml")
            assert recheck(initial, final).ok
            assert [r["loss"] for r in _history(runs[0], entry["scene_id"])] == \
                [r["loss"] for r in _history(runs[1], entry["scene_id"])]
        strip = lambda s: [{k: v for k, v in e.items() if k != "seconds"} for e in s["scenes"]]
        assert strip(a) == strip(b)
    capsys.readouterr()


@pytest.mark.slow
def test_final_yaml_renders_what_the_search_scored(capsys, tmp_path):
    """final.yaml holds the link and the inserted vehicles: re-rendering it gives the final AP."""
    from asg.objective import ap_at
    from asg.perception.data import in_range
    from fakes import OracleDetector

    out = oracle_run(tmp_path, 2, "--budget", "8", "--space", UNION)
    det = OracleDetector()
    for entry in json.loads((out / "summary.json").read_text())["scenes"]:
        frame = simulate_frame(load_scene(out / "scenes" / entry["scene_id"] / "final.yaml"), load_lidar_spec("v2xp"))
        boxes, scores = det.detect(frame)
        gt = frame.ego_boxes
        assert ap_at([(boxes, scores, gt[in_range(gt)])], (0.3, 0.5, 0.7)) == pytest.approx(entry["ap_final"])
    capsys.readouterr()


def test_insert_with_no_free_lane_position_is_said():
    d = _scene_dict("s0")
    d["lanes"] = {"lanes": [], "junctions": []}
    scene = Scene.from_dict(d)
    space = SearchSpace(scene, (), SpaceConfig(kinds=("insert",), n_q=20, max_draw_factor=2))
    with pytest.raises(EmptyFeasibleSet, match="no free lane position"):
        FeasibleSet(space, np.random.default_rng(0))


@pytest.mark.parametrize("flags, said", [
    (["--space", "poses,teleport"], "unknown perturbation space 'teleport'"),
    (["--space", "poses,poses"], "names a space twice"),
])
def test_bad_space_flags_are_one_line(capsys, tmp_path, flags, said):
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict("s0"))
    code = main(["generate", "--scenes", str(scenes), "--detector", "fakes:oracle_factory", "--out", str(tmp_path / "o"),
                 *flags])
    err = capsys.readouterr().err
    assert code == 2 and said in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("block, said", [
    ({"pose_error": {"xy_m": -0.5}}, "space.pose_error.xy_m"),
    ({"pose_error": {"yaw_deg": 57.3}}, "space.pose_error.yaw_deg"),   # radians mistaken for degrees the other way
    ({"latency": {"max_delay_s": 400}}, "space.latency.max_delay_s"),   # milliseconds given as seconds
    ({"insert": {"max_vehicles": 0}}, "space.insert.max_vehicles"),
    ({"dropout": {"max_lost": -1}}, "space.dropout.max_lost"),
])
def test_bounds_of_the_wrong_sign_or_unit_are_refused(capsys, tmp_path, block, said):
    cfg = yaml.safe_load(Path("configs/generate.yaml").read_text())
    for key, values in block.items():
        cfg["space"][key].update(values)
    path = tmp_path / "g.yaml"
    path.write_text(yaml.safe_dump(cfg))
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict("s0"))
    code = main(["generate", "--scenes", str(scenes), "--detector", "fakes:oracle_factory", "--out", str(tmp_path / "o"),
                 "--config", str(path)])
    err = capsys.readouterr().err
    assert code == 2 and said in err and "Traceback" not in err


def test_space_configs_check_their_bounds():
    for bad in (lambda: PoseErrorConfig(xy_m=float("nan")), lambda: LatencyConfig(max_delay_s=0.0),
                lambda: InsertConfig(max_vehicles=100)):
        with pytest.raises(InputError):
            bad()


@pytest.fixture(scope="module")
def fine_log(tmp_path_factory):
    """A short SUMO log recorded every 0.1 s, and scenes of it (an RSU ego, two collaborators)."""
    from sumo_scenarios.simulate import SimulationRequest, simulate_sumo
    from asg.scene import save_scene
    from asg.scene.from_log import ExtractParams, extract_scenes

    root = tmp_path_factory.mktemp("latency")
    log = root / "log"
    simulate_sumo(SimulationRequest(out_dir=log, town="grid_small", seed=3, duration_s=4.0, warmup_s=40.0,
                                    record_period_s=0.1, density="dense"))
    scenes = list(extract_scenes(log, ExtractParams(every=10, min_vehicles=3, collaborators=2)))
    assert len(scenes) >= 2
    folders = {}
    for name, picked in (("first", scenes[:1]), ("later", scenes[-1:])):
        folders[name] = root / name
        for s in picked:
            save_scene(s, folders[name] / f"{s.scene_id}.yaml")
    return folders


@pytest.mark.slow
def test_latency_renders_the_collaborators_earlier_world(capsys, tmp_path, fine_log):
    out = tmp_path / "run"
    argv = ["generate", "--scenes", str(fine_log["later"]), "--detector", "fakes:oracle_factory", "--budget", "6",
            "--space", "latency", "--workers", "1", "--out", str(out)]
    assert main(argv) == 0
    entry = json.loads((out / "summary.json").read_text())["scenes"][0]
    assert entry["space"]["bounds"]["latency"] == {"max_delay_s": 0.4, "step_s": 0.1, "steps": 4}
    delays = {float(v) for row in _history(out, entry["scene_id"]) for k, v in row.items() if k.endswith("_delay_s")}
    assert delays <= {0.0, 0.1, 0.2, 0.3, 0.4} and len(delays) > 1
    initial = load_scene(out / "scenes" / entry["scene_id"] / "after_acs.yaml")
    spec = load_lidar_spec("v2xp")
    from asg.scene.link import LinkState
    from asg.search.spaces.latency import LatencySpace
    from asg.search.spaces.base import SpaceContext

    space = LatencySpace(SpaceContext(initial, ()), SpaceConfig(kinds=("latency",)))
    cid = initial.collaborators[0]
    earlier = space.earlier_agents(cid, 4)
    state = LinkState(delay_s=0.4, earlier_agents=earlier)
    now = simulate_frame(initial, spec)
    late = simulate_frame(initial.with_link({cid: state}), spec)
    # the collaborator's cloud and shared pose are those of 0.4 s earlier; the ego's are untouched
    me_then = state.earlier_self(cid)
    assert late.poses[cid].x_m == pytest.approx(me_then.x_m) and late.poses[cid].y_m == pytest.approx(me_then.y_m)
    assert np.array_equal(late.clouds[initial.ego_id], now.clouds[initial.ego_id])
    moved = math.hypot(me_then.x_m - initial.agent(cid).x_m, me_then.y_m - initial.agent(cid).y_m)
    assert moved > 0.0 or not np.array_equal(late.clouds[cid], now.clouds[cid])
    capsys.readouterr()


def test_a_latency_before_the_logs_start_is_one_line(capsys, tmp_path, fine_log):
    code = main(["generate", "--scenes", str(fine_log["first"]), "--detector", "fakes:oracle_factory", "--budget", "4",
                 "--space", "latency", "--workers", "1", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 2 and "before its log's start" in err and "Traceback" not in err


def test_latency_needs_the_scenes_log(capsys, tmp_path):
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict("s0"))
    code = main(["generate", "--scenes", str(scenes), "--detector", "fakes:oracle_factory", "--budget", "4",
                 "--space", "latency", "--workers", "1", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 2 and "needs the scene's SUMO log" in err and "Traceback" not in err


@pytest.mark.slow
def test_a_town_sources_scenes_keep_their_log_for_latency(capsys, tmp_path):
    """A source simulated on the fly (a town, a net) keeps its log in the run folder when a space
    reads the past: the scenes are the same as without it, and latency works on them."""
    from dataclasses import replace

    from asg.generator.run import SceneSource, load_scenes

    source = SceneSource(town="grid_small", duration_s=10.0)
    plain = load_scenes(source, 2, 3, tmp_path / "plain")
    kept = load_scenes(source, 2, 3, tmp_path / "work", log_dir=tmp_path / "run" / "log")
    assert [replace(s, log=None).to_dict() for s in kept] == [s.to_dict() for s in plain]
    assert all(s.log is None for s in plain)
    assert all(s.log == str((tmp_path / "run" / "log").resolve()) for s in kept)

    def run(out):
        argv = ["generate", "--town", "grid_small", "--count", "1", "--budget", "3", "--space", "poses,latency",
                "--detector", "fakes:oracle_factory", "--workers", "1", "--out", str(out)]
        assert main(argv) == 0, capsys.readouterr().err
        return json.loads((out / "summary.json").read_text())["scenes"][0]

    entry = run(tmp_path / "a")
    assert entry["space"]["bounds"]["latency"]["step_s"] == pytest.approx(0.1)
    folder = tmp_path / "a" / "scenes" / entry["scene_id"]
    assert "log: ../../log" in (folder / "final.yaml").read_text()
    assert load_scene(folder / "final.yaml").log == str((tmp_path / "a" / "log").resolve())
    run(tmp_path / "b")  # another folder, the same files
    assert (folder / "final.yaml").read_text() == (tmp_path / "b" / "scenes" / entry["scene_id"] / "final.yaml").read_text()
    capsys.readouterr()


def test_each_space_declares_what_it_needs_from_the_run():
    """The generator asks the spaces, not their names: whether to pick movers, how far back to read."""
    from asg.search.space import SpaceConfig
    from asg.search.spaces import LatencyConfig

    poses, links = SpaceConfig(kinds=("poses",)), SpaceConfig(kinds=("dropout", "pose-error"))
    assert poses.needs_movers and not links.needs_movers
    assert poses.past_s == 0.0 and not links.needs_past
    late = SpaceConfig(kinds=("insert", "latency"), latency=LatencyConfig(max_delay_s=0.3))
    assert late.past_s == 0.3 and late.needs_past and not late.needs_movers
