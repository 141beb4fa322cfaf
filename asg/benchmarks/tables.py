"""``asg bench paper --table main|finetune|transfer|acs|ablation|blackbox|spaces|all``: the paper's tables
and, beyond the paper, the perturbation spaces (``spaces``).

Every table is measured at the paper's sizes by default (the 219 scenes of normal's train split;
fine-tuning on the 112 of its val split) or on the first ``scenes`` of each split for a quick run,
and written as ``OUT/TABLE.json``, ``.csv`` and ``.md`` with our numbers beside the paper's. What
they share is computed once and reused: the challenging sets (``asg dataset build challenging``,
in the data folder) and the generator runs of the collaborator-search and black-box tables
(``OUT/runs/...``, resumable ``asg generate`` folders). JSON schema: docs/results/tables.md.
"""
from __future__ import annotations

import csv
import io
import itertools
import json
import os
import platform
import subprocess
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

from sumo_scenarios.atomic import write_text_atomic
from sumo_scenarios.errors import InputError

from ..objective import AP_KEYS
from ..registry import Registry
from ..objective.ap import DEFAULT_AP_METHOD, Yardstick, check_ap_method
from ..objective.pooled import REATTACK_PAIR, PooledAP, pooled_pair
from . import paper_figures as paper

#: the four shipped models of the paper, in its order
MODELS = ("none", "late", "early", "attfuse")
THRESHOLDS = AP_KEYS  # the keys of AP@0.3 / 0.5 / 0.7 in results (asg.objective)


@dataclass(frozen=True)
class TableRun:
    """How the tables are measured: where they go, on how many scenes (None: the paper's sizes),
    on which executor, against which detectors (``detector_factory``: "module:function" standing in
    for every model, as ``asg generate --detector``; None: the shipped weights)."""

    out: Path
    scenes: int | None = None
    executor: object | None = None
    detector_factory: str | None = None
    seed: int = 1
    command: str = "asg bench paper"
    #: finetune table: also this many rounds of ``asg harden --fusion attfuse`` with each kind of
    #: data (adversarial and the two controls), each a row a round (0: the paper's rows only)
    harden_rounds: int = 0
    #: their train.yaml ``harden`` block (None: configs/detectors/train.yaml's; ``data`` is set per run)
    harden_config: object | None = None
    #: how AP ranks the detections of several frames (asg.objective.ap.AP_METHODS): global (ours)
    #: or per-frame (the paper's yardstick)
    ap_method: str = DEFAULT_AP_METHOD
    #: the models with rows in Table I (main), Table III (transfer), Table IV (acs) and the spaces
    #: table: any shipped models (rows without the paper's figures for the ones it lacks); None:
    #: each table's own (the paper's four; AttFuse alone in the spaces table)
    models: tuple[str, ...] | None = None
    #: the searches the spaces table compares (None: SPACE_SEARCHES)
    searches: tuple[str, ...] | None = None
    #: detector evaluations already scored in this measurement, {(model, set): result}: a table
    #: written with a second AP method rescores them instead of detecting again
    scored: dict = field(default_factory=dict, compare=False, repr=False)
    #: the targets of the models named, {model: Target}, each resolved once a measurement (:meth:`target`)
    targets: dict = field(default_factory=dict, compare=False, repr=False)

    def target(self, model: str):
        """``model``'s target (asg.perception.targets), resolved once for every table of the run."""
        if model not in self.targets:
            from ..perception.targets import resolve_target

            self.targets[model] = resolve_target(model)
        return self.targets[model]


def run_tables(names: tuple[str, ...], run: TableRun, log: Callable[[str], None] = print,
               ap_methods: tuple[str, ...] | None = None) -> dict[str, dict]:
    """Measure and write each table of ``names`` with each AP method of ``ap_methods`` (default:
    ``run.ap_method``); returns {file stem: its JSON} (TABLE, or TABLE.per-frame for that method)."""
    for n in names:
        TABLE_KINDS.check(n, ("all",))
    methods = tuple(check_ap_method(m) for m in (ap_methods or (run.ap_method,)))
    run.out.mkdir(parents=True, exist_ok=True)
    return {table_stem(name, m): run_table(name, replace(run, ap_method=m), log) for name in names for m in methods}


