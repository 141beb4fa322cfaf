"""Argument types and shared options of the ``asg`` command, for the CLI and for the workflow
modules that declare their own subcommand (``add_arguments``/``run``, see asg.cli's
COMMAND_MODULES): whole numbers and reals in a range, seeds, counts, the executor options."""
from __future__ import annotations

import argparse
import math
import re
from pathlib import Path
from typing import Callable

from .executors import EXECUTORS, Executor, build_executor, default_workers


def whole(lo: int, hi: int, what: str) -> Callable[[str], int]:
    """An argparse type: a whole number in [lo, hi]."""

    def parse(text: str) -> int:
        # ASCII digits only: int() also reads other scripts' digits ("٣", "３") and "1_000"
        if not re.fullmatch(r"\s*[+-]?[0-9]+\s*", text):
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number (digits 0-9)")
        value = int(text)
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"{value} is out of range: {what} must be between {lo} and {hi}")
        return value

    parse.__name__ = "whole number"
    return parse


def real(lo: float, hi: float, what: str, lo_open: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite number in [lo, hi] (or (lo, hi] with ``lo_open``)."""

    def parse(text: str) -> float:
        if not text.isascii():  # float() also reads other scripts' digits
            raise argparse.ArgumentTypeError(f"{text!r} is not a number (digits 0-9)")
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not math.isfinite(value) or value < lo or value > hi or (lo_open and value <= lo):
            low = f"above {lo:g}" if lo_open else f"at least {lo:g}"
            raise argparse.ArgumentTypeError(f"{text} is out of range: {what} must be {low} and at most {hi:g}")
        return value

    parse.__name__ = "number"
    return parse


#: seeds go to SUMO and numpy: a non-negative 31-bit number
SEED = whole(0, 2**31 - 1, "a seed")
#: counts of scenes, frames, repeats
COUNT = whole(1, 1_000_000, "a count")
#: training threads
THREADS = whole(1, 256, "--threads")


def fusion_arg(p: argparse.ArgumentParser, what: str, required: bool = False) -> None:
    """--fusion: a detector by name; the help lists every one (the shipped models of the fusion
    registry and the installed plugins), validated where the command runs, by
    asg.perception.check_fusion, before any run folder or worker starts. Only the parser of a
    command that runs the detectors calls this (it imports torch)."""
    from .perception.targets import detector_names

    p.add_argument("--fusion", required=required, default=None, metavar="NAME",
                   help=f"{what}: one of {', '.join(detector_names())}")


def weights_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--weights", type=Path, default=None, metavar="PATH",
                   help="weights file (.pt) of --fusion's model to use instead of the shipped ones "
                        "(e.g. runs/finetune/attfuse-ft/attfuse-ft.pt)")


def executor_args(p: argparse.ArgumentParser) -> None:
    """--workers, --executor, --address: how a batch command spreads its items."""
    p.add_argument("--workers", type=whole(1, 1024, "--workers"), default=None,
                   help="worker processes, one thread each (default: one per core); results do not depend on it")
    p.add_argument("--executor", choices=EXECUTORS.names(), default="local",
                   help="local processes (default) or Ray actors (pip install 'asg[ray]')")
    p.add_argument("--address", default=None, help="an existing Ray cluster (default: a local Ray instance)")


def training_run_args(p: argparse.ArgumentParser, block: str) -> None:
    """--config (a yaml with a ``block`` block), --threads, --force and the executor options of a
    command that trains and writes a run folder (finetune, harden)."""
    p.add_argument("--config", type=Path, default=None,
                   help=f"a yaml with a '{block}' block (default configs/detectors/train.yaml's)")
    p.add_argument("--threads", type=THREADS, default=2, help="training threads")
    p.add_argument("--force", action="store_true", help="start the output folder over")
    executor_args(p)


def executor_from_args(args: argparse.Namespace, items: int) -> Executor:
    """The executor of ``--executor``, ``--workers`` (default: one per core, at most ``items``) and
    ``--address``: one thread per worker."""
    workers = args.workers if args.workers is not None else default_workers(items)
    return build_executor(args.executor, workers, threads=1, address=args.address)
