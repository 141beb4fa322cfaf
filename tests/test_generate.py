"""The generator end to end with a fake detector (ground truth for well-seen boxes): fast."""
import dataclasses
import math

import numpy as np
import pytest

from asg.generator.pipeline import GenerateConfig, Generator
from asg.scene.feasibility import FeasibilityChecker
from asg.scene.recheck import moved_vehicles
from asg.scene.from_log import ExtractParams, extract_scenes
from asg.search import FeasibleSet, SearchSpace, SpaceConfig
from asg.search.space import EmptyFeasibleSet
from sumo_scenarios.errors import InputError

from conftest import car, make_scene, rsu
from fakes import OracleDetector

FAST = GenerateConfig(fusion="none", search="rs", acs="attention", budget=8, space=SpaceConfig(n_q=200))


@pytest.fixture(scope="module")
def busy_scene(sumo_log):
    scenes = list(extract_scenes(sumo_log, ExtractParams(every=20, min_vehicles=8)))
    assert scenes
    return max(scenes, key=lambda s: len(s.vehicles))


def make_gen(cfg=FAST):
    det = OracleDetector()
    return Generator(cfg, det, det)


def test_generate_is_plausible_and_reproducible(busy_scene):
    gen = make_gen()
    a = gen.attack(busy_scene, seed=4)
    b = gen.attack(busy_scene, seed=4)
    assert a.final.to_dict() == b.final.to_dict() and [e.loss for e in a.history] == [e.loss for e in b.history]
    assert a.plausibility.ok
    assert len(a.after_acs.collaborators) == 2 and len(a.perturbed) == 3
    assert not set(a.perturbed) & set(a.after_acs.sensing_ids)
    assert a.loss_final <= min([e.loss for e in a.history] + [a.loss_final]) + 1e-12
    assert a.evaluations == 1 + 3 + 8
    moved = {x.agent_id for x in a.final.agents} and [x for x in a.final.agents
                                                       if x.to_dict() != a.after_acs.agent(x.agent_id).to_dict()]
    assert {x.agent_id for x in moved} <= set(a.perturbed)
    # the fcl checker that built Q agrees with the published, independently re-checked scene
    moved_now = {m.agent_id: m for m in moved_vehicles(a.after_acs, a.final)}
    assert FeasibilityChecker(a.after_acs, list(moved_now)).check(moved_now).ok


def test_every_algorithm_runs_and_finals_are_plausible(busy_scene):
    for search in ("rs", "ga", "bo"):
        cfg = GenerateConfig(fusion="none", search=search, acs="random", budget=6, space=SpaceConfig(n_q=100))
        r = make_gen(cfg).attack(busy_scene, seed=1)
        assert r.plausibility.ok and len(r.history) == 6


def test_projection_returns_a_member_of_q(busy_scene):
    gen = make_gen()
    ids = gen.pick_perturbed(busy_scene.with_collaborators([]), [])
    space = SearchSpace(busy_scene, ids, SpaceConfig(n_q=100))
    q = FeasibleSet(space, np.random.default_rng(0))
    rng = np.random.default_rng(1)
    checker = FeasibilityChecker(busy_scene, ids)
    for _ in range(20):
        p = q.project(rng.uniform(-1.5, 1.5, space.dim))
        assert any(np.array_equal(p, m) for m in q.members)
        assert checker.check(space.moved_agents(p)).ok


