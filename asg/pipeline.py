"""``generate(scene, ...)``: Adversarial Collaborator Search, then Adversarial Perturbation Search.

What the CLI and the benchmarks call. Works with any detector behind the V2XDetector interface
(the tests use a fake one); AttFuse's attention steers ACS-A whatever the target model is.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Literal

import numpy as np

from sumo_scenarios import checks
from sumo_scenarios.errors import InputError
from sumo_scenarios.paths import configs_dir
from sumo_scenarios.strict import from_mapping, read_yaml

from .objective import ObjectiveConfig, adversarial_loss, ap_at
from .scene import Scene
from .perception.data import in_range
from .scene.feasibility import Plausibility, in_eval_range
from .scene.recheck import recheck
from .scene.neighbours import COMM_RANGE_M, vehicles_within
from .search import EmptyFeasibleSet, Evaluation, FeasibleSet, SearchSpace, SpaceConfig, best_of, build_optimizer, check_settings, run_search
from .sensors import LidarSpec, World, load_lidar_spec, occlusion_scores
from .sensors.lidar_spec import DEFAULT_LIDAR
from .sensors.frame import CooperativeFrame, apply_link, delayed_view, render_frame

#: evaluations per scene at most (a scene at 50 takes seconds; this many is a day)
MAX_BUDGET = 100_000

Detections = tuple[np.ndarray, np.ndarray, np.ndarray]  # boxes (K, 7), scores (K,), ground truth (M, 7)


@dataclass(frozen=True)
class GenerateConfig:
    """The generator's settings; configs/generate.yaml mirrors these defaults (a test checks it)."""

    fusion: str = "attfuse"
    #: the target's weights file (.pt) instead of the fusion's shipped weights (e.g. a fine-tuned model)
    weights: str | None = None
    search: str = "bo"
    acs: Literal["attention", "random", "off"] = "attention"
    aps: bool = True
    budget: int = 50
    sensing_agents: int = 3
    acs_samples: int = 3
    acs_tau: float = 0.03
    attention_cells: Literal["all", "vehicles"] = "all"
    perturbed: int = 3
    comm_range_m: float = COMM_RANGE_M
    lidar: str = DEFAULT_LIDAR
    objective: ObjectiveConfig = field(default_factory=ObjectiveConfig)
    space: SpaceConfig = field(default_factory=SpaceConfig)

    def validate(self) -> "GenerateConfig":
        from .registry import names
        from . import search as _  # noqa: F401

        if self.search not in names("search"):
            raise InputError(f"unknown search algorithm '{self.search}'; known: {', '.join(names('search'))}")
        if self.acs not in ("attention", "random", "off"):
            raise InputError(f"--acs must be attention, random or off, got {self.acs!r}")
        if not 1 <= self.budget <= MAX_BUDGET:
            raise InputError(f"--budget must be between 1 and {MAX_BUDGET}, got {self.budget}")
        checks.number(self.sensing_agents, "sensing_agents", 1, 16)
        checks.number(self.acs_samples, "acs_samples", 1, 1000)
        checks.number(self.acs_tau, "acs_tau", 0.0, 100.0, lo_open=True)
        checks.number(self.perturbed, "perturbed", 0, 64)
        checks.number(self.comm_range_m, "comm_range_m", 0.0, 1000.0, lo_open=True)
        return self


def load_generate_config(path: Path | None = None, **overrides) -> GenerateConfig:
    """The generator's settings: ``path`` (default configs/generate.yaml), then the non-None
    ``overrides`` (CLI flags); an error names the file it came from."""
    path = Path(path) if path is not None else configs_dir() / "generate.yaml"
    data = read_yaml(path)
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a mapping of settings (key: value), got a {type(data).__name__}")
    data.update({k: v for k, v in overrides.items() if v is not None})
    try:
        return from_mapping(GenerateConfig, data, str(path)).validate()
    except InputError as exc:  # a range check inside a component's config: say which file it came from
        text = str(exc)
        if str(path) in text or text.startswith("--"):
            raise
        raise InputError(f"{path}: {text}") from None


