"""``asg export``: each format read back by a reader that is not ours (Open3D as OpenCOOD reads PCD,
OpenCOOD's box projection for the OPV2V yaml, numpy and OpenPCDet's conversion for KITTI, the
ASAM XML schema for OpenSCENARIO, sumolib and SUMO itself for the routes); unsafe input refused."""
import math
from itertools import islice

import numpy as np
import pytest
import yaml

from asg.io.export import EXPORT_FORMATS, export
from sumo_scenarios.errors import InputError
from asg.io.export.kitti import TR_VELO_TO_CAM
from asg.sensors.opv2v import opv2v_ids
from asg.perception.data import in_range
from asg.scene import save_scene
from asg.scene.from_log import ExtractParams, extract_scenes
from asg.sensors import load_lidar_spec, simulate_frame

from opencood_reader import boxes_from_opv2v_yaml, pcd_to_np
from test_cli import assert_one_line_error, run


@pytest.fixture(scope="module")
def scenes_dir(sumo_log, tmp_path_factory):
    """Two scenes of grid_small: one with an RSU ego, one with a vehicle ego, 2 collaborators each."""
    out = tmp_path_factory.mktemp("export_scenes")
    rsu = next(extract_scenes(sumo_log, ExtractParams(every=20, ego="rsu", min_vehicles=5, collaborators=2)))
    veh = next(islice(extract_scenes(sumo_log, ExtractParams(every=20, ego="vehicle", min_vehicles=5, collaborators=2)), 1, None))
    for scene in (rsu, veh):
        save_scene(scene, out / f"{scene.scene_id}.yaml")
    return out, (rsu, veh)


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _assert_same_boxes(got, want, atol):
    """Each box of ``want`` (M, 7) has its own box in ``got`` at its centre, equal within ``atol``."""
    got, want = np.asarray(got, float), np.asarray(want, float)
    assert got.shape == want.shape and len(want) > 0
    for b in want:
        a = got[np.argmin(np.hypot(got[:, 0] - b[0], got[:, 1] - b[1]))]
        assert np.allclose(a[:6], b[:6], atol=atol) and abs(_wrap(a[6] - b[6])) < atol, (a, b)


@pytest.mark.slow
def test_opv2v_reads_back_as_opencood_reads_it(scenes_dir, tmp_path):
    folder, scenes = scenes_dir
    assert export(folder, "opv2v", tmp_path) == 2
    spec = load_lidar_spec("v2xp")
    for scene in scenes:
        frame = simulate_frame(scene, spec)
        ids = opv2v_ids(scene)
        scenario = tmp_path / scene.scene_id
        agents = sorted(p.name for p in scenario.iterdir() if p.is_dir())
        assert sorted(agents) == sorted(str(ids[a]) for a in frame.sensing_ids)
        record = yaml.safe_load((scenario / "ids.yaml").read_text())
        order = agents[1:] + agents[:1] if int(agents[0]) < 0 else agents  # OpenCOOD's rule, written out
        assert record["opencood_ego"] == int(order[0]) == record["ego"] == ids[scene.ego_id]  # our ego, always
        for agent_id in frame.sensing_ids:
            meta = yaml.safe_load((scenario / str(ids[agent_id]) / "000000.yaml").read_text())
            cloud = pcd_to_np(scenario / str(ids[agent_id]) / "000000.pcd")
            ours = frame.clouds[agent_id]
            # each agent's frame at a car's sensor height: its points raised, its lidar_pose lowered by this
            drop = record["frames_lowered_m"][ids[agent_id]]
            assert agent_id != scene.ego_id or drop == record["ego_frame_lowered_m"]
            assert cloud.shape == ours.shape
            assert np.allclose(cloud[:, 0], ours[:, 0], atol=1e-4) and np.allclose(cloud[:, 1], -ours[:, 1], atol=1e-4)
            assert np.allclose(cloud[:, 2], ours[:, 2] + drop, atol=1e-4)
            assert np.allclose(cloud[:, 3], np.clip(ours[:, 3], 0, 1), atol=1 / 255 + 1e-6)
            # OpenCOOD's projection of the yaml's vehicles into this agent's lidar frame = our
            # ground truth in that frame, mirrored (y -> -y, yaw -> -yaw)
            boxes = boxes_from_opv2v_yaml(meta["vehicles"], meta["lidar_pose"])
            truth = frame.boxes_in(agent_id)
            truth = truth[np.asarray(frame.gt_ids) != agent_id]
            if frame.ego_box_world is not None and agent_id != frame.ego_id:
                from asg.sensors.frame import boxes_to_sensor

                truth = np.vstack([truth, boxes_to_sensor(frame.ego_box_world[None], frame.poses[agent_id])])
            mirrored = truth.copy()
            mirrored[:, 1] *= -1
            mirrored[:, 6] *= -1
            mirrored[:, 2] += drop
            _assert_same_boxes(boxes, mirrored, atol=1e-3)


