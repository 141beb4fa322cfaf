import math

import numpy as np
import pytest

from asg.collaborators import attention_combinations, combination_weakness, random_combinations
from asg.search import SEARCHES, build_optimizer, check_settings, run_search
from asg.search.loop import Evaluation, best_of
from sumo_scenarios.errors import InputError


class PlantedQ:
    """A feasible set of 1000 random points in [-1, 1]^9 (no scene needed)."""

    def __init__(self, rng, dim=9, n=1000):
        self.members = rng.uniform(-1, 1, (n, dim))

    def project(self, x):
        return self.members[int(np.argmin(((self.members - x) ** 2).sum(axis=1)))]


def planted(target, batches=None):
    """The squared distance to ``target`` of each member of a batch; ``batches`` collects the
    batch sizes asked."""
    def objective(xs):
        if batches is not None:
            batches.append(len(xs))
        return [(float(((x - target) ** 2).sum()), {}) for x in xs]
    return objective


@pytest.mark.slow
def test_bo_beats_random_search_on_a_planted_objective():
    wins, bo_best, rs_best = 0, [], []
    for seed in range(3):
        rng = np.random.default_rng(seed)
        q = PlantedQ(rng)
        target = rng.uniform(-0.6, 0.6, 9)
        res = {}
        for name in ("rs", "bo"):
            opt = build_optimizer(name, 9, 50, np.random.default_rng(100 + seed), **({"n_initial": 20} if name == "bo" else {}))
            hist = run_search(opt, q, planted(target), 50)
            res[name] = best_of(hist).loss
        bo_best.append(res["bo"])
        rs_best.append(res["rs"])
        wins += res["bo"] < res["rs"]
    assert wins >= 2 and np.mean(bo_best) < np.mean(rs_best)


def test_no_member_of_q_is_evaluated_twice_until_q_runs_out():
    for name in ("rs", "ga", "bo"):
        q = PlantedQ(np.random.default_rng(0), n=40)
        params = {"n_initial": 10} if name == "bo" else {}
        opt = build_optimizer(name, 9, 50, np.random.default_rng(2), **params)
        hist = run_search(opt, q, planted(np.zeros(9)), 50)
        rows = [int(np.flatnonzero(np.all(q.members == e.x, axis=1))[0]) for e in hist]
        assert sorted(rows[:40]) == list(range(40)), name  # every member once, then repeats
        assert len(rows) == 50


def test_start_member_is_not_evaluated_again():
    q = PlantedQ(np.random.default_rng(0), n=30)
    q.members[0] = 0.0  # Q's row 0 is "no move", the start
    opt = build_optimizer("rs", 9, 29, np.random.default_rng(0))
    start = Evaluation(0, np.zeros(9), 5.0, {}, 0.0)
    hist = run_search(opt, q, planted(np.ones(9)), 29, start)
    assert not any(np.all(e.x == 0.0) for e in hist)


def test_ga_improves_over_its_first_generation():
    rng = np.random.default_rng(0)
    q = PlantedQ(rng)
    target = rng.uniform(-0.5, 0.5, 9)
    opt = build_optimizer("ga", 9, 60, np.random.default_rng(1), population=15)
    hist = run_search(opt, q, planted(target), 60)
    first = min(e.loss for e in hist[:15])
    assert best_of(hist).loss < first


def test_ga_carries_its_elites_without_asking_them_again():
    rng = np.random.default_rng(0)
    opt = build_optimizer("ga", 4, 40, np.random.default_rng(3), population=6, elites=2)
    cands = rng.uniform(-1, 1, (5, 4))
    first = [opt.ask(cands) for _ in range(6)]
    for i, x in enumerate(first):
        opt.tell(x, float(i))  # the first two are the elites
    second = [opt.ask(cands) for _ in range(4)]  # population - elites children
    assert not any(np.array_equal(c, e) for c in second for e in first[:2])
    for x in second:
        opt.tell(x, 10.0)
    opt.ask(cands)  # the third generation is bred from the elites and the children
    assert [l for _, l in opt.elites] == [0.0, 1.0]


def test_optimizers_are_seeded():
    for name in ("rs", "ga", "bo"):
        runs = []
        for _ in range(2):
            q = PlantedQ(np.random.default_rng(0))
            params = {"n_initial": 10} if name == "bo" else {}
            opt = build_optimizer(name, 9, 25, np.random.default_rng(5), **params)
            runs.append([e.loss for e in run_search(opt, q, planted(np.zeros(9)), 25)])
        assert runs[0] == runs[1], name


def test_unknown_setting_is_named():
    with pytest.raises(InputError, match="configs/search/bo.yaml: unknown setting 'n_points' for bo; known: batch, kappa, n_initial, refit_every"):
        build_optimizer("bo", 9, 10, np.random.default_rng(0), n_points=500)
    with pytest.raises(InputError, match="unknown setting 'kappa' for ga"):
        build_optimizer("ga", 9, 10, np.random.default_rng(0), kappa=1.0)
    with pytest.raises(InputError, match="unknown setting 'x' for rs; known: none"):
        build_optimizer("rs", 9, 10, np.random.default_rng(0), x=1)