def _detectors(run: TableRun) -> str:
    """What detected, for a table's header: the factory standing in for every model, or the shipped
    weights and any OpenCOOD model folders among the models (named in the rows)."""
    if run.detector_factory:
        return run.detector_factory
    headers = list(dict.fromkeys(run.target(m).header for m in run.models or ()))
    return ", and ".join(headers) or "shipped"


def table_stem(name: str, ap_method: str) -> str:
    """The file stem of a table written with ``ap_method``: NAME (global) or NAME.per-frame."""
    return name if ap_method == DEFAULT_AP_METHOD else f"{name}.{ap_method}"


def run_table(name: str, run: TableRun, log: Callable[[str], None] = print) -> dict:
    log(f"table {name} (AP {run.ap_method}) ...")
    started = time.perf_counter()
    rows, scenes = TABLE_KINDS.entry(name).build(run)
    result = {"table": name, "command": run.command, "scenes": scenes, "seconds": round(time.perf_counter() - started, 1),
              "commit": _commit(), "machine": _machine(), "detector": _detectors(run),
              "ap_method": run.ap_method, "rows": rows}
    stem = table_stem(name, run.ap_method)
    write_text_atomic(run.out / f"{stem}.json", json.dumps(result, indent=1))
    write_text_atomic(run.out / f"{stem}.csv", to_csv(rows))
    write_text_atomic(run.out / f"{stem}.md", to_markdown(result))
    return result


# ---- the tables --------------------------------------------------------------------------------------
def main_table(run: TableRun) -> tuple[list[dict], int]:
    """Table I: each model on normal (train split) and on its own challenging scenes."""
    rows, counts = [], set()
    for model in run.models or MODELS:
        ap = _challenging(model, "train", run)
        counts.add(ap["scenes"])
        rows.append({"model": model, "normal": ap["normal"], "challenging": ap["challenging"],
                     "paper": paper.MAIN.get(model)})
    return rows, min(counts)


def finetune_table(run: TableRun) -> tuple[list[dict], int]:
    """Table II: AttFuse and AttFuse-FT on normal-val, heuristic and challenging-val (the val split
    attacked against AttFuse) and, beyond the paper, each under its own attack on normal-val.

    Every row is scored by today's detector code: the own-attack row evaluates the model on the
    scenes its attack found, not the detections the attack stored when it built them (which an
    older build of the set would leave behind)."""
    from functools import cache

    from ..workflows.challenging import build_challenging

    @cache
    def own_set(model: str) -> str:
        return build_challenging(run.target(model), "val", run.executor, count=run.scenes,
                                 detector_factory=run.detector_factory).name

    challenging = own_set("attfuse")
    scored: dict[tuple[str, str], dict] = {}  # AttFuse's own attack is challenging-val: scored once
    rows = []
    for model in ("attfuse", "attfuse-ft"):
        own = own_set(model)
        for set_, key in (("normal-val", "normal-val"), ("heuristic", "heuristic"), (challenging, "challenging-val"),
                          (own, "own-attack-val")):
            res = scored.get((model, set_)) or scored.setdefault((model, set_), _evaluate(model, set_, run))
            rows.append({"model": model, "set": key, "scenes_from": set_, "ap": res["ap"], "frames": res["frames"],
                         "paper": paper.FINETUNE.get((model, key))})
    counted = min(r["frames"] for r in rows if r["set"] != "heuristic")
    return rows + harden_rows(run), counted


