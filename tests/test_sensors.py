import math

import numpy as np
import pytest

from asg.sensors import count_points_in_boxes, load_lidar_spec, occlusion_matrix, occlusion_scores, simulate_frame
from asg.sensors.lidar_spec import LidarSpec
from asg.sensors.raycast import EmbreeCaster, TrimeshCaster
from asg.sensors.world import World
from sumo_scenarios.buildings import Building
from sumo_scenarios.errors import InputError

from conftest import car, make_scene, rsu

SMALL = LidarSpec(name="small", channels=16, fov_up_deg=2.0, fov_down_deg=-25.0, points_per_s=16 * 180 * 10,
                  rotation_hz=10.0, range_m=70.0)


def unit_box_triangles():
    import trimesh

    m = trimesh.creation.box(extents=[1, 1, 1])
    return m.vertices[m.faces]


@pytest.mark.parametrize("caster_cls", [EmbreeCaster, lambda tris: EmbreeCaster(tris, packets=False), TrimeshCaster],
                         ids=["embree-packets", "embree-single", "trimesh"])
def test_ray_hits_box_and_plane_analytically(caster_cls):
    box = unit_box_triangles()
    plane = np.array([[[-50, -50, -2.0], [50, -50, -2.0], [50, 50, -2.0]], [[-50, -50, -2.0], [50, 50, -2.0], [-50, 50, -2.0]]])
    c = caster_cls(np.concatenate([box, plane]))
    o = np.array([[-5.0, 0.1, 0.2], [0.0, 0.0, 5.0], [3.0, 3.0, 0.0], [0.2, -6.0, 0.0]])
    s = math.sqrt(0.5)
    d = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, s, -s], [0, 1.0, 0]])
    t, prim = c.first_hits(o, d)
    assert t[0] == pytest.approx(4.5, abs=1e-5)     # box face x = -0.5
    assert t[1] == pytest.approx(4.5, abs=1e-5)     # box top z = 0.5
    assert t[2] == pytest.approx(2 * math.sqrt(2), abs=1e-5)  # plane z = -2 at 45 deg
    assert t[3] == pytest.approx(5.5, abs=1e-5)
    assert (prim >= 0).all()
    t_far, prim_far = c.first_hits(o[:1], d[:1], np.array([3.0]))
    assert np.isinf(t_far[0]) and prim_far[0] == -1


def test_packet_cast_agrees_with_single_rays_on_axis_aligned_fans():
    """Embree's packets (16 rays a call, coherent traversal) hit what embreex's one-ray-at-a-time
    cast hits, also for rays with a direction component of exactly 0 or below Embree's 1e-18
    (a sensor yawed a multiple of 90 deg): such a ray was culled before those are cast as 1e-6."""
    from asg.sensors.embree import packet_library

    if packet_library() is None:
        pytest.skip("embreex's Embree 4 library is not where a Linux wheel puts it")
    wall = np.array([[[10.0, -20, -2], [10, 20, -2], [10, 20, 6]], [[10.0, -20, -2], [10, 20, 6], [10, -20, 6]]])
    tris = np.concatenate([wall, unit_box_triangles() * 2 + [5.0, 3.0, 0.0]])
    azimuth = np.radians(np.linspace(-40, 40, 81))
    d = np.stack([np.cos(azimuth), np.sin(azimuth), np.full_like(azimuth, -0.05)], axis=1)
    d[40, 1] = -5.19e-33  # the straight-ahead ray: y below 1e-18, negative
    d = np.concatenate([d, d * [1.0, 1.0, 0.0]])  # and a fan with z exactly 0
    d /= np.linalg.norm(d, axis=1)[:, None]
    o = np.tile([0.0, 0.0, 1.0], (len(d), 1))
    packets = EmbreeCaster(tris, robust=False)
    single = EmbreeCaster(tris, robust=False, packets=False)
    assert packets._packets is not None and single._packets is None
    t_p, prim_p = packets.first_hits(o, d, np.full(len(d), 60.0))
    t_s, prim_s = single.first_hits(o, d, np.full(len(d), 60.0))
    assert (prim_s >= 0).all()
    assert np.array_equal(prim_p, prim_s)
    assert np.allclose(t_p, t_s, atol=1e-4)
    assert np.array_equal(packets.first_prims(o, d, np.full(len(d), 60.0, dtype=np.float32)), prim_s)


