"""docs/experiments: each script still compiles, and every name it imports from the package exists
and is public (no leading underscore: a script uses what a user could, so a refactoring of the
internals does not break it silently)."""
import ast
import importlib.util
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


def test_ap_bootstrap_builds_any_shipped_fusion_named_before_a_weights_path(monkeypatch):
    """``NAME=FUSION:weights.pt`` loads the weights into that shipped network (attfuse-wide too);
    ``NAME=weights.pt`` into AttFuse's; a bare name is the shipped model."""
    spec = importlib.util.spec_from_file_location("ap_bootstrap", SCRIPTS[0].parent / "ap_bootstrap.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    monkeypatch.setattr(script, "build_detector", lambda fusion, weights_file=None: (fusion, weights_file))
    built = script.build_models(["hw=attfuse-wide:run/round-1/weights.pt", "ft=run/weights.pt",
                                 "e=early:w.pt", "late"])
    assert built == {"hw": ("attfuse-wide", "run/round-1/weights.pt"), "ft": ("attfuse", "run/weights.pt"),
                     "e": ("early", "w.pt"), "late": ("late", None)}


def test_the_tables_index_lists_every_table_file():
    """docs/results/tables/README.md names every JSON of the folder (an index that cannot drift)."""
    root = Path(__file__).resolve().parent.parent / "docs" / "results" / "tables"
    index = (root / "README.md").read_text()
    missing = [str(f.relative_to(root)) for f in root.rglob("*.json") if f"]({f.relative_to(root)})" not in index]
    assert not missing, missing
