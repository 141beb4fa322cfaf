"""``asg bench paper``: the paper's tables (``--table``), or the generator's targets table (AttFuse
with ACS-A/BO, GA, RS and ACS-R/BO on 30 normal scenes)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from rich.table import Table

from sumo_scenarios.checks import output_dir
from sumo_scenarios.errors import InputError

from ..cli_args import COUNT, executor_args, executor_from_args, fusion_arg, whole
from ..objective import ap_text
from ..objective.ap import AP_METHODS, DEFAULT_AP_METHOD
from ..progress import console, stdout
from ..workflows import MAX_ROUNDS


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..benchmarks.tables import TABLE_KINDS

    p.add_argument("--table", default=None, metavar="NAME[,NAME]",
                   help=f"{', '.join(TABLE_KINDS.names())} (spaces, beyond the paper: the perturbation "
                        "spaces on 30 benchmark scenes) or all: write OUT/NAME.json, .csv, .md "
                        "(default: the generator's targets table)")
    p.add_argument("--scenes", type=COUNT, default=None,
                   help="scenes per split (tables: default the whole split, as the paper; targets: default 30)")
    p.add_argument("--budget", type=COUNT, default=None,
                   help="targets table only (default the generator's budget; the tables use configs/generate.yaml)")
    fusion_arg(p, "targets table only (default attfuse)")
    p.add_argument("--detector", default=None, metavar="MODULE:FACTORY",
                   help="tables: a factory standing in for every model (as 'asg generate --detector')")
    p.add_argument("--models", default=None, metavar="NAME[,NAME]",
                   help="main, transfer, acs and spaces tables: the models with a row, shipped ones or OpenCOOD "
                        "model folders (opencood:DIR); default the paper's four: none, late, early, attfuse "
                        "(attfuse alone in the spaces table)")
    p.add_argument("--searches", default=None, metavar="NAME[,NAME]",
                   help="spaces table: the searches it compares at the same budget (default rs,bo,ng)")
    p.add_argument("--harden-rounds", type=whole(1, MAX_ROUNDS, "--harden-rounds"), default=None,
                   help="finetune table: also this many rounds of 'asg harden --fusion attfuse' with adversarial, "
                        "random and normal scenes (the controls), a row a round (OUT/harden/DATA, resumable)")
    p.add_argument("--ap-method", default=DEFAULT_AP_METHOD, choices=[*AP_METHODS, "both"],
                   help="how AP ranks the detections of many frames: global (default, ours: one sort across frames), "
                        "per-frame (the paper's yardstick: no sort across frames; tables as NAME.per-frame.*) or both")
    p.add_argument("--out", type=Path, default=Path("runs/bench-paper"))
    executor_args(p)
    p.add_argument("--jobs", type=whole(1, 64, "--jobs"), default=None, dest="workers", help=argparse.SUPPRESS)
    p.add_argument("--json", action="store_true", help="print JSON only")


def run(args: argparse.Namespace) -> int:
    _table_names(args)  # a bad --table is refused before anything is written
    if args.harden_rounds and "finetune" not in _table_names(args):
        raise InputError("--harden-rounds adds rows to the finetune table; give --table finetune (or all)")
    if args.searches is not None and "spaces" not in _table_names(args):
        raise InputError("--searches chooses the searches of the spaces table; give --table spaces (or all)")
    if args.table is not None:
        return _tables(args)
    return _targets(args)


def _table_names(args: argparse.Namespace) -> tuple[str, ...]:
    """The tables ``--table`` names (none without it)."""
    from ..benchmarks.tables import TABLE_KINDS

    if args.table is None:
        return ()
    tables = tuple(TABLE_KINDS.names())
    if args.table == "all":
        return tables
    names = tuple(t.strip() for t in args.table.split(","))
    if not names or any(n not in tables for n in names) or len(set(names)) != len(names):
        raise InputError(f"--table {args.table!r}: an unknown table, an empty list or a table twice; give distinct "
                         f"names of {', '.join(tables)}, or all")
    return names


def _tables(args: argparse.Namespace) -> int:
    """``--table NAME[,NAME]|all``: each table's files in --out, the markdown printed."""
    import shlex

    from ..benchmarks.tables import TableRun, run_tables

    names = _table_names(args)
    models = _models(args.models)
    if args.budget is not None or args.fusion is not None:
        raise InputError("--budget and --fusion apply to the targets table; the paper's tables use "
                         "configs/generate.yaml and every model")
    if args.detector:
        from ..generator.run import load_factory

        load_factory(args.detector)
    output_dir(Path(args.out))  # /proc, a file in the way: one line before any work
    command = "asg " + " ".join(shlex.quote(a) for a in args.argv)
    methods = AP_METHODS if args.ap_method == "both" else (args.ap_method,)
    with executor_from_args(args, args.scenes or 10**6) as executor:
        results = run_tables(names, TableRun(out=Path(args.out), scenes=args.scenes, executor=executor,
                                             detector_factory=args.detector, command=command,
                                             harden_rounds=args.harden_rounds or 0, models=models,
                                             searches=_searches(args.searches)),
                             log=console.print,
                             ap_methods=methods)
    for stem, result in results.items():
        if args.json:
            print(json.dumps(result))
        else:
            stdout.print(f"[bold]{stem}[/bold] ({Path(args.out) / (stem + '.md')})")
            stdout.print((Path(args.out) / f"{stem}.md").read_text(), markup=False, highlight=False)
    return 0