def harden_rows(run: TableRun) -> list[dict]:
    """Beyond the paper: ``run.harden_rounds`` rounds of ``asg harden --fusion attfuse`` with
    adversarial scenes and with the two controls at equal compute (random plausible perturbations,
    unperturbed scenes), each into ``OUT/harden/DATA`` (resumable); a row per round and evaluation
    set, named ``harden-DATA-rK`` (``own-attack-val``: the round's weights attacked again on normal-val).
    With ``run.scenes``, each round draws that many scenes."""
    if not run.harden_rounds:
        return []
    from dataclasses import replace

    from ..workflows.harden import DATA_KINDS, harden, load_harden_config

    base = run.harden_config or load_harden_config()
    if run.scenes:
        base = replace(base, scenes_per_round=run.scenes)
    rows = []
    for data in DATA_KINDS:
        card = harden(run.target("attfuse"), run.harden_rounds, run.out / "harden" / data, config=replace(base, data=data),
                      executor=run.executor, detector_factory=run.detector_factory, log=lambda *_: None)
        for row in card["rounds"][1:]:
            model = f"harden-{data}-r{row['round']}"
            aps = {set_: PooledAP.from_json(ev).of(run.ap_method) for set_, ev in row["evaluation"].items()}
            if row.get("reattack"):
                aps["own-attack-val"] = pooled_pair(row["reattack"], REATTACK_PAIR)["challenging"].of(run.ap_method)
            if any(ap is None for ap in aps.values()):
                raise InputError(f"{run.out / 'harden' / data / 'card.json'} was written before asg harden recorded "
                                 "the paper's yardstick; give another --out, or leave out --ap-method")
            for set_, ev in row["evaluation"].items():
                key = "challenging-val" if set_.startswith("challenging-") else set_
                rows.append({"model": model, "set": key, "scenes_from": set_, "frames": ev["frames"],
                             "ap": {t: aps[set_][t] for t in THRESHOLDS}, "paper": None})
            if row.get("reattack"):
                rows.append({"model": model, "set": "own-attack-val", "scenes_from": f"harden/{data}/round-{row['round']}/reattack", "frames": row["reattack"]["frames"],
                             "ap": aps["own-attack-val"], "paper": None})
    return rows


def transfer_table(run: TableRun) -> tuple[list[dict], int]:
    """Table III: each model scored on the challenging scenes generated against each model (train
    split), and on the normal scenes they came from."""
    from ..workflows.challenging import set_name

    rows, counts = [], set()
    models = run.models or MODELS
    for source in models:
        _challenging(source, "train", run)
    # each source's set named once (an OpenCOOD folder's label hashes its checkpoint)
    attacked = {source: set_name(run.target(source), "train") for source in models}
    for target in models:
        normal = _evaluate(target, "normal", run)
        rows.append({"source": "normal", "target": target, "ap": normal["ap"], "paper": None})
        for source in models:
            res = _evaluate(target, attacked[source], run)
            counts.add(res["frames"])
            rows.append({"source": source, "target": target, "ap": res["ap"],
                         "paper": paper.TRANSFER.get((source, target))})
    return rows, min(counts)


def acs_table(run: TableRun) -> tuple[list[dict], int]:
    """Table IV: collaborator search alone (no perturbation): random (ACS-R) against attention (ACS-A)."""
    rows, counts = [], set()
    for model in run.models or MODELS:
        random_ = _generator_run(run, model, acs="random", search="bo", aps=False)
        attention = _generator_run(run, model, acs="attention", search="bo", aps=False)
        counts.add(attention["scenes"])
        rows.append({"model": model, "normal": attention["normal"], "acs_random": random_["challenging"],
                     "acs_attention": attention["challenging"],
                     "paper": None if model not in paper.ACS else
                     dict(zip(("normal", "acs_random", "acs_attention"),
                              ({"0.3": None, "0.5": None, "0.7": round(v / 100, 4)} for v in paper.ACS[model])))})
    return rows, min(counts)


