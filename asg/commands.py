"""What each CLI subcommand does: call the pipeline functions, show progress, print results."""
from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path

from rich.table import Table

from sumo_scenarios import towns as towns_mod
from sumo_scenarios.errors import InputError
from sumo_scenarios.highway import HighwayRequest, simulate_highway
from sumo_scenarios.log import NEAR_RADIUS_M
from sumo_scenarios.paths import nets_dir
from sumo_scenarios.simulate import SimulationRequest, simulate_sumo

from .objective import ap_text
from .objective.ap import AP_METHODS
from .progress import console, print_result, progress_bar, stdout
from .scene.from_log import ExtractParams, extract_scenes
from .scene.scene import save_scene


def towns_build(args: argparse.Namespace) -> int:
    cfg = towns_mod.load_towns_config(args.config)
    specs = [s for s in cfg.towns if args.only is None or s.name in args.only]
    if args.only:
        unknown = sorted(set(args.only) - {s.name for s in cfg.towns})
        if unknown:
            raise InputError(f"unknown town '{unknown[0]}' in --only; towns in the config: {', '.join(s.name for s in cfg.towns)}")
    out = args.out or nets_dir()
    with progress_bar() as bar:
        task = bar.add_task("building towns", total=len(specs))
        for spec in specs:
            towns_mod.build_town(spec, out, cfg.buildings)
            bar.advance(task)
    console.print(f"built {len(specs)} towns in {out}")
    return 0


def towns_import(args: argparse.Namespace) -> int:
    from sumo_scenarios.town_import import import_town

    net = import_town(args.map, args.name, force=args.force)
    info = towns_mod.town_info(net)
    console.print(f"imported '{info.name}' into {net.parent}: {info.lane_count} lanes, {info.junctions} junctions, "
                  f"{info.buildings} buildings; use --town {info.name}")
    return 0


def towns_list(args: argparse.Namespace) -> int:
    infos = [towns_mod.town_info(p) for p in towns_mod.list_towns(args.dir)]
    if args.json:
        print(json.dumps([asdict(i) for i in infos], indent=2))
        return 0
    table = Table(title="SUMO towns")
    for col in ("name", "area km²", "lanes/edge", "lanes", "junctions", "signals", "buildings", "where"):
        table.add_column(col, justify="left" if col in ("name", "where") else "right", no_wrap=True)
    bundled = nets_dir().resolve()
    for i in infos:
        where = "bundled" if Path(i.net).resolve().parent == bundled else "imported"
        table.add_row(i.name, f"{i.area_km2:.3f}", f"{i.lanes_min}-{i.lanes_max}", str(i.lane_count),
                      str(i.junctions), str(i.traffic_lights), str(i.buildings), where)
    stdout.print(table)
    return 0


def simulate(args: argparse.Namespace) -> int:
    with progress_bar() as bar:
        task = bar.add_task(f"simulating ({args.source})", total=100)

        def report(done_s: float, total_s: float) -> None:
            bar.update(task, completed=100.0 * done_s / total_s)

        if args.source == "highway-env":
            if args.town or args.net:
                raise InputError("--town/--net do not apply to --source highway-env; use --env instead")
            req = HighwayRequest(out_dir=args.out, env_id=args.env, seed=args.seed, duration_s=args.duration,
                                 density=args.density, record_period_s=args.record_period,
                                 warmup_s=0.0 if args.warmup is None else args.warmup)
            stats = simulate_highway(req, report)
        else:
            if not args.town and not args.net:
                raise InputError("give --town NAME (see 'asg towns list') or --net PATH")
            req = SimulationRequest(out_dir=args.out, town=args.town, net=args.net, seed=args.seed,
                                    duration_s=args.duration, density=args.density, step_s=args.step,
                                    record_period_s=args.record_period,
                                    warmup_s=90.0 if args.warmup is None else args.warmup)
            stats = simulate_sumo(req, report)
    console.print(
        f"wrote {args.out}: {stats.get('frames', 0)} frames; vehicles within {NEAR_RADIUS_M:g} m of an RSU: "
        f"median {stats.get('near_rsu_median', 0):g} (p10 {stats.get('near_rsu_p10', 0):g}, p90 {stats.get('near_rsu_p90', 0):g})"
    )
    return 0


def scenes_extract(args: argparse.Namespace) -> int:
    from .generator.config import GenerateConfig

    k = GenerateConfig().sensing_agents - 1 if args.collaborators is None else args.collaborators
    params = ExtractParams(every=args.every, radius_m=args.radius, ego=args.ego, min_vehicles=args.min_vehicles,
                           collaborators=k)
    n = 0
    for scene in extract_scenes(args.log, params):
        save_scene(scene, Path(args.out) / f"{scene.scene_id}.yaml")
        n += 1
    if n == 0:
        raise InputError(f"{args.log}: no frame had an ego with {args.min_vehicles}+ vehicles within {NEAR_RADIUS_M:g} m; "
                         "lower --min-vehicles")
    console.print(f"wrote {n} scenes to {args.out}")
    return 0


