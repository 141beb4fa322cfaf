"""``open_run(cfg, out, ...).run()`` (or ``run_scenes(cfg, scenes, out, ...)``): run ACS then APS on each scene and write the run folder.

The library call behind ``asg generate`` and the benchmarks. A run folder records the settings it
was made with (``OUT/run.json``): a rerun with the same settings resumes (finished scenes are kept),
a rerun with other settings is refused unless ``force`` starts the folder over. Temporary work
stays inside the folder and stale partial files of an interrupted run are removed on the next.
"""
from __future__ import annotations

import itertools
import json
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator, Sequence

from sumo_scenarios.atomic import remove_stale_partials
from sumo_scenarios.checks import inside
from sumo_scenarios.digest import file_digest  # noqa: F401  (asg.generator.run.file_digest: the workflows import it from here)
from sumo_scenarios.errors import InputError

from ..executors import Executor, Job
from ..executors.local import LocalExecutor
from ..io.run_record import RUN_RECORD, claim, with_defaults
from .config import GenerateConfig
from .pipeline import Generator
from ..scene import Scene

if TYPE_CHECKING:  # (the targets load torch: only a run that asks for its target needs it)
    from ..perception.targets import Target

#: temporary work (a simulated log) inside the run folder, removed when the run ends
WORK_DIR = ".work"
#: what a run folder may hold: the only names ``force`` removes
#: the run's own SUMO log (a town or net source whose scenes need their past: the latency space)
LOG_DIR = "log"
RUN_CONTENTS = ("scenes", "summary.json", RUN_RECORD, WORK_DIR, LOG_DIR)
#: a town or net source: seconds between the frames that become scenes (every 10th of a log
#: recorded every 0.5 s, SimulationRequest's default)
SCENE_PERIOD_S = 5.0


@dataclass(frozen=True)
class SceneSource:
    """Where the normal scenes come from: a bundled town or any SUMO net (60 s of normal traffic,
    every 10th recorded frame with 5+ vehicles near the ego), or a folder / named set of scenes."""

    town: str | None = None
    net: Path | None = None
    scenes: Path | None = None
    #: recorded seconds of traffic simulated for a town or net
    duration_s: float = 60.0

    def describe(self) -> dict:
        """The source as recorded in run.json: a folder or file by its absolute path and the
        digest of what it holds (so that ``./x`` and ``/abs/x`` are one source, and a scene or net
        edited since is another); a named set or town by its name."""
        out: dict = {k: (None if v is None else str(v)) for k, v in
                     (("town", self.town), ("net", self.net), ("scenes", self.scenes))}
        if self.net is not None and Path(self.net).is_file():
            out["net"] = str(Path(self.net).resolve())
            out["net_sha256"] = file_digest(Path(self.net))
        if self.scenes is not None and Path(self.scenes).is_dir():
            out["scenes"] = str(Path(self.scenes).resolve())
            out["scenes_sha256"] = folder_digest(Path(self.scenes))
        return out


@dataclass(frozen=True)
class GenerateRun:
    """A finished (or resumed) run: its summary.json content and what was skipped, with why."""

    out: Path
    summary: dict
    skipped: tuple[tuple[str, str], ...]


#: called after each finished scene (scenes done, total, scene id) and after each evaluation (step)
SceneProgress = Callable[[int, int, str], None]
StepProgress = Callable[[int], None]


@dataclass(frozen=True)
class OpenRun:
    """A claimed run folder and the scenes it will run (:func:`open_run`); ``run`` runs them."""

    cfg: GenerateConfig
    out: Path
    scenes: tuple[Scene, ...]
    seed: int
    #: this run created ``out``: bad input that stops it before any scene is done removes it again
    fresh: bool

    def run(self, *, detector_factory: str | None = None, executor: Executor | None = None,
                 on_scene: SceneProgress | None = None, on_step: StepProgress | None = None,
                 artifacts: bool = True) -> GenerateRun:
        """:func:`run_scenes` on this folder's scenes (resuming what an earlier run finished)."""
        try:
            return run_scenes(self.cfg, self.scenes, self.out, seed=self.seed, detector_factory=detector_factory,
                            executor=executor, on_scene=on_scene, on_step=on_step, artifacts=artifacts)
        except InputError:
            if self.fresh and not any((self.out / "scenes").glob("*/result.json")):
                shutil.rmtree(self.out, ignore_errors=True)
            raise


