"""The ``asg`` command's entry point (also ``python -m asg``): SIGINT and SIGTERM are held while
the command's modules import and its arguments are read, and taken as soon as it starts.

A signal that lands inside an import is lost or worse: trimesh wraps its scipy imports in
``except BaseException``, so a Ctrl-C in the first second of ``asg generate`` was swallowed (the
run went on and exited 0) or left scipy half-imported (a NameError seconds later). Held (blocked)
signals wait in the kernel; :func:`asg.cli.main` releases them inside its handlers, where they end
the command as any Ctrl-C (exit 130) or SIGTERM (exit 143) does. This module imports nothing heavy.
"""
from __future__ import annotations

import signal
import sys

#: the signals held while the command starts
HELD = frozenset({signal.SIGINT, signal.SIGTERM})


def main() -> int:
    signal.pthread_sigmask(signal.SIG_BLOCK, HELD)
    try:
        from .cli import main as cli_main
    except BaseException:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, HELD)
        raise
    from .executors.base import quiet_third_party_warnings

    quiet_third_party_warnings()  # the command's stderr: asg's words only (its workers do the same)
    return cli_main(sys.argv[1:], held_signals=HELD)
