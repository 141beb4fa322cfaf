"""Recordings in OPV2V's layout as a scene source (asg.scene.from_opv2v, asg.sensors.recorded): a
simulated scene exported with ``asg export --format opv2v`` and imported back is the same frame bit
for bit; an edit of the recorded clouds agrees with the simulator re-rendering the same move; bad
recordings are one line."""
from __future__ import annotations

import importlib.util
import math
import os
from dataclasses import replace
from itertools import islice
from pathlib import Path

import numpy as np
import pytest
import yaml

from asg.io.export import export
from asg.scene import save_scene
from asg.scene.from_log import ExtractParams, extract_scenes
from asg.scene.from_opv2v import ImportParams, import_scenes
from asg.scene.recorded_pcd import read_recorded_pcd
from asg.scene.scene import load_scene
from asg.sensors import load_lidar_spec, render_frame, simulate_frame, world_for
from asg.sensors.agreement import share_within
from sumo_scenarios.errors import InputError

from test_cli import assert_one_line_error, run

SPEC = load_lidar_spec()


@pytest.fixture(scope="module")
def recorded(sumo_log, tmp_path_factory):
    """(native scene, its OPV2V export folder, the imported scene, {native id: OPV2V id}): a vehicle
    ego of grid_small with its two nearest vehicles as collaborators."""
    from asg.scene.neighbours import with_nearest_collaborators

    root = tmp_path_factory.mktemp("recorded")
    scene = next(islice(extract_scenes(sumo_log, ExtractParams(every=20, ego="vehicle", min_vehicles=8)), 1, None))
    scene = with_nearest_collaborators(scene, 2)
    save_scene(scene, root / "native" / f"{scene.scene_id}.yaml")
    assert export(root / "native", "opv2v", root / "export") == 1
    (imported,) = import_scenes(root / "export")
    ids = yaml.safe_load((root / "export" / scene.scene_id / "ids.yaml").read_text())["ids"]
    return scene, root / "export", imported, {k: str(v) for k, v in ids.items()}


def test_an_unedited_recording_renders_its_recorded_points_bit_for_bit(recorded):
    scene, export_dir, imported, ids = recorded
    assert imported.source == "recording" and imported.ego_id == ids[scene.ego_id]
    assert set(imported.sensing_ids) == {ids[a] for a in scene.sensing_ids}
    native, frame = simulate_frame(scene, SPEC), simulate_frame(imported, SPEC)
    for agent in scene.sensing_ids:
        cloud = frame.clouds[ids[agent]]
        raw = read_recorded_pcd(export_dir / scene.scene_id / ids[agent] / "000000.pcd")
        assert cloud.dtype == np.float32 and np.array_equal(cloud[:, [0, 2]], raw[:, [0, 2]])
        assert np.array_equal(cloud[:, 1], -raw[:, 1])  # CARLA's left-handed y, mirrored back exactly
        assert np.array_equal(cloud[:, :3], native.clouds[agent][:, :3])  # the simulated frame itself
        pose, ours = native.poses[agent], frame.poses[ids[agent]]
        assert np.allclose([pose.x_m, pose.y_m, pose.z_m, pose.yaw_rad], [ours.x_m, ours.y_m, ours.z_m, ours.yaw_rad])
    assert len(frame.gt_ids) == len(native.gt_ids)
    order = [native.gt_ids.index(next(k for k, v in ids.items() if v == g)) for g in frame.gt_ids]
    assert np.allclose(frame.gt_boxes_world, native.gt_boxes_world[order], atol=1e-9)