def test_views_all_writes_each_collaborators_view_as_its_own_scenario(scenes_dir, tmp_path):
    """``--views all``: each scene once more as each collaborator sees it (SCENE-as-AGENT), that agent
    OpenCOOD's ego; its cloud and its ground truth there are the ones it had as a collaborator, and
    the scene's ego is a collaborator of it."""
    from asg.scene.views import Views

    folder, scenes = scenes_dir
    assert export(folder, "opv2v", tmp_path, views=Views.ALL) == sum(len(s.sensing_ids) for s in scenes) == 6
    for scene in scenes:
        ids = opv2v_ids(scene)
        for agent_id in scene.collaborators:
            view = tmp_path / f"{scene.scene_id}-as-{agent_id}"
            record = yaml.safe_load((view / "ids.yaml").read_text())
            assert record["ego"] == record["opencood_ego"] == 0
            assert record["ids"][agent_id] == 0 and record["ids"][scene.ego_id] in record["sensing"]
            as_collaborator = tmp_path / scene.scene_id / str(ids[agent_id])
            assert (view / "0" / "000000.pcd").read_bytes() == (as_collaborator / "000000.pcd").read_bytes()
            meta = [yaml.safe_load((d / "000000.yaml").read_text()) for d in (view / "0", as_collaborator)]
            boxes = [boxes_from_opv2v_yaml(m["vehicles"], m["lidar_pose"]) for m in meta]
            _assert_same_boxes(boxes[0], boxes[1], atol=1e-6)


def test_views_all_refuses_a_scene_whose_links_were_degraded(capsys, cross_map, tmp_path):
    """A link record (what a collaborator's message went through on its way to the ego) holds for
    that ego only: ``--views all`` of such a scene is one line, not a scene with a wrong link."""
    from dataclasses import replace

    from asg.scene.link import LinkState
    from conftest import car, make_scene, rsu

    scene = make_scene(cross_map, [rsu("r", 8.0, 8.0), car("a", -10.0, -1.6)], collaborators=["a"])
    save_scene(replace(scene, link={"a": LinkState(dx_m=0.2)}), tmp_path / "scenes" / "s.yaml")
    code, err = run(capsys, "export", str(tmp_path / "scenes"), "--format", "opv2v", "--views", "all",
                    "--out", str(tmp_path / "o"))
    assert code == 2
    assert_one_line_error(err, "links were degraded", "--views ego")


def test_an_export_into_a_folder_of_another_export_is_refused(capsys, scenes_dir, tmp_path):
    """The folder records what it holds: another format, views or source into it is one line and
    writes nothing; the same command again redoes it; a bad source claims nothing."""
    folder, scenes = scenes_dir
    out = tmp_path / "o"
    command = ["export", str(folder), "--format", "sumo", "--out", str(out)]
    assert run(capsys, *command)[0] == 0
    held = sorted(p.name for p in out.iterdir())
    assert "asg-export.json" in held
    for change, says in ((["--format", "openscenario"], "format 'sumo', not 'openscenario'"),
                         (["--views", "all"], "views 'ego', not 'all'")):
        code, err = run(capsys, *command, *change)
        assert code == 2
        assert_one_line_error(err, says, "give another --out")
        assert sorted(p.name for p in out.iterdir()) == held
    code, err = run(capsys, "export", str(tmp_path / "missing"), "--format", "sumo", "--out", str(out))
    assert code == 2 and sorted(p.name for p in out.iterdir()) == held
    assert run(capsys, *command)[0] == 0
    code, err = run(capsys, "export", str(tmp_path / "missing"), "--format", "sumo", "--out", str(tmp_path / "new"))
    assert code == 2 and not (tmp_path / "new" / "asg-export.json").exists()
    (out / "asg-export.json").write_text("[1, 2]")
    code, err = run(capsys, *command)
    assert code == 2
    assert_one_line_error(err, "not a record asg wrote")