def with_space_flags(cfg: GenerateConfig, plausibility: str | None, spaces: str | None) -> GenerateConfig:
    """``cfg`` with the --plausibility and --space flags (``spaces``: comma-separated names) applied."""
    changes = {}
    if plausibility is not None:
        changes["plausibility"] = plausibility
    if spaces is not None:
        changes["kinds"] = tuple(k.strip() for k in spaces.split(",") if k.strip())
    if not changes:
        return cfg
    fields = {f: getattr(cfg.space, f) for f in SpaceConfig.__dataclass_fields__} | changes
    return replace(cfg, space=SpaceConfig(**fields))


def search_params(name: str) -> dict:
    p = configs_dir() / "search" / f"{name}.yaml"
    return (read_yaml(p) or {}) if p.is_file() else {}


@dataclass
class SceneResult:
    scene_id: str
    initial: Scene
    after_acs: Scene
    final: Scene
    ap_normal: dict[str, float]
    ap_after_acs: dict[str, float]
    ap_final: dict[str, float]
    loss_normal: float
    loss_final: float
    evaluations: int
    seconds: float
    perturbed: tuple[str, ...]
    delta: list[list[float]]
    plausibility: Plausibility
    history: list[Evaluation]
    frames: dict[str, CooperativeFrame]
    notes: list[str]
    acs_probabilities: dict[str, float] = field(default_factory=dict)
    bo_overhead_s: list[float] = field(default_factory=list)
    #: (boxes, scores, ground truth) of the target model on the initial and final scene (ego frame)
    detections: dict[str, "Detections"] = field(default_factory=dict)
    #: history.csv's columns for a member (units in the names) and each evaluation's values in them
    history_columns: list[str] = field(default_factory=list)
    history_values: list[list[float]] = field(default_factory=list)
    #: the spaces searched with their bounds; what the final scene inserted and did to the link
    space: dict = field(default_factory=dict)
    inserted: tuple[str, ...] = ()

    @property
    def moved(self) -> tuple[str, ...]:
        """The perturbed vehicles that the final scene actually moved (none if APS kept the start)."""
        return tuple(vid for vid, d in zip(self.perturbed, self.delta) if any(d))


