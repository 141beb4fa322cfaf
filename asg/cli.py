"""The ``asg`` command: one entry, subcommands. Holds no logic: it parses, calls, and prints.

A user mistake (bad file, unknown name, bad value) prints one line ``asg: error: ...`` and exits
with code 2; Ctrl-C exits with 130 and leaves no half-written file.
"""
from __future__ import annotations

import argparse
import errno
import importlib
import os
import signal
import sys
from typing import NamedTuple, Sequence

from sumo_scenarios.errors import InputError

from . import __version__, interrupts, registry
from .interrupts import Terminated
from .executors.base import WorkerLost


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage mistake is one line (what is wrong, where to look) and exit code 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        sys.stderr.write(f"asg: error: {message} (see '{self.prog} --help')\n")
        raise SystemExit(2)

    def _get_values(self, action: argparse.Action, arg_strings: list[str]):
        """argparse's, with an empty value refused: ``--out ""`` would be the current folder, and
        ``--fusion ""`` the default model (what a shell variable that was never set gives)."""
        if action.nargs not in (argparse.PARSER, argparse.REMAINDER) and \
                any(not text.strip() for text in arg_strings if isinstance(text, str)):
            name = "/".join(action.option_strings) or action.metavar or action.dest
            self.error(f"argument {name}: an empty value (a shell variable never set?); give one")
        return super()._get_values(action, arg_strings)


#: Command groups (``asg GROUP ACTION``): name -> (help, description, what the action is called)
COMMAND_GROUPS = {
    "towns": ("build or list the bundled SUMO towns", "Build or list the SUMO towns in nets/.", "ACTION"),
    "scenes": ("scenes (one frame each) from a traffic log or a recording", "Scenes from traffic logs and recordings.",
               "ACTION"),
    "dataset": ("build the data sets (detector-train, normal, challenging)", "Data sets.", "ACTION"),
    "bench": ("benchmarks: simulate, lidar, detect, generate, train, scale, paper",
              "Speed benchmarks and the paper's tables.", "WHAT"),
}

class Command(NamedTuple):
    """One subcommand: its name (two words: an action of a group in COMMAND_GROUPS), the module
    holding ``add_arguments(parser)`` and ``run(args) -> exit code``, its one-line help, and
    whether it runs the detectors (then PyTorch is imported before a held signal is released:
    a Ctrl-C inside torch's import, C++ calling back into Python, aborted the process with exit
    -6 instead of ending the command)."""

    name: str
    module: str
    help: str
    needs_torch: bool = False


#: Every subcommand, declared one way (Command). The module holds
#: ``add_arguments(parser)`` and ``run(args) -> exit code``, beside what it runs (the generator,
#: training, a workflow) or in asg/commands/, and is imported only when its command is asked for,
#: so ``asg --help`` stays quick. A new command: its module and one line here (a name of two
#: words is an action of a group in COMMAND_GROUPS).
COMMAND_MODULES: tuple[Command, ...] = tuple(Command(*c) for c in (
    ("towns build", "asg.commands.towns_build", "rebuild nets/NAME.net.xml and NAME.poly.xml from configs/towns.yaml"),
    ("towns import", "asg.commands.towns_import", "make a town of your own map (OpenDRIVE .xodr, OpenStreetMap .osm, "
     "SUMO .net.xml) with SUMO's netconvert and polyconvert"),
    ("towns list", "asg.commands.towns_list", "print name, area, lanes, junctions and buildings of each town"),
    ("simulate", "asg.commands.simulate", "run dense traffic in a town and record a SUMO fcd-output log"),
    ("scenes extract", "asg.commands.scenes_extract", "write every N-th frame of a log as a scene yaml"),
    ("scenes import", "asg.commands.scenes_import", "write each timestamp of a recording in OPV2V's layout (OPV2V, "
     "V2XSet, V2V4Real) as a scene yaml; its clouds are edited, not simulated"),
    ("render", "asg.commands.render", "render a scene's cooperative LiDAR frame to a bird's-eye picture (and PCD files)"),
    ("dataset build", "asg.commands.dataset_build", "simulate and extract a data set from configs/datasets.yaml, or "
     "generate a challenging set", True),
    ("export", "asg.commands.export", "write scenes in other tools' formats (--format: OpenCOOD's OPV2V, OpenPCDet's "
     "KITTI, OpenSCENARIO, SUMO, ROS 2 bags)"),
    ("report", "asg.commands.report", "one self-contained HTML page of a run folder or an 'asg bench paper' folder"),
    ("generate", "asg.generator.command", "generate challenging scenes: collaborator search, then perturbation search "
     "(no arguments: a one-minute demo)", True),
    ("train", "asg.training.command", "train a detector on CPU (resumes from runs/train/NAME/last.pt)", True),
    ("finetune", "asg.workflows.finetune", "train a detector further on its challenging scenes, then evaluate it "
     "before and after and attack it again (runs/finetune/FUSION-ft/)", True),
    ("harden", "asg.workflows.harden_command", "iterated adversarial training: each round attacks the current weights on "
     "fresh training scenes, fine-tunes on them and evaluates (runs/harden/FUSION/)", True),
    ("evaluate", "asg.workflows.evaluate", "AP of a detector on a scene set", True),
    ("bench simulate", "asg.commands.bench_simulate", "10 simulated minutes of a dense town at 0.1 s steps"),
    ("bench lidar", "asg.commands.bench_lidar", "cooperative-frame ray casting vs Open3D, and re-render after moves"),
    ("bench detect", "asg.commands.bench_detect", "median inference time of each shipped model with 3 agents", True),
    ("bench generate", "asg.commands.bench_generate", "seconds per scene of AttFuse + ACS-A + BO, BO overhead per "
     "suggestion", True),
    ("bench train", "asg.commands.bench_train", "seconds a training step of AttFuse takes (batch 4, 2 threads) and its "
     "phases' shares", True),
    ("bench scale", "asg.commands.bench_scale", "scenes per hour of the generator benchmark: 1 worker (1 thread, all "
     "threads), 2 workers, 2 Ray actors", True),
    ("bench paper", "asg.commands.bench_paper", "the paper's tables (--table), or the generator's targets: AttFuse with "
     "ACS-A/BO, GA, RS and ACS-R/BO on 30 normal scenes", True),
))


