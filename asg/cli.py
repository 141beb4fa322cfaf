"""The ``asg`` command: one entry, subcommands. Holds no logic: it parses, calls, and prints.

A user mistake (bad file, unknown name, bad value) prints one line ``asg: error: ...`` and exits
with code 2; Ctrl-C exits with 130 and leaves no half-written file.
"""
from __future__ import annotations

import argparse
import errno
import importlib
import signal
import sys
from pathlib import Path
from typing import Callable, Sequence

from sumo_scenarios.errors import InputError
from sumo_scenarios.log import SOURCES
from sumo_scenarios.routes import DENSITIES

from . import __version__, commands
from .cli_args import COUNT, SEED, executor_args, fusion_arg, real, whole
from .executors.base import WorkerLost
from .io.export import FORMATS as EXPORT_FORMATS
from .objective.ap import AP_METHODS, DEFAULT_AP_METHOD
from .scene.from_log import EGO_KINDS
from .workflows import MAX_ROUNDS


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage mistake is one line (what is wrong, where to look) and exit code 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        sys.stderr.write(f"asg: error: {message} (see '{self.prog} --help')\n")
        raise SystemExit(2)


def _add(sub, name: str, help_text: str, func: Callable[[argparse.Namespace], int]) -> argparse.ArgumentParser:
    p = sub.add_parser(name, help=help_text, description=help_text)
    p.set_defaults(func=func)
    return p


#: Subcommands a module declares itself: (name, module, one-line help). The module holds
#: ``add_arguments(parser)`` and ``run(args) -> exit code`` beside what it runs (the generator, a
#: workflow), and is imported only when its command is asked for, so ``asg --help`` stays quick. A
#: new command: its module and one line here.
COMMAND_MODULES = (
    ("generate", "asg.generator.command", "generate challenging scenes: collaborator search, then perturbation search "
     "(no arguments: a one-minute demo)"),
    ("train", "asg.workflows.train", "train a detector on CPU (resumes from runs/train/NAME/last.pt)"),
    ("finetune", "asg.workflows.finetune", "train a detector further on its challenging scenes, then evaluate it "
     "before and after and attack it again (runs/finetune/FUSION-ft/)"),
    ("harden", "asg.workflows.harden", "iterated adversarial training: each round attacks the current weights on "
     "fresh training scenes, fine-tunes on them and evaluates (runs/harden/FUSION/)"),
    ("evaluate", "asg.workflows.evaluate", "AP of a detector on a scene set"),
)


