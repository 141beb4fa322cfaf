"""``asg simulate``: dense traffic in a town (SUMO) or a highway-env scenario, recorded as a SUMO
fcd-output log."""
from __future__ import annotations

import argparse
from dataclasses import asdict
from pathlib import Path

from sumo_scenarios.digest import file_digest
from sumo_scenarios.errors import InputError
from sumo_scenarios.highway import ENVS, HighwayRequest, simulate_highway
from sumo_scenarios.log import NEAR_RADIUS_M, SOURCES
from sumo_scenarios.routes import DENSITIES
from sumo_scenarios.simulate import SimulationRequest, simulate_sumo
from sumo_scenarios.towns import resolve_net

from ..cli_args import SEED
from ..io.run_record import check_log_folder, claim_log_folder
from ..progress import console, progress_bar


def add_arguments(p: argparse.ArgumentParser) -> None:
    where = p.add_mutually_exclusive_group()
    where.add_argument("--town", help="a bundled town name (see 'asg towns list')")
    where.add_argument("--net", type=Path, help="any SUMO .net.xml")
    p.add_argument("--source", choices=SOURCES, default="sumo", help="traffic source (default sumo)")
    sumo, highway = SimulationRequest, HighwayRequest  # their defaults are the command's
    p.add_argument("--env", default=None, help=f"highway-env scenario: {', '.join(ENVS)} (default {highway.env_id})")
    p.add_argument("--seed", type=SEED, default=None, help=f"(default {sumo.seed})")
    p.add_argument("--duration", type=float, default=None, help=f"recorded seconds (default {sumo.duration_s:g})")
    p.add_argument("--warmup", type=float, default=None, help=f"seconds simulated before recording (default "
                                                              f"{sumo.warmup_s:g} for SUMO, {highway.warmup_s:g} for highway-env)")
    p.add_argument("--density", choices=DENSITIES, default=None, help=f"(default {sumo.density})")
    p.add_argument("--step", type=float, default=None, help=f"SUMO's simulation step, s (default {sumo.step_s:g})")
    p.add_argument("--record-period", type=float, default=None,
                   help=f"seconds between recorded frames (default {sumo.record_period_s:g})")
    p.add_argument("--out", type=Path, required=True, help="log folder to write")
    p.add_argument("--force", action="store_true",
                   help="replace the log of an --out simulated with other settings (its files alone are removed)")


def _request(args: argparse.Namespace) -> SimulationRequest | HighwayRequest:
    """The checked request of the command line (InputError, its one line, for a bad one); what the
    command line leaves out takes the request's own default."""
    given = {field: value for field, value in (("seed", args.seed), ("duration_s", args.duration), ("density", args.density),
                                               ("record_period_s", args.record_period), ("warmup_s", args.warmup))
             if value is not None}
    if args.source == "highway-env":
        if args.town or args.net:
            raise InputError("--town/--net do not apply to --source highway-env; use --env instead")
        if args.step is not None:
            raise InputError("--step applies to SUMO; highway-env steps at its own rate (drop --step)")
        req = HighwayRequest(out_dir=args.out, **given, **({"env_id": args.env} if args.env else {}))
    else:
        if not args.town and not args.net:
            raise InputError("give --town NAME (see 'asg towns list') or --net PATH")
        if args.env is not None:
            raise InputError("--env applies to --source highway-env; a SUMO run takes --town or --net")
        req = SimulationRequest(out_dir=args.out, town=args.town, net=args.net, **given,
                                **({"step_s": args.step} if args.step is not None else {}))
    req.validate()
    return req


def _settings(req: SimulationRequest | HighwayRequest) -> dict:
    """What the log folder's run.json records of ``req``: its fields, a user's net by its path and
    content (the sha256 of the file)."""
    settings = {"command": "simulate", "source": "highway-env" if isinstance(req, HighwayRequest) else "sumo",
                **{k: v for k, v in asdict(req).items() if k not in ("out_dir", "net")}}
    if getattr(req, "net", None) is not None:
        _, net = resolve_net(net=req.net)  # one line for a missing or unreadable net
        settings["net"] = str(net.resolve())
        settings["net_sha256"] = file_digest(net)
    return settings


def run(args: argparse.Namespace) -> int:
    req = _request(args)
    settings = _settings(req)
    check_log_folder(args.out, settings, args.force)
    if args.force:  # the old log goes before the new one is simulated
        claim_log_folder(args.out, settings, force=True)
    with progress_bar() as bar:
        task = bar.add_task(f"simulating ({args.source})", total=100)

        def report(done_s: float, total_s: float) -> None:
            bar.update(task, completed=100.0 * done_s / total_s)

        simulate = simulate_highway if isinstance(req, HighwayRequest) else simulate_sumo
        stats = simulate(req, report)
    claim_log_folder(args.out, settings)  # once the log is there: a failed run leaves no folder
    console.print(
        f"wrote {args.out}: {stats.get('frames', 0)} frames; vehicles within {NEAR_RADIUS_M:g} m of an RSU: "
        f"median {stats.get('near_rsu_median', 0):g} (p10 {stats.get('near_rsu_p10', 0):g}, p90 {stats.get('near_rsu_p90', 0):g})"
    )
    return 0
