"""The generator's settings (``GenerateConfig``), mirrored by configs/generate.yaml, and how they
are read: the yaml, then the command line's flags (``load_generate_config``, ``with_space_flags``),
and each search algorithm's own yaml (``search_params``)."""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from sumo_scenarios import checks
from sumo_scenarios.errors import InputError
from sumo_scenarios.paths import configs_dir
from sumo_scenarios.strict import from_mapping, read_yaml

from ..objective import ObjectiveConfig
from ..scene.neighbours import COMM_RANGE_M
from ..search import SpaceConfig
from ..sensors.lidar_spec import DEFAULT_LIDAR

if TYPE_CHECKING:  # (the targets import torch: the config does not need it to load)
    from ..perception.targets import Target

#: ``--acs off``: no collaborator search (the scene's own collaborators)
ACS_OFF = "off"
#: evaluations per scene at most (a scene at 50 takes seconds; this many is a day)
MAX_BUDGET = 100_000

@dataclass(frozen=True)
class GenerateConfig:
    """The generator's settings; configs/generate.yaml mirrors these defaults (a test checks it)."""

    fusion: str = "attfuse"
    #: the target's weights file (.pt) instead of the fusion's shipped weights (e.g. a fine-tuned model)
    weights: str | None = None
    search: str = "bo"
    #: the collaborator search: a registered strategy (asg.collaborators: attention, random) or off
    acs: str = "attention"
    aps: bool = True
    budget: int = 50
    sensing_agents: int = 3
    acs_samples: int = 3
    acs_tau: float = 0.03
    attention_cells: Literal["all", "vehicles"] = "all"
    perturbed: int = 3
    comm_range_m: float = COMM_RANGE_M
    lidar: str = DEFAULT_LIDAR
    objective: ObjectiveConfig = field(default_factory=ObjectiveConfig)
    space: SpaceConfig = field(default_factory=SpaceConfig)

    @property
    def target(self) -> "Target":
        """The target ``fusion`` names (asg.perception.targets.Target): what the run asks about
        it (its detector, attention, digests) it asks this object, never the name."""
        from ..perception.targets import resolve_target

        return resolve_target(self.fusion)

    @property
    def acs_needs_attention(self) -> bool:
        """Does the collaborator search read attention weights (then the run loads an attention model)?"""
        from ..collaborators import ACS_STRATEGIES

        return self.acs != ACS_OFF and ACS_STRATEGIES.entry(self.acs).needs_attention

    def validate(self) -> "GenerateConfig":
        """The settings checked: the target (its own messages name its source: a model folder's
        config.yaml, not this config), then every other value (:meth:`validate_values`)."""
        self.target.check()
        return self.validate_values()

    def validate_values(self) -> "GenerateConfig":
        """Every setting but the target checked (its names and ranges)."""
        from ..collaborators import ACS_STRATEGIES
        from ..search import SEARCHES

        SEARCHES.check(self.search)
        ACS_STRATEGIES.check(self.acs, extra=(ACS_OFF,))
        if not 1 <= self.budget <= MAX_BUDGET:
            raise InputError(f"--budget must be between 1 and {MAX_BUDGET}, got {self.budget}")
        checks.number(self.sensing_agents, "sensing_agents", 1, 16)
        checks.number(self.acs_samples, "acs_samples", 1, 1000)
        checks.number(self.acs_tau, "acs_tau", 0.0, 100.0, lo_open=True)
        checks.number(self.perturbed, "perturbed", 0, 64)
        checks.number(self.comm_range_m, "comm_range_m", 0.0, 1000.0, lo_open=True)
        return self


def protocols() -> tuple[str, ...]:
    """The named protocols (configs/protocols/NAME.yaml): settings that replace the config's."""
    return tuple(sorted(p.stem for p in (configs_dir() / "protocols").glob("*.yaml")))


def _read_mapping(path: Path) -> dict:
    data = read_yaml(path)
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a mapping of settings (key: value), got a {type(data).__name__}")
    return data


def _merge(base: dict, overlay: dict) -> dict:
    """``base`` with ``overlay``'s keys, mappings merged key by key (a protocol's ``space`` block
    keeps the config's other space settings)."""
    out = dict(base)
    for k, v in overlay.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def load_generate_config(path: Path | None = None, protocol: str | None = None, **overrides) -> GenerateConfig:
    """The generator's settings: ``path`` (default configs/generate.yaml), then the named
    ``protocol``'s (configs/protocols/NAME.yaml, e.g. "paper"), then the non-None ``overrides``
    (CLI flags); an error names the file it came from."""
    path = Path(path) if path is not None else configs_dir() / "generate.yaml"
    data = _read_mapping(path)
    budget_by_search: dict = {}
    if protocol is not None:
        if protocol not in protocols():
            raise InputError(f"unknown protocol '{protocol}'; known: {', '.join(protocols())}")
        path = configs_dir() / "protocols" / f"{protocol}.yaml"
        overlay = _read_mapping(path)
        budget_by_search = overlay.pop("budget_by_search", None) or {}
        if not isinstance(budget_by_search, dict):
            raise InputError(f"{path}: budget_by_search must map a search to its budget")
        data = _merge(data, overlay)
    data.update({k: v for k, v in overrides.items() if v is not None})
    if overrides.get("budget") is None and data.get("search") in budget_by_search:
        data["budget"] = budget_by_search[data["search"]]
    try:
        cfg = from_mapping(GenerateConfig, data, str(path)).validate_values()
    except InputError as exc:  # a range check inside a component's config: say which file it came from
        text = str(exc)
        if str(path) in text or text.startswith("--"):
            raise
        raise InputError(f"{path}: {text}") from None
    cfg.target.check()  # outside the try: its refusal names its own source (a model folder), not this file
    return cfg


def with_space_flags(cfg: GenerateConfig, plausibility: str | None, spaces: str | None) -> GenerateConfig:
    """``cfg`` with the --plausibility and --space flags (``spaces``: comma-separated names) applied."""
    changes = {}
    if plausibility is not None:
        changes["plausibility"] = plausibility
    if spaces is not None:
        changes["kinds"] = tuple(k.strip() for k in spaces.split(",") if k.strip())
    if not changes:
        return cfg
    fields = {f: getattr(cfg.space, f) for f in SpaceConfig.__dataclass_fields__} | changes
    return replace(cfg, space=SpaceConfig(**fields))


def search_params(name: str) -> dict:
    p = configs_dir() / "search" / f"{name}.yaml"
    return (read_yaml(p) or {}) if p.is_file() else {}
