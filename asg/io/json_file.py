"""Reading a JSON file a user hands in (a run folder's summary, a card, a table): a regular file of
bounded size, parsed without unbounded recursion; anything else is one InputError naming it."""
from __future__ import annotations

import json
import stat
from pathlib import Path
from typing import Any

from sumo_scenarios.errors import InputError

#: the largest JSON file asg reads back (a 10,000-scene summary is about 40 MB)
MAX_JSON_BYTES = 256 * 1024 * 1024


def read_json(path: Path, what: str = "a file asg wrote", max_bytes: int = MAX_JSON_BYTES) -> Any:
    """The parsed contents of ``path``. InputError (one line, naming it) if it is missing, a link,
    a special file (a FIFO would block the read forever, a device never end), over ``max_bytes``,
    not UTF-8, not JSON, or nested deeper than the parser's recursion allows."""
    path = Path(path)
    try:
        st = path.lstat()
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror}); regenerate {what}") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{path}: not a regular file (a link, a folder or a special file); regenerate {what}")
    if st.st_size > max_bytes:
        raise InputError(f"{path}: {st.st_size:,} bytes, over the {max_bytes:,} asg reads; regenerate {what}")
    try:
        return json.loads(path.read_bytes().decode("utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise InputError(f"{path}: not readable JSON ({type(exc).__name__}); regenerate {what}") from None
