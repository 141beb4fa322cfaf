"""The package reads top-down: every import (also one inside a function) goes to a lower layer.

Layers, lowest first: settings and registries; the scene; the stages (sensors, objective, search,
collaborators); perception (networks and detectors) and the executors; data sets and the
generator's settings; the pipeline (one scene); outputs (io); the generator; the workflows; the
benchmarks; the command line. A new module has to be given its layer here, which is the point: a
test that fails when an arrow runs upward."""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent / "asg"

#: each part of asg (a sub-package, or a module directly in asg/) and its layer
LAYERS = {
    "__init__": 0, "registry": 0, "dataset_spec": 0, "progress": 0,
    "scene": 1,
    "sensors": 2, "objective": 2, "search": 2, "collaborators": 2,
    "metrics": 3, "perception": 3, "executors": 3,
    "datasets": 4, "generator_config": 4, "cli_args": 4,
    "pipeline": 5,
    "io": 6,
    "generate": 7,
    "workflows": 8,
    "benchmarks": 9,
    "generate_cmd": 10,
    "commands": 11,
    "cli": 12,
    "entry": 13, "__main__": 14,
}


def _part(module: str) -> str:
    """``asg.perception.fusion.attfuse`` -> ``perception``; ``asg`` -> ``__init__``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _imports(path: Path) -> set[str]:
    """The asg modules that ``path`` imports (absolute names), anywhere in the file."""
    package = path.relative_to(ROOT.parent).with_suffix("").parts[:-1]  # a module's package, or the package itself
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = list(package[:len(package) - (node.level - 1)])
                target = ".".join(base + ([node.module] if node.module else []))
                out |= {target} if node.module else {f"{target}.{a.name}" for a in node.names}
            elif node.module:
                out.add(node.module)
    return {m for m in out if m == "asg" or m.startswith("asg.")}


def test_every_part_of_the_package_has_a_layer():
    parts = {p.stem if p.parent == ROOT else p.relative_to(ROOT).parts[0] for p in ROOT.rglob("*.py")}
    assert parts <= set(LAYERS), f"give these a layer in LAYERS: {sorted(parts - set(LAYERS))}"


def test_no_import_runs_upward_or_sideways():
    upward = []
    for path in sorted(ROOT.rglob("*.py")):
        here = path.stem if path.parent == ROOT else path.relative_to(ROOT).parts[0]
        for module in _imports(path):
            there = _part(module)
            if there != here and there in LAYERS and LAYERS[there] >= LAYERS[here]:
                upward.append(f"{path.relative_to(ROOT.parent)} imports {module} ({here} {LAYERS[here]} -> "
                              f"{there} {LAYERS[there]})")
    assert not upward, "\n".join(upward)


def test_the_checker_resolves_relative_imports_inside_functions(tmp_path):
    """The checker itself: a function-level ``from ..x import y`` two packages down is resolved."""
    assert "asg.dataset_spec" in _imports(ROOT / "scene" / "history.py")
    assert {"asg.io.run_record", "asg.executors"} <= _imports(ROOT / "generate.py")