def test_empty_world_sees_only_ground(cross_map):
    spec = SMALL
    scene = make_scene(cross_map, [rsu("r", 0.0, 0.0)])
    pts = World(scene, spec).render("r")
    el = spec.elevations_rad()
    expected = 0
    for e in el:
        if e < 0 and 4.5 / math.tan(-e) <= spec.range_m:
            expected += spec.azimuth_steps
    assert len(pts) == expected
    assert np.allclose(pts[:, 2], -4.5, atol=1e-4)
    assert (pts[:, 3] > 0).all() and (pts[:, 3] <= 0.2 + 1e-6).all()


def test_car_in_front_is_hit_where_expected(cross_map):
    # a bus 20 m east of a car sensor: its rear face is at x = 20 - 6 = 14 m
    scene = make_scene(cross_map, [car("ego", 0.0, -1.6), car("bus", 20.0, -1.6, type_id="bus")])
    pts = World(scene, SMALL).render("ego")
    ahead = pts[(np.abs(pts[:, 1]) < 0.5) & (pts[:, 0] > 0) & (pts[:, 2] > -1.5)]
    assert len(ahead) and ahead[:, 0].min() == pytest.approx(14.0, abs=0.05)
    # the sensor never sees its own body
    own = (np.abs(pts[:, 0]) <= 2.3) & (np.abs(pts[:, 1]) <= 0.93)
    assert not own.any()


@pytest.mark.parametrize("type_id", ["car", "truck", "bus"])
def test_sensor_never_sees_its_own_body_when_surrounded(cross_map, type_id):
    # objects in every direction make every ray a candidate for the static scene, own body included
    ring = [car(f"n{k}", 14 * math.cos(k * math.pi / 4), 14 * math.sin(k * math.pi / 4), k * math.pi / 4) for k in range(8)]
    ego = car("ego", 0.0, 0.0, 0.3, type_id)
    pts = World(make_scene(cross_map, [ego, *ring]), SMALL).render("ego")
    half_l, half_w = ego.length_m / 2 + 0.01, ego.width_m / 2 + 0.01
    own = (np.abs(pts[:, 0]) <= half_l) & (np.abs(pts[:, 1]) <= half_w)
    assert not own.any()


def test_embree_matches_trimesh_backend(cross_map):
    agents = [car("ego", 0.0, -1.6), car("a", 12.0, -1.6, type_id="van"), car("b", -9.0, 1.6, math.pi, "truck"),
              car("c", 1.6, 15.0, math.pi / 2, "suv"), rsu("r", 9.0, 9.0)]
    bld = [Building("b0", np.array([[10.0, 12.0], [30.0, 12.0], [30.0, 25.0], [10.0, 25.0]]), 12.0)]
    scene = make_scene(cross_map, agents, bld)
    fast = World(scene, SMALL).render("ego")
    slow = World(scene, SMALL.with_overrides(backend="trimesh")).render("ego")
    # Embree can miss hits exactly on triangle edges: compare within a tolerance
    assert abs(len(fast) - len(slow)) <= 0.005 * len(slow)
    r_fast = np.sort(np.linalg.norm(fast[:, :3], axis=1))
    r_slow = np.sort(np.linalg.norm(slow[:, :3], axis=1))
    n = min(len(r_fast), len(r_slow))
    assert np.mean(np.abs(r_fast[:n] - r_slow[:n]) < 1e-3) > 0.99


