"""``asg generate``: sample or load normal scenes, run ACS then APS on each, write the run folder."""
from __future__ import annotations

import argparse
import itertools
import tempfile
import time
from dataclasses import asdict
from pathlib import Path
from typing import Iterator

from rich.table import Table

from sumo_scenarios.errors import InputError

from .pipeline import Generator, load_generate_config
from .progress import console, progress_bar, stdout
from .scene import Scene, load_scene

#: the no-argument demo: a held-out town, the strongest shipped model as target (Early Fusion:
#: ahead of Late at AP@0.7, in a third of Late's inference time; AttFuse still steers the
#: collaborator search), a short budget
DEMO = {"town": "fiveleg", "count": 2, "budget": 15, "fusion": "early"}


def _scenes_from_town(town: str | None, net: Path | None, seed: int, tmp: Path) -> Iterator[Scene]:
    from sumo_scenarios.simulate import SimulationRequest, simulate_sumo

    from .scene.from_log import ExtractParams, extract_scenes

    log = tmp / "log"
    simulate_sumo(SimulationRequest(out_dir=log, town=town, net=net, seed=seed, duration_s=60.0, density="normal"))
    return extract_scenes(log, ExtractParams(every=10, min_vehicles=5))


def _scenes_from_dir(path: Path) -> Iterator[Scene]:
    from .datasets import iter_frames
    from .perception.evaluate import SETS, scenes_of

    if str(path) in SETS:  # a named set: normal (its 219-scene split), normal-val, normal-all
        return scenes_of(str(path))
    if (path / "index.json").is_file():
        return iter_frames(path)
    if not path.is_dir():
        raise InputError(f"{path}: not a folder of scenes; give the --out folder of 'asg scenes extract'")
    files = sorted(path.glob("*.yaml"))
    if not files:
        raise InputError(f"{path}: no scene yaml files in it")
    return (load_scene(f) for f in files)


def run_generate(args: argparse.Namespace, table_console=None) -> int:
    """Run ``asg generate`` with parsed ``args``; the before/after table goes to ``table_console``
    (a rich Console; stdout by default)."""
    from .io.run import load_done, previous_wall_s, write_scene, write_summary
    from .perception import build_detector

    demo = args.town is None and args.net is None and args.scenes is None
    town = DEMO["town"] if demo else args.town
    count = args.count if args.count is not None else (DEMO["count"] if demo else 10)
    budget = args.budget if args.budget is not None else (DEMO["budget"] if demo else None)
    if count < 1:
        raise InputError(f"--count must be at least 1, got {count}")
    fusion = args.fusion or (DEMO["fusion"] if demo else None)
    cfg = load_generate_config(args.config, fusion=fusion, search=args.search, acs=args.acs,
                               aps=None if args.aps is None else args.aps == "on", budget=budget)
    out = Path(args.out)
    target = build_detector(cfg.fusion)
    acs_model = None
    if cfg.acs == "attention":
        acs_model = target if cfg.fusion == "attfuse" else build_detector("attfuse")
    gen = Generator(cfg, target, acs_model)
    done = load_done(out)
    entries = [done[k] for k in sorted(done)]
    started = time.perf_counter() - (previous_wall_s(out) if done else 0.0)  # a resumed run adds its time
    with tempfile.TemporaryDirectory() as tmp:
        scenes = _scenes_from_dir(Path(args.scenes)) if args.scenes else _scenes_from_town(town, args.net, args.seed, Path(tmp))
        scenes = list(itertools.islice(scenes, count))
        if not scenes:
            raise InputError("no usable scene (none with 5+ vehicles near the ego); try another town or seed")
        if demo:
            console.print(f"demo: {len(scenes)} scenes of the bundled town '{town}', {cfg.fusion} + ACS-{cfg.acs} + {cfg.search}, budget {cfg.budget}")
        with progress_bar() as bar:
            scene_task = bar.add_task("scenes", total=len(scenes))
            eval_task = bar.add_task("evaluations", total=cfg.budget)
            for scene in scenes:
                if scene.scene_id in done:
                    bar.advance(scene_task)
                    continue
                bar.update(eval_task, completed=0, description=f"{scene.scene_id[-28:]}")
                try:
                    result = gen.generate(scene, args.seed, on_step=lambda e: bar.update(eval_task, completed=e.step))
                except InputError as exc:
                    console.print(f"[yellow]skipped {scene.scene_id}: {exc}")
                    bar.advance(scene_task)
                    continue
                entries.append(write_scene(out, result, list(result.perturbed)))
                write_summary(out, entries, asdict(cfg) | {"seed": args.seed}, time.perf_counter() - started)
                bar.advance(scene_task)
    if not entries:
        raise InputError("no scene could be generated (see the messages above)")
    summary = write_summary(out, entries, asdict(cfg) | {"seed": args.seed}, time.perf_counter() - started)
    _print_table(summary, table_console or stdout)
    console.print(f"wrote {out}/summary.json and {len(entries)} scene folders")
    return 0


def _print_table(summary: dict, out) -> None:
    from .io.run import after_acs_ap

    table = Table(title="AP before / after (fractions)")
    table.add_column("scene")
    for col in ("normal 0.3/0.5/0.7", "after ACS", "final", "moved", "s"):
        table.add_column(col, justify="right")
    fmt = lambda ap: " / ".join(f"{ap[k]:.2f}" for k in ("0.3", "0.5", "0.7"))
    for e in summary["scenes"]:
        table.add_row(e["scene_id"][-32:], fmt(e["ap_normal"]), fmt(e["ap_after_acs"]), fmt(e["ap_final"]),
                      str(len(e["perturbed"])), f"{e['seconds']:.1f}")
    agg = summary["aggregate"]
    after_ap, pooled = after_acs_ap(agg.get("ap_after_acs"), agg["mean_scene_ap_after_acs"])
    table.add_row("[bold]pooled", fmt(agg["ap_normal"]), fmt(after_ap) + ("" if pooled else "*"),
                  fmt(agg["ap_challenging"]), "", f"{agg['seconds_per_scene_median']:.1f}")
    out.print(table)
    if not pooled:
        out.print("* mean over scenes (this folder has scenes written before after-ACS detections were stored)")