def test_feasible_set_fills_for_a_tight_queue():
    # three cars 1 m apart in one lane: each alone accepts a few percent of uniform moves, so joint
    # rejection sampling (p^3) would keep almost nothing in 2,000 draws; Q must still fill, with
    # every member plausible (neighbours in the queue can collide with each other) and reproducible
    from sumo_scenarios.lanes import Lane, LaneMap

    one_lane = LaneMap([Lane("e_0", np.array([[-100.0, 0.0], [100.0, 0.0]]), 3.2, 13.9)])
    agents = [rsu("r", 0.0, 8.0)] + [car(f"c{i}", -5.6 * i, 0.0) for i in range(3)]
    scene = make_scene(one_lane, agents)
    ids = ["c0", "c1", "c2"]
    space = SearchSpace(scene, ids, SpaceConfig(n_q=50, max_draw_factor=40))
    q = FeasibleSet(space, np.random.default_rng(0))
    assert len(q) == 51 and len({m.tobytes() for m in q.members}) == 51
    checker = FeasibilityChecker(scene, ids)
    assert all(checker.check(space.moved_agents(m)).ok for m in q.members)
    assert np.array_equal(q.members, FeasibleSet(space, np.random.default_rng(0)).members)
    # joint rejection on the same draw count keeps (almost) nothing
    rng = np.random.default_rng(0)
    joint = sum(checker.check(space.moved_agents(x)).ok for x in rng.uniform(-1, 1, (2000, 9)))
    assert joint <= 5


def test_boxed_in_vehicle_has_empty_feasible_set():
    # a car squeezed between two buses on a one-lane road cannot move without touching one or leaving it
    from sumo_scenarios.lanes import Lane, LaneMap

    one_lane = LaneMap([Lane("e_0", np.array([[-100.0, 0.0], [100.0, 0.0]]), 3.2, 13.9)])
    agents = [rsu("r", 0.0, 6.0), car("front", 8.0, 0.0, type_id="bus"), car("mid", -0.5, 0.0),
              car("back", -9.0, 0.0, type_id="bus")]
    scene = make_scene(one_lane, agents)
    space = SearchSpace(scene, ["mid"], SpaceConfig(n_q=50, max_draw_factor=4))
    with pytest.raises(EmptyFeasibleSet, match="no plausible move"):
        FeasibleSet(space, np.random.default_rng(0))


def test_fewer_vehicles_than_m_is_reported(cross_map):
    agents = [rsu("r", 9.0, 9.0), car("a", -20.0, -1.6), car("b", 20.0, 1.6, math.pi), car("c", 1.6, -25.0, math.pi / 2)]
    scene = make_scene(cross_map, agents)
    cfg = GenerateConfig(fusion="none", search="rs", acs="random", budget=4, space=SpaceConfig(n_q=50))
    r = make_gen(cfg).attack(scene, seed=0)
    assert any("fewer than m" in n for n in r.notes) or any("candidate" in n for n in r.notes)
    assert r.plausibility.ok


def test_unknown_search_name_in_config():
    with pytest.raises(InputError, match="unknown search algorithm 'sa'"):
        GenerateConfig(search="sa").validate()


@pytest.mark.slow
def test_bench_paper_spreads_its_scenes_over_the_set(tmp_path, busy_scene):
    """The benchmark takes scenes evenly over the set (the set lists logs one after another), in
    set order, and keeps a pick already written."""
    import dataclasses

    from asg.benchmarks.paper import pick_scenes
    from asg.scene import load_scene, save_scene

    for i in range(10):
        save_scene(dataclasses.replace(busy_scene, scene_id=f"s{i:02d}"), tmp_path / "set" / f"s{i:02d}.yaml")
    picked = pick_scenes(tmp_path / "pick", 4, set_name=str(tmp_path / "set"))
    ids = [load_scene(f).scene_id for f in sorted(picked.glob("*.yaml"))]
    assert ids == ["s00", "s02", "s05", "s08"]
    before = {f.name: f.stat().st_mtime_ns for f in picked.glob("*.yaml")}
    pick_scenes(tmp_path / "pick", 4, set_name=str(tmp_path / "set"))
    assert {f.name: f.stat().st_mtime_ns for f in picked.glob("*.yaml")} == before
    assert len(list(pick_scenes(tmp_path / "all", 30, set_name=str(tmp_path / "set")).glob("*.yaml"))) == 10