def ablation_table(run: TableRun) -> tuple[list[dict], int]:
    """Table V: AttFuse with neither, either or both of ACS and APS (BO)."""
    acs_only = _generator_run(run, "attfuse", acs="attention", search="bo", aps=False)
    aps_only = _generator_run(run, "attfuse", acs="off", search="bo", aps=True)
    both = _challenging("attfuse", "train", run)
    rows = [{"acs": False, "aps": False, "ap": acs_only["normal"]},
            {"acs": True, "aps": False, "ap": acs_only["challenging"]},
            {"acs": False, "aps": True, "ap": aps_only["challenging"]},
            {"acs": True, "aps": True, "ap": both["challenging"]}]
    for row in rows:
        row["paper"] = {"0.3": None, "0.5": None, "0.7": round(paper.ABLATION[(row["acs"], row["aps"])] / 100, 4)}
    return rows, min(acs_only["scenes"], aps_only["scenes"], both["scenes"])


def blackbox_table(run: TableRun) -> tuple[list[dict], int]:
    """Table VI: the black-box searches alone (APS without ACS) on AttFuse, same scenes and budget."""
    runs = {search: _generator_run(run, "attfuse", acs="off", search=search, aps=True) for search in ("rs", "ga", "bo")}
    rows = [{"search": "normal", "ap": runs["bo"]["normal"], "paper": paper.BLACKBOX["normal"]}]
    rows += [{"search": s, "ap": r["challenging"], "paper": paper.BLACKBOX[s]} for s, r in runs.items()]
    return rows, min(r["scenes"] for r in runs.values())


#: the spaces table: each space alone, then all together (asg.search.spaces)
#: every space together (the "union" rows)
UNION = "poses,insert,pose-error,latency,dropout"
SPACES = ("poses", UNION, "pose-error", "latency", "insert", "dropout")
#: the searches it compares at the same budget
SPACE_SEARCHES = ("rs", "bo", "ng")
#: the spaces that place vehicles (moved or inserted), measured at the traffic plausibility level too
#: (the others move none, so the level does not change them)
TRAFFIC_SPACES = ("poses", UNION, "insert")
#: the union once more with this many moved vehicles instead of the config's (the paper's 3): a
#: larger space of the same kinds
WIDE_UNION_MOVERS = 6
#: the spaces table runs on the generator benchmark's scenes (asg bench paper without --table)
BENCHMARK_SCENES = 30


def spaces_table(run: TableRun) -> tuple[list[dict], int]:
    """Beyond the paper: each model of ``run.models`` (default AttFuse alone) with ACS-A, then each
    perturbation space alone and all of them together, searched by each of ``run.searches`` (default
    random search, BO and nevergrad) at the same budget, on the generator benchmark's scenes
    (``run.scenes`` of them, default 30), at the config's plausibility level; the spaces that place
    vehicles (TRAFFIC_SPACES) also at the ``traffic`` level, and the union with WIDE_UNION_MOVERS
    moved vehicles. Drop = AP on the normal scenes minus AP after the search. A model without
    attention weights takes ACS-A's from AttFuse, as ``asg generate`` does."""
    from ..generator.config import load_generate_config
    from .paper import pick_scenes

    count = run.scenes or BENCHMARK_SCENES
    scene_dir = pick_scenes(run.out / f"benchmark-scenes-{count}", count)
    rows, counts = [], set()
    runs = ([(kinds, None, None) for kinds in SPACES] + [(kinds, "traffic", None) for kinds in TRAFFIC_SPACES]
            + [(UNION, None, WIDE_UNION_MOVERS)])
    for model, (kinds, plausibility, movers) in itertools.product(run.models or ("attfuse",), runs):
        for search in run.searches or SPACE_SEARCHES:
            row = {"model": model, "space": "union" if kinds == UNION else kinds, "kinds": kinds.split(","),
                   "search": search}
            try:
                res = _generator_run(run, model, acs="attention", search=search, aps=True, kinds=kinds,
                                     scenes=scene_dir, plausibility=plausibility, movers=movers)
            except InputError as exc:  # e.g. latency on scenes without a traffic log: say why, measure the rest
                cfg = load_generate_config()
                rows.append(row | {"plausibility": plausibility or cfg.space.plausibility,
                                   "movers": movers or cfg.perturbed, "error": str(exc)})
                continue
            counts.add(res["scenes"])
            rows.append(row | {"plausibility": res["plausibility"], "movers": res["movers"],
                               "ap": res["challenging"], "normal": res["normal"],
                               "drop": {k: round(res["normal"][k] - res["challenging"][k], 6) for k in THRESHOLDS},
                               "mean_loss": res["mean_loss"], "seconds_per_scene": res["seconds_per_scene"],
                               "implausible_scenes": res["implausible"]})
    return rows, min(counts, default=0)