def test_embree_robust_mode_changes_almost_nothing(cross_map):
    """Robust traversal off (the presets' default, about 20% faster casts) and on give the same
    points, ray by ray, but for rays slipping through a shared triangle edge."""
    ring = [car(f"n{k}", 11 * math.cos(k * 0.8), 11 * math.sin(k * 0.8), k * 0.8, ["car", "van", "truck", "bus"][k % 4])
            for k in range(7)]
    bld = [Building("b0", np.array([[10.0, 12.0], [30.0, 12.0], [30.0, 25.0], [10.0, 25.0]]), 12.0)]
    scene = make_scene(cross_map, [car("ego", 0.0, 0.0, 0.2), *ring], bld)
    assert not SMALL.embree_robust
    fast = World(scene, SMALL).render("ego")
    robust = World(scene, SMALL.with_overrides(embree_robust=True)).render("ego")
    assert len(fast) == len(robust)
    moved_m = np.abs(fast[:, :3] - robust[:, :3]).max(axis=1)
    assert np.mean(moved_m < 0.01) > 0.999


def test_culled_render_equals_casting_every_ray(cross_map):
    """The renderer casts only candidate rays and takes the ground analytically; casting every ray
    of the sweep against all triangles of the world (ground square included) gives the same
    first-hit distance on every ray (Embree's edge misses aside)."""
    ring = [car(f"n{k}", 9 * math.cos(k * 0.7), 9 * math.sin(k * 0.7), k * 0.7, ["car", "van", "truck"][k % 3])
            for k in range(9)]
    bld = [Building("b0", np.array([[10.0, 12.0], [30.0, 12.0], [30.0, 25.0], [10.0, 25.0]]), 12.0),
           Building("b1", np.array([[-30.0, -25.0], [-12.0, -25.0], [-12.0, -10.0]]), 5.0),
           # an L, clockwise: extruded by trimesh rather than fanned
           Building("b2", np.array([[12.0, -12.0], [12.0, -30.0], [30.0, -30.0], [30.0, -26.0], [16.0, -26.0], [16.0, -12.0]]), 9.0)]
    scene = make_scene(cross_map, [car("ego", 0.0, 0.0, 0.2), rsu("r", -14.0, 14.0), *ring], bld, collaborators=["r"])
    world = World(scene, SMALL)
    world.render_many(scene.sensing_ids)
    every = EmbreeCaster(world.world_triangles())
    for sid in scene.sensing_ids:
        rays = world._rays(sid)
        t, prim = every.first_hits(rays.starts32.astype(float), rays.dirs_w, SMALL.range_m - rays.t_start)
        brute = np.where(prim >= 0, t + rays.t_start, np.inf)
        brute[brute > SMALL.range_m] = np.inf
        ours = world._base_cache[sid].t.copy()
        ours[ours > SMALL.range_m] = np.inf
        with np.errstate(invalid="ignore"):  # inf - inf where both miss
            same = (np.isinf(brute) & np.isinf(ours)) | (np.abs(brute - ours) < 2e-3)
        assert np.isfinite(ours).sum() > 0.5 * len(ours)
        assert same.mean() > 0.998, (sid, same.mean())


def test_xy_distance_to_triangles():
    """The range cull of each sensor's static view: distance seen from above, 0 inside."""
    from asg.sensors.world import xy_distance_to_triangles

    tris = np.array([
        [[0, 0, 0], [10, 0, 0], [0, 10, 5]],      # the point (2, 2) lies inside it
        [[20, -5, 0], [20, 5, 0], [20, 5, 8]],    # a wall: a segment x = 20 seen from above
        [[5, 30, 3], [8, 34, 3], [5, 34, 3]],     # a corner nearest: (5, 30)
    ], dtype=float)
    d = xy_distance_to_triangles(tris, np.array([2.0, 2.0]))
    assert d == pytest.approx([0.0, 18.0, math.hypot(3.0, 28.0)])


