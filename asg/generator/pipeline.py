"""``Generator.attack(scene, ...)``: Adversarial Collaborator Search, then Adversarial Perturbation Search.

What the CLI and the benchmarks call. Works with any detector behind the V2XDetector interface
(the tests use a fake one); AttFuse's attention steers ACS-A whatever the target model is.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from sumo_scenarios.errors import InputError

from .config import ACS_OFF, MAX_BUDGET, GenerateConfig, load_generate_config, search_params, with_space_flags  # noqa: F401  (re-exported)
from .candidates import CandidateThreads
from .stages import Stage
from ..objective import adversarial_loss, ap_at
from ..scene import Scene
from ..perception.data import in_range
from ..scene.feasibility import Plausibility, in_eval_range
from ..scene.recheck import recheck
from ..scene.neighbours import collaborator_candidates
from ..search import EmptyFeasibleSet, Evaluation, FeasibleSet, SearchSpace, best_of, build_optimizer, check_settings, run_search
from ..sensors import LidarSpec, load_lidar_spec, occlusion_scores, world_for
from ..sensors.frame import CooperativeFrame, apply_link, delayed_view, render_frame

Detections = tuple[np.ndarray, np.ndarray, np.ndarray]  # boxes (K, 7), scores (K,), ground truth (M, 7)


@dataclass(kw_only=True)
class SceneResult:
    scene_id: str
    normal: Scene
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
    #: (boxes, scores, ground truth) of the target model on each stage's scene (ego frame)
    detections: dict[str, "Detections"] = field(default_factory=dict)
    #: history.csv's columns for a member (units in the names) and each evaluation's values in them
    history_columns: list[str] = field(default_factory=list)
    history_values: list[list[float]] = field(default_factory=list)
    #: the spaces searched with their bounds; what the final scene inserted and did to the link
    space: dict = field(default_factory=dict)
    inserted: tuple[str, ...] = ()

    def scene(self, stage: Stage) -> Scene:
        return {Stage.NORMAL: self.normal, Stage.AFTER_ACS: self.after_acs, Stage.FINAL: self.final}[stage]

    def ap(self, stage: Stage) -> dict[str, float]:
        return {Stage.NORMAL: self.ap_normal, Stage.AFTER_ACS: self.ap_after_acs, Stage.FINAL: self.ap_final}[stage]

    @property
    def moved(self) -> tuple[str, ...]:
        """The perturbed vehicles that the final scene actually moved (none if APS kept the start)."""
        return tuple(vid for vid, d in zip(self.perturbed, self.delta) if any(d))


class Generator:
    """Holds the target detector, the AttFuse model for ACS-A and the LiDAR spec across scenes."""

    def __init__(self, cfg: GenerateConfig, target, acs_model=None, spec: LidarSpec | None = None,
                 candidate_threads: int = 1):
        """``candidate_threads``: the threads a search's batch of candidates is scored on, one torch
        thread each (:mod:`.candidates`; only for a detector whose target kind detects frames on
        several threads at once); the result does not depend on it."""
        self.cfg = cfg.validate()
        self.target = target
        self.acs_model = acs_model
        self.spec = spec or load_lidar_spec(cfg.lidar)
        self.params = search_params(cfg.search)
        check_settings(cfg.search, self.params)
        self.candidates = CandidateThreads(candidate_threads)

    # ---- evaluation ------------------------------------------------------------------------
    def _detections(self, frame: CooperativeFrame) -> Detections:
        boxes, scores = self.target.detect(frame)
        gt = frame.ego_boxes
        return boxes, scores, gt[in_range(gt)]

    def _judged(self, frame: CooperativeFrame) -> "Judged":
        detections = self._detections(frame)
        ap = ap_at([detections], self.cfg.objective.thresholds)
        return Judged(adversarial_loss(ap, self.cfg.objective), ap, detections)

    def evaluate_scene(self, scene: Scene) -> "Scored":
        frame = render_frame(world_for(scene, self.spec))
        return Scored.of(scene, frame, self._judged(frame))

    # ---- the two stages ----------------------------------------------------------------------
    def normal_collaborators(self, scene: Scene, rng: np.random.Generator, notes: list[str]) -> Scene:
        if scene.collaborators:
            return scene
        cands = [a.agent_id for a in collaborator_candidates(scene, scene.ego_id, self.cfg.comm_range_m)]
        need = self.cfg.sensing_agents - 1
        if len(cands) < need:
            notes.append(f"only {len(cands)} vehicles within {self.cfg.comm_range_m:g} m of the ego; using them all")
        pick = sorted(rng.choice(len(cands), size=min(need, len(cands)), replace=False).tolist()) if cands else []
        return scene.with_collaborators([cands[i] for i in pick])

    def normal_and_acs(self, scene: Scene, rng: np.random.Generator, notes: list[str]) -> tuple["Scored", "AcsOutcome"]:
        """``scene`` (the normal stage's) scored, and the collaborator search from it (``cfg.acs``
        off: ``scene`` itself). Its frame is scored in one batch with the search's combinations: on
        several candidate threads it takes a core that the combinations leave idle."""
        if self.cfg.acs == ACS_OFF:
            normal = self.evaluate_scene(scene)
            return normal, AcsOutcome(normal, {}, 0)
        frame = render_frame(world_for(scene, self.spec))
        combos = self.collaborator_combinations(scene, rng, notes)
        judged = self.candidates.map(self._judged, [frame, *combos.frames])  # one batch
        return Scored.of(scene, frame, judged[0]), combos.outcome(judged[1:])

    def collaborator_search(self, scene: Scene, rng: np.random.Generator, notes: list[str]) -> "AcsOutcome":
        """The lowest-loss of the combinations ``cfg.acs``'s strategy proposes (asg.collaborators),
        with the strategy's probabilities."""
        combos = self.collaborator_combinations(scene, rng, notes)
        return combos.outcome(self.candidates.map(self._judged, combos.frames))

    def collaborator_combinations(self, scene: Scene, rng: np.random.Generator, notes: list[str]) -> "AcsCombinations":
        """The combinations ``cfg.acs``'s strategy proposes (asg.collaborators), rendered, with the
        strategy's probabilities; not scored yet."""
        from ..collaborators import ACS_STRATEGIES

        strategy = ACS_STRATEGIES.entry(self.cfg.acs)(self.cfg.acs_samples, self.cfg.acs_tau)
        cands = [a.agent_id for a in collaborator_candidates(scene, scene.ego_id, self.cfg.comm_range_m)]
        size = self.cfg.sensing_agents - 1
        if len(cands) < size:
            notes.append(f"ACS: {len(cands)} candidate collaborators for {size} places; using what exists")
        # one world for every candidate: who senses does not change what is there, and a sensor's
        # rays are cast once (the attention's frame casts every candidate's, the combinations reuse them)
        world = world_for(scene.with_collaborators(cands), self.spec)
        attention_of = None
        if strategy.needs_attention:
            if self.acs_model is None:
                raise InputError(f"ACS-{self.cfg.acs} needs an attention model (AttFuse); pass --acs random or off")
            attention_of = lambda s: self._attention_of(render_frame(world, s.sensing_ids))
        combos, probs = strategy.propose(scene, cands, size, rng, attention_of)
        combos = combos or [tuple()]
        scenes = [scene.with_collaborators(combo) for combo in combos]
        return AcsCombinations(scenes, [render_frame(world, s.sensing_ids) for s in scenes], probs)

    def _attention_of(self, frame: CooperativeFrame) -> dict[str, float]:
        """The ACS model's attention weight of each sensing agent of ``frame``; InputError if it gives none."""
        weights = self.acs_model.attention_weights(frame, self.cfg.attention_cells)
        if weights is None:
            raise InputError(f"ACS-{self.cfg.acs}: the ACS model gave no attention weights (its attention_weights "
                             "returned None); return a model with attention from the factory, or pass --acs random or off")
        return weights

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
    def attack(self, scene: Scene, seed: int, on_step: Callable[[Evaluation], None] | None = None) -> SceneResult:
        """ACS, then APS, then the independent plausibility re-check of one scene (BLAS on one
        thread meanwhile: see :func:`asg.executors.base.blas_on_one_thread`)."""
        from ..executors.base import blas_on_one_thread

        with blas_on_one_thread():
            return self._generate(scene, seed, on_step)

    def _generate(self, scene: Scene, seed: int, on_step: Callable[[Evaluation], None] | None) -> SceneResult:
        t0 = time.perf_counter()
        rng = np.random.default_rng([seed, *(ord(ch) for ch in scene.scene_id[-16:])])
        notes: list[str] = []
        normal_scene = self.normal_collaborators(scene, rng, notes)
        normal, acs = self.normal_and_acs(normal_scene, rng, notes)
        after = acs.best
        if after.loss > normal.loss:  # the paper's ACS samples among the candidates, not the scene's own pair
            notes.append(f"ACS ended easier than the scene began (loss {normal.loss:.3f} -> {after.loss:.3f}): "
                         f"its {acs.combinations} sampled collaborator combinations did not include the scene's own")
        aps = ApsOutcome(after, [], [], ())
        if self.cfg.aps:
            perturbed = self.pick_perturbed(after.scene, notes) if self.cfg.space.needs_movers else []
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
        stages = {Stage.NORMAL: normal, Stage.AFTER_ACS: after, Stage.FINAL: final}
        return SceneResult(
            scene_id=scene.scene_id, normal=normal_scene, after_acs=after.scene, final=final.scene,
            ap_normal=normal.ap, ap_after_acs=after.ap, ap_final=final.ap, loss_normal=normal.loss,
            loss_final=final.loss, evaluations=1 + acs.combinations + len(aps.history),
            seconds=time.perf_counter() - t0, perturbed=aps.perturbed, delta=aps.delta, plausibility=plaus,
            history=aps.history, frames={k: v.frame for k, v in stages.items()}, notes=notes,
            acs_probabilities=acs.probabilities, bo_overhead_s=[e.optimizer_s for e in aps.history],
            detections={k: v.detections for k, v in stages.items()}, history_columns=aps.columns,
            history_values=aps.values, space=aps.space, inserted=aps.inserted)

    def _perturb(self, start_at: "Scored", perturbed: list[str], rng: np.random.Generator, on_step) -> "ApsOutcome":
        """Search the spaces of ``cfg.space.kinds`` from ``start_at`` (``perturbed``: the vehicles the
        poses space moves; the start's loss is told first, not counted)."""
        scene = start_at.scene
        space = SearchSpace(scene, perturbed, self.cfg.space)
        if space.dim == 0:
            raise EmptyFeasibleSet("nothing to perturb (no vehicle to move, no collaborator)")
        feasible = FeasibleSet(space, rng)
        world = world_for(space.world_scene, self.spec, movable_ids=space.movable_ids)
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

        lowest: list = [start_at.loss, None, None]  # the lowest loss scored, its frame and detections

        def objective(xs: list[np.ndarray]) -> list[tuple[float, dict[str, float]]]:
            frames = [frame_of(x) for x in xs]  # rendered here: the world moves its vehicles in place
            judged = self.candidates.map(self._judged, frames)
            for frame, j in zip(frames, judged):
                if j.loss < lowest[0]:  # best_of's pick: the first of the lowest, the start if none beats it
                    lowest[:] = [j.loss, frame, j.detections]
            return [(j.loss, j.ap) for j in judged]

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
        return ApsOutcome(Scored(final, best.loss, best.ap, lowest[1], lowest[2]), history, delta, tuple(perturbed),
                          columns, values, record, inserted)