def open_run(cfg: GenerateConfig, out: Path, *, source: SceneSource | None = None,
             scenes: Sequence[Scene] | None = None, count: int | None = None,
             pick: Callable[[list[Scene]], list[Scene]] | None = None, record: dict | None = None,
             seed: int = 1, force: bool = False) -> OpenRun:
    """The one entry of a generator run (``asg generate``, the challenging sets, the tables, the
    paper and scale benchmarks, hardening): claim run folder ``out`` for these settings (run.json:
    ``cfg``, ``seed``, the scene count, ``source`` described, ``record``; a folder of other settings
    is refused, ``force`` starts it over), then take the scenes: ``scenes`` as given, or the first
    ``count`` of ``source`` (all of a scene folder or set when None; a town or net needs a count,
    its traffic simulated inside ``out``), and refuse what cannot run before any scene is computed.
    ``pick``: which of the scenes taken to run (the settings count them all)."""
    if (source is None) == (scenes is None):
        raise ValueError("open_run takes a source or scenes")
    if scenes is None and count is None and source.scenes is None:
        raise ValueError("a town or net source needs a count")
    out = Path(out)
    fresh = not out.exists()
    taken = list(scenes) if scenes is not None else None
    if taken is None and count is None:  # a scene folder or set: read whole before the claim counts it
        taken = load_scenes(source, 10**6, seed, out / WORK_DIR)
    described = (source.describe() if source is not None else {}) | (record or {})
    prepare_run(out, run_settings(cfg, seed, len(taken) if count is None else count, described), force=force)
    try:
        if taken is None:
            taken = load_scenes(source, count, seed, out / WORK_DIR,
                                log_dir=out / LOG_DIR if cfg.space.needs_past else None)
        chosen = pick(taken) if pick else taken
        check_scenes(cfg, chosen)
    except BaseException:
        if fresh:  # bad input: leave no trace of the folder this run created
            shutil.rmtree(out, ignore_errors=True)
        raise
    finally:
        shutil.rmtree(out / WORK_DIR, ignore_errors=True)
    return OpenRun(cfg, out, tuple(chosen), seed, fresh)


def run_scenes(cfg: GenerateConfig, scenes: Sequence[Scene], out: Path, *, seed: int = 1,
             detector_factory: str | None = None, executor: Executor | None = None,
             on_scene: SceneProgress | None = None, on_step: StepProgress | None = None,
             artifacts: bool = True) -> GenerateRun:
    """Generate a challenging scene from each of ``scenes`` into run folder ``out`` (prepared by
    :func:`prepare_run`); finished scenes of an earlier run with the same settings are kept.

    ``detector_factory``: ``"module:function"`` returning (target, ACS model or None), built once
    per worker (default: the shipped ``cfg.fusion`` and AttFuse). ``executor``: where the scenes run
    (default: this process, one thread). A scene's result depends only on the scene, ``cfg`` and
    ``seed``, so any executor and worker count gives the same summary (timings aside).
    ``on_step`` reports evaluations only when the scenes run in this process
    (``executor.in_process``). ``artifacts``: write each scene's final clouds and pictures too (off
    for data sets of challenging scenes)."""
    from .run_folder import load_done, previous_wall_s, write_summary

    check_scenes(cfg, scenes)
    for s in scenes:
        inside(out / "scenes", out / "scenes" / s.scene_id)
    executor = executor or LocalExecutor(workers=1, threads=1)
    done = load_done(out)
    entries = {s.scene_id: done[s.scene_id] for s in scenes if s.scene_id in done}
    todo = [s.to_dict() for s in scenes if s.scene_id not in done]
    config = asdict(cfg) | {"seed": seed}
    started = time.perf_counter() - (previous_wall_s(out) if entries else 0.0)  # a resumed run adds its time
    order = [s.scene_id for s in scenes]
    in_order = lambda: [entries[i] for i in order if i in entries]
    matches: dict = {}  # each finished scene's matched detections, for the summary written after every scene
    skipped: list[tuple[str, str]] = []
    # the evaluation callback reaches the generator only where it runs in this process
    job = Job(_worker_setup, _worker_run,
              (cfg, detector_factory, str(out), seed, artifacts, on_step if executor.in_process else None,
               candidate_threads(cfg, detector_factory, executor, len(todo))))
    try:
        for n, (item, (status, value)) in enumerate(executor.map_unordered(job, todo), start=1):
            if status == "skipped":
                skipped.append((item["scene_id"], value))
            else:
                entries[item["scene_id"]] = value
                write_summary(out, in_order(), config, time.perf_counter() - started, matches)
            if on_scene:
                on_scene(n, len(todo), item["scene_id"])
    except BaseException:  # interrupted, or a worker lost: the workers are stopped; what they half-wrote goes
        remove_stale_partials(out / "scenes")  # (a Ray actor is killed, not left to clean up)
        raise
    if not entries:
        reasons = "; ".join(f"{sid}: {why}" for sid, why in skipped[:2])
        raise InputError(f"no scene could be generated ({reasons})")
    skipped.sort(key=lambda s: order.index(s[0]))
    summary = write_summary(out, in_order(), config, time.perf_counter() - started, matches)
    return GenerateRun(out, summary, tuple(skipped))