def test_unknown_algorithm():
    from asg.search import SEARCHES

    with pytest.raises(InputError, match="unknown search algorithm 'annealing'.*" + ", ".join(SEARCHES.names())):
        build_optimizer("annealing", 9, 10, np.random.default_rng(0))


def test_attention_sampling_prefers_weak_agents():
    weights = {"a": 0.5, "b": 0.3, "c": 0.1, "d": 0.05}
    combos, p = attention_combinations(weights, list(weights), 2, 3, 0.03, np.random.default_rng(0))
    assert len(combos) == 3 and len(set(combos)) == 3
    assert combos[0] == ("c", "d")  # the weakest pair dominates at tau = 0.03
    assert math.isclose(p.sum(), 1.0) and np.all(np.isfinite(p))
    w = combination_weakness(weights, [("a", "b"), ("c", "d")])
    assert w[1] > w[0]


def test_attention_sampling_frequencies_follow_softmax():
    weights = {"a": 1.0, "b": 1.0 / 1.02, "c": 1.0 / 1.04}
    counts = {}
    rng = np.random.default_rng(0)
    for _ in range(4000):
        c, p = attention_combinations(weights, list(weights), 1, 1, 0.03, rng)
        counts[c[0]] = counts.get(c[0], 0) + 1
    expected = dict(zip([("a",), ("b",), ("c",)], p))
    for k, v in expected.items():
        assert abs(counts.get(k, 0) / 4000 - v) < 0.03


def test_random_combinations_and_fewer_candidates_than_needed():
    rng = np.random.default_rng(0)
    assert len(random_combinations(["a", "b", "c", "d"], 2, 3, rng)) == 3
    assert random_combinations(["a"], 2, 3, rng) == [("a",)]
    assert random_combinations([], 2, 3, rng) == []



@pytest.mark.parametrize("name, params", [("rs", {}), ("ga", {"population": 8, "elites": 2}), ("bo", {"n_initial": 10})])
def test_a_batched_search_finds_what_one_at_a_time_finds(name, params):
    """Random search, a GA's generations and BO's random start propose the same members, and so
    find the same, whether their proposals are evaluated in batches or one by one."""
    runs, sizes = [], []
    for batched in (True, False):
        batches = []
        q = PlantedQ(np.random.default_rng(0), n=200)
        opt = build_optimizer(name, 9, 30, np.random.default_rng(4), **params)
        hist = run_search(opt, q, planted(np.full(9, 0.3), batches), 30, batched=batched)
        runs.append([(e.step, e.x.tolist(), e.loss) for e in hist])
        sizes.append(batches)
    assert runs[0] == runs[1]
    assert sizes[1] == [1] * 30
    expected = {"rs": [30], "ga": [8, 6, 6, 6, 4], "bo": [10] + [1] * 20}[name]
    assert sizes[0] == expected


def test_batched_bo_proposes_its_batch_by_the_constant_liar():
    q = PlantedQ(np.random.default_rng(0), n=300)
    batches = []
    opt = build_optimizer("bo", 9, 30, np.random.default_rng(4), n_initial=10, batch=5)
    hist = run_search(opt, q, planted(np.full(9, 0.3), batches), 30)
    assert batches == [10, 5, 5, 5, 5]
    rows = [int(np.flatnonzero(np.all(q.members == e.x, axis=1))[0]) for e in hist]
    assert len(set(rows)) == 30  # a batch's members are distinct
    # the lies spread a batch: its members are not all the GP's one favourite's neighbours
    first_batch = np.array([e.x for e in hist[10:15]])
    assert np.ptp(first_batch, axis=0).max() > 0.2
    assert best_of(hist).loss < min(e.loss for e in hist[:10])


@pytest.mark.parametrize("name", ["bo", "ng"])
@pytest.mark.parametrize("batch", [0, -1, 65, 2.5, True, "4"])
def test_a_batch_out_of_range_is_refused(name, batch):
    with pytest.raises(InputError, match=f"configs/search/{name}.yaml: batch: (expected a whole number|.* out of range "
                                         "\\(must be at least 1 and at most 64\\))"):
        build_optimizer(name, 9, 10, np.random.default_rng(0), batch=batch)