# ---- shared measurements -------------------------------------------------------------------------------
def _challenging(model: str, split: str, run: TableRun) -> dict:
    """{"scenes", "normal", "challenging"}: the model's challenging set of ``split`` (built or
    resumed), pooled over its first ``run.scenes`` scenes."""
    from ..workflows.challenging import build_challenging, first_scenes_ap

    out = build_challenging(run.target(model), split, run.executor, count=run.scenes, detector_factory=run.detector_factory)
    return first_scenes_ap(out, run.scenes, run.ap_method)


def _evaluate(model: str, set_name: str, run: TableRun) -> dict:
    """{"ap": AP by threshold ranked by ``run.ap_method``, "frames"} of ``model`` on ``set_name``
    (detected once per measurement: see TableRun.scored)."""
    from ..evaluation import evaluate

    key = (model, set_name)
    if key not in run.scored:
        run.scored[key] = evaluate(run.target(model), set_name, limit=run.scenes, executor=run.executor,
                                   detector_factory=run.detector_factory)
    res = run.scored[key]
    ap = PooledAP.from_result(res).of(run.ap_method)
    return {"ap": {k: round(v, 6) for k, v in ap.items()}, "frames": res["frames"]}


def _generator_run(run: TableRun, model: str, *, acs: str, search: str, aps: bool, kinds: str | None = None,
                   scenes: Path | None = None, plausibility: str | None = None, movers: int | None = None) -> dict:
    """{"scenes", "normal", "challenging", "mean_loss", "seconds_per_scene", "plausibility", "movers",
    "implausible"} of one generator configuration on the first scenes of normal's train split
    (or of folder ``scenes``), with the perturbation spaces ``kinds`` (comma-separated; default the
    config's) at the plausibility level ``plausibility`` and with ``movers`` moved vehicles (default:
    the config's): an ``asg generate`` folder under OUT/runs/, resumed if there."""
    import statistics

    from ..generator.run import SceneSource, open_run
    from ..generator.config import load_generate_config, with_space_flags
    from ..generator.run_folder import aggregate_ap
    from ..generator.stages import Stage

    cfg = with_space_flags(load_generate_config(fusion=model, acs=acs, search=search, aps=aps, perturbed=movers),
                           plausibility, kinds)
    source = SceneSource(scenes=scenes or Path("normal"))
    name = f"{run.target(model).label}-acs_{acs}-{search if aps else 'no_aps'}"
    if kinds is not None:
        name = f"{scenes.name if scenes else 'normal'}-{name}-space_{kinds.replace(',', '+')}"
    if plausibility is not None:
        name += f"-plausibility_{plausibility}"
    if movers is not None:
        name += f"-movers_{movers}"
    run_dir = run.out / "runs" / name
    summary = open_run(cfg, run_dir, source=source, count=run.scenes, record={"detector": run.detector_factory},
                       seed=run.seed).run(detector_factory=run.detector_factory, executor=run.executor,
                                               artifacts=False).summary
    agg, entries = summary["aggregate"], summary["scenes"]
    return {"scenes": agg["scenes"], "normal": aggregate_ap(agg, Stage.NORMAL, run.ap_method),
            "challenging": aggregate_ap(agg, Stage.FINAL, run.ap_method),
            "mean_loss": round(statistics.fmean(e["loss_final"] for e in entries), 6),
            "seconds_per_scene": round(statistics.median(e["seconds"] for e in entries), 3),
            "plausibility": cfg.space.plausibility, "movers": cfg.perturbed,
            "implausible": sum(any(v for v in e["plausibility"].values()) for e in entries)}