# ---- one worker ------------------------------------------------------------------------------------
def candidate_threads(cfg: GenerateConfig, detector_factory: str | None, executor: Executor, items: int) -> int:
    """The threads each worker scores a search's candidates on: the cores its executor leaves idle,
    for a target whose kind detects frames on several threads at once (a factory's detector: 1)."""
    if detector_factory or not cfg.target.concurrent_frames:
        return 1
    return executor.spare_threads(items)


def _worker_setup(cfg: GenerateConfig, detector_factory: str | None, out: str, seed: int, artifacts: bool,
                  on_step: StepProgress | None, threads: int = 1):
    """A worker's state: the generator with its detectors (scoring candidates on ``threads``
    threads), where to write, the seed, what to write, the evaluation callback (a worker in this
    process only)."""
    target, acs_model = factory_models(detector_factory, cfg) if detector_factory else _shipped_models(cfg)
    return Generator(cfg, target, acs_model, candidate_threads=threads), Path(out), seed, artifacts, on_step


def _worker_run(state, scene_dict: dict) -> tuple[str, object]:
    """One scene: generated and written to its folder; ("done", its summary entry) or ("skipped",
    why) when the scene cannot be attacked (too few vehicles, nothing plausible to move)."""
    from .run_folder import write_scene

    gen, out, seed, artifacts, on_step = state
    scene = Scene.from_dict(scene_dict)
    try:
        result = gen.attack(scene, seed, on_step=(lambda e: on_step(e.step)) if on_step else None)
    except InputError as exc:
        return "skipped", str(exc)
    return "done", write_scene(out, result, artifacts)


def load_factory(spec: str):
    """The callable named by ``"module:function"``; InputError if it cannot be imported."""
    import importlib

    module_name, _, attr = spec.partition(":")
    if not module_name or not attr:
        raise InputError(f"detector factory {spec!r} must be written module:function")
    try:
        factory = getattr(importlib.import_module(module_name), attr)
    except (Exception, SystemExit) as exc:  # its module may fail in any way (a syntax error, an exit)
        raise InputError(f"detector factory {spec!r} cannot be loaded ({type(exc).__name__}: {exc})".splitlines()[0]) from None
    if not callable(factory):
        raise InputError(f"detector factory {spec!r} is a {type(factory).__name__}, not a function")
    return factory


def factory_models(spec: str, cfg: GenerateConfig):
    """(target, ACS model or None) that factory ``spec`` returns for ``cfg``, each behind the checks
    every detector from outside gets (asg.perception.plugins.CheckedDetector); InputError if the
    factory fails or returns something else."""
    from ..perception.plugins import CheckedDetector, guarded_call

    where = f"detector factory {spec!r}"
    out = guarded_call(where, "the factory", load_factory(spec), cfg)
    if not isinstance(out, (tuple, list)) or len(out) != 2 or not callable(getattr(out[0], "detect", None)):
        raise InputError(f"{where} must return (target, ACS model or None), the target with a detect(frame) method; "
                         f"got {type(out).__name__}")
    target, acs_model = out
    if acs_model is not None and not callable(getattr(acs_model, "attention_weights", None)):
        raise InputError(f"{where}: its ACS model has no attention_weights(frame, cells) method")
    if acs_model is None and cfg.acs_needs_attention:  # as for a shipped model without attention: AttFuse's
        from ..perception import build_detector
        from ..perception.fusion import ATTENTION_LENDER

        return CheckedDetector(where, target), build_detector(ATTENTION_LENDER)
    return CheckedDetector(where, target), (None if acs_model is None else CheckedDetector(where, acs_model))


def _shipped_models(cfg: GenerateConfig):
    from ..perception import build_detector
    from ..perception.fusion import ATTENTION_LENDER, has_own_attention

    target = cfg.target.detector(cfg.weights)
    acs_model = None
    if cfg.acs_needs_attention:  # the target's own attention when it has one, else the shipped AttFuse's
        acs_model = target if has_own_attention(target) else build_detector(ATTENTION_LENDER)
    return target, acs_model