def test_a_high_sensors_view_comes_back_in_its_lidars_frame(sumo_log, tmp_path):
    """An RSU ego's view (4.5 m up) is exported in a frame lowered to a car's sensor height; imported,
    it is given back in its LiDAR's own frame, as the native scene has it: the same poses, the same
    ground truth in the ego's frame, the RSU's height, the points within a micrometre, and an
    export of the imported scene lowers it by the same again."""
    scene = next(extract_scenes(sumo_log, ExtractParams(every=20, ego="rsu", min_vehicles=8)))
    assert scene.ego.kind == "rsu"
    save_scene(scene, tmp_path / "native" / f"{scene.scene_id}.yaml")
    assert export(tmp_path / "native", "opv2v", tmp_path / "export") == 1
    record = yaml.safe_load((tmp_path / "export" / scene.scene_id / "ids.yaml").read_text())
    ids, lowered = ({str(k): str(v) for k, v in record[key].items()} for key in ("ids", "frames_lowered_m"))
    assert float(lowered[ids[scene.ego_id]]) > 2.0
    (imported,) = import_scenes(tmp_path / "export")
    native, frame = simulate_frame(scene, SPEC), simulate_frame(imported, SPEC)
    for agent in scene.sensing_ids:
        pose, ours = native.poses[agent], frame.poses[ids[agent]]
        assert np.allclose([pose.x_m, pose.y_m, pose.z_m, pose.yaw_rad], [ours.x_m, ours.y_m, ours.z_m, ours.yaw_rad])
        a, b = native.clouds[agent][:, :3], frame.clouds[ids[agent]][:, :3]
        assert np.abs(a - b).max() <= 1e-6  # the float32 rounding of the export's raise and the import's fall
    rsu = imported.agent(ids[scene.ego_id])
    assert rsu.kind == "rsu" and rsu.z_m == pytest.approx(scene.ego.z_m, abs=1e-5)
    assert rsu.height_m == pytest.approx(scene.ego.height_m, abs=1e-5)
    assert np.allclose(np.sort(frame.ego_boxes, axis=0), np.sort(native.ego_boxes, axis=0), atol=1e-5)
    save_scene(imported, tmp_path / "scenes" / f"{imported.scene_id}.yaml")
    assert export(tmp_path / "scenes", "opv2v", tmp_path / "again") == 1
    again = yaml.safe_load((tmp_path / "again" / imported.scene_id / "ids.yaml").read_text())["frames_lowered_m"]
    assert again == record["frames_lowered_m"]


def test_an_imported_scene_saved_and_loaded_exports_the_recorded_files_again(recorded, tmp_path):
    scene, export_dir, imported, ids = recorded
    save_scene(imported, tmp_path / "scenes" / f"{imported.scene_id}.yaml")
    assert load_scene(tmp_path / "scenes" / f"{imported.scene_id}.yaml").to_dict() == imported.to_dict()
    assert export(tmp_path / "scenes", "opv2v", tmp_path / "again") == 1
    again = tmp_path / "again" / imported.scene_id
    for agent in imported.sensing_ids:
        # the agent numbering is the export's own (0 for the ego, 1000 + i for the others) on both trips
        first = export_dir / scene.scene_id / agent / "000000.pcd"
        assert (again / agent / "000000.pcd").read_bytes() == first.read_bytes()
        ours = yaml.safe_load((again / agent / "000000.yaml").read_text())
        theirs = yaml.safe_load((export_dir / scene.scene_id / agent / "000000.yaml").read_text())
        assert np.allclose(ours["lidar_pose"], theirs["lidar_pose"], atol=1e-9)
        assert ours["vehicles"].keys() == theirs["vehicles"].keys()
        for vid, box in theirs["vehicles"].items():
            for key in ("location", "center", "extent", "angle"):
                assert np.allclose(ours["vehicles"][vid][key], box[key], atol=1e-6), (vid, key)


def _movers(scene, count=2):
    ego = scene.ego
    return sorted((a for a in scene.vehicles if a.agent_id not in scene.sensing_ids),
                  key=lambda a: math.hypot(a.x_m - ego.x_m, a.y_m - ego.y_m))[:count]


@pytest.mark.numeric
def test_an_edit_agrees_with_the_simulator_rendering_the_same_move(recorded):
    """The two nearest other vehicles moved by 1.5 m and turned: the edited scans hold at least
    95 % of the re-simulated points within 5 cm, and the other way round (measured on more scenes:
    docs/experiments/recording_fidelity.py)."""
    scene, _, imported, ids = recorded
    movers = _movers(scene)
    native = {a.agent_id: a.moved(1.5, -1.0, 0.3) for a in movers}
    edited = {ids[k]: replace(v, agent_id=ids[k]) for k, v in native.items()}
    sim = render_frame(world_for(scene, SPEC, movable_ids=native), moved=native)
    world = world_for(imported, SPEC, movable_ids=edited)
    assert world.changed(world.current_vehicles(edited)) == sorted(edited)
    frame = render_frame(world, moved=edited)
    for agent in scene.sensing_ids:
        a, b = sim.clouds[agent], frame.clouds[ids[agent]]
        assert share_within(a, b, 0.05) >= 0.95 and share_within(b, a, 0.05) >= 0.95, agent
    assert not any(np.array_equal(frame.clouds[ids[a]], simulate_frame(imported, SPEC).clouds[ids[a]])
                   for a in scene.sensing_ids)