def test_blas_runs_on_one_thread_while_a_scene_is_generated(busy_scene):
    """OpenBLAS's spinning threads fought torch's for the cores: a scene is generated with every
    loaded BLAS on one thread, and the caller's setting is back afterwards."""
    from threadpoolctl import threadpool_info, threadpool_limits

    blas_threads = lambda: {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}  # noqa: E731
    seen = []
    with threadpool_limits(limits=2, user_api="blas"):
        gen = make_gen(GenerateConfig(fusion="none", search="bo", acs="random", budget=4, space=SpaceConfig(n_q=50)))
        gen.attack(busy_scene, seed=1, on_step=lambda e: seen.append(blas_threads()))
        after = blas_threads()
    assert seen and all(s == {1} for s in seen)
    assert after == {2}


def test_a_scene_leaves_torchs_thread_count_as_it_found_it(busy_scene):
    """Putting a BLAS library back to its own thread count after a scene set OpenMP's, which torch
    reads: a worker of one thread ran its next scenes on two (their numbers then depended on the
    scenes before)."""
    import torch

    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        make_gen(GenerateConfig(fusion="none", search="rs", acs="off", budget=3, space=SpaceConfig(n_q=50))).attack(busy_scene, seed=1)
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)


def test_acs_that_ends_easier_than_the_start_says_so(busy_scene, monkeypatch):
    """The paper's ACS samples combinations among the candidates and may miss the scene's own pair:
    when the scene after ACS is easier than the scene as given, the scene's notes say so."""
    from asg.generator.pipeline import AcsOutcome

    gen = make_gen()
    start = busy_scene.with_collaborators(busy_scene.collaborators or [a.agent_id for a in busy_scene.vehicles[:2]])

    def easier(scene, rng, notes):
        scored = gen.evaluate_scene(scene)
        return scored, AcsOutcome(dataclasses.replace(scored, loss=scored.loss + 0.5), {}, 3)

    monkeypatch.setattr(gen, "normal_and_acs", easier)
    result = gen.attack(start, seed=4)
    assert any(n.startswith("ACS ended easier than the scene began") for n in result.notes)
    monkeypatch.undo()
    from asg.objective import adversarial_loss

    real = make_gen().attack(start, seed=4)  # the note only when it happened
    after_loss = adversarial_loss(real.ap_after_acs, FAST.objective)
    assert any(n.startswith("ACS ended easier") for n in real.notes) == (after_loss > real.loss_normal)


def test_acs_renders_each_combination_as_its_own_world_does(busy_scene):
    """The collaborator search renders the attention's frame and every combination in one world
    of all its candidates: the chosen combination's frame is the one its own scene renders."""
    from asg.sensors.frame import render_frame
    from asg.sensors.renderers import world_for

    gen = make_gen()
    rng = np.random.default_rng(2)
    initial = gen.normal_collaborators(busy_scene, rng, [])
    best = gen.collaborator_search(initial, rng, []).best
    own = render_frame(world_for(best.scene, gen.spec))
    assert best.frame.sensing_ids == own.sensing_ids == best.scene.sensing_ids
    for aid in own.sensing_ids:
        assert np.array_equal(best.frame.clouds[aid], own.clouds[aid])
    assert np.array_equal(best.frame.ego_boxes, own.ego_boxes)


def test_a_new_collaborator_search_is_one_class_and_one_registry_line(busy_scene, capsys, tmp_path):
    """A strategy registered under "acs" runs in the generator and from the command line."""
    from dataclasses import replace

    from asg.collaborators import ACS_STRATEGIES, CollaboratorSearch

    @ACS_STRATEGIES.register("first-two")
    class FirstTwo(CollaboratorSearch):
        def propose(self, scene, candidates, size, rng, attention_of):
            return [tuple(sorted(candidates)[:size])], {}

    try:
        result = make_gen(replace(FAST, acs="first-two")).attack(busy_scene, seed=4)
        cands = sorted(a.agent_id for a in busy_scene.vehicles if a.agent_id != busy_scene.ego_id)
        assert result.evaluations == 1 + 1 + 8 and set(result.after_acs.collaborators) <= set(cands)
        from asg.cli import build_parser

        assert build_parser().parse_args(["generate", "--acs", "first-two"]).acs == "first-two"
    finally:
        ACS_STRATEGIES.unregister("first-two")


