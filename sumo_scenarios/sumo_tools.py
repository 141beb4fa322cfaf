"""Locate and run SUMO's programs (netgenerate, netconvert, duarouter) and tools (randomTrips.py).

They come from the ``eclipse-sumo`` wheel; ``SUMO_HOME`` is set for them so that they find their
XML schemas and data.
"""
from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

from .errors import InputError


def sumo_home() -> Path:
    import sumo  # the eclipse-sumo wheel

    return Path(sumo.SUMO_HOME)


def sumo_env() -> dict[str, str]:
    env = dict(os.environ)
    env["SUMO_HOME"] = str(sumo_home())
    return env


def binary(name: str) -> str:
    path = sumo_home() / "bin" / name
    if not path.exists():
        raise InputError(f"SUMO program '{name}' not found under {path.parent}; reinstall with 'pip install eclipse-sumo'")
    return str(path)


def tool(relpath: str) -> str:
    return str(sumo_home() / "tools" / relpath)


#: the address space a SUMO program may take (bytes): an input that makes one explode (a map with a
#: negative road length grew netconvert to 9 GB in 90 s) ends in one line instead of taking the machine
MAX_TOOL_MEMORY_BYTES = 6 * 1024**3


def _memory_capped() -> None:
    """In the child, before the program starts: cap its address space at MAX_TOOL_MEMORY_BYTES."""
    resource.setrlimit(resource.RLIMIT_AS, (MAX_TOOL_MEMORY_BYTES, MAX_TOOL_MEMORY_BYTES))


def run(args: list[str], what: str, timeout_s: float | None = None) -> str:
    """Run a SUMO program (at most ``timeout_s`` seconds and MAX_TOOL_MEMORY_BYTES of memory); a
    failure raises InputError with its first error line (SUMO's last one is only "Quitting (on error).")."""
    try:
        proc = subprocess.run(args, capture_output=True, text=True, env=sumo_env(), timeout=timeout_s,
                              preexec_fn=_memory_capped)
    except subprocess.TimeoutExpired:
        raise InputError(f"{what} took over {timeout_s:g} s; give a smaller map or extract") from None
    if proc.returncode != 0:
        lines = [l.strip() for l in (proc.stderr + proc.stdout).splitlines() if l.strip()]
        if any(w in l for l in lines for w in ("bad_alloc", "MemoryError", "out of memory")):
            raise InputError(f"{what} ran out of its {MAX_TOOL_MEMORY_BYTES / 1024**3:g} GiB of memory; "
                             "check the input's numbers or give a smaller map")
        raise InputError(f"{what} failed: {first_error(lines) or 'exit code ' + str(proc.returncode)}")
    return proc.stdout


def first_error(lines: list[str]) -> str:
    """The line of a SUMO program's output that says what went wrong (at most 300 characters): its
    first error line, else its first line; empty for no output (SUMO's last line is only
    'Quitting (on error).')."""
    errors = [l for l in lines if "rror" in l and not l.startswith("Quitting")] or lines
    return errors[0][:300] if errors else ""


def run_python_tool(relpath: str, args: list[str], what: str) -> str:
    return run([sys.executable, tool(relpath), *args], what)