def test_a_world_that_edits_one_move_after_another_gives_what_a_fresh_world_gives(recorded):
    """A search renders many moves in one world, which keeps each vehicle's removal from one move
    to the next: the same bits as a new world for each move, whichever vehicles change (one, the
    other, both, one removed, none)."""
    from asg.sensors.recorded import RecordedWorld

    _, _, imported, _ = recorded
    a, b = _movers(imported)
    moves = [{a.agent_id: a.moved(1.5, -1.0, 0.3), b.agent_id: b.moved(-1.0, 0.5, -0.2)},
             {a.agent_id: a.moved(0.5, 0.5, 0.1)}, {b.agent_id: b.moved(2.0, 0.0, 0.0)},
             {a.agent_id: None, b.agent_id: b.moved(-1.0, 0.5, -0.2)}, {},
             {a.agent_id: a.moved(1.0, 1.0, 0.0), b.agent_id: b.moved(1.0, -0.5, 0.2)}]
    world = RecordedWorld(imported, SPEC)
    for moved in moves:
        once = RecordedWorld(imported, SPEC).render_many(imported.sensing_ids, moved)
        kept = world.render_many(imported.sensing_ids, moved)
        assert all(np.array_equal(kept[k], once[k]) for k in imported.sensing_ids), moved


def test_a_vehicle_taken_out_and_put_back_at_its_pose_gives_the_recorded_scan(recorded):
    """Removal (its points out, their rays re-cast on the fitted ground and the other vehicles) then
    insertion (the scan's rays on its mesh) at the very same pose: at least 99 % of the recorded
    points within 2 cm, both ways."""
    _, _, imported, _ = recorded
    (car,) = _movers(imported, 1)
    world = world_for(imported, SPEC)
    twin = replace(car, agent_id=car.agent_id + "-twin")
    frame = render_frame(world, moved={car.agent_id: None, twin.agent_id: twin})
    plain = simulate_frame(imported, SPEC)
    for agent in imported.sensing_ids:
        a, b = plain.clouds[agent], frame.clouds[agent]
        assert share_within(a, b, 0.02) >= 0.99 and share_within(b, a, 0.02) >= 0.99, agent


def test_an_inserted_car_hides_what_is_behind_it_and_holds_no_point(recorded):
    """A car put on the road in front of the ego: no returned point lies inside its mesh, the ground
    under it is not hit, points that lay behind it in its shadow are gone, and its faces are hit."""
    from asg.scene.agent import Agent

    _, _, imported, _ = recorded
    world = world_for(imported, SPEC)
    ego = world.sensor_pose(imported.ego_id)
    before = simulate_frame(imported, SPEC).clouds[imported.ego_id]

    def car_at(distance_m: float, bearing_rad: float) -> Agent:
        a = ego.yaw_rad + bearing_rad
        return Agent("inserted", "vehicle", "car", ego.x_m + distance_m * math.cos(a), ego.y_m + distance_m * math.sin(a),
                     imported.ego.z_m, a, 4.5, 1.9, 1.5)

    # the first place on the scanned road, 8 m out, whose shadow holds recorded ground (no other vehicle there)
    car = next(c for c in (car_at(8.0, b) for b in np.radians(np.arange(0, 360, 15)))
               if imported.lane_map.footprint_on_road(c.footprint_xy()) and _in_car(before, ego, c)["behind"].sum() >= 20)
    after = render_frame(world, moved={"inserted": car}).clouds[imported.ego_id]
    local, mesh = _in_car(after, ego, car), _car_mesh(car)
    in_box = np.flatnonzero(local["in_box"])
    assert len(in_box) >= 20  # its faces are hit
    depth = __import__("trimesh").proximity.signed_distance(mesh, local["xyz"][in_box])  # > 0: inside the mesh
    assert depth.max() <= 0.03  # every point in its box lies on its surface, none inside it
    assert not local["ground_under"].any()
    assert _in_car(before, ego, car)["behind"].sum() >= 20 and local["behind"].sum() == 0


def _car_mesh(car):
    from asg.sensors.meshes import agent_template

    return agent_template(car.type_id, car.kind, car.length_m, car.width_m, car.height_m)