# ---- output ---------------------------------------------------------------------------------------------
def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, timeout=10,
                              cwd=Path(__file__).resolve().parent, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        from .. import __version__

        return f"asg {__version__} (not a git checkout)"


def _machine() -> str:
    return f"{platform.machine()}, {os.cpu_count()} cores, {platform.system()} {platform.release()}, Python {platform.python_version()}"


def _flat(row: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in row.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}_"))
        else:
            out[f"{prefix}{k}"] = v
    return out


def to_csv(rows: list[dict]) -> str:
    """One line a row; nested AP columns flattened (``normal_0.7``, ``paper_challenging_0.7``)."""
    flat = [_flat(r) for r in rows]
    columns = list(dict.fromkeys(k for r in flat for k in r))
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    writer.writerows(flat)
    return buf.getvalue()


def _pct(ap: dict | None, key: str = "0.7") -> str:
    return "" if not ap or ap.get(key) is None else f"{100 * ap[key]:.1f}"


def _triple(ap: dict | None) -> str:
    if not ap:
        return ""
    if all(ap.get(t) is not None for t in THRESHOLDS):
        return " / ".join(_pct(ap, t) for t in THRESHOLDS)
    return _pct(ap)


def to_markdown(result: dict) -> str:
    """The table as markdown (AP in %, ours beside the paper's) under the command that made it."""
    method = result.get("ap_method", DEFAULT_AP_METHOD)
    yardstick = ("ranked per frame with no sort across frames (the paper's yardstick)" if method == Yardstick.PER_FRAME else
                 "ranked globally across frames (ours)")
    head = (f"`{result['command']}`: {result['scenes']} scenes, {result['seconds']:.0f} s, commit {result['commit']}, "
            f"{result['machine']}; detector {result['detector']}. AP@0.3 / 0.5 / 0.7 in %, {yardstick}.\n\n")
    return head + TABLE_KINDS.entry(result["table"]).markdown(result["rows"]) + "\n"


def _md_table(header: list[str], lines: list[list[str]]) -> str:
    return "\n".join(["| " + " | ".join(header) + " |", "|" + "---|" * len(header)] +
                     ["| " + " | ".join(line) + " |" for line in lines])


def _md_main(rows):
    return _md_table(["model", "normal", "challenging", "drop @0.7", "paper normal", "paper challenging", "paper drop @0.7"],
                     [[r["model"], _triple(r["normal"]), _triple(r["challenging"]),
                       f"{100 * (r['normal']['0.7'] - r['challenging']['0.7']):.1f}",
                       *((_triple(r["paper"]["normal"]), _triple(r["paper"]["challenging"]),
                          f"{100 * (r['paper']['normal']['0.7'] - r['paper']['challenging']['0.7']):.1f}")
                         if r["paper"] else ("", "", ""))] for r in rows])


def _md_finetune(rows):
    return _md_table(["model", "set", "frames", "AP", "paper AP@0.7"],
                     [[r["model"], r["set"], str(r["frames"]), _triple(r["ap"]), _pct(r["paper"])] for r in rows])


def _md_transfer(rows):
    sources = list(dict.fromkeys(r["source"] for r in rows))
    targets = list(dict.fromkeys(r["target"] for r in rows))
    cell = {(r["source"], r["target"]): r for r in rows}

    def show(s, t):
        r = cell[(s, t)]
        text = _pct(r["ap"]) + (f" ({_pct(r['paper'])})" if r["paper"] else "")
        return f"**{text}**" if s == t else text
    return ("AP@0.7 of each target (row) on the scenes generated against each source (column); the paper's in "
            "parentheses.\n\n" + _md_table(["target \\ source", *sources], [[t, *[show(s, t) for s in sources]] for t in targets]))