def _models(text: str | None) -> tuple[str, ...] | None:
    """``--models``: shipped model names or OpenCOOD model folders (``opencood:DIR``), comma-separated
    (None: each table's own); one line for an unknown or repeated name or a folder that cannot run."""
    from ..perception.fusion import FUSIONS
    from ..perception.targets import resolve_target

    def model_folder(name: str) -> bool:  # another framework's model folder (checked below)
        try:
            return resolve_target(name).prefixed
        except InputError:
            return False

    chosen = _distinct_names(text, "--models", FUSIONS, "shipped models or opencood:DIR", extra=model_folder)
    for name in chosen or ():
        resolve_target(name).check()
    return chosen


def _searches(text: str | None) -> tuple[str, ...] | None:
    """``--searches``: search names, comma-separated (None: the spaces table's own)."""
    from ..search import SEARCHES

    return _distinct_names(text, "--searches", SEARCHES, "searches")


def _distinct_names(text: str | None, flag: str, registry, what: str,
                    extra=lambda name: False) -> tuple[str, ...] | None:
    """The comma-separated names of ``text``, each an entry of ``registry`` (or a name ``extra``
    accepts), none twice (None: ``text`` is None); one line naming the known ones otherwise."""
    if text is None:
        return None
    chosen = tuple(m.strip() for m in text.split(",") if m.strip())
    known = registry.names()
    if not chosen or any(m not in known and not extra(m) for m in chosen) or len(set(chosen)) != len(chosen):
        raise InputError(f"{flag} takes distinct {what} ({', '.join(known)}), got {text!r}")
    return chosen


def _targets(args: argparse.Namespace) -> int:
    """The generator's targets table: AttFuse (or --fusion) under each search on normal scenes."""
    from ..benchmarks.paper import bench_paper
    from ..generator.config import GenerateConfig
    from ..generator.run_folder import after_acs_ap

    if args.detector or args.models:
        raise InputError("--detector and --models apply to --table runs; the targets table attacks the shipped --fusion")
    if args.ap_method == "both":
        raise InputError("--ap-method both applies to --table runs; the targets table takes global or per-frame")
    scenes = args.scenes or 30
    defaults = GenerateConfig()
    output_dir(Path(args.out))
    with executor_from_args(args, scenes) as executor:
        result = bench_paper(Path(args.out), scenes=scenes, budget=args.budget or defaults.budget,
                             fusion=args.fusion or defaults.fusion, executor=executor, ap_method=args.ap_method)
    if args.json:
        print(json.dumps(result))
        return 0
    table = Table(title=f"AP of {result['fusion']} (pooled over scenes, {result['ap_method']} ranking)")
    for col in ("ACS-search", "normal 0.3/0.5/0.7", "after ACS", "challenging 0.3/0.5/0.7", "scenes"):
        table.add_column(col)
    for k, v in result["table"].items():
        after_ap, pooled = after_acs_ap(v["after_acs"], v["after_acs_mean"])
        after = ap_text(after_ap) + ("" if pooled else " (mean)")
        table.add_row(k, ap_text(v["normal"]), after, ap_text(v["challenging"]), str(v["scenes"]))
    stdout.print(table)
    return 0