def _in_car(cloud: np.ndarray, pose, car) -> dict[str, np.ndarray]:
    """The points (sensor frame of ``pose``) in ``car``'s local frame (``xyz``, origin on the ground
    under its centre), and per point: in its box (grown by 5 cm), ground hit under its middle (1 m
    in from its ends, 30 cm from its sides: a low ray may pass under an overhang, as under a real
    car's), behind it (the ray to the point crosses its body first)."""
    world = cloud[:, :3].astype(float) @ pose.rotation().T + pose.origin
    c, s = math.cos(car.yaw_rad), math.sin(car.yaw_rad)
    d = world - (car.x_m, car.y_m, car.z_m)
    local = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]], axis=1)
    half = np.array([car.length_m, car.width_m]) / 2
    in_box = (np.abs(local[:, :2]) <= half + 0.05).all(axis=1) & (local[:, 2] <= car.height_m + 0.05)
    under = (np.abs(local[:, :2]) <= half - (1.0, 0.3)).all(axis=1) & (local[:, 2] < 0.1)
    origin = pose.origin - (car.x_m, car.y_m, car.z_m)
    o = np.array([c * origin[0] + s * origin[1], -s * origin[0] + c * origin[1], origin[2]])
    behind = np.zeros(len(cloud), bool)
    for frac in np.linspace(0.05, 0.95, 19):  # the ray to the point crosses the body's core first
        p = o + (local - o) * frac
        behind |= (np.abs(p[:, :2]) < half - 0.3).all(axis=1) & (p[:, 2] > 0.4) & (p[:, 2] < car.height_m * 0.5)
    return {"xyz": local, "in_box": in_box, "ground_under": under, "behind": behind & ~in_box}


def test_the_ground_fit_of_a_scan_finds_the_road(recorded):
    from asg.scene.scan_ground import fit_ground

    _, _, imported, _ = recorded
    cloud = simulate_frame(imported, SPEC).clouds[imported.ego_id]
    plane = fit_ground(cloud)
    height_m = world_for(imported, SPEC).sensor_pose(imported.ego_id).z_m - imported.ego.z_m
    assert abs(plane.a) < 1e-3 and abs(plane.b) < 1e-3 and abs(plane.c + height_m) < 0.02
    with pytest.raises(InputError, match="no road"):
        fit_ground(cloud[cloud[:, 2] > -1.0])


def test_numbers_written_without_a_dot_read_as_opencood_reads_them(recorded, tmp_path):
    """OpenCOOD's ``load_yaml`` reads ``2384e-1`` as a number (YAML 1.1 reads a string): a frame
    whose pose and boxes are written so imports as the same scene."""
    from decimal import Decimal

    _, export_dir, imported, _ = recorded
    src = _copy(export_dir, tmp_path / "src")
    scenario = _scenario(src)
    rewritten = 0
    for yml in scenario.glob("*/000000.yaml"):
        meta = yaml.safe_load(yml.read_text())
        tokens = {}

        def undotted(x: float) -> str:  # 238.4 -> "2384e-1", the same decimal value
            sign, digits, exponent = Decimal(repr(float(x))).as_tuple()
            tokens[key := f"NUMBER{len(tokens)}"] = f"{'-' if sign else ''}{int(''.join(map(str, digits)))}e{exponent}"
            return key

        meta["lidar_pose"] = [undotted(v) for v in meta["lidar_pose"]]
        for box in meta["vehicles"].values():
            box["location"] = [undotted(v) for v in box["location"]]
        text = yaml.safe_dump(meta)
        for key, token in sorted(tokens.items(), key=lambda kv: -len(kv[0])):
            text = text.replace(f"'{key}'", token).replace(key, token)
        assert "e-1" in text and "NUMBER" not in text
        yml.write_text(text)
        rewritten += 1
    assert rewritten == 3
    (again,) = import_scenes(src)
    assert again.agents == imported.agents and again.ego_id == imported.ego_id


def test_an_opv2v_ascii_scan_reads_as_open3d_reads_it(tmp_path):
    """OPV2V's own PCDs are ASCII ``x y z rgb`` with the intensity in the red byte of a packed
    colour printed as a float (a subnormal below red 128): read as Open3D reads them (red / 255)."""
    o3d = pytest.importorskip("open3d")

    rng = np.random.default_rng(0)
    xyz = rng.normal(0, 20, (300, 3)).astype(np.float32)
    red = rng.integers(0, 256, 300).astype(np.uint32)
    path = tmp_path / "000070.pcd"
    body = "\n".join(f"{x:.10g} {y:.10g} {z:.10g} {_float32_value(int(r) << 16):.10g}" for (x, y, z), r in zip(xyz, red))
    path.write_text("# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\n"
                    "TYPE F F F F\nCOUNT 1 1 1 1\nWIDTH 300\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 300\n"
                    f"DATA ascii\n{body}\n")
    ours = read_recorded_pcd(path)
    theirs = o3d.io.read_point_cloud(str(path))
    assert np.array_equal(ours[:, :3], xyz) and np.allclose(ours[:, :3], np.asarray(theirs.points), atol=1e-6)
    assert np.allclose(ours[:, 3], np.asarray(theirs.colors)[:, 0], atol=1e-6)
    assert np.array_equal(ours[:, 3], (red / 255.0).astype(np.float32))