def openpcdet_info_builder_reads(root, frames: int) -> None:
    """What OpenPCDet's ``create_kitti_infos`` reads before it looks at a label, as its
    ``KittiDataset`` does it (8cacccec): the split lists ``ImageSets/{train,val,test}.txt``, each
    listed frame's ``training/image_2/NNNNNN.png`` (its shape: ``io.imread(f).shape[:2]``), calib
    and velodyne; then the field-of-view flag it counts points in boxes with."""
    from PIL import Image

    from asg.io.export.kitti import IMAGE_WH, P2

    splits = {s: (root / "ImageSets" / f"{s}.txt").read_text().split() for s in ("train", "val", "test")}
    assert len(splits["train"]) == len(splits["val"]) == frames and splits["test"] == []
    for idx in splits["train"]:
        image = root / "training" / "image_2" / f"{idx}.png"
        assert image.exists()  # KittiDataset.get_image_shape asserts this
        shape = np.asarray(Image.open(image)).shape[:2]
        assert tuple(shape) == (IMAGE_WH[1], IMAGE_WH[0])
        points = np.fromfile(root / "training" / "velodyne" / f"{idx}.bin", dtype=np.float32).reshape(-1, 4)
        # get_fov_flag: points projected with P2 (rect = velo -> cam here) inside the image, depth >= 0
        rect = points[:, :3] @ TR_VELO_TO_CAM[:, :3].T
        uvw = np.hstack([rect, np.ones((len(rect), 1))]) @ P2.T
        u, v = uvw[:, 0] / uvw[:, 2], uvw[:, 1] / uvw[:, 2]
        fov = (u >= 0) & (u < shape[1]) & (v >= 0) & (v < shape[0]) & (rect[:, 2] >= 0)
        assert 0 < fov.sum() < len(points)  # a forward-looking camera sees part of a 360-degree sweep


def test_kitti_labels_convert_back_to_the_ego_ground_truth(scenes_dir, tmp_path):
    folder, scenes = scenes_dir
    export(folder, "kitti", tmp_path)
    ids = yaml.safe_load((tmp_path / "ids.yaml").read_text())
    lowered = yaml.safe_load((tmp_path / "ego_frame.yaml").read_text())["lowered_m"]
    advised = yaml.safe_load((tmp_path / "point_cloud_range.yaml").read_text())["POINT_CLOUD_RANGE"]
    assert (tmp_path / "ImageSets" / "val.txt").read_text().split() == sorted(ids)
    openpcdet_info_builder_reads(tmp_path, len(ids))
    spec = load_lidar_spec("v2xp")
    for name, scene_id in ids.items():
        scene = next(s for s in scenes if s.scene_id == scene_id)
        frame = simulate_frame(scene, spec)
        points = np.fromfile(tmp_path / "training" / "velodyne" / f"{name}.bin", dtype=np.float32).reshape(-1, 4)
        assert len(points) == sum(len(c) for c in frame.clouds.values())
        # OpenPCDet: location (bottom centre, camera) -> lidar, z to the centre, yaw = -(ry + pi/2)
        back = []
        for line in (tmp_path / "training" / "label_2" / f"{name}.txt").read_text().splitlines():
            f = line.split()
            assert f[0] in ("Car", "Truck") and len(f) == 15
            h, w, l_, x, y, z, ry = map(float, f[8:15])
            velo = np.linalg.lstsq(TR_VELO_TO_CAM[:, :3], np.array([x, y, z]), rcond=None)[0]
            back.append([velo[0], velo[1], velo[2] + h / 2, l_, w, h, -(ry + math.pi / 2)])
        want = frame.ego_boxes[in_range(frame.ego_boxes)].copy()
        want[:, 2] += lowered[name]  # an RSU ego's view in a frame at a car's sensor height
        _assert_same_boxes(back, want, atol=0.011)
        # the range the export advises covers every label's centre (KITTI's stock one is front-only)
        lo, hi = np.array(advised[:3]), np.array(advised[3:])
        centres = np.asarray(back)[:, :3]
        assert np.all((centres >= lo) & (centres <= hi)), centres