@pytest.mark.parametrize("name, settings, says", [
    ("ga", {"population": 10**9}, "population: 1e+09 is out of range"),  # filled the memory in a scene
    ("ga", {"population": 1.5}, "population: expected a whole number"),  # a TypeError traceback
    ("ga", {"population": 0}, "population: 0 is out of range"), ("ga", {"temperature": math.nan}, "not a finite number"),
    ("ga", {"crossover": 5}, "crossover: 5 is out of range"), ("ga", {"elites": 15}, "elites (15) must be fewer"),
    ("ga", {"mutation_p": 0.05}, "mutation_p_min (0.1) is above mutation_p (0.05)"),
    ("bo", {"refit_every": "x"}, "refit_every: expected a whole number"),  # a TypeError traceback
    ("bo", {"kappa": -1.0}, "kappa: -1 is out of range"), ("bo", {"n_initial": 0}, "n_initial: 0 is out of range"),
    ("ls", {"grow": 0.0}, "grow: 0 is out of range"),  # a ZeroDivisionError traceback
    ("ls", {"step": 3.0}, "step: 3 is out of range"), ("ls", {"step_min": 1.0}, "step (0.5) must lie within"),
    ("ng", {"optimizer": "nope"}, "unknown nevergrad optimizer 'nope'"), ("ng", {"optimizer": 5}, "expected text")])
def test_a_search_setting_out_of_range_is_refused_naming_it(name, settings, says):
    """Every setting of configs/search/NAME.yaml is checked for its kind and range, and with the
    others, before a search is built: nonsense used to run silently (a crossover of 5, a NaN
    temperature), crash in a scene or fill the memory (a population of 10^9)."""
    with pytest.raises(InputError) as error:
        check_settings(name, settings)
    assert str(error.value).startswith(f"configs/search/{name}.yaml: ") and says in str(error.value)


def test_every_setting_of_every_search_has_a_range():
    """What a constructor takes is what its table checks, and the shipped settings pass."""
    import dataclasses
    import inspect

    from asg.generator.config import search_params
    from asg.search.genetic import GAParams

    for name in SEARCHES.names():
        optimizer = SEARCHES.entry(name)
        takes = ({f.name for f in dataclasses.fields(GAParams)} if name == "ga" else
                 set(inspect.signature(optimizer.__init__).parameters) - {"self", "dim", "budget", "rng"})
        assert set(optimizer.SETTINGS) == takes, name
        assert set(optimizer.defaults()) == takes, name
        check_settings(name, optimizer.defaults())
        check_settings(name, search_params(name))
    with pytest.raises(InputError, match="expected a mapping of settings"):
        check_settings("ga", [1, 2])


def test_nevergrad_takes_a_batch():
    q = PlantedQ(np.random.default_rng(0), n=200)
    batches = []
    opt = build_optimizer("ng", 9, 20, np.random.default_rng(1), batch=4)
    hist = run_search(opt, q, planted(np.zeros(9), batches), 20)
    assert batches == [4] * 5 and len(hist) == 20


def test_bo_puts_candidates_in_the_gps_units_as_skopt_does():
    from skopt.space import Space
    from skopt.utils import normalize_dimensions

    opt = build_optimizer("bo", 9, 50, np.random.default_rng(0))
    pts = np.random.default_rng(1).uniform(-1, 1, (500, 9))
    pts[0], pts[1] = -1.0, 1.0
    space = Space(normalize_dimensions([(-1.0, 1.0)] * 9))  # what skopt's Optimizer fits its GP in
    assert np.array_equal(opt._unit(pts), np.asarray(space.transform(pts.tolist())))


@pytest.mark.parametrize("batch", [1, 5])
def test_bo_fits_its_gp_as_skopts_optimizer_does(batch):
    """The GP fitted directly (each told point in skopt's units, the kernel refitted every
    refit_every tells and held between) is the one skopt's Optimizer fits from the same tells: the
    same predictions to the bit, so the same search."""
    from sklearn.base import clone
    from skopt import Optimizer as SkOptimizer

    rng = np.random.default_rng(3)
    opt = build_optimizer("bo", 9, 40, np.random.default_rng(7), n_initial=10, refit_every=3, batch=batch)
    sk = SkOptimizer([(-1.0, 1.0)] * 9, base_estimator=clone(opt._base), n_initial_points=10, acq_func="LCB",
                     acq_optimizer="sampling", acq_optimizer_kwargs={"n_points": 1}, random_state=0)
    probe = opt._unit(rng.uniform(-1, 1, (200, 9)))
    for k in range(25):
        x, loss = rng.uniform(-1, 1, 9), float(rng.normal())
        fitting = k + 1 - 10
        sk.base_estimator_.set_params(optimizer="fmin_l_bfgs_b" if fitting <= 0 or fitting % 3 == 0 else None)
        sk.tell([float(v) for v in x], loss)
        opt.tell(x, loss)
        if sk.models:
            sk.base_estimator_.set_params(kernel=sk.models[-1].kernel_)
            mean, std = opt._model.predict(probe, return_std=True)
            sk_mean, sk_std = sk.models[-1].predict(probe, return_std=True)
            assert np.array_equal(mean, sk_mean) and np.array_equal(std, sk_std), k
    assert opt._model is not None and len(sk.models) == 16