def _refuse_duplicates(scenes: Sequence[Scene]) -> None:
    seen: set[str] = set()
    for s in scenes:
        if s.scene_id in seen:
            raise InputError(f"scene id '{s.scene_id}' appears twice in the input; give each scene its own id")
        seen.add(s.scene_id)


# ---- the run folder ----------------------------------------------------------------------------
def run_settings(cfg: GenerateConfig, seed: int, count: int, source: dict) -> dict:
    """What run.json records: every setting that changes the run's scenes or numbers (with the
    digest of the target's weights file, so that other weights at the same path are noticed, and
    of the shipped weights the run loads, so that a run resumed after they changed is noticed)."""
    from .config import search_params

    settings = {"config": asdict(cfg), "seed": seed, "count": count, "source": source,
                "search_settings": search_params(cfg.search)}  # configs/search/NAME.yaml (BO's batch, ...)
    if cfg.weights:
        settings["weights_sha256"] = file_digest(Path(cfg.weights))
    shipped = shipped_digests(cfg.target, cfg.weights, cfg.acs_needs_attention)
    if shipped:
        settings["shipped_weights_sha256"] = shipped
    settings.update(cfg.target.run_record())  # e.g. a model folder's files' digests
    return settings


def shipped_digests(target: "Target", weights: str | None, acs_attention: bool) -> dict[str, str]:
    """{weights name: sha256} of the shipped weights files a run against ``target`` loads (its own
    when it is given no ``weights`` file; the shipped AttFuse's for attention-based ACS)."""
    from ..perception.targets import shipped_weights_of

    files = shipped_weights_of(target, own=not weights, acs_attention=acs_attention)
    return {name: file_digest(path) for name, path in sorted(files.items())}


def folder_digest(folder: Path) -> str:
    """sha256 over the names and contents of a scene folder's files (yaml, or a data set's index
    and frames), sorted by name."""
    import hashlib

    h = hashlib.sha256()
    for p in sorted(folder.iterdir()):
        if p.is_file() and not p.name.startswith(".") and p.suffix in (".yaml", ".yml", ".json", ".gz"):
            h.update(p.name.encode() + b"\0" + file_digest(p).encode())
    return h.hexdigest()


def prepare_run(out: Path, settings: dict, force: bool = False) -> None:
    """Check and claim run folder ``out`` before any scene is computed (asg.io.run_record.claim):
    a writable folder that records no other settings while it holds finished scenes (``force``:
    start it over); removes stale partial files and work left by an interrupted run."""
    out = Path(out)
    claim(out, settings, force, what="a run", contents=RUN_CONTENTS, holds_results=_has_finished_scenes,
          as_today=with_new_defaults)
    remove_stale_partials(out)
    remove_stale_partials(out / "scenes")
    shutil.rmtree(out / WORK_DIR, ignore_errors=True)


def with_new_defaults(record: dict) -> dict:
    """``record`` with every setting it lacks filled in with today's default: a setting added to
    the generator after the record was written has a default that reproduces the earlier
    behaviour, so a folder written before it resumes instead of being refused. A record from before
    the shipped weights' digests, or the search's settings, were recorded is taken as made with
    today's."""
    from .config import search_params

    filled = with_defaults(record, {"config": asdict(GenerateConfig())})
    cfg = filled.get("config")
    if "search_settings" not in filled and isinstance(cfg, dict) and isinstance(cfg.get("search"), str):
        filled["search_settings"] = search_params(cfg["search"])
    if "shipped_weights_sha256" not in filled and isinstance(cfg, dict):
        from ..perception.targets import resolve_target  # the name a record holds: resolved as a flag is

        shipped = shipped_digests(resolve_target(str(cfg.get("fusion"))), cfg.get("weights"), _reads_attention(cfg.get("acs")))
        if shipped:
            filled["shipped_weights_sha256"] = shipped
    return filled


def _reads_attention(acs: object) -> bool:
    """Does the collaborator search ``acs`` recorded by an older run folder read attention?"""
    from ..collaborators import ACS_STRATEGIES

    return isinstance(acs, str) and acs in ACS_STRATEGIES and ACS_STRATEGIES.entry(acs).needs_attention


