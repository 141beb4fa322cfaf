"""Progress bars (rich) on stderr, quiet when not a terminal unless asked."""
from __future__ import annotations

import contextlib
import json
import math
import sys
from typing import Callable, Iterator

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


def loss_progress(bar: Progress, task, doing: str, without_loss: str | None = None) -> Callable[[int, int, float], None]:
    """A training run's ``progress(step, total, loss)``: moves ``task`` on ``bar`` and shows "DOING
    loss L" (``without_loss`` instead while the loss is not a number, e.g. a collection phase)."""

    def report(step: int, total: int, loss: float) -> None:
        what = f"{doing} loss {loss:.3f}" if without_loss is None or math.isfinite(loss) else without_loss
        bar.update(task, completed=step, total=total, description=what)

    return report


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