def _float32_value(bits: int) -> float:
    """The number a float32 of these bits holds, in Python's integer and float64 arithmetic (a cast
    of a subnormal float32 reads 0 where a library set the CPU's denormals-are-zero mode, as torch's
    threads do)."""
    exponent, mantissa = (bits >> 23) & 0xFF, bits & 0x7FFFFF
    assert exponent < 0xFF
    return mantissa * 2.0 ** -149 if exponent == 0 else (1 + mantissa / 2 ** 23) * 2.0 ** (exponent - 127)


# ---- bad recordings ------------------------------------------------------------------------------
def _copy(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst, symlinks=True)
    return dst


def _scenario(root: Path) -> Path:
    return next(p for p in root.iterdir() if p.is_dir())


PCD_HEADER = ("VERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH {n}\nHEIGHT 1\n"
              "POINTS {n}\nDATA ascii\n")


def _break(case: str, folder: Path) -> None:
    """Spoil the copy of an export ``folder`` as ``case`` says."""
    scenario = _scenario(folder)
    agent = sorted(p for p in scenario.iterdir() if p.is_dir())[-1]
    yml, pcd = agent / "000000.yaml", agent / "000000.pcd"
    if case == "malformed yaml":
        yml.write_text("lidar_pose: [1, 2\n")
    elif case == "a Python tag":
        yml.write_text(yml.read_text() + "hook: !!python/object/apply:os.system ['true']\n")
    elif case == "a NaN in a pose":
        meta = yaml.safe_load(yml.read_text())
        meta["lidar_pose"][0] = float("nan")
        yml.write_text(yaml.safe_dump(meta))
    elif case == "a wrong PCD header":
        pcd.write_text("not a pcd\n")
    elif case == "fewer points than declared":
        pcd.write_text(PCD_HEADER.format(n=3) + "1 2 3 1e-38\n")
    elif case == "a NaN point":
        pcd.write_text(PCD_HEADER.format(n=1) + "nan 2 3 1e-38\n")
    elif case == "10^9 points declared":
        pcd.write_text(PCD_HEADER.format(n=10**9) + "1 2 3 1e-38\n")
    elif case == "timestamps that disagree":
        yml.rename(agent / "000001.yaml")
        pcd.rename(agent / "000001.pcd")
    elif case == "a yaml without its pcd":
        pcd.unlink()
    elif case == "a link out of the source":
        outside = folder.parent / f"outside-{folder.name}"
        outside.mkdir()
        pcd.rename(outside / "000000.pcd")
        os.symlink(outside / "000000.pcd", pcd)
    elif case == "no agent folder":
        for p in scenario.iterdir():
            if p.is_dir():
                import shutil

                shutil.rmtree(p)
    elif case == "an agent id twice":  # "1000" and "01000": one agent to OpenCOOD
        import shutil

        shutil.copytree(agent, agent.with_name("0" + agent.name))
    elif case == "a vehicle id twice":  # a second box under an id the yaml lists already
        vid = next(iter(yaml.safe_load(yml.read_text())["vehicles"]))
        box = "{location: [0, 0, 0], center: [0, 0, 0.7], extent: [2, 1, 0.7], angle: [0, 0, 0]}"
        yml.write_text(yml.read_text().replace("vehicles:\n", f"vehicles:\n  {vid}: {box}\n", 1))
    elif case == "a pose that is a number":
        meta = yaml.safe_load(yml.read_text())
        meta["lidar_pose"] = 5
        yml.write_text(yaml.safe_dump(meta))
    elif case == "a folder that is not a recording":
        (folder / "notes.txt").write_text("x")
        for p in folder.iterdir():
            if p.is_dir():
                import shutil

                shutil.rmtree(p)
    else:
        raise AssertionError(case)


