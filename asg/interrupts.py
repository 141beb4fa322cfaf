"""A signal once taken is never forgotten: SIGINT and SIGTERM end a command even when the exception
they raise is swallowed on its way up.

Third-party code catches ``BaseException`` in places (trimesh wraps its optional imports in it, and a
few computations), so a Ctrl-C that lands inside them raises a KeyboardInterrupt nobody sees: the run
went on and exited 0. Here the handlers record the signal before raising; :func:`raise_if_taken`,
called where a run passes from one item to the next (the executors) and when a command returns
(:func:`asg.cli.main`), raises it again. Where the interpreter itself swallows it (a signal landing
in an at-fork hook, such as logging's lock release after a worker is forked, or in a ``__del__``),
it prints "Exception ignored in ..." with a traceback; inside :func:`handled` that print is dropped
for a signal already taken (its one line follows when it is raised again). This module imports
nothing heavy.
"""
from __future__ import annotations

import contextlib
import os
import signal
import sys
from typing import Iterator

#: the signals a command ends on
HANDLED = (signal.SIGINT, signal.SIGTERM)

_taken: list[int] = []
#: the process's own os._exit, taken at import (a detector call runs with os._exit refused)
_exit_now = os._exit


class Terminated(BaseException):
    """SIGTERM arrived: unwind like Ctrl-C (a BaseException, so that ``except Exception`` in a
    loader or a plugin cannot mistake it for a broken input), and every temporary file is removed."""


def _exception(signum: int) -> BaseException:
    return KeyboardInterrupt() if signum == signal.SIGINT else Terminated()


def _on_signal(signum, frame) -> None:
    _taken.append(signum)
    raise _exception(signum)


def raise_if_taken() -> None:
    """Raise again the first signal taken since :func:`handled` began (KeyboardInterrupt or
    Terminated); nothing when none was."""
    if _taken:
        raise _exception(_taken[0])


def _quiet_about_taken_signals(previous_hook):
    """A ``sys.unraisablehook`` that says nothing of a KeyboardInterrupt or Terminated the
    interpreter could not raise, once its signal is taken (it is raised again later), and hands every
    other unraisable exception to ``previous_hook``."""

    def hook(unraisable) -> None:
        if _taken and isinstance(unraisable.exc_value, (KeyboardInterrupt, Terminated)):
            return
        previous_hook(unraisable)

    return hook


@contextlib.contextmanager
def handled() -> Iterator[None]:
    """SIGINT and SIGTERM raise (and are remembered) while inside; the previous handlers after."""
    _taken.clear()
    previous = {sig: signal.signal(sig, _on_signal) for sig in HANDLED}
    previous_hook = sys.unraisablehook
    sys.unraisablehook = _quiet_about_taken_signals(previous_hook)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)
        sys.unraisablehook = previous_hook
        _taken.clear()


#: where a worker process leaves its last word before :func:`give_up` ends it (None: in the command's
#: own process, which says it on stderr)
_last_word_path: str | None = None


def leave_last_word_in(path: str | None) -> None:
    """In a worker process: :func:`give_up` writes its message to ``path`` for the parent to say."""
    global _last_word_path
    _last_word_path = path


def give_up(message: str, exit_code: int = 2) -> None:
    """The last resort against code that will not stop (it catches every exception, so no raise can
    end it): ``message`` as the command's one line (or, in a worker, to its parent), then the process
    ends at once. Temporary files it leaves are removed when the command is run again."""
    import sys

    if _last_word_path is None:
        sys.stderr.write(f"asg: error: {message}\n")
        sys.stderr.flush()
    else:
        with open(_last_word_path + ".part", "w") as f:
            f.write(message)
        os.replace(_last_word_path + ".part", _last_word_path)
    _exit_now(exit_code)