def test_openscenario_validates_against_the_schema(scenes_dir, tmp_path):
    import xmlschema
    import scenariogeneration
    from pathlib import Path

    folder, scenes = scenes_dir
    export(folder, "openscenario", tmp_path)
    schema = xmlschema.XMLSchema(str(Path(scenariogeneration.__file__).parents[1] / "schemas" / "OpenSCENARIO_1_2.xsd"))
    for scene in scenes:
        path = tmp_path / f"{scene.scene_id}.xosc"
        schema.validate(str(path))
        text = path.read_text()
        assert f'name="ego_{scene.ego_id}"' in text and all(f'name="collaborator_{c}"' in text for c in scene.collaborators)
        assert 'filepath="grid_small.xodr"' in text
    assert (tmp_path / "grid_small.xodr").read_text().lstrip().startswith("<?xml")


def test_sumo_routes_continue_in_sumo(scenes_dir, tmp_path):
    import sumolib

    folder, scenes = scenes_dir
    export(folder, "sumo", tmp_path)
    scene = scenes[1]
    vehicles = list(sumolib.xml.parse(str(tmp_path / f"{scene.scene_id}.rou.xml"), "vehicle"))
    assert sorted(v.id for v in vehicles) == sorted(a.agent_id for a in scene.vehicles)
    import libsumo

    libsumo.start(["sumo", "-c", str(tmp_path / f"{scene.scene_id}.sumocfg"), "--no-step-log", "--no-warnings"])
    try:
        libsumo.simulationStep()
        running = set(libsumo.vehicle.getIDList())
        near = 0
        for a in scene.vehicles:
            if a.agent_id in running:
                x, y = libsumo.vehicle.getPosition(a.agent_id)  # the front of the vehicle
                fx, fy = a.x_m + math.cos(a.yaw_rad) * a.length_m / 2, a.y_m + math.sin(a.yaw_rad) * a.length_m / 2
                near += math.hypot(x - fx, y - fy) < 2.0 + a.speed_mps * 1.0
    finally:
        libsumo.close()
    assert len(running) >= 0.8 * len(scene.vehicles) and near >= 0.8 * len(running)
    # SUMO's own snapshot of the scene, read back by sumolib: every vehicle with its route
    states = {v.id: v for v in sumolib.xml.parse(str(tmp_path / f"{scene.scene_id}.state.xml"), "vehicle")}
    assert set(states) == {a.agent_id for a in scene.vehicles}


def _resized(scene, sizes_m):
    """``scene`` with its first vehicles made cars of the given (length, width, height) each."""
    from dataclasses import replace

    from asg.scene import Scene

    vehicles = sorted(scene.vehicles, key=lambda a: a.agent_id)[:len(sizes_m)]
    new = {a.agent_id: replace(a, type_id="car", length_m=s[0], width_m=s[1], height_m=s[2])
           for a, s in zip(vehicles, sizes_m)}
    d = scene.to_dict()
    d["agents"] = [new[a["id"]].to_dict() if a["id"] in new else a for a in d["agents"]]
    return Scene.from_dict(d), sorted(new)


def test_vehicles_of_one_type_keep_their_own_sizes_in_sumo(scenes_dir, tmp_path):
    """A recording's cars share a type and differ in size: each keeps its own length, width and
    height in the routes and in SUMO's own state (one vType a size), not the first car's."""
    import sumolib

    _, scenes = scenes_dir
    sizes = [(4.2, 1.8, 1.5), (5.1, 2.0, 1.6), (4.2, 1.8, 1.5)]
    scene, ids = _resized(scenes[1], sizes)
    folder = tmp_path / "in"
    folder.mkdir()
    save_scene(scene, folder / f"{scene.scene_id}.yaml")
    export(folder, "sumo", tmp_path / "out")
    routes = str(tmp_path / "out" / f"{scene.scene_id}.rou.xml")
    vtypes = {t.id: (float(t.length), float(t.width), float(t.height)) for t in sumolib.xml.parse(routes, "vType")}
    of = {v.id: v.type for v in sumolib.xml.parse(routes, "vehicle")}
    assert [vtypes[of[i]] for i in ids] == sizes and len({of[i] for i in ids}) == 2
    state = str(tmp_path / "out" / f"{scene.scene_id}.state.xml")
    in_state = {t.id: float(t.length) for t in sumolib.xml.parse(state, "vType") if t.id in vtypes}
    assert [in_state[of[i]] for i in ids] == [s[0] for s in sizes]


