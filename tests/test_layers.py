"""The package reads top-down: every import (also one inside a function) goes to a lower layer.

Layers, lowest first: settings and registries; the scene; the stages (sensors, objective, search,
collaborators); perception (networks and detectors) and the executors; training's settings,
checkpoints and branch fit; data sets and the generator's settings; the training loop; the
generator's pipeline (one scene); outputs (io) and the run folder; the generator's run and the
report; the evaluation core; training's model cards, runs and command; the workflows; the
benchmarks; the command line. A wing (``generator/``, ``training/``) spans layers: each of its
modules has its own. A new module has to be given its layer here, which is the point: a test that
fails when an arrow runs upward."""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent / "asg"

#: each part of asg (a sub-package, or a module directly in asg/) and its layer
LAYERS = {
    "__init__": 0, "registry": 0, "dataset_spec": 0, "progress": 0, "interrupts": 0, "schemas": 0,
    "scene": 1,
    "sensors": 2, "objective": 2, "search": 2, "collaborators": 2,
    "metrics": 3, "perception": 3, "executors": 3,
    "training.__init__": 3.5, "training.checkpoint": 3.5, "training.branch_fit": 3.5, "training.config": 3.6,
    "datasets": 4, "generator.config": 4, "generator.stages": 4, "generator.__init__": 4, "cli_args": 4,
    "training.loop": 4.5,
    "generator.candidates": 4, "generator.pipeline": 5,
    "io": 6, "generator.run_folder": 6.5,
    "generator.run": 7, "report": 7,
    "evaluation": 7.5,
    "training.cards": 7.6, "training.train": 7.7, "training.point_stage_fit": 7.7, "training.command": 7.8,
    "workflows": 8,
    "benchmarks": 9,
    "generator.command": 10,
    "commands": 11,
    "cli": 12,
    "entry": 13, "__main__": 14,
}


#: sub-packages whose modules sit on layers of their own (a wing: one feature from its settings to
#: its command); their parts are named ``wing.module``
WINGS = ("generator", "training")


def _part(module: str) -> str:
    """``asg.perception.fusion.attfuse`` -> ``perception``; ``asg`` -> ``__init__``;
    ``asg.generator.run`` -> ``generator.run``; ``asg.generator`` -> ``generator.__init__``."""
    parts = module.split(".")
    if len(parts) > 1 and parts[1] in WINGS:
        return f"{parts[1]}.{parts[2] if len(parts) > 2 else '__init__'}"
    return parts[1] if len(parts) > 1 else "__init__"


def _imports(path: Path, packages_read: bool = False, packages: tuple[str, ...] = ("asg",)) -> set[str]:
    """The modules of ``packages`` that ``path`` imports (absolute names), anywhere in the file,
    also through ``importlib.import_module("name")`` with a literal name; with ``packages_read``
    also the package a ``from . import x`` reads ``x`` from."""
    # a module's package, or the package itself (none for a file outside the repository)
    package = path.relative_to(ROOT.parent).with_suffix("").parts[:-1] if path.is_relative_to(ROOT.parent) else ()
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = list(package[:len(package) - (node.level - 1)])
                target = ".".join(base + ([node.module] if node.module else []))
                out |= {target} if node.module else {f"{target}.{a.name}" for a in node.names}
                if packages_read and not node.module:
                    out.add(target)
            elif node.module:
                out.add(node.module)
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "import_module"
              and node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)
              and not node.args[0].value.startswith(".")):
            out.add(node.args[0].value)
    return {m for m in out if m in packages or m.startswith(tuple(f"{p}." for p in packages))}


def _part_of_file(path: Path) -> str:
    return _part(".".join(("asg",) + path.relative_to(ROOT).with_suffix("").parts))


def test_every_part_of_the_package_has_a_layer():
    parts = {_part_of_file(p) for p in ROOT.rglob("*.py")}
    assert parts <= set(LAYERS), f"give these a layer in LAYERS: {sorted(parts - set(LAYERS))}"


def test_no_import_runs_upward_or_sideways():
    upward = []
    for path in sorted(ROOT.rglob("*.py")):
        here = _part_of_file(path)
        for module in _imports(path):
            there = _part(module)
            if there != here and there in LAYERS and LAYERS[there] >= LAYERS[here]:
                upward.append(f"{path.relative_to(ROOT.parent)} imports {module} ({here} {LAYERS[here]} -> "
                              f"{there} {LAYERS[there]})")
    assert not upward, "\n".join(upward)