@pytest.mark.parametrize("footprint", [
    [[0, 0], [10, 0], [10, 8], [0, 8]],                                  # convex, counter-clockwise
    [[0, 8], [10, 8], [10, 0], [0, 0]],                                  # convex, clockwise
    [[0, 0], [20, 0], [20, 5], [5, 5], [5, 15], [0, 15]],                # an L, counter-clockwise
    [[0, 15], [5, 15], [5, 5], [20, 5], [20, 0], [0, 0]],                # an L, clockwise
])
def test_building_meshes_are_closed_and_face_outward(footprint):
    """Each sensor casts only against the static faces turned towards it, which is exact only if
    every mesh is closed with its normals outward (a positive signed volume)."""
    from shapely.geometry import Polygon

    from asg.sensors.meshes import building_mesh

    m = building_mesh(Building("b", np.array(footprint, dtype=float), 7.0))
    assert m.is_watertight and m.volume == pytest.approx(Polygon(footprint).area * 7.0)


@pytest.mark.parametrize("type_id", ["car", "suv", "van", "truck", "bus", "rsu"])
def test_agent_meshes_are_closed_and_face_outward(type_id):
    from asg.sensors.meshes import agent_template, vehicle_parts

    if type_id == "rsu":
        parts = [agent_template("rsu", "rsu", 0.4, 0.4, 5.0)]
    else:
        parts = vehicle_parts(type_id, 4.6, 1.9, 1.7)
    for part in parts:
        assert part.is_watertight and part.volume > 0


def test_rerender_after_move_equals_full_render(cross_map):
    agents = [car("ego", 0.0, -1.6), car("m1", 12.0, -1.6), car("m2", -15.0, 1.6, math.pi), car("s", 25.0, 1.6, math.pi),
              car("col", -1.6, 20.0, -math.pi / 2)]
    bld = [Building("b0", np.array([[10.0, 8.0], [30.0, 8.0], [30.0, 25.0], [10.0, 25.0]]), 8.0)]
    scene = make_scene(cross_map, agents, bld, collaborators=["col"])
    world = World(scene, SMALL, movable_ids=["m1", "m2"])
    world.render_many(scene.sensing_ids)  # fill the static cache at the original poses
    moves = {"m1": (1.5, 0.3, math.radians(20)), "m2": (-2.0, -0.4, math.radians(-30))}
    moved = {k: scene.agent(k).moved(*v) for k, v in moves.items()}
    quick = world.render_many(scene.sensing_ids, moved)
    full = World(scene.moved(moves), SMALL).render_many(scene.sensing_ids)
    for sid in scene.sensing_ids:
        assert quick[sid].shape == full[sid].shape
        assert np.allclose(quick[sid], full[sid], atol=2e-3)


def test_noise_and_dropoff_are_seeded(cross_map):
    scene = make_scene(cross_map, [car("ego", 0.0, -1.6), car("a", 10.0, -1.6)])
    spec = SMALL.with_overrides(noise_std_m=0.05, dropoff=0.1)
    w = World(scene, spec)
    a, b, c = w.render("ego", seed=1), w.render("ego", seed=1), w.render("ego", seed=2)
    clean = World(scene, SMALL).render("ego")
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert 0.85 * len(clean) < len(a) < 0.95 * len(clean)


def test_points_in_box_counts():
    pts = np.array([[0.0, 0.0, 0.0, 1], [1.5, 0.5, 0.2, 1], [2.4, 0.0, 0.0, 1], [0.0, 0.0, 1.0, 1], [5.0, 5.0, 0.0, 1]])
    boxes = np.array([[0.0, 0.0, 0.0, 4.0, 2.0, 1.5, 0.0], [0.0, 0.0, 0.0, 4.0, 2.0, 1.5, math.pi / 2], [5, 5, 0, 1, 1, 1, 0]])
    assert count_points_in_boxes(pts, boxes).tolist() == [2, 1, 1]