def bench_simulate(args: argparse.Namespace) -> int:
    from .benchmarks.simulate import bench_simulate as run

    if args.minutes <= 0 or args.repeats < 1:
        raise InputError("--minutes must be positive and --repeats at least 1")
    print_result("asg bench simulate", run(town=args.town, minutes=args.minutes, repeats=args.repeats), args.json)
    return 0


def bench_lidar(args: argparse.Namespace) -> int:
    from .benchmarks.lidar import bench_lidar as run

    if args.repeats < 1:
        raise InputError("--repeats must be at least 1")
    print_result("asg bench lidar", run(repeats=args.repeats), args.json)
    return 0


def render(args: argparse.Namespace) -> int:
    from .io.figures import bev_figure
    from .io.pcd import write_pcd
    from .scene import load_scene
    from .scene.neighbours import with_nearest_collaborators
    from .perception.data import points_in_range_boxes
    from .sensors import load_lidar_spec, simulate_frame

    spec = load_lidar_spec(args.lidar) if args.lidar else load_lidar_spec()
    scene = with_nearest_collaborators(load_scene(args.scene), args.collaborators)
    frame = simulate_frame(scene, spec, seed=args.seed)
    bev_figure(scene, frame, args.out, title=f"{scene.scene_id} ({spec.name})")
    if args.pcd_dir is not None:
        from sumo_scenarios.atomic import atomic_path
        from sumo_scenarios.checks import inside
        import numpy as np

        for aid, cloud in frame.clouds.items():
            inside(Path(args.pcd_dir), Path(args.pcd_dir) / aid)
            write_pcd(Path(args.pcd_dir) / f"{aid}.pcd", cloud)
            with atomic_path(Path(args.pcd_dir) / f"{aid}.npy") as tmp:
                np.save(tmp, cloud)
    in_range = points_in_range_boxes(frame)
    mean_pts = float(in_range.mean()) if len(in_range) else 0.0
    console.print(f"wrote {args.out}: agents {', '.join(frame.sensing_ids)}; "
                  f"{sum(len(c) for c in frame.clouds.values())} points; {len(in_range)} vehicles in range, "
                  f"{mean_pts:.1f} points per box on average")
    return 0


def dataset_build(args: argparse.Namespace) -> int:
    from .datasets import build_dataset, load_spec

    from .cli_args import executor_from_args

    if args.name == "challenging":
        return _build_challenging(args)
    if args.fusion or args.split or args.count:
        raise InputError("--fusion, --split and --count apply to 'asg dataset build challenging' only")

    spec = load_spec(args.name)
    logs = len(spec.towns) * len(spec.densities) * len(spec.seeds)
    with progress_bar() as bar, executor_from_args(args, logs) as executor:
        task = bar.add_task(f"building {args.name}", total=logs)
        out = build_dataset(args.name, lambda done, total: bar.update(task, completed=done), executor)
    console.print(f"wrote {out}")
    return 0


def _build_challenging(args: argparse.Namespace) -> int:
    from .workflows.challenging import build_challenging
    from .cli_args import executor_from_args

    if not args.fusion or not args.split:
        raise InputError("give --fusion NAME and --split train|val, e.g. 'asg dataset build challenging "
                         "--fusion attfuse --split val'")
    with progress_bar() as bar, executor_from_args(args, args.count or 10**6) as executor:
        task = bar.add_task(f"challenging {args.fusion} {args.split}", total=None)
        out = build_challenging(args.fusion, args.split, executor, args.count,
                                on_scene=lambda done, total, sid: bar.update(task, completed=done, total=total))
    index = json.loads((out / "index.json").read_text())
    console.print(f"wrote {out}: {index['frames']} scenes; AP normal {ap_text(index['ap_normal'])} -> "
                  f"challenging {ap_text(index['ap_challenging'])}")
    per_frame = index.get("per_frame")
    if per_frame:
        console.print(f"  by the paper's yardstick (per frame): {ap_text(per_frame['ap_normal'])} -> "
                      f"{ap_text(per_frame['ap_challenging'])}")
    return 0


def report(args: argparse.Namespace) -> int:
    from .report.page import write_report

    if not args.run_dir.is_dir():
        raise InputError(f"{args.run_dir}: not a folder; give a folder written by 'asg generate' or 'asg bench paper'")
    console.print(f"wrote {write_report(args.run_dir, args.out, args.scenes)}")
    return 0