class Generator:
    """Holds the target detector, the AttFuse model for ACS-A and the LiDAR spec across scenes."""

    def __init__(self, cfg: GenerateConfig, target, acs_model=None, spec: LidarSpec | None = None):
        self.cfg = cfg.validate()
        self.target = target
        self.acs_model = acs_model
        self.spec = spec or load_lidar_spec(cfg.lidar)
        self.params = search_params(cfg.search)
        check_settings(cfg.search, self.params)

    # ---- evaluation ------------------------------------------------------------------------
    def _detections(self, frame: CooperativeFrame) -> Detections:
        boxes, scores = self.target.detect(frame)
        gt = frame.ego_boxes
        return boxes, scores, gt[in_range(gt)]

    def _score(self, frame: CooperativeFrame) -> tuple[float, dict[str, float]]:
        ap = ap_at([self._detections(frame)], self.cfg.objective.thresholds)
        return adversarial_loss(ap, self.cfg.objective), ap

    def evaluate_scene(self, scene: Scene) -> "Scored":
        frame = render_frame(World(scene, self.spec))
        loss, ap = self._score(frame)
        return Scored(scene, loss, ap, frame)

    # ---- the two stages ----------------------------------------------------------------------
    def normal_collaborators(self, scene: Scene, rng: np.random.Generator, notes: list[str]) -> Scene:
        if scene.collaborators:
            return scene
        cands = [a.agent_id for a in vehicles_within(scene, scene.ego_id, self.cfg.comm_range_m)]
        need = self.cfg.sensing_agents - 1
        if len(cands) < need:
            notes.append(f"only {len(cands)} vehicles within {self.cfg.comm_range_m:g} m of the ego; using them all")
        pick = sorted(rng.choice(len(cands), size=min(need, len(cands)), replace=False).tolist()) if cands else []
        return scene.with_collaborators([cands[i] for i in pick])

    def collaborator_search(self, scene: Scene, rng: np.random.Generator, notes: list[str]) -> "AcsOutcome":
        """The lowest-loss of the sampled collaborator combinations, with ACS-A's probabilities."""
        from .collaborators import attention_combinations, random_combinations

        cands = [a.agent_id for a in vehicles_within(scene, scene.ego_id, self.cfg.comm_range_m)]
        size = self.cfg.sensing_agents - 1
        if len(cands) < size:
            notes.append(f"ACS: {len(cands)} candidate collaborators for {size} places; using what exists")
        probs: dict[str, float] = {}
        if self.cfg.acs == "attention":
            if self.acs_model is None:
                raise InputError("ACS-A needs the AttFuse model; pass --acs random or off")
            everyone = render_frame(World(scene.with_collaborators(cands), self.spec))
            weights = self.acs_model.attention_weights(everyone, self.cfg.attention_cells)
            combos, p = attention_combinations(weights, cands, size, self.cfg.acs_samples, self.cfg.acs_tau, rng)
            from .collaborators.sampling import all_combinations

            probs = {"+".join(c): float(v) for c, v in zip(all_combinations(cands, size), p) if v > 1e-4}
        else:
            combos = random_combinations(cands, size, self.cfg.acs_samples, rng)
        best: Scored | None = None
        combos = combos or [tuple()]
        for combo in combos:
            scored = self.evaluate_scene(scene.with_collaborators(combo))
            if best is None or scored.loss < best.loss:
                best = scored
        return AcsOutcome(best, probs, len(combos))

    def pick_perturbed(self, scene: Scene, notes: list[str]) -> list[str]:
        sensing = set(scene.sensing_ids)
        others = [a for a in scene.vehicles if a.agent_id not in sensing]
        movable = [a for a, ok in zip(others, in_eval_range(scene.ego, others)) if ok]
        if len(movable) < self.cfg.perturbed:
            notes.append(f"APS: {len(movable)} vehicles can move (fewer than m = {self.cfg.perturbed}); moving them all")
        viewers = [scene.agent(i) for i in scene.sensing_ids]
        scores = occlusion_scores(viewers, movable, self.spec.range_m)
        ranked = sorted(movable, key=lambda a: (-scores[a.agent_id], a.agent_id))
        return [a.agent_id for a in ranked[: self.cfg.perturbed]]

    # ---- one scene ---------------------------------------------------------------------------
    def generate(self, scene: Scene, seed: int, on_step: Callable[[Evaluation], None] | None = None) -> SceneResult:
        """ACS, then APS, then the independent plausibility re-check of one scene (BLAS on one
        thread meanwhile: see :func:`asg.executors.base.blas_on_one_thread`)."""
        from .executors.base import blas_on_one_thread

        with blas_on_one_thread():
            return self._generate(scene, seed, on_step)

    def _generate(self, scene: Scene, seed: int, on_step: Callable[[Evaluation], None] | None) -> SceneResult:
        t0 = time.perf_counter()
        rng = np.random.default_rng([seed, *(ord(ch) for ch in scene.scene_id[-16:])])
        notes: list[str] = []
        initial = self.normal_collaborators(scene, rng, notes)
        normal = self.evaluate_scene(initial)
        acs = AcsOutcome(normal, {}, 0) if self.cfg.acs == "off" else self.collaborator_search(initial, rng, notes)
        after = acs.best
        if after.loss > normal.loss:  # the paper's ACS samples among the candidates, not the scene's own pair
            notes.append(f"ACS ended easier than the scene began (loss {normal.loss:.3f} -> {after.loss:.3f}): "
                         f"its {acs.combinations} sampled collaborator combinations did not include the scene's own")
        aps = ApsOutcome(after, [], [], ())
        if self.cfg.aps:
            perturbed = self.pick_perturbed(after.scene, notes) if "poses" in self.cfg.space.kinds else []
            try:
                aps = self._perturb(after, perturbed, rng, on_step)
            except EmptyFeasibleSet as exc:
                notes.append(f"APS skipped: {exc}")
        level = (self.cfg.space.plausibility, self.cfg.space.traffic_heading_deg)
        plaus = recheck(after.scene, aps.best.scene, *level)  # shapely, not the fcl checker that built Q
        if not plaus.ok:  # never publish an implausible scene
            notes.append(f"final scene failed the independent plausibility check {plaus.to_dict()}; kept the scene after ACS")
            aps = ApsOutcome(after, aps.history, [], aps.perturbed, aps.columns, aps.values, aps.space)
            plaus = recheck(after.scene, after.scene, *level)
        final = aps.best
        stages = {"initial": normal, "after_acs": after, "final": final}
        return SceneResult(
            scene.scene_id, initial, after.scene, final.scene, normal.ap, after.ap, final.ap, normal.loss, final.loss,
            1 + acs.combinations + len(aps.history), time.perf_counter() - t0, aps.perturbed, aps.delta, plaus,
            aps.history, {k: v.frame for k, v in stages.items()}, notes, acs.probabilities,
            [e.optimizer_s for e in aps.history], {k: self._detections(v.frame) for k, v in stages.items()},
            aps.columns, aps.values, aps.space, aps.inserted)

    def _perturb(self, start_at: "Scored", perturbed: list[str], rng: np.random.Generator, on_step) -> "ApsOutcome":
        """Search the spaces of ``cfg.space.kinds`` from ``start_at`` (``perturbed``: the vehicles the
        poses space moves; the start's loss is told first, not counted)."""
        scene = start_at.scene
        space = SearchSpace(scene, perturbed, self.cfg.space)
        if space.dim == 0:
            raise EmptyFeasibleSet("nothing to perturb (no vehicle to move, no collaborator)")
        feasible = FeasibleSet(space, rng)
        world = World(space.world_scene, self.spec, movable_ids=space.movable_ids)
        world.prepare(scene.sensing_ids)
        delayed: dict[tuple[str, float], tuple] = {}  # a delayed message renders once per (collaborator, delay)

        def view(aid: str, state) -> tuple:
            key = (aid, state.delay_s)
            if key not in delayed:
                delayed[key] = delayed_view(scene, aid, state, self.spec)
            return delayed[key]

        def frame_of(x: np.ndarray) -> CooperativeFrame:
            p = space.decode(x)
            frame = render_frame(world, scene.sensing_ids, moved=p.moved)
            return apply_link(frame, p.link, view) if p.link else frame

        def objective(x: np.ndarray) -> tuple[float, dict[str, float]]:
            return self._score(frame_of(x))

        optimizer = build_optimizer(self.cfg.search, space.dim, self.cfg.budget, rng, **self.params)
        start = Evaluation(0, space.identity(), start_at.loss, start_at.ap, 0.0)
        history = run_search(optimizer, feasible, objective, self.cfg.budget, start, on_step)
        best = best_of(history, start)
        record = {"kinds": list(self.cfg.space.kinds), "bounds": space.bounds(), "dimensions": space.dim,
                  "q_members": len(feasible)}
        columns, values = space.columns(), [space.readable(e.x) for e in history]
        if best.step == 0:
            return ApsOutcome(start_at, history, [], tuple(perturbed), columns, values, record)
        final = space.apply(best.x)
        # the movers' (dx_m, dy_m, dyaw_rad) as the member gives them: slots come in ``perturbed``'s order
        delta = [[round(float(v), 4) for v in np.asarray(x) * slot.scale]
                 for slot, x in zip(space.slots, space.slot_values(best.x)) if slot.agent_id in perturbed]
        before = {a.agent_id for a in scene.agents}
        inserted = tuple(a.agent_id for a in final.agents if a.agent_id not in before)
        record["link"] = {cid: {k: v for k, v in st.to_dict().items() if k != "earlier_agents"}
                          for cid, st in final.link.items()}
        record["inserted"] = list(inserted)
        return ApsOutcome(Scored(final, best.loss, best.ap, frame_of(best.x)), history, delta, tuple(perturbed),
                          columns, values, record, inserted)


@dataclass(frozen=True)
class Scored:
    """A scene as the target model sees it: its adversarial loss, AP by threshold and rendered frame."""

    scene: Scene
    loss: float
    ap: dict[str, float]
    frame: CooperativeFrame


@dataclass(frozen=True)
class AcsOutcome:
    """The collaborator search: the best combination scored, ACS-A's probability of each
    combination ("a+b" -> p; empty for ACS-R and off) and how many combinations were scored."""

    best: Scored
    probabilities: dict[str, float]
    combinations: int


@dataclass(frozen=True)
class ApsOutcome:
    """The perturbation search: the final scene scored (the start if no move helped), every
    evaluation, the kept moves (dx_m, dy_m, dyaw_rad per perturbed vehicle; [] if none) and the
    vehicles the search moved."""

    best: Scored
    history: list[Evaluation]
    delta: list[list[float]]
    perturbed: tuple[str, ...]
    #: history.csv's columns and each evaluation's values in them
    columns: list[str] = field(default_factory=list)
    values: list[list[float]] = field(default_factory=list)
    #: the spaces, their bounds and (when the search changed the scene) what it inserted and did to the link
    space: dict = field(default_factory=dict)
    inserted: tuple[str, ...] = ()