def test_frame_labels_and_counts(cross_map):
    scene = make_scene(cross_map, [rsu("r", 8.0, 8.0), car("a", -10.0, -1.6), car("b", 20.0, 1.6, math.pi)],
                       collaborators=["a"])
    frame = simulate_frame(scene, SMALL)
    assert frame.gt_ids == ("a", "b")
    counts = frame.points_in_boxes()
    assert counts["r"][1] > 20  # the RSU sees car b
    assert counts["a"][0] == 0  # car a never sees itself
    assert (counts["fused"] == counts["r"] + counts["a"]).all()
    # boxes in the RSU frame: the RSU's yaw is 0, so only a shift
    assert np.allclose(frame.ego_boxes[1, :2], [12.0, -6.4])


def test_car_behind_car_occluded_from_one_side_only(cross_map):
    front, behind = car("front", 10.0, -1.6), car("behind", 20.0, -1.6)
    west = occlusion_matrix((-5.0, -1.6), [front, behind])
    east = occlusion_matrix((35.0, -1.6), [front, behind])
    north = occlusion_matrix((15.0, 40.0), [front, behind])
    assert west[0, 1] and not west[1, 0]
    assert east[1, 0] and not east[0, 1]
    assert not north.any()
    scores = occlusion_scores([rsu("r", -5.0, -1.6)], [front, behind])
    assert scores == {"front": 1, "behind": 1}


def test_bad_lidar_specs():
    with pytest.raises(InputError, match="channels"):
        LidarSpec(channels=0).validate()
    with pytest.raises(InputError, match="range_m"):
        LidarSpec(range_m=-1.0).validate()
    with pytest.raises(InputError, match="embree_robust"):
        LidarSpec(embree_robust="no").validate()
    # a preset whose sweep would not fit in memory (points_per_s 1e12 took 24 GB and was killed), or
    # that no sensor has, is refused when loaded
    for key, value in (("points_per_s", 1e12), ("rotation_hz", 1e-9), ("channels", 10**7), ("range_m", 1e12),
                       ("fov_down_deg", -200.0), ("noise_std_m", 1e9), ("vehicle_mount_above_roof_m", -100.0)):
        with pytest.raises(InputError, match=key):
            LidarSpec(**{key: value}).validate()
    with pytest.raises(InputError, match="unknown lidar preset"):
        load_lidar_spec("nope")
    assert load_lidar_spec("v2xp").rays_per_sweep == 32 * 390
    assert load_lidar_spec("dense64").channels == 64
    vlp16 = load_lidar_spec("vlp16")
    assert (vlp16.channels, vlp16.rays_per_sweep) == (16, 16 * 1875)
    assert np.allclose(np.degrees(vlp16.elevations_rad()[[0, -1]]), [15.0, -15.0])


def test_empty_scene_is_refused(cross_map):
    scene = make_scene(cross_map, [rsu("r", 8.0, 8.0)])
    with pytest.raises(InputError, match="empty scene"):
        simulate_frame(scene, SMALL)


@pytest.mark.parametrize("type_id", ["car", "suv", "van", "truck", "bus"])
def test_vehicle_meshes_lie_strictly_inside_their_box(type_id):
    from asg.sensors.meshes import MESH_INSET_M, vehicle_template

    l, w, h = 4.6, 1.9, 1.7
    v = vehicle_template(type_id, l, w, h).vertices
    assert np.abs(v[:, 0]).max() == pytest.approx(l / 2 - MESH_INSET_M)
    assert np.abs(v[:, 1]).max() == pytest.approx(w / 2 - MESH_INSET_M)
    assert v[:, 2].max() == pytest.approx(h - MESH_INSET_M) and v[:, 2].min() == pytest.approx(0.0)