@dataclass(frozen=True)
class Scored:
    """A scene as the target model sees it: its adversarial loss, AP by threshold and rendered frame."""

    scene: Scene
    loss: float
    ap: dict[str, float]
    frame: CooperativeFrame
    #: the target model's (boxes, scores, ground truth) on ``frame``
    detections: Detections

    @staticmethod
    def of(scene: Scene, frame: CooperativeFrame, judged: "Judged") -> "Scored":
        return Scored(scene, judged.loss, judged.ap, frame, judged.detections)


@dataclass(frozen=True)
class Judged:
    """A frame as the target model sees it: its adversarial loss, AP by threshold and detections."""

    loss: float
    ap: dict[str, float]
    detections: Detections


@dataclass(frozen=True)
class AcsCombinations:
    """The collaborator search's combinations (the scene with each), their frames and the
    strategy's probability of each ("a+b" -> p; empty for ACS-R)."""

    scenes: list[Scene]
    frames: list[CooperativeFrame]
    probabilities: dict[str, float]

    def outcome(self, judged: list["Judged"]) -> "AcsOutcome":
        """The search's outcome from each frame's judgement (in order): the first of the lowest loss."""
        best = min(range(len(judged)), key=lambda i: judged[i].loss)  # min keeps the first of ties
        return AcsOutcome(Scored.of(self.scenes[best], self.frames[best], judged[best]), self.probabilities,
                          len(judged))


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
