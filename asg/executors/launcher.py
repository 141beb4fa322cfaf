"""Worker processes born ignoring Ctrl-C.

A terminal's Ctrl-C reaches the whole process group, workers too. A worker spawned by
multiprocessing spends its first second starting the interpreter and unpickling its job (imports),
before its initializer can ignore SIGINT; a Ctrl-C there printed a KeyboardInterrupt traceback from
the worker beside the command's own line. The parent decides what Ctrl-C does, so a worker should
ignore it from its first instruction on.

A signal's disposition "ignored" survives fork and exec (its mask does not: multiprocessing's
spawn resets it), and Python leaves an ignored SIGINT ignored at startup. Setting it in the parent
around the spawn would make the parent drop its own Ctrl-C (any thread of it that does not block
SIGINT, the progress bar's or a native pool's, takes and discards it). So the ignoring happens in
the child, before Python starts: :func:`spawned_ignoring_sigint` points multiprocessing's spawn at
a two-line shell launcher (``trap '' INT; exec python "$@"``) for the processes started inside
it. A Ctrl-C that lands before the ``trap`` ends the shell quietly (no traceback), as SIGTERM does a
starting worker. Where the launcher cannot run (no /bin/sh, a temporary folder mounted noexec) the
spawn stays as it was.
"""
from __future__ import annotations

import atexit
import contextlib
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Iterator

_LAUNCHER: list[Path | None] = []  # [the launcher, or None when it cannot run]: made once a process

#: the launcher's check: started through it, Python finds SIGINT ignored
_CHECK = "import signal, sys; sys.exit(0 if signal.getsignal(signal.SIGINT) == signal.SIG_IGN else 3)"


def sigint_ignoring_launcher() -> Path | None:
    """A shell script that starts this interpreter with SIGINT ignored (made and checked once, in a
    private temporary folder removed at exit); None where it cannot run."""
    if not _LAUNCHER:
        _LAUNCHER.append(_make_launcher())
    return _LAUNCHER[0]


def _make_launcher() -> Path | None:
    if not os.path.exists("/bin/sh") or not sys.executable:
        return None
    folder = Path(tempfile.mkdtemp(prefix="asg-launcher-"))
    atexit.register(shutil.rmtree, folder, True)
    path = folder / "python"
    path.write_text(f"#!/bin/sh\ntrap '' INT\nexec {shlex.quote(sys.executable)} \"$@\"\n")
    path.chmod(0o700)
    try:
        ok = subprocess.run([str(path), "-c", _CHECK], timeout=60, stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode == 0
    except (OSError, subprocess.SubprocessError):
        ok = False
    return path if ok else None


@contextlib.contextmanager
def spawned_ignoring_sigint() -> Iterator[None]:
    """Processes that multiprocessing's ``spawn`` starts inside the block start with SIGINT
    ignored (see the module's docstring); the spawn's interpreter is restored after it."""
    from multiprocessing import spawn

    launcher = sigint_ignoring_launcher()
    if launcher is None:
        yield
        return
    before = spawn.get_executable()
    spawn.set_executable(str(launcher))
    try:
        yield
    finally:
        spawn.set_executable(before)