def test_every_return_off_a_vehicle_passes_a_strict_in_box_test(cross_map):
    """OpenCOOD keeps a point in a box only strictly inside it: each vehicle's returns (above the
    ground) are counted the same with no margin as with a generous one."""
    scene = make_scene(cross_map, [car("ego", 0.0, -1.6), car("a", 9.0, -1.6), car("b", -8.0, 1.6, math.pi),
                                   car("c", 2.0, 12.0, math.radians(70))])
    frame = simulate_frame(scene, SMALL)
    pts = frame.clouds["ego"]
    above = pts[pts[:, 2] > frame.ego_boxes[:, 2].min() - frame.ego_boxes[:, 5].max() / 2 + 0.05]
    strict = count_points_in_boxes(above, frame.ego_boxes, margin_m=-1e-6)
    loose = count_points_in_boxes(above, frame.ego_boxes, margin_m=0.3)
    assert (loose > 10).all() and strict.tolist() == loose.tolist()


def _hammer_embree(iterations: int) -> None:
    """Build, cast and release Embree scenes ``iterations`` times, two casters at a time cast on two
    threads (as World's static views are), some dropped in reference cycles that the collector
    frees on whichever thread allocates; every cast checked against the first."""
    import gc

    from asg.sensors import world as world_mod

    rng = np.random.default_rng(0)
    box = unit_box_triangles()
    dirs = rng.normal(size=(512, 3)).astype(np.float32)
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    origins = np.zeros((512, 3), dtype=np.float32)
    far = np.full(512, 50.0, dtype=np.float32)
    wall = np.array([[[10.0, -20, -2], [10, 20, -2], [10, 20, 6]], [[10.0, -20, -2], [10, 20, 6], [10, -20, 6]]])
    kept = []
    for i in range(iterations):
        tris = np.concatenate([wall, *(box + rng.normal(0, 6, 3) for _ in range(int(rng.integers(1, 40))))])
        casters = [EmbreeCaster(tris, robust=bool(i % 2)), EmbreeCaster(tris, robust=bool(i % 2))]
        results = [None, None]

        def cast(k):
            results[k] = casters[k].first_prims(origins, dirs, far)
            _ = [object() for _ in range(500)]  # allocations: the collector may run on this thread

        world_mod._run_on_two_threads([lambda: cast(0), lambda: cast(1)])
        assert np.array_equal(results[0], results[1])
        cycle = {"caster": casters[0]}
        cycle["self"] = cycle  # freed by the collector, not by reference counting
        kept.append(casters[1])
        del kept[:-8]
        if i % 50 == 0:
            gc.collect()


def test_embree_scenes_built_cast_and_released_many_times():
    """The lifetime pattern of a render (issue: a native crash of the suite), hammered."""
    _hammer_embree(300)


@pytest.mark.exhaustive
def test_embree_scenes_built_cast_and_released_thousands_of_times():
    _hammer_embree(3000)


def _hammer_trimesh_caster(iterations: int) -> None:
    """Two threads casting through one TrimeshCaster at once (World's static views with backend
    trimesh), each caster then freed by the collector: the pattern that corrupted the heap when
    two threads queried trimesh's R-tree together (the suite's native crash); every cast checked
    against a cast on one thread."""
    import gc
    import threading

    rng = np.random.default_rng(1)
    box = unit_box_triangles()
    dirs = rng.normal(size=(500, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    origins = np.zeros((500, 3))
    for i in range(iterations):
        caster = TrimeshCaster(np.concatenate([box + rng.normal(0, 6, 3) for _ in range(100)]))
        expected = caster.first_hits(origins, dirs)
        results = [None, None]

        def cast(k, caster=caster):
            results[k] = caster.first_hits(origins, dirs)

        threads = [threading.Thread(target=cast, args=(k,)) for k in range(2)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        for t, prim in results:
            assert np.array_equal(t, expected[0]) and np.array_equal(prim, expected[1])
        cycle = {"caster": caster}
        cycle["self"] = cycle
        del caster, cycle
        if i % 10 == 0:
            gc.collect()


@pytest.mark.slow
def test_trimesh_caster_cast_on_two_threads_many_times():
    _hammer_trimesh_caster(60)


@pytest.mark.exhaustive
def test_trimesh_caster_cast_on_two_threads_thousands_of_times():
    _hammer_trimesh_caster(2000)
