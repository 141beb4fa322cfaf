"""The process's handlers of fatal signals (SIGSEGV, SIGBUS, SIGILL, SIGFPE, SIGABRT), kept across
a library that replaces them.

``ray.init`` installs Abseil's failure handler for these signals in the driver process (it writes
a stack trace to Ray's own log file), and ``ray.shutdown`` leaves them at SIG_DFL: measured with
Ray 2.x here, a process whose faulthandler was on before (as pytest's is) dies of a later segfault
with no word at all, neither on stderr nor in a log. :func:`fatal_handlers_kept` saves the C-level
``struct sigaction`` of each signal and puts it back, so that a crash after (or during) a Ray batch
is reported as it would be without Ray.
"""
from __future__ import annotations

import contextlib
import ctypes
import signal
import sys
from typing import Iterator

FATAL_SIGNALS = (signal.SIGSEGV, signal.SIGBUS, signal.SIGILL, signal.SIGFPE, signal.SIGABRT)
#: bytes that hold a C ``struct sigaction`` (152 on glibc x86-64 and aarch64; room to spare)
_SIGACTION_BYTES = 512


def _libc():
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.sigaction  # noqa: B018  (present)
    except (OSError, AttributeError):
        return None
    return libc


def saved_fatal_handlers() -> dict[int, ctypes.Array]:
    """{signal: its current ``struct sigaction``, opaque bytes} ({} where the C call is not available)."""
    libc = _libc()
    if libc is None:
        return {}
    saved = {}
    for sig in FATAL_SIGNALS:
        buf = ctypes.create_string_buffer(_SIGACTION_BYTES)
        if libc.sigaction(int(sig), None, buf) == 0:
            saved[int(sig)] = buf
    return saved


def handler_address(saved: ctypes.Array) -> int:
    """The handler function's address of a saved ``struct sigaction`` (its first member on Linux;
    0: SIG_DFL, 1: SIG_IGN). The rest of the struct holds bytes the C library leaves unset."""
    return ctypes.c_void_p.from_buffer(saved).value or 0


def restore_fatal_handlers(saved: dict[int, ctypes.Array]) -> None:
    """Put back the handlers :func:`saved_fatal_handlers` returned."""
    libc = _libc()
    if libc is None:
        return
    for sig, buf in saved.items():
        libc.sigaction(sig, buf, None)


@contextlib.contextmanager
def fatal_handlers_kept() -> Iterator[dict[int, ctypes.Array]]:
    """Inside, a library may replace the fatal-signal handlers; on leaving, the ones in place
    before are back. Yields the saved handlers (for :func:`restore_fatal_handlers` later too)."""
    saved = saved_fatal_handlers()
    try:
        yield saved
    finally:
        restore_fatal_handlers(saved)