def test_a_scene_sumo_refuses_leaves_none_of_its_files_and_says_why(capsys, scenes_dir, tmp_path, monkeypatch):
    """SUMO's first error is the one line, and the scene's routes and config are not left behind
    half done (its state file never came)."""
    from sumo_scenarios import sumo_tools

    folder, scenes = scenes_dir
    fake = tmp_path / "sumo"
    fake.write_text("#!/bin/sh\necho 'Error: the cause' >&2\necho 'Quitting (on error).' >&2\nexit 1\n")
    fake.chmod(0o755)
    monkeypatch.setattr(sumo_tools, "binary", lambda name: str(fake))
    code, err = run(capsys, "export", str(folder), "--format", "sumo", "--out", str(tmp_path / "out"))
    assert code == 2
    assert_one_line_error(err, "SUMO could not load the exported routes (Error: the cause)")
    assert not [p.name for p in (tmp_path / "out").iterdir() if p.suffix in (".xml", ".sumocfg")]


def test_unsafe_or_bad_export_input_is_one_line(capsys, scenes_dir, tmp_path):
    folder, _ = scenes_dir
    bad = tmp_path / "bad"
    bad.mkdir()
    text = next(folder.glob("*.yaml")).read_text()
    (bad / "x.yaml").write_text(text.replace(text.split("scene_id: ")[1].split("\n")[0], "../../escape"))
    for argv, needle in ((["export", str(bad), "--format", "opv2v", "--out", str(tmp_path / "o")], "scene_id"),
                         (["export", str(folder), "--format", "nope", "--out", str(tmp_path / "o")], "--format"),
                         (["export", str(tmp_path / "missing"), "--format", "kitti", "--out", str(tmp_path / "o")], "unknown set"),
                         (["export", str(folder), "--format", "sumo", "--out", str(tmp_path / "o"),
                           "--net", str(tmp_path / "none.net.xml")], "not found")):
        code, err = run(capsys, *argv)
        assert code == 2, argv
        assert_one_line_error(err, needle)
    assert not list(tmp_path.parent.glob("escape*"))


@pytest.mark.parametrize("fmt", ["sumo", "openscenario"])
def test_a_town_that_is_a_path_is_not_read(capsys, scenes_dir, tmp_path, fmt):
    """A scene whose ``town`` climbs out of nets/ is refused, not read from where it points."""
    folder, _ = scenes_dir
    bad = tmp_path / "bad"
    bad.mkdir()
    text = next(folder.glob("*.yaml")).read_text()
    town = text.split("\ntown: ")[1].split("\n")[0]
    (bad / "x.yaml").write_text(text.replace(f"\ntown: {town}\n", f"\ntown: ../nets/{town}\n"))
    code, err = run(capsys, "export", str(bad), "--format", fmt, "--out", str(tmp_path / "o"))
    assert code == 2
    assert_one_line_error(err, "not a bundled or imported town")


def test_an_out_folder_that_cannot_be_is_one_line(capsys, scenes_dir, tmp_path):
    """--out on a symbolic link to nowhere, or where no folder can be made (/proc): one line."""
    folder, _ = scenes_dir
    dangling = tmp_path / "dangling"
    dangling.symlink_to(tmp_path / "missing" / "dir")
    for out, needle in ((dangling, "symbolic link"), ("/proc/asg-export-test", "cannot create")):
        code, err = run(capsys, "export", str(folder), "--format", "kitti", "--out", str(out))
        assert code == 2
        assert_one_line_error(err, needle)


def test_opencood_takes_our_ego_whatever_its_kind(cross_map):
    """Every mix of ego kind and sensing RSUs (0 to 3 besides the ego): OpenCOOD's ego rule applied
    to the folder names picks our ego; ids are unique."""
    from dataclasses import replace

    from asg.sensors.opv2v import opencood_ego
    from conftest import car, make_scene, rsu

    agents = [car("v0", 0, 0), car("v1", 10, 0), car("v2", 20, 0)] + [rsu(f"r{i}", 5 * i, 8) for i in range(4)]
    base = make_scene(cross_map, agents, ego="v0")
    for ego in ("v0", "r0"):
        for k in range(4):  # sensing RSUs besides an RSU ego / with a vehicle ego
            collaborators = ("v1", "v2") if ego == "r0" else ("v1",)
            sensing_rsus = [f"r{i}" for i in range(1, k + 1)] if ego == "r0" else [f"r{i}" for i in range(k)]
            scene = replace(base, ego_id=ego, collaborators=(*collaborators, *sensing_rsus))
            sensing = (ego, *scene.collaborators)
            ids = opv2v_ids(scene, sensing)
            assert len(set(ids.values())) == len(ids) == len(agents)
            assert opencood_ego([str(ids[a]) for a in sensing]) == str(ids[ego]), (ego, sensing, ids)