BAD = {"malformed yaml": "not a readable frame yaml", "a Python tag": "numpy",
       "a NaN in a pose": "lidar_pose", "a wrong PCD header": "PCD header",
       "fewer points than declared": "values where POINTS", "a NaN point": "non-finite",
       "10^9 points declared": "declares 1000000000 points", "timestamps that disagree": "other timestamps",
       "a yaml without its pcd": "without a pcd", "a link out of the source": "outside",
       "no agent folder": "holds no OPV2V scenario", "a folder that is not a recording": "holds no OPV2V scenario",
       "an agent id twice": "two agent folders", "a vehicle id twice": "written twice", "a pose that is a number": "lidar_pose"}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_recording_is_one_line_and_writes_nothing(case, recorded, capsys, tmp_path):
    _, export_dir, _, _ = recorded
    src = _copy(export_dir, tmp_path / "src")
    _break(case, src)
    code, err = run(capsys, "scenes", "import", str(src), "--out", str(tmp_path / "out"))
    assert code == 2, err
    assert_one_line_error(err, BAD[case])
    assert not (tmp_path / "out").exists()


def test_import_every_and_limit(recorded, capsys, tmp_path):
    from asg.scene.from_opv2v import planned_count

    _, export_dir, _, _ = recorded
    assert planned_count(export_dir) == 1 == planned_count(export_dir, ImportParams(limit=5))
    code, err = run(capsys, "scenes", "import", str(export_dir), "--out", str(tmp_path / "o"), "--limit", "1")
    assert code == 0 and len(list((tmp_path / "o").glob("*.yaml"))) == 1
    code, err = run(capsys, "scenes", "import", str(export_dir), "--out", str(tmp_path / "p"), "--every", "0")
    assert code == 2


def test_an_import_into_a_folder_of_other_settings_is_refused(recorded, capsys, tmp_path):
    _, export_dir, _, _ = recorded
    out = tmp_path / "o"
    assert run(capsys, "scenes", "import", str(export_dir), "--out", str(out))[0] == 0
    code, err = run(capsys, "scenes", "import", str(export_dir), "--out", str(out), "--every", "3")
    assert code == 2
    assert_one_line_error(err, "other settings (every: 1 -> 3)")
    assert run(capsys, "scenes", "import", str(export_dir), "--out", str(out), "--every", "3", "--force")[0] == 0


@pytest.mark.skipif(not Path("/dev/zero").exists(), reason="needs /dev/zero")
def test_a_scene_naming_a_device_as_its_scan_is_refused_not_read(recorded):
    """A scene file names its scans by path: one that names an endless device is one line, not a
    read until memory runs out."""
    from asg.scene.recording import Recording

    _, _, imported, _ = recorded
    views = dict(imported.recording.views)
    views[imported.ego_id] = replace(views[imported.ego_id], cloud="/dev/zero")
    spoiled = replace(imported, recording=replace(imported.recording, views=views))
    assert isinstance(spoiled.recording, Recording)
    with pytest.raises(InputError, match="not a regular file"):
        simulate_frame(spoiled, SPEC)


def test_a_changed_scan_is_refused_when_the_scene_is_rendered(recorded, tmp_path):
    scene, export_dir, _, _ = recorded
    src = _copy(export_dir, tmp_path / "src")
    (imported,) = import_scenes(src)
    pcd = Path(imported.recording.views[imported.ego_id].cloud)
    pcd.write_bytes(pcd.read_bytes()[:-16] + b"\0" * 16)
    with pytest.raises(InputError, match="sha256 changed"):
        simulate_frame(imported, SPEC)


@pytest.mark.parametrize("flags, needle", [
    (["--space", "insert"], "has no lanes"), (["--plausibility", "traffic"], "has no lanes"),
    (["--space", "latency"], "earlier frames are not imported")])
def test_a_space_a_recording_cannot_take_is_refused_up_front(flags, needle, recorded, capsys, tmp_path):
    _, _, imported, _ = recorded
    save_scene(imported, tmp_path / "scenes" / f"{imported.scene_id}.yaml")
    code, err = run(capsys, "generate", "--scenes", str(tmp_path / "scenes"), "--fusion", "none", "--acs", "off",
                    "--budget", "2", *flags, "--out", str(tmp_path / "gen"))
    assert code == 2
    assert_one_line_error(err, needle)
    assert not (tmp_path / "gen" / "scenes").exists()