def export(args: argparse.Namespace) -> int:
    from .io.export import export as run

    with progress_bar() as bar:
        task = bar.add_task(f"exporting {args.format}", total=None)
        n = run(args.source, args.format, args.out, net=args.net, progress=lambda i: bar.update(task, completed=i))
    console.print(f"wrote {n} scenes as {args.format} to {args.out}")
    return 0


def _table_names(args: argparse.Namespace) -> tuple[str, ...]:
    """The tables ``--table`` names (none without it)."""
    from .benchmarks.tables import TABLES

    if args.table is None:
        return ()
    return TABLES if args.table == "all" else tuple(t.strip() for t in args.table.split(",") if t.strip())


def _bench_tables(args: argparse.Namespace) -> int:
    """``asg bench paper --table NAME[,NAME]|all``: each table's files in --out, the markdown printed."""
    import shlex

    from .benchmarks.tables import TableRun, run_tables
    from .cli_args import executor_from_args

    names = _table_names(args)
    if args.budget is not None or args.fusion is not None:
        raise InputError("--budget and --fusion apply to the targets table; the paper's tables use "
                         "configs/generate.yaml and every model")
    if args.detector:
        from .generator.run import load_factory

        load_factory(args.detector)
    command = "asg " + " ".join(shlex.quote(a) for a in args.argv)
    methods = AP_METHODS if args.ap_method == "both" else (args.ap_method,)
    with executor_from_args(args, args.scenes or 10**6) as executor:
        results = run_tables(names, TableRun(out=Path(args.out), scenes=args.scenes, executor=executor,
                                             detector_factory=args.detector, command=command,
                                             harden_rounds=args.harden_rounds or 0), log=console.print,
                             ap_methods=methods)
    for stem, result in results.items():
        if args.json:
            print(json.dumps(result))
        else:
            stdout.print(f"[bold]{stem}[/bold] ({Path(args.out) / (stem + '.md')})")
            stdout.print((Path(args.out) / f"{stem}.md").read_text(), markup=False, highlight=False)
    return 0


def bench_detect(args: argparse.Namespace) -> int:
    from .benchmarks.detect import bench_detect as run

    print_result("asg bench detect", run(frames=args.frames), args.json)
    return 0


def bench_generate(args: argparse.Namespace) -> int:
    from .benchmarks.generate import bench_generate as run

    if args.scenes < 1 or args.budget < 1:
        raise InputError("--scenes and --budget must be at least 1")
    print_result("asg bench generate", run(scenes=args.scenes, budget=args.budget), args.json)
    return 0


def bench_train(args: argparse.Namespace) -> int:
    from .benchmarks.train import bench_train as run

    print_result("asg bench train", run(steps=args.steps), args.json)
    return 0


def bench_scale(args: argparse.Namespace) -> int:
    from .benchmarks.scale import bench_scale as run

    print_result("asg bench scale", run(Path(args.out), scenes=args.scenes, budget=args.budget), args.json)
    return 0


def bench_paper(args: argparse.Namespace) -> int:
    from .benchmarks.paper import bench_paper as run
    from .generator.run_folder import after_acs_ap

    from .cli_args import executor_from_args

    if args.harden_rounds and "finetune" not in _table_names(args):
        raise InputError("--harden-rounds adds rows to the finetune table; give --table finetune (or all)")
    if args.table is not None:
        return _bench_tables(args)
    if args.detector:
        raise InputError("--detector applies to --table runs; the targets table attacks the shipped --fusion")
    from .generator.config import GenerateConfig

    if args.ap_method == "both":
        raise InputError("--ap-method both applies to --table runs; the targets table takes global or per-frame")
    scenes = args.scenes or 30
    defaults = GenerateConfig()
    with executor_from_args(args, scenes) as executor:
        result = run(Path(args.out), scenes=scenes, budget=args.budget or defaults.budget,
                     fusion=args.fusion or defaults.fusion, executor=executor, ap_method=args.ap_method)
    if args.json:
        print(json.dumps(result))
    else:
        table = Table(title=f"AP of {result['fusion']} (pooled over scenes, {result['ap_method']} ranking)")
        for col in ("ACS-search", "normal 0.3/0.5/0.7", "after ACS", "challenging 0.3/0.5/0.7", "scenes"):
            table.add_column(col)
        for k, v in result["table"].items():
            after_ap, pooled = after_acs_ap(v["after_acs"], v["after_acs_mean"])
            after = ap_text(after_ap) + ("" if pooled else " (mean)")
            table.add_row(k, ap_text(v["normal"]), after, ap_text(v["challenging"]), str(v["scenes"]))
        stdout.print(table)
    return 0