#: the stacks' stock ranges, as their configs write them: OpenCOOD's ground-truth range (its
#: point_pillar yaml's postprocess gt_range) and OpenPCDet's KITTI point-cloud range
OPENCOOD_GT_RANGE = (-140.8, -40.0, -3.0, 140.8, 40.0, 1.0)
OPENPCDET_RANGE = (0.0, -39.68, -3.0, 69.12, 39.68, 1.0)


def _inside(centres, limits, axes: int = 3) -> np.ndarray:
    """OpenCOOD's and OpenPCDet's box-centre test: (M,) every coordinate (the first ``axes``) within its limits."""
    lo, hi = np.asarray(limits[:axes]), np.asarray(limits[3:3 + axes])
    return ((centres[:, :axes] >= lo) & (centres[:, :axes] <= hi)).all(axis=1)


def test_every_in_range_vehicle_survives_each_stacks_stock_range(scenes_dir, tmp_path):
    """RSU ego and vehicle ego: of the vehicles our evaluation counts whose x and y lie in a stack's
    stock range, every one is kept once z is checked too (seen from an RSU's pole they all had z
    near -3.8 and both stacks dropped them): OpenCOOD's ego (the ego's yaml projected into its
    lidar_pose) and OpenPCDet's frame (the KITTI labels)."""
    folder, scenes = scenes_dir
    assert {s.ego.kind for s in scenes} == {"rsu", "vehicle"}
    export(folder, "opv2v", tmp_path / "opv2v")
    export(folder, "kitti", tmp_path / "kitti")
    spec = load_lidar_spec("v2xp")
    for scene in scenes:
        truth = simulate_frame(scene, spec).ego_boxes
        truth = truth[in_range(truth)]
        record = yaml.safe_load((tmp_path / "opv2v" / scene.scene_id / "ids.yaml").read_text())
        meta = yaml.safe_load((tmp_path / "opv2v" / scene.scene_id / str(record["opencood_ego"]) / "000000.yaml").read_text())
        boxes = boxes_from_opv2v_yaml(meta["vehicles"], meta["lidar_pose"])
        counted = in_range(boxes) & _inside(boxes, OPENCOOD_GT_RANGE, axes=2)
        assert counted.sum() == _inside(truth, OPENCOOD_GT_RANGE, axes=2).sum() > 0
        assert _inside(boxes[counted], OPENCOOD_GT_RANGE).all(), (scene.scene_id, boxes[counted, 2])
    for name in yaml.safe_load((tmp_path / "kitti" / "ids.yaml").read_text()):
        centres = []
        for line in (tmp_path / "kitti" / "training" / "label_2" / f"{name}.txt").read_text().splitlines():
            h, x, y, z = (float(v) for v in [line.split()[8], *line.split()[11:14]])
            centres.append(np.linalg.lstsq(TR_VELO_TO_CAM[:, :3], np.array([x, y - h / 2, z]), rcond=None)[0])
        centres = np.array(centres)
        in_xy = _inside(centres, OPENPCDET_RANGE, axes=2)
        assert in_xy.any() and _inside(centres[in_xy], OPENPCDET_RANGE).all(), (name, centres[in_xy, 2])


@pytest.mark.parametrize("fmt", EXPORT_FORMATS.names())
@pytest.mark.parametrize("views", ["ego", "all"])
def test_export_of_an_rsu_ego_run_exits_zero(capsys, scenes_dir, tmp_path, fmt, views):
    """A folder holding an RSU-ego scene (the default ``asg generate`` makes them) exports in every format
    with exit code 0 and no error, as its egos' views and as every sensing agent's."""
    folder, scenes = scenes_dir
    assert any(s.ego.kind == "rsu" for s in scenes)
    code, err = run(capsys, "export", str(folder), "--format", fmt, "--views", views, "--out", str(tmp_path / "o"))
    assert code == 0, err
    assert "error" not in err
    assert len([p for p in (tmp_path / "o").iterdir() if not p.name.startswith(".") and p.name != "asg-export.json"]) >= 1


def test_scenes_of_one_id_are_exported_apart(tmp_path, cross_map):
    """A data set may hold two scenes of one id (detector-train: the same town, seed and time at two
    densities); the export gives the second its own folder instead of merging their agents."""
    from asg.datasets import unique_ids
    from conftest import car, make_scene, rsu

    scene = make_scene(cross_map, [rsu("r", 8.0, 8.0), car("a", -10.0, -1.6)], collaborators=["a"])
    ids = [s.scene_id for s in unique_ids(iter([scene, scene, scene]))]
    assert ids == [scene.scene_id, f"{scene.scene_id}-2", f"{scene.scene_id}-3"]


