"""Training curves written beside a chunk's checkpoint and read by the report."""
from __future__ import annotations

from pathlib import Path

from sumo_scenarios.atomic import write_text_atomic

#: the training loss of a chunk, every 50 steps (beside its checkpoint: OUT/ or OUT/round-K/)
LOSS_CURVE = "loss.csv"


class LossCurve:
    """The file ``step,loss`` of a chunk (mean training loss of the 50 steps up to each step),
    rewritten whole at each point; a resumed chunk keeps the points up to where it resumes."""

    def __init__(self, path: Path, resumed_at: int):
        self.path = path
        self.rows = [r for r in read_loss_curve(path) if r[0] <= resumed_at] if resumed_at else []

    def add(self, step: int, loss: float) -> None:
        self.rows.append((step, round(loss, 5)))
        write_text_atomic(self.path, "step,loss\n" + "".join(f"{s},{v}\n" for s, v in self.rows))


def read_loss_curve(path: Path) -> list[tuple[int, float]]:
    """(step, loss) rows of a loss.csv; [] if there is none; unreadable rows are left out."""
    rows = []
    if path.is_file():
        for line in path.read_text(encoding="utf-8", errors="replace").splitlines()[1:]:
            try:
                step, loss = line.split(",")
                rows.append((int(step), float(loss)))
            except ValueError:
                continue
    return rows
