"""What each bundled data set is (``configs/datasets.yaml``) and where data sets live on disk.

The lowest layer of the package (it reads a yaml file and the environment, nothing of asg), so
that the scene layer may find a data set's log; building and reading data sets is asg.datasets.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from sumo_scenarios.errors import InputError
from sumo_scenarios.paths import configs_dir, runs_dir
from sumo_scenarios.strict import from_mapping, read_yaml


@dataclass(frozen=True)
class DatasetSpec:
    towns: tuple[str, ...]
    densities: tuple[str, ...] = ("normal",)
    seeds: tuple[int, ...] = (1,)
    duration_s: float = 60.0
    every: int = 10
    ego_rsu_share: float = 0.5
    collaborators: int = 2
    frames_per_log: int | None = None
    total: int | None = None
    val: int | None = None
    #: only the first this many (town, density, seed) logs
    max_logs: int | None = None
    #: the split that holds every frame of a set without ``total`` (a test-only set: "test")
    split: str = "train"
    #: keep frames with this many vehicles (ego aside) within the evaluation range, inclusive
    vehicles_in_range: tuple[int, int] | None = None
    #: keep this share of the frames (those passing the other filters) whose vehicles in range hold
    #: the fewest fused LiDAR points on average: the most occluded ones
    fewest_points_share: float | None = None

    def check(self, where: str) -> "DatasetSpec":
        """``self`` if every setting is in range (one InputError naming ``where`` and the first that
        is not): towns and a split that are names, known densities, seeds, a log of at most a day,
        a frame every 1 or more recorded periods, shares in [0, 1], counts of 1 or more."""
        from sumo_scenarios import checks
        from sumo_scenarios.routes import DENSITIES

        for name, values in (("towns", self.towns), ("densities", self.densities), ("seeds", self.seeds)):
            if not values:
                raise InputError(f"{where}.{name}: give at least one")
        for town in self.towns:
            checks.safe_id(town, f"{where}.towns")
        for density in self.densities:
            if density not in DENSITIES:
                raise InputError(f"{where}.densities: {density!r} is not one of {', '.join(DENSITIES)}")
        for seed in self.seeds:
            checks.number(seed, f"{where}.seeds", 0, 2**31 - 1)
        checks.number(self.duration_s, f"{where}.duration_s", 0.0, 86_400.0, lo_open=True)
        checks.number(self.every, f"{where}.every", 1, 100_000)
        checks.number(self.ego_rsu_share, f"{where}.ego_rsu_share", 0.0, 1.0)
        checks.number(self.collaborators, f"{where}.collaborators", 0, 16)
        for key in ("frames_per_log", "total", "max_logs"):
            if getattr(self, key) is not None:
                checks.number(getattr(self, key), f"{where}.{key}", 1, 10_000_000)
        if self.val is not None:
            checks.number(self.val, f"{where}.val", 0, (self.total or 1) - 1)
        checks.safe_id(self.split, f"{where}.split")
        if self.vehicles_in_range is not None:
            low, high = (checks.number(v, f"{where}.vehicles_in_range", 0, 10_000) for v in self.vehicles_in_range)
            if low > high:
                raise InputError(f"{where}.vehicles_in_range: [{low:g}, {high:g}] runs from high to low")
        if self.fewest_points_share is not None:
            checks.number(self.fewest_points_share, f"{where}.fewest_points_share", 0.0, 1.0, lo_open=True)
        return self


def data_root() -> Path:
    """Where the data sets are built and read: ``ASG_DATA`` when set and not empty, else
    runs/datasets; made if missing (InputError, one line, if it cannot be)."""
    given = os.environ.get("ASG_DATA", "")
    root = Path(given) if given.strip() else runs_dir() / "datasets"
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        where = f"ASG_DATA={given}" if given.strip() else str(root)
        raise InputError(f"{where}: the data folder cannot be created ({exc.strerror}); set ASG_DATA to a writable folder") from None
    return root


def check_train_source(name: str, where: str) -> str:
    """``name`` if training can draw on its train split: a set ``configs/datasets.yaml`` builds with
    one, or one built under :func:`data_root` (a challenging set); else one InputError naming
    ``where``. Checked when a config is loaded, so that no run attacks for hours first."""
    from sumo_scenarios import checks

    checks.safe_id(name, f"{where}: data set")
    specs = read_yaml(configs_dir() / "datasets.yaml")
    if name in specs:
        spec = _spec(specs, name)
        if spec.total is None and spec.split != "train":
            raise InputError(f"{where}: data set '{name}' has no train split (its one split is '{spec.split}': "
                             "never trained on); name a set with one, e.g. normal or detector-train")
    elif not (data_root() / name / "index.json").is_file():
        raise InputError(f"{where}: unknown data set '{name}'; known: {', '.join(sorted(specs))} or a built challenging set")
    return name


def load_spec(name: str) -> DatasetSpec:
    data = read_yaml(configs_dir() / "datasets.yaml")
    if name not in data:
        raise InputError(f"unknown data set '{name}'; known: {', '.join(sorted(data))}")
    return _spec(data, name)


def _spec(data: dict, name: str) -> DatasetSpec:
    """Set ``name`` of datasets.yaml's mapping ``data``, checked."""
    return from_mapping(DatasetSpec, data[name], f"datasets.yaml:{name}").check(f"datasets.yaml:{name}")