def _md_acs(rows):
    def cell(r, k):
        return _pct(r[k]) + (f" ({_pct(r['paper'][k])})" if r["paper"] else "")
    return ("AP@0.7; the paper's in parentheses.\n\n" +
            _md_table(["model", "normal", "ACS-R", "ACS-A"],
                      [[r["model"], cell(r, "normal"), cell(r, "acs_random"), cell(r, "acs_attention")] for r in rows]))


def _md_ablation(rows):
    mark = lambda b: "yes" if b else ""
    return _md_table(["ACS", "APS", "AP", "paper AP@0.7"],
                     [[mark(r["acs"]), mark(r["aps"]), _triple(r["ap"]), _pct(r["paper"])] for r in rows])


def _md_blackbox(rows):
    return _md_table(["search", "AP", "paper"], [[r["search"], _triple(r["ap"]), _triple(r["paper"])] for r in rows])


def _md_spaces(rows):
    return (_md_spaces_by_model(rows) +
            "AP@0.3 / 0.5 / 0.7 after ACS-A and the search, drop of AP@0.7 from the normal scenes (points), mean "
            "final loss, median seconds a scene.\n\n" +
            _md_table(["model", "space", "movers", "plausibility", "search", "AP", "drop @0.7", "mean loss",
                       "s / scene", "implausible"],
                      [[r["model"], r["space"], str(r["movers"]), r["plausibility"], r["search"], _triple(r["ap"]),
                        f"{100 * r['drop']['0.7']:.1f}", f"{r['mean_loss']:.3f}", f"{r['seconds_per_scene']:.1f}",
                        str(r["implausible_scenes"])]
                       if "error" not in r else
                       [r["model"], r["space"], str(r["movers"]), r["plausibility"], r["search"],
                        f"not measured: {r['error']}",
                        "", "", "", ""]
                       for r in rows]))


def _md_spaces_by_model(rows) -> str:
    """With more than one model: a model's AP@0.7 on the normal scenes and its drop (points) under
    each space (a column per space, plausibility level and movers; one figure per search, " / "
    between them), above the full table. Empty for one model."""
    models = list(dict.fromkeys(r["model"] for r in rows))
    if len(models) < 2:
        return ""

    def column(r):
        return r["space"] + ("" if r["plausibility"] == "paper" else f" ({r['plausibility']})") + \
            (f", {r['movers']} movers" if r["movers"] != 3 else "")

    columns = list(dict.fromkeys(column(r) for r in rows))
    searches = list(dict.fromkeys(r["search"] for r in rows))
    cells = {(r["model"], column(r), r["search"]): r for r in rows}

    def cell(model, col):
        found = [cells.get((model, col, s)) for s in searches]
        return " / ".join("" if r is None or "error" in r else f"{100 * r['drop']['0.7']:.1f}" for r in found)

    def normal(model):
        measured = [r for r in rows if r["model"] == model and "error" not in r]
        return _pct(measured[0]["normal"]) if measured else ""

    return (f"Drop of AP@0.7 (points) from the normal scenes under each space, search {' / '.join(searches)}:\n\n" +
            _md_table(["model", "normal AP@0.7", *columns],
                      [[m, normal(m), *(cell(m, c) for c in columns)] for m in models]) + "\n\n")


@dataclass
class Table:
    """A table of ``asg bench paper --table``: how its rows are measured (rows, scenes) and how they
    print as markdown; ``registry_name`` is set when it is registered."""

    build: Callable[["TableRun"], tuple[list, int]]
    markdown: Callable[[list], str]
    registry_name: str = ""


#: every table, in the order ``--table all`` runs them
TABLE_KINDS: Registry[Table] = Registry("table", "--table", ordered=True)
for _name, _table in {"main": Table(main_table, _md_main), "finetune": Table(finetune_table, _md_finetune),
                      "transfer": Table(transfer_table, _md_transfer), "acs": Table(acs_table, _md_acs),
                      "ablation": Table(ablation_table, _md_ablation), "blackbox": Table(blackbox_table, _md_blackbox),
                      "spaces": Table(spaces_table, _md_spaces)}.items():
    TABLE_KINDS.register(_name)(_table)