def _add_commands(sub, argv: Sequence[str] | None) -> None:
    """Every COMMAND_MODULES subparser; the arguments of the one ``argv`` names (all without ``argv``)."""
    chosen = [a for a in argv if not a.startswith("-")][:2] if argv is not None else None
    groups: dict[str, argparse._SubParsersAction] = {}
    for name, module, help_text, _ in map(lambda c: Command(*c), COMMAND_MODULES):
        words = name.split()
        parent = sub
        if len(words) == 2:
            if words[0] not in groups:
                group_help, description, metavar = COMMAND_GROUPS[words[0]]
                group = sub.add_parser(words[0], help=group_help, description=description)
                group.set_defaults(func=lambda a, group=group: (group.print_help(), 2)[1])
                groups[words[0]] = group.add_subparsers(dest=f"{words[0]}_command", metavar=metavar, parser_class=_Parser)
            parent = groups[words[0]]
        p = parent.add_parser(words[-1], help=help_text, description=help_text)
        if chosen is None or chosen[:len(words)] == words:
            command = importlib.import_module(module)
            command.add_arguments(p)
            p.set_defaults(func=command.run)


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The ``asg`` parser; with ``argv``, a command's module is imported only if it is the command
    ``argv`` runs (without: every one, the complete parser)."""
    parser = _Parser(prog="asg", description="Adversarial scene generation for cooperative V2X LiDAR perception.")
    parser.add_argument("--version", action="version", version=f"asg {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    _add_commands(sub, argv)
    return parser


#: errno values of output problems a user can fix (disk full, read-only, no permission, quota)
_OUTPUT_ERRNOS = {errno.ENOSPC, errno.EROFS, errno.EACCES, errno.EPERM, errno.EDQUOT, errno.ENOTDIR, errno.EISDIR,
                  errno.ENAMETOOLONG}


def _preload(argv: Sequence[str]) -> None:
    """Import what the command will need and cannot be interrupted while importing (Command.needs_torch)."""
    words = [a for a in argv if not a.startswith("-")][:2]
    if any(Command(*c).needs_torch and c[0].split() == words[:len(c[0].split())] for c in COMMAND_MODULES):
        import torch  # noqa: F401


def main(argv: Sequence[str] | None = None, held_signals: frozenset = frozenset()) -> int:
    """Run ``asg ARGV``; its exit code. ``held_signals``: signals the caller blocked while this
    module imported (asg.entry), released once the handlers that end a command cleanly are in place."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        parser = build_parser(argv)
        args = parser.parse_args(argv)
        _spin_for_opencood(argv)
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
    with interrupts.handled():
        return _run(args, held_signals)


def _spin_for_opencood(argv: Sequence[str]) -> None:
    """A target whose runtime wants it (an OpenCOOD model, ``opencood:DIR``, anywhere in the command)
    runs with OpenMP's waiting threads spinning (``OMP_WAIT_POLICY=ACTIVE``) unless the user set the
    policy: under ``PASSIVE`` its forward took 7.8 s a frame against 1.1 s (``asg bench detect
    --fusion opencood:DIR``, two threads, a 2-core AVX2 machine; docs/results/speed.md). Set before
    torch loads (OpenMP reads it then): the prefixes come from ``asg.registry``, which is torch-free."""
    import asg

    if registry.wants_spinning_omp(argv):
        asg.spin_waiting_threads(os.environ)


def _run(args, held_signals: frozenset) -> int:
    """``args.func(args)``'s exit code, with every way it can end told in one line."""
    try:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, held_signals)  # a signal held since the start ends it here
        try:
            code = int(args.func(args) or 0)
        except BaseException:
            interrupts.raise_if_taken()  # a signal taken on the way is the cause, whatever it broke
            raise
        interrupts.raise_if_taken()  # taken, and swallowed by third-party code: the run still ends on it
        return code
    except InputError as exc:
        sys.stderr.write(f"asg: error: {exc}\n")
        return 2
    except OSError as exc:
        if exc.errno not in _OUTPUT_ERRNOS:
            raise
        if exc.errno == errno.ENAMETOOLONG:
            name = f" ({str(exc.filename)[:80]}...)" if exc.filename else ""
            sys.stderr.write(f"asg: error: a name or path is longer than the file system allows{name}; shorten it\n")
            return 2
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


if __name__ == "__main__":  # prefer ``python -m asg``, which holds signals while this module imports
    raise SystemExit(main())
