"""docs/experiments: each script still compiles, and every name it imports from the package exists
and is public (no leading underscore: a script uses what a user could, so a refactoring of the
internals does not break it silently)."""
import ast
import importlib
from pathlib import Path

import pytest

SCRIPTS = sorted((Path(__file__).resolve().parent.parent / "docs" / "experiments").glob("*.py"))


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_experiment_imports_resolve(script):
    tree = ast.parse(script.read_text(), str(script))
    compile(tree, str(script), "exec")
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in ("asg", "sumo_scenarios"):
            module = importlib.import_module(node.module)
            for alias in node.names:
                assert not alias.name.startswith("_"), f"{script.name}: imports the private {node.module}.{alias.name}"
                assert hasattr(module, alias.name) or importlib.util.find_spec(f"{node.module}.{alias.name}"), \
                    f"{script.name}: {node.module}.{alias.name} is gone"