@pytest.mark.parametrize("search", ["rs", "ga"])
def test_candidates_scored_side_by_side_give_the_scene_one_thread_gives(busy_scene, search):
    """The shipped AttFuse scoring a search's batches (the collaborator search's combinations, the
    perturbation search's candidates) on two threads, one torch thread each, finds the same
    collaborators, members, losses and final scene as one thread scoring them one by one."""
    import torch

    from asg.perception import build_detector

    det = build_detector("attfuse")
    cfg = GenerateConfig(fusion="attfuse", search=search, acs="random", budget=12, space=SpaceConfig(n_q=100))
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        results = [Generator(cfg, det, det, candidate_threads=n).attack(busy_scene, seed=3) for n in (1, 2)]
        assert torch.get_num_threads() == 1  # the scoring threads leave the caller's count as it was
    finally:
        torch.set_num_threads(before)
    one, two = results
    assert [(e.x.tolist(), e.loss, e.ap) for e in one.history] == [(e.x.tolist(), e.loss, e.ap) for e in two.history]
    assert one.after_acs.collaborators == two.after_acs.collaborators and one.ap_after_acs == two.ap_after_acs
    assert one.final.to_dict() == two.final.to_dict() and one.ap_final == two.ap_final
    for stage in one.detections:
        for a, b in zip(one.detections[stage], two.detections[stage]):
            assert np.array_equal(a, b)


def test_the_scene_as_given_scored_in_the_collaborator_searchs_batch_is_the_scene_scored_alone(busy_scene):
    """The scene as given is scored in one batch with ACS-A's combinations (on two candidate
    threads): the same loss, AP and detections as scored alone on the caller's threads, and the
    same collaborator search as without it."""
    import copy

    from asg.perception import build_detector

    det = build_detector("attfuse")
    cfg = GenerateConfig(fusion="attfuse", search="rs", acs="attention", budget=4, space=SpaceConfig(n_q=50))
    gen = Generator(cfg, det, det, candidate_threads=2)
    rng = np.random.default_rng(5)
    initial = gen.normal_collaborators(busy_scene, rng, [])
    rng_again = copy.deepcopy(rng)
    normal, acs = gen.normal_and_acs(initial, rng, [])
    alone, search = gen.evaluate_scene(initial), gen.collaborator_search(initial, rng_again, [])
    assert normal.scene is initial and (normal.loss, normal.ap) == (alone.loss, alone.ap)
    for a, b in zip(normal.detections, alone.detections, strict=True):
        assert np.array_equal(a, b)
    assert acs.combinations == search.combinations == cfg.acs_samples and acs.probabilities == search.probabilities
    assert acs.best.scene.collaborators == search.best.scene.collaborators
    assert (acs.best.loss, acs.best.ap) == (search.best.loss, search.best.ap)


def test_the_final_scene_keeps_the_detections_its_search_scored(busy_scene):
    """The final stage's detections are the ones scored during the search (not detected again),
    and they are what the detector gives on the final frame."""
    gen = make_gen(dataclasses.replace(FAST, budget=10))
    r = gen.attack(busy_scene, seed=2)
    again = gen._detections(r.frames["final"])
    for a, b in zip(r.detections["final"], again):
        assert np.array_equal(a, b)


def test_candidate_threads_map_in_order_on_one_torch_thread_and_give_back_the_callers_count():
    import threading

    import torch

    from asg.generator.candidates import CandidateThreads

    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        pool = CandidateThreads(2)
        seen = pool.map(lambda i: (i, torch.get_num_threads(), threading.current_thread().name), list(range(8)))
        assert [s[0] for s in seen] == list(range(8))
        assert {s[1] for s in seen} == {1} and all(s[2].startswith("asg-candidate") for s in seen)
        assert torch.get_num_threads() == 2
        assert CandidateThreads(1).map(lambda i: threading.current_thread().name, [1, 2]) == [threading.current_thread().name] * 2
        pool.close()
    finally:
        torch.set_num_threads(before)
    with pytest.raises(ValueError):
        CandidateThreads(0)