def test_the_checker_resolves_relative_imports_inside_functions(tmp_path):
    """The checker itself: a function-level ``from ..x import y`` two packages down is resolved."""
    assert "asg.dataset_spec" in _imports(ROOT / "scene" / "history.py")
    assert {"asg.io.run_record", "asg.executors", "asg.generator.config"} <= _imports(ROOT / "generator" / "run.py")


#: the traffic package asg builds on: it imports nothing of asg
SUMO_ROOT = ROOT.parent / "sumo_scenarios"


def _module_graph() -> dict[str, set[str]]:
    """{module: the modules of asg and sumo_scenarios it imports}, every file of both packages; an
    imported name that is not a module (``from .space import SpaceConfig`` resolved to
    ``asg.search.space.SpaceConfig``) counts as its module."""
    def name_of(path: Path) -> str:
        parts = path.relative_to(ROOT.parent).with_suffix("").parts
        return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)

    modules = {name_of(p): p for root in (ROOT, SUMO_ROOT) for p in root.rglob("*.py")}

    def module_of(name: str) -> str | None:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    return {m: {t for t in map(module_of, _imports(p, True, ("asg", "sumo_scenarios"))) if t and t != m}
            for m, p in modules.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle through each strongly connected group of more than one module (Tarjan's)."""
    index, low, stack, on_stack, groups = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return groups


def test_sumo_scenarios_never_imports_asg():
    """sumo_scenarios (SUMO, traffic logs, lanes, the checks every input goes through) sits below
    every layer of asg."""
    upward = [f"{p.relative_to(ROOT.parent)} imports {m}" for p in sorted(SUMO_ROOT.rglob("*.py")) for m in _imports(p)]
    assert not upward, "\n".join(upward)


def test_imports_through_importlib_are_checked_too(tmp_path):
    """A literal ``importlib.import_module("asg.x")`` counts as an import; cli.py imports each
    command's module by a name in COMMAND_MODULES, and each of those runs on a lower layer."""
    from asg.cli import COMMAND_MODULES

    probe = tmp_path / "probe.py"
    probe.write_text('import importlib\nimportlib.import_module("asg.cli")\n')
    assert _imports(probe) == {"asg.cli"}
    upward = [c.module for c in COMMAND_MODULES if LAYERS[_part(c.module)] >= LAYERS["cli"]]
    assert not upward, upward


def test_no_import_cycle_even_inside_a_folder():
    """Modules of one folder may import each other, but never round in a circle (asg.search ->
    search.loop -> search.space -> asg.search, through a ``from . import spaces``, was one)."""
    assert _cycles(_module_graph()) == []


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def _floor_diagram() -> list[list[str]]:
    """docs/architecture.md's floor diagram, top floor first: the parts of asg each line names (a
    folder ``io/``, a module ``cli``, a wing ``generator/`` for all its parts)."""
    import re

    text = (ROOT.parent / "docs" / "architecture.md").read_text(encoding="utf-8")
    block = text.split("## The floors", 1)[1].split("```", 2)[1]
    floors = []
    for line in block.strip("\n").splitlines():
        if not line.strip() or line.startswith(" "):  # a floor's description continued
            continue
        names = re.split(r"\s{2,}", line.strip(), maxsplit=1)[0]
        floors.append([n.strip().rstrip("/") for n in re.split(r"[,\s]+", names) if n.strip()])
    return floors


def _layers_of(name: str) -> list[float]:
    """The layers of a part the diagram names: a wing's are all its modules'."""
    if name in WINGS:
        return [v for k, v in LAYERS.items() if k.startswith(f"{name}.")]
    return [LAYERS[name]] if name in LAYERS else []


def test_the_floor_diagram_agrees_with_the_layers():
    """Every part of LAYERS is on a floor of docs/architecture.md's diagram, and no floor is drawn
    above one that holds a part wholly above it (a wing spans the layers of its modules)."""
    floors = _floor_diagram()
    named = {n for floor in floors for n in floor}
    top_level = {p.split(".")[0] for p in LAYERS} - {"__init__", "__main__", "entry", "cli_args", "schemas", "interrupts",
                                                     "progress", "dataset_spec", "metrics", "evaluation", "datasets"}
    assert top_level <= named | {"registry"}, f"parts missing from the diagram: {sorted(top_level - named)}"
    wrong = []
    for i, upper in enumerate(floors):
        for lower in floors[i + 1:]:
            for a in upper:
                for b in lower:
                    la, lb = _layers_of(a), _layers_of(b)
                    if la and lb and max(la) < min(lb):
                        wrong.append(f"{a} (layers {min(la)}-{max(la)}) drawn above {b} ({min(lb)}-{max(lb)})")
    assert not wrong, "\n".join(wrong)