def _add_command_modules(sub, argv: Sequence[str] | None) -> None:
    """The COMMAND_MODULES subparsers; the arguments of the one ``argv`` names (all without ``argv``)."""
    chosen = next((a for a in argv if not a.startswith("-")), None) if argv is not None else None
    for name, module, help_text in COMMAND_MODULES:
        p = sub.add_parser(name, help=help_text, description=help_text)
        if argv is None or name == chosen:
            workflow = importlib.import_module(module)
            workflow.add_arguments(p)
            p.set_defaults(func=workflow.run)


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The ``asg`` parser; with ``argv``, a workflow command's module is imported only if it is the
    command ``argv`` runs (without: every one, the complete parser)."""
    parser = _Parser(prog="asg", description="Adversarial scene generation for cooperative V2X LiDAR perception.")
    parser.add_argument("--version", action="version", version=f"asg {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    towns = sub.add_parser("towns", help="build or list the bundled SUMO towns", description="Build or list the SUMO towns in nets/.")
    tsub = towns.add_subparsers(dest="towns_command", metavar="ACTION", parser_class=_Parser)
    p = _add(tsub, "build", "rebuild nets/NAME.net.xml and NAME.poly.xml from configs/towns.yaml", commands.towns_build)
    p.add_argument("--config", type=Path, default=None, help="towns yaml (default configs/towns.yaml)")
    p.add_argument("--out", type=Path, default=None, help="folder for the nets (default nets/)")
    p.add_argument("--only", nargs="*", default=None, help="build only these towns")
    p = _add(tsub, "import", "make a town of your own map (OpenDRIVE .xodr, OpenStreetMap .osm, SUMO .net.xml) "
             "with SUMO's netconvert and polyconvert", commands.towns_import)
    p.add_argument("map", type=Path, help="the map file")
    p.add_argument("--name", required=True, help="the town's name (then --town NAME in every command)")
    p.add_argument("--force", action="store_true", help="replace an imported town of that name")
    p = _add(tsub, "list", "print name, area, lanes, junctions and buildings of each town", commands.towns_list)
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--dir", type=Path, default=None, help="folder of nets (default nets/)")
    towns.set_defaults(func=lambda a: (towns.print_help(), 2)[1])

    p = _add(sub, "simulate", "run dense traffic in a town and record a SUMO fcd-output log", commands.simulate)
    where = p.add_mutually_exclusive_group()
    where.add_argument("--town", help="a bundled town name (see 'asg towns list')")
    where.add_argument("--net", type=Path, help="any SUMO .net.xml")
    p.add_argument("--source", choices=SOURCES, default="sumo", help="traffic source (default sumo)")
    p.add_argument("--env", default="highway-v0", help="highway-env scenario: highway-v0, merge-v0, roundabout-v0, intersection-v0")
    p.add_argument("--seed", type=SEED, default=1)
    p.add_argument("--duration", type=float, default=60.0, help="recorded seconds (default 60)")
    p.add_argument("--warmup", type=float, default=None, help="seconds simulated before recording (default 90 for SUMO, 0 for highway-env)")
    p.add_argument("--density", choices=DENSITIES, default="normal")
    p.add_argument("--step", type=float, default=0.1, help="simulation step, s (default 0.1)")
    p.add_argument("--record-period", type=float, default=0.5, help="seconds between recorded frames (default 0.5)")
    p.add_argument("--out", type=Path, required=True, help="log folder to write")

    scenes = sub.add_parser("scenes", help="extract scenes (one frame each) from a traffic log", description="Scenes from traffic logs.")
    ssub = scenes.add_subparsers(dest="scenes_command", metavar="ACTION", parser_class=_Parser)
    p = _add(ssub, "extract", "write every N-th frame of a log as a scene yaml", commands.scenes_extract)
    p.add_argument("log", type=Path, help="log folder written by 'asg simulate'")
    p.add_argument("--every", type=COUNT, default=10, help="take every N-th recorded frame (default 10)")
    p.add_argument("--ego", choices=EGO_KINDS, default="rsu", help="ego agent kind (default rsu: V2I)")
    p.add_argument("--radius", type=float, default=120.0, help="keep agents within this many metres of the ego")
    p.add_argument("--min-vehicles", type=whole(0, 10_000, "--min-vehicles"), default=1, help="skip frames with fewer vehicles within 48 m of the ego")
    p.add_argument("--collaborators", type=whole(0, 16, "--collaborators"), default=None,
                   help="sensing vehicles drawn at random within communication range of the ego, as the "
                        "data sets draw them (default: the generator's sensing_agents - 1, i.e. 2)")
    p.add_argument("--out", type=Path, required=True, help="folder for the scene yaml files")
    scenes.set_defaults(func=lambda a: (scenes.print_help(), 2)[1])

    p = _add(sub, "render", "render a scene's cooperative LiDAR frame to a bird's-eye picture (and PCD files)", commands.render)
    p.add_argument("scene", type=Path, help="scene yaml (from 'asg scenes extract')")
    p.add_argument("--out", type=Path, required=True, help="PNG to write")
    p.add_argument("--lidar", default=None, help="LiDAR preset in configs/lidar/ or a yaml path (default: the "
                   "detectors' preset, v2xp)")
    p.add_argument("--collaborators", type=whole(0, 16, "--collaborators"), default=2, help="if the scene names none: this many nearest vehicles")
    p.add_argument("--pcd-dir", type=Path, default=None, help="also write each agent's cloud as PCD and .npy here")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the LiDAR noise (if the preset has any)")

    ds = sub.add_parser("dataset", help="build the data sets (detector-train, normal, challenging)", description="Data sets.")
    dsub = ds.add_subparsers(dest="dataset_command", metavar="ACTION", parser_class=_Parser)
    p = _add(dsub, "build", "simulate and extract a data set from configs/datasets.yaml, or generate a "
             "challenging set", commands.dataset_build)
    p.add_argument("name", help="detector-train, normal, or challenging (with --fusion and --split)")
    fusion_arg(p, "challenging: the shipped model attacked")
    p.add_argument("--split", default=None, help="challenging: train or val (of the normal set)")
    p.add_argument("--count", type=COUNT, default=None, help="challenging: only the first N scenes of the split")
    executor_args(p)
    ds.set_defaults(func=lambda a: (ds.print_help(), 2)[1])

    p = _add(sub, "export", "write scenes for other tools: OPV2V (OpenCOOD), KITTI (OpenPCDet), OpenSCENARIO "
             "1.2 + OpenDRIVE, SUMO routes", commands.export)
    p.add_argument("source", help="a run folder of 'asg generate', a data set (name or folder) or a folder of scene yaml")
    p.add_argument("--format", required=True, choices=EXPORT_FORMATS)
    p.add_argument("--out", type=Path, required=True, help="folder to write (nothing is written outside it)")
    p.add_argument("--net", type=Path, default=None,
                   help="openscenario, sumo: the SUMO net of scenes from a net that is not a bundled town")

    p = _add(sub, "report", "one self-contained HTML page of a run folder or an 'asg bench paper' folder", commands.report)
    p.add_argument("run_dir", type=Path, help="a folder written by 'asg generate' or 'asg bench paper'")
    p.add_argument("--out", type=Path, default=None, help="HTML file to write (default RUN_DIR/report.html)")
    p.add_argument("--scenes", type=whole(0, 10_000, "--scenes"), default=6,
                   help="scenes drawn as bird's-eye views per run (default 6; the tables list all)")

    _add_command_modules(sub, argv)

    bench = sub.add_parser("bench", help="benchmarks: simulate, lidar, detect, generate, train, scale, paper",
                           description="Speed benchmarks and the paper's tables.")
    bsub = bench.add_subparsers(dest="bench_command", metavar="WHAT", parser_class=_Parser)
    p = _add(bsub, "simulate", "10 simulated minutes of a dense town at 0.1 s steps", commands.bench_simulate)
    p.add_argument("--town", default="grid_small")
    p.add_argument("--minutes", type=real(0.0, 1440.0, "--minutes", lo_open=True), default=10.0)
    p.add_argument("--repeats", type=COUNT, default=3)
    p.add_argument("--json", action="store_true", help="print JSON only")
    p = _add(bsub, "lidar", "cooperative-frame ray casting vs Open3D, and re-render after moves", commands.bench_lidar)
    p.add_argument("--repeats", type=COUNT, default=15)
    p.add_argument("--json", action="store_true", help="print JSON only")
    p = _add(bsub, "detect", "median inference time of each shipped model with 3 agents", commands.bench_detect)
    p.add_argument("--frames", type=COUNT, default=10)
    p.add_argument("--json", action="store_true", help="print JSON only")
    p = _add(bsub, "generate", "seconds per scene of AttFuse + ACS-A + BO, BO overhead per suggestion", commands.bench_generate)
    p.add_argument("--scenes", type=COUNT, default=5)
    p.add_argument("--budget", type=COUNT, default=50)
    p.add_argument("--json", action="store_true", help="print JSON only")
    p = _add(bsub, "train", "seconds a training step of AttFuse takes (batch 4, 2 threads) and its phases' shares",
             commands.bench_train)
    p.add_argument("--steps", type=COUNT, default=12, help="steps timed after 3 warm-up steps (median)")
    p.add_argument("--json", action="store_true", help="print JSON only")
    p = _add(bsub, "scale", "scenes per hour of the generator benchmark: 1 worker (1 thread, all threads), "
             "2 workers, 2 Ray actors", commands.bench_scale)
    p.add_argument("--scenes", type=COUNT, default=8)
    p.add_argument("--budget", type=COUNT, default=50)
    p.add_argument("--out", type=Path, default=Path("runs/bench-scale"))
    p.add_argument("--json", action="store_true", help="print JSON only")
    p = _add(bsub, "paper", "the paper's tables (--table), or the generator's targets: AttFuse with ACS-A/BO, GA, "
             "RS and ACS-R/BO on 30 normal scenes", commands.bench_paper)
    p.add_argument("--table", default=None, metavar="NAME[,NAME]",
                   help="main, finetune, transfer, acs, ablation, blackbox, spaces (beyond the paper: the perturbation "
                        "spaces on 30 benchmark scenes) or all: write OUT/NAME.json, .csv, .md "
                        "(default: the generator's targets table)")
    p.add_argument("--scenes", type=COUNT, default=None,
                   help="scenes per split (tables: default the whole split, as the paper; targets: default 30)")
    p.add_argument("--budget", type=COUNT, default=None,
                   help="targets table only (default the generator's, 50; the tables use configs/generate.yaml)")
    fusion_arg(p, "targets table only (default attfuse)")
    p.add_argument("--detector", default=None, metavar="MODULE:FACTORY",
                   help="tables: a factory standing in for every model (as 'asg generate --detector')")
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
    bench.set_defaults(func=lambda a: (bench.print_help(), 2)[1])
    return parser


class Terminated(Exception):
    """SIGTERM arrived: unwind like Ctrl-C, so that every temporary file is removed."""


def _on_sigterm(signum, frame) -> None:
    raise Terminated()


#: errno values of output problems a user can fix (disk full, read-only, no permission, quota)
_OUTPUT_ERRNOS = {errno.ENOSPC, errno.EROFS, errno.EACCES, errno.EPERM, errno.EDQUOT, errno.ENOTDIR, errno.EISDIR}


#: commands that run the detectors: PyTorch is imported before a held signal is released, because
#: a Ctrl-C inside torch's import (C++ calling back into Python) aborted the process (exit -6)
#: instead of ending the command
_TORCH_COMMANDS = {"generate", "evaluate", "train", "finetune", "harden", "dataset", "bench"}


def _preload(argv: Sequence[str]) -> None:
    """Import what the command will need and cannot be interrupted while importing."""
    if argv and argv[0] in _TORCH_COMMANDS:
        import torch  # noqa: F401


def main(argv: Sequence[str] | None = None, held_signals: frozenset = frozenset()) -> int:
    """Run ``asg ARGV``; its exit code. ``held_signals``: signals the caller blocked while this
    module imported (asg.entry), released once the handlers that end a command cleanly are in place."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        parser = build_parser(argv)
        args = parser.parse_args(argv)
        if held_signals:
            _preload(argv)
    except BaseException:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, held_signals)
        raise
    args.argv = argv  # the command as typed, for result files
    if not getattr(args, "func", None):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, held_signals)
        parser.print_help()
        return 2
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, held_signals)  # a signal held since the start ends it here
        return int(args.func(args) or 0)
    except InputError as exc:
        sys.stderr.write(f"asg: error: {exc}\n")
        return 2
    except OSError as exc:
        if exc.errno not in _OUTPUT_ERRNOS:
            raise
        where = f" ({exc.filename})" if exc.filename else ""
        sys.stderr.write(f"asg: error: cannot write or read{where}: {exc.strerror}; free space or pick a writable folder\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("asg: interrupted; nothing half-written was left behind (rerun the command to resume)\n")
        return 130
    except WorkerLost as exc:
        sys.stderr.write(f"asg: error: {exc}; what finished is kept: rerun the command to resume\n")
        return 1
    except Terminated:
        sys.stderr.write("asg: terminated; nothing half-written was left behind (rerun the command to resume)\n")
        return 143
    finally:
        signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":  # prefer ``python -m asg``, which holds signals while this module imports
    raise SystemExit(main())