@pytest.mark.parametrize("link", ["final.yaml", "scene folder"])
def test_a_link_out_of_a_run_folder_is_not_followed(capsys, scenes_dir, tmp_path, link):
    """A run folder's final.yaml, or a scene's folder, that is a link (asg writes none) is one line,
    as asg report refuses it; nothing is exported."""
    folder, _ = scenes_dir
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "final.yaml").write_text(next(folder.glob("*.yaml")).read_text())
    run_dir = tmp_path / "run"
    (run_dir / "scenes").mkdir(parents=True)
    (run_dir / "run.json").write_text("{}")
    if link == "final.yaml":
        (run_dir / "scenes" / "s0").mkdir()
        (run_dir / "scenes" / "s0" / "final.yaml").symlink_to(outside / "final.yaml")
    else:
        (run_dir / "scenes" / "s0").symlink_to(outside)
    code, err = run(capsys, "export", str(run_dir), "--format", "opv2v", "--out", str(tmp_path / "o"))
    assert code == 2
    assert_one_line_error(err, "a link, which asg never writes")
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_rosbag2_reads_back_as_the_frame(scenes_dir, tmp_path):
    """Each scene's bag, read by rosbags' own reader and deserialiser: every sensing agent's cloud
    equal to the simulated one in its sensor frame, its sensor pose on /tf_static, the ground truth
    the AP counts as boxes in the map frame, every message at the scene's time."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    from asg.io.export.rosbag2 import ros_names
    from asg.perception.data import in_range

    folder, scenes = scenes_dir
    assert export(folder, "rosbag2", tmp_path) == 2
    store = get_typestore(Stores.ROS2_JAZZY)
    ids = yaml.safe_load((tmp_path / "ids.yaml").read_text())
    spec = load_lidar_spec("v2xp")
    for scene in scenes:
        frame = simulate_frame(scene, spec)
        names = ros_names(frame.sensing_ids)
        assert ids[scene.scene_id]["ego"] == names[scene.ego_id] and ids[scene.scene_id]["agents"] == names
        bag = tmp_path / scene.scene_id
        assert {p.name for p in bag.iterdir()} == {"metadata.yaml", f"{scene.scene_id}.mcap"}
        with Reader(bag) as reader:
            msgs = {c.topic: store.deserialize_cdr(raw, c.msgtype) for c, t, raw in reader.messages()}
            stamps = {t for _, t, _ in reader.messages()}
        assert stamps == {round(scene.time_s * 1e9)}
        assert set(msgs) == {"/tf_static", "/asg/ground_truth", *(f"/asg/{names[a]}/points" for a in frame.sensing_ids)}
        tf = {t.child_frame_id: t for t in msgs["/tf_static"].transforms}
        for agent in frame.sensing_ids:
            cloud = msgs[f"/asg/{names[agent]}/points"]
            assert cloud.header.frame_id == names[agent] and [f.name for f in cloud.fields] == ["x", "y", "z", "intensity"]
            points = np.frombuffer(cloud.data.tobytes(), "<f4").reshape(cloud.width, 4)
            assert np.array_equal(points, frame.clouds[agent][:, :4].astype(np.float32)) and len(points) > 100
            t, pose = tf[names[agent]], frame.poses[agent]
            assert t.header.frame_id == "map"
            assert np.allclose([t.transform.translation.x, t.transform.translation.y, t.transform.translation.z],
                               pose.origin, atol=1e-9)
            q = t.transform.rotation
            assert abs(_wrap(2 * math.atan2(q.z, q.w) - pose.yaw_rad)) < 1e-9 and q.x == q.y == 0.0
        keep = in_range(frame.ego_boxes)
        markers = msgs["/asg/ground_truth"].markers
        assert [m.text for m in markers] == [v for v, k in zip(frame.gt_ids, keep) if k] == ids[scene.scene_id]["ground_truth"]
        got = [[m.pose.position.x, m.pose.position.y, m.pose.position.z, m.scale.x, m.scale.y, m.scale.z,
                2 * math.atan2(m.pose.orientation.z, m.pose.orientation.w)] for m in markers]
        _assert_same_boxes(got, frame.gt_boxes_world[keep], 1e-9)
        assert all(m.header.frame_id == "map" and m.type == 1 for m in markers)
        # Foxglove's reader (its own ROS 2 decoder, from the schemas the bag carries) reads the same
        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory

        with open(bag / f"{scene.scene_id}.mcap", "rb") as fh:
            decoded = {c.topic: (s.name, m) for s, c, _, m in make_reader(fh, decoder_factories=[DecoderFactory()])
                       .iter_decoded_messages()}
        assert {t: name for t, (name, _) in decoded.items()} == {t: m.__msgtype__ for t, m in msgs.items()}
        for agent in frame.sensing_ids:
            theirs = decoded[f"/asg/{names[agent]}/points"][1]
            assert theirs.width == len(frame.clouds[agent]) and bytes(theirs.data) == msgs[f"/asg/{names[agent]}/points"].data.tobytes()
        assert [m.text for m in decoded["/asg/ground_truth"][1].markers] == [m.text for m in markers]


def test_rosbag2_names_are_ros_names():
    """Agent ids become ROS name tokens (a letter first; [A-Za-z0-9_]); two that would meet stay apart."""
    from asg.io.export.rosbag2 import ros_names, stamp_ns

    assert ros_names(["12", "flow.3", "flow_3", "-1"]) == {"12": "agent_12", "flow.3": "agent_flow_3",
                                                          "flow_3": "agent_flow_3_2", "-1": "agent__1"}
    assert stamp_ns(12.5) == 12_500_000_000
    for bad in (-1.0, float("nan")):
        with pytest.raises(InputError, match="cannot stamp"):
            stamp_ns(bad)


def test_rosbag2_without_rosbags_is_one_line(capsys, scenes_dir, tmp_path, monkeypatch):
    """Without the ros extra, --format rosbag2 names the extra in one line and writes nothing."""
    import builtins

    real_import = builtins.__import__

    def no_rosbags(name, *args, **kwargs):
        if name.startswith("rosbags"):
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_rosbags)
    folder, _ = scenes_dir
    code, err = run(capsys, "export", str(folder), "--format", "rosbag2", "--out", str(tmp_path / "o"))
    assert code == 2
    assert_one_line_error(err, "asg[ros]")
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


@pytest.mark.parametrize("fmt, planted", [("kitti", "training/velodyne"), ("kitti", "ImageSets"),
                                          ("opv2v", "SCENE/0"), ("sumo", "x")])
def test_no_export_writes_through_a_link_planted_inside_out(fmt, planted, scenes_dir, capsys, tmp_path):
    """A link inside --out (to another folder) is refused before anything is written, in every format."""
    import os

    folder, (scene, _) = scenes_dir
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    elsewhere.mkdir()
    link = out / planted.replace("SCENE", scene.scene_id)
    link.parent.mkdir(parents=True)
    os.symlink(elsewhere, link)
    code, err = run(capsys, "export", str(folder), "--format", fmt, "--out", str(out))
    assert code == 2
    assert_one_line_error(err, "symbolic link inside --out")
    assert not any(elsewhere.iterdir())


@pytest.mark.parametrize("argv", [
    ["export", "SCENES", "--format", "opv2v", "--out", "LONG"],
    ["evaluate", "--fusion", "none", "--set", "LONG", "--limit", "1"],
    ["generate", "--scenes", "SCENES", "--fusion", "none", "--acs", "off", "--budget", "1", "--out", "LONG"],
    ["export", "LONG", "--format", "kitti", "--out", "OUT"]])
def test_a_name_longer_than_the_file_system_allows_is_one_line(argv, scenes_dir, capsys, tmp_path):
    folder, _ = scenes_dir
    long = str(tmp_path / ("n" * 300) / "x")
    argv = [{"SCENES": str(folder), "LONG": long, "OUT": str(tmp_path / "o")}.get(a, a) for a in argv]
    code, err = run(capsys, *argv)
    assert code == 2
    assert_one_line_error(err)


def test_every_export_format_says_whether_it_reads_the_net():
    """``--net`` is refused for a format that does not read it: each writer says which it is."""
    from asg.io.export import EXPORT_FORMATS

    reads = {name: EXPORT_FORMATS.entry(name).reads_net for name in EXPORT_FORMATS.names()}
    assert all(isinstance(v, bool) for v in reads.values())
    assert {name for name, v in reads.items() if v} == {"openscenario", "sumo"}