@pytest.mark.slow
def test_a_recording_is_attacked_and_its_edited_clouds_export(recorded, capsys, tmp_path):
    """``asg generate --scenes`` on an imported recording (ACS-A, BO) moves vehicles on the area the
    scans show; the attacked run exports to OPV2V with the edited clouds, which OpenCOOD's reader
    (Open3D) reads."""
    import json

    _, _, imported, _ = recorded
    save_scene(imported, tmp_path / "scenes" / f"{imported.scene_id}.yaml")
    code, err = run(capsys, "generate", "--scenes", str(tmp_path / "scenes"), "--budget", "6",
                    "--out", str(tmp_path / "gen"))
    assert code == 0, err
    result = json.loads(next((tmp_path / "gen" / "scenes").glob("*/result.json")).read_text())
    final = load_scene(tmp_path / "gen" / "scenes" / imported.scene_id / "final.yaml")
    assert final.recording is not None and result["plausibility"]["off_road"] == 0
    code, err = run(capsys, "export", str(tmp_path / "gen"), "--format", "opv2v", "--out", str(tmp_path / "x"))
    assert code == 0, err
    frame = simulate_frame(final, SPEC)
    pcd = next((tmp_path / "x").glob(f"*/{final.ego_id}/000000.pcd"))
    assert np.array_equal(read_recorded_pcd(pcd)[:, 0], frame.clouds[final.ego_id][:, 0])  # the edited scan
    if importlib.util.find_spec("opencood") is not None:  # OpenCOOD's own dataset reads the edited export
        from opencood_models import make_model_dir

        from asg.perception.opencood.folder import read_hypes
        from asg.perception.opencood.runtime import module

        hypes = read_hypes(make_model_dir(tmp_path / "m", "intermediate"))
        hypes.update(root_dir=str(tmp_path / "x"), validate_dir=str(tmp_path / "x"))
        item = module("data_utils.datasets").build_dataset(hypes, visualize=False, train=False)[0]
        assert item["ego"]["object_bbx_mask"].sum() > 0 and len(item["ego"]["processed_lidar"]["voxel_features"])


def test_a_map_gives_a_recording_its_lanes_and_a_map_elsewhere_is_refused(recorded, capsys, tmp_path):
    """``--map``: the town's SUMO net, or its OpenDRIVE map (netconvert's own conversion, moved back
    by its netOffset to the map's frame), carries the recording's vehicles on its lanes; another
    town's map is one line."""
    from sumo_scenarios import sumo_tools
    from sumo_scenarios.paths import nets_dir

    scene, export_dir, _, _ = recorded
    net = nets_dir() / f"{scene.town}.net.xml"
    xodr = tmp_path / "town.xodr"
    sumo_tools.run([sumo_tools.binary("netconvert"), "--sumo-net-file", str(net), "--opendrive-output", str(xodr)],
                   "netconvert")
    for map_file in (net, xodr):
        (mapped,) = import_scenes(export_dir, ImportParams(map=map_file))
        assert mapped.lane_map.lanes
        on = [mapped.lane_map.point_on_road(a.x_m, a.y_m) for a in mapped.vehicles]
        assert np.mean(on) >= 0.9, map_file
    code, err = run(capsys, "scenes", "import", str(export_dir), "--map", str(nets_dir() / "roundabout.net.xml"),
                    "--out", str(tmp_path / "o"))
    assert code == 2 and not (tmp_path / "o").exists()
    assert_one_line_error(err, "does not cover the recording")


def test_with_its_map_a_recording_takes_the_traffic_level_and_insertion(recorded, capsys, tmp_path):
    from sumo_scenarios.paths import nets_dir

    scene, export_dir, _, _ = recorded
    code, err = run(capsys, "scenes", "import", str(export_dir), "--map", str(nets_dir() / f"{scene.town}.net.xml"),
                    "--out", str(tmp_path / "scenes"))
    assert code == 0, err
    code, err = run(capsys, "generate", "--scenes", str(tmp_path / "scenes"), "--fusion", "none", "--acs", "off",
                    "--budget", "2", "--plausibility", "traffic", "--space", "poses,insert", "--out", str(tmp_path / "g"))
    assert code == 0, err


def test_cloud_agreement_counts_the_points_near_the_other_cloud():
    a = np.array([[0.0, 0, 0], [1, 0, 0], [5, 0, 0]])
    b = np.array([[0.01, 0, 0], [1.2, 0, 0]])
    assert share_within(a, b, 0.05) == pytest.approx(1 / 3) and share_within(b, a, 0.25) == 1.0
    assert share_within(a[:0], b, 0.1) != share_within(a[:0], b, 0.1) and share_within(a, b[:0], 0.1) == 0.0