def made_with_other_shipped_weights(out: Path, cfg: GenerateConfig) -> str | None:
    """The first shipped weights file whose digest differs between the run recorded in folder
    ``out`` and today's install (None if the same, or nothing recorded)."""
    try:
        recorded = json.loads((Path(out) / RUN_RECORD).read_text())["shipped_weights_sha256"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not isinstance(recorded, dict):
        return None  # a damaged record: claiming the folder refuses it
    today = shipped_digests(cfg.target, cfg.weights, cfg.acs_needs_attention)
    return next((name for name in sorted(set(recorded) | set(today)) if recorded.get(name) != today.get(name)), None)


def _has_finished_scenes(out: Path) -> bool:
    """Does run folder ``out`` hold a scene that a rerun would keep? (A folder claimed by a run that
    failed before its first scene holds none, and may be claimed anew with other settings.)"""
    return any((out / "scenes").glob("*/result.json"))


def check_scenes(cfg: GenerateConfig, scenes: Sequence[Scene]) -> None:
    """What a run refuses before computing any scene (InputError): two scenes of one id, a scene
    whose log cannot give the past a space reads (latency), a scene without lanes where a space or
    the plausibility level reads them."""
    _refuse_duplicates(scenes)
    if cfg.space.needs_lanes and (bare := next((s for s in scenes if not s.lane_map.lanes), None)):
        raise InputError(f"scene {bare.scene_id} has no lanes (a recording imported without --map): the insert space "
                         "and --plausibility traffic read lanes; use --space poses (or a link space) and "
                         "--plausibility paper, or import it with its town's map")
    if cfg.space.needs_past and (recorded := next((s for s in scenes if not s.keeps_past), None)):
        raise InputError(f"scene {recorded.scene_id} is a recording, whose earlier frames are not imported: the "
                         "latency space reads a scene's past; use another space")
    if cfg.space.needs_past:
        from ..scene.history import check_past

        for s in scenes:
            check_past(s, cfg.space.past_s)


# ---- where scenes come from ----------------------------------------------------------------------
def load_scenes(source: SceneSource, count: int, seed: int, workdir: Path, *,
                log_dir: Path | None = None) -> list[Scene]:
    """The first ``count`` scenes of ``source``. A town's traffic is simulated into ``workdir``
    (removed by the caller), or, with ``log_dir`` (the run's own log, kept: a source whose scenes
    need their past, as the latency space does), into ``log_dir``, recorded every simulation step;
    the scenes then name it as their log. The scenes are the same either way."""
    scenes = _scenes_from_dir(source.scenes) if source.scenes is not None else \
        _scenes_from_town(source, seed, workdir, log_dir)
    picked = list(itertools.islice(scenes, count))
    _refuse_duplicates(picked)
    if not picked:
        raise InputError("no usable scene (none with 5+ vehicles near the ego); try another town or seed")
    return picked


def _scenes_from_town(source: SceneSource, seed: int, workdir: Path, log_dir: Path | None) -> Iterator[Scene]:
    from dataclasses import replace

    from sumo_scenarios.log import META_NAME
    from sumo_scenarios.simulate import SimulationRequest, simulate_sumo

    from ..scene.from_log import ExtractParams, extract_scenes
    from ..scene.history import HISTORY_MARGIN_S

    request = SimulationRequest(out_dir=workdir / "log", town=source.town, net=source.net, seed=seed,
                                duration_s=source.duration_s, density="normal")
    if log_dir is None:
        simulate_sumo(request)
        every = round(SCENE_PERIOD_S / request.record_period_s)
        # the log lives in the run's work folder, removed at the end: the scenes name no log
        return (replace(s, log=None) for s in extract_scenes(request.out_dir, ExtractParams(every=every, min_vehicles=5)))
    # the same traffic (the same routes and end), recorded every step from HISTORY_MARGIN_S earlier:
    # the past a latency delay reaches; the scenes are the frames of the same instants
    first_s = request.warmup_s
    request = replace(request, out_dir=log_dir, record_period_s=request.step_s, warmup_s=first_s - HISTORY_MARGIN_S,
                      duration_s=request.duration_s + HISTORY_MARGIN_S)
    if not (log_dir / META_NAME).is_file():  # a resumed run keeps the log its scenes came from
        shutil.rmtree(log_dir, ignore_errors=True)
        simulate_sumo(request)
    params = ExtractParams(every=round(SCENE_PERIOD_S / request.record_period_s), min_vehicles=5, from_s=first_s)
    return (replace(s, log=str(log_dir.resolve())) for s in extract_scenes(log_dir, params))


def _scenes_from_dir(path: Path) -> Iterator[Scene]:
    from ..datasets import scenes_of

    return scenes_of(str(path))
