"""Progress bars (rich) on stderr, quiet when not a terminal unless asked."""
from __future__ import annotations

import contextlib
import json
import sys
from typing import Iterator

from rich.console import Console
from rich.table import Table
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

console = Console(stderr=True)
stdout = Console(width=None if sys.stdout.isatty() else 120)


@contextlib.contextmanager
def progress_bar() -> Iterator[Progress]:
    with Progress(
        TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
        TextColumn("ETA"), TimeRemainingColumn(), console=console, transient=False, disable=not sys.stderr.isatty(),
    ) as bar:
        yield bar


def print_result(title: str, result: dict, as_json: bool) -> None:
    """``result`` ({metric: value}) as one JSON line, or as a two-column table titled ``title``."""
    if as_json:
        print(json.dumps(result))
        return
    table = Table(title=title)
    table.add_column("metric")
    table.add_column("value", justify="right")
    for k, v in result.items():
        table.add_row(k, str(v))
    stdout.print(table)