@pytest.mark.slow
@pytest.mark.parametrize("space", ["poses", "pose-error,dropout", "poses,pose-error"])
def test_every_space_a_recording_takes_runs_on_it(space, recorded, capsys, tmp_path):
    """The spaces a recording takes without a map (moves on the scanned area, the V2X link) each run
    a search on it (one worker, then two: the scene crosses to a worker process and back)."""
    import json

    _, _, imported, _ = recorded
    save_scene(imported, tmp_path / "scenes" / f"{imported.scene_id}.yaml")
    for workers in ("1", "2"):
        code, err = run(capsys, "generate", "--scenes", str(tmp_path / "scenes"), "--fusion", "none", "--acs", "random",
                        "--budget", "3", "--space", space, "--workers", workers, "--out", str(tmp_path / f"g{workers}"))
        assert code == 0, err
    results = [json.loads(next((tmp_path / f"g{w}" / "scenes").glob("*/result.json")).read_text()) for w in "12"]
    assert results[0]["ap_final"] == results[1]["ap_final"] and results[0]["evaluations"] >= 3


def test_a_v2v4real_frame_reads_its_matrix_poses_and_numpy_tags(tmp_path):
    """V2V4Real's layout: lidar_pose a 4 x 4 matrix to its map, written by PyYAML's full dumper with
    numpy's tags (read as data, nothing constructed), right-handed clouds (not mirrored), obj_type."""
    import math as m

    from asg.io.pcd import write_pcd_rgb_intensity

    scenario = tmp_path / "v2v4real" / "testoutput_CAV_data_2022-03-15-09-54-40_0"
    yaw = 0.3
    pose = np.eye(4)
    pose[:2, :2] = [[m.cos(yaw), -m.sin(yaw)], [m.sin(yaw), m.cos(yaw)]]
    pose[:3, 3] = [10.0, 20.0, 1.8]
    rng = np.random.default_rng(1)
    cloud = np.column_stack([rng.uniform(-30, 30, (400, 2)), np.full(400, -1.8), rng.uniform(0, 1, 400)]).astype(np.float32)
    for agent, shift_m in (("0", 0.0), ("1", 5.0)):  # the second car 5 m further along x
        folder = scenario / agent
        folder.mkdir(parents=True)
        write_pcd_rgb_intensity(folder / "000000.pcd", cloud)
        agent_pose = pose.copy()
        agent_pose[0, 3] += shift_m
        meta = {"lidar_pose": agent_pose,
                "vehicles": {np.int64(7): {"location": np.array([15.0, 22.0, 0.0]), "center": [0.0, 0.0, 0.8],
                                            "extent": [2.3, 1.0, 0.8], "angle": [0.0, np.float64(45.0), 0.0],
                                            "obj_type": "Truck", "ass_id": 3}}}
        (folder / "000000.yaml").write_text(yaml.dump(meta))
    assert "!!python/object/apply:numpy" in (scenario / "0" / "000000.yaml").read_text()
    (scene,) = import_scenes(scenario)
    x, y, z, yaw_read = scene.recording.views["0"].sensor
    assert scene.recording.handed.value == "right" and np.allclose([x, y, z, yaw_read], [10.0, 20.0, 1.8, yaw])
    truck = scene.agent("7")
    assert truck.type_id == "truck" and np.allclose([truck.x_m, truck.y_m, truck.yaw_rad], [15.0, 22.0, m.radians(45)])
    frame = simulate_frame(scene, SPEC)
    assert np.array_equal(frame.clouds["0"][:, :3], cloud[:, :3])  # right-handed: as recorded, not mirrored
    evil = scenario / "1" / "000000.yaml"
    evil.write_text(evil.read_text() + "hook: !!python/object/apply:os.system ['true']\n")
    with pytest.raises(InputError, match="numpy"):
        list(import_scenes(scenario))


def test_a_recording_attacked_in_batches_finds_what_one_at_a_time_finds(recorded):
    """A recorded scene's candidates edited in turn and detected side by side (two threads, one
    torch thread each): the same members, losses and final scene as one thread; the final frame is
    the edit of the final scene (the batch's frames do not share a buffer)."""
    import torch

    from asg.generator.pipeline import GenerateConfig, Generator
    from asg.perception import build_detector
    from asg.search import SpaceConfig

    _, _, imported, _ = recorded
    det = build_detector("attfuse")
    cfg = GenerateConfig(fusion="attfuse", search="rs", acs="off", budget=10, space=SpaceConfig(n_q=60))
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        one, two = (Generator(cfg, det, det, candidate_threads=n).attack(imported, seed=2) for n in (1, 2))
    finally:
        torch.set_num_threads(before)
    assert [(e.x.tolist(), e.loss) for e in one.history] == [(e.x.tolist(), e.loss) for e in two.history]
    assert one.final.to_dict() == two.final.to_dict() and two.moved  # the search moved vehicles
    fresh = render_frame(world_for(two.final, SPEC))
    assert all(np.array_equal(fresh.clouds[a], two.frames["final"].clouds[a]) for a in fresh.sensing_ids)
