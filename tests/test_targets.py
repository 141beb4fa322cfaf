"""Targets: a ``--fusion`` name resolved once into an object of its kind, which callers ask; no
module outside the target registry tells the kinds apart by their names."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from asg.perception.fusion import FUSIONS
from asg.perception.targets import TARGET_KINDS, Training, detector_names, resolve_target
from sumo_scenarios.errors import InputError

ROOT = Path(__file__).resolve().parent.parent


def test_each_name_goes_to_its_kind(tmp_path):
    assert resolve_target("attfuse").kind == "shipped" and resolve_target("attfuse").training is Training.ASG
    folder = resolve_target(f"opencood:{tmp_path}")  # its form alone: nothing loaded yet
    assert folder.kind == "opencood" and folder.training is Training.OPENCOOD and folder.prefixed
    assert resolve_target("attfuse") == resolve_target("attfuse") != resolve_target("none")
    assert set(TARGET_KINDS.names()) == {"shipped", "plugin", "opencood"}
    with pytest.raises(InputError, match="unknown fusion 'nope'; known: .*attfuse.*opencood:DIR"):
        resolve_target("nope")


def test_a_shipped_name_wins_over_a_plugin_of_the_same_name(monkeypatch):
    import asg.perception.targets.plugin as plugin

    monkeypatch.setattr(plugin, "plugin_names", lambda: ["attfuse", "toy-x"])
    assert resolve_target("attfuse").kind == "shipped"
    assert resolve_target("toy-x").kind == "plugin"
    assert "toy-x" in detector_names() and detector_names()[-1] == "opencood:DIR"


def test_what_each_kind_answers():
    """A shipped model without attention borrows AttFuse's; a plugin's wrapper answers for itself;
    only a shipped model has a shipped entry (the others: the one line naming who trains them)."""
    none = resolve_target("none")
    assert not none.own_attention and none.borrows_attention and none.shipped_weights == FUSIONS.entry("none").weights
    assert resolve_target("attfuse").own_attention and resolve_target("attfuse").label == "attfuse"
    assert resolve_target("attfuse").shipped_entry() is FUSIONS.entry("attfuse")
    assert resolve_target("attfuse").run_record() == {} and resolve_target("attfuse").evaluation_note() == ""
    with pytest.raises(InputError, match="OpenCOOD's own trainer trains it"):
        resolve_target("opencood:x").shipped_entry()


def test_a_weights_file_given_to_a_target_that_loads_its_own_is_refused(tmp_path):
    with pytest.raises(InputError, match="--weights applies to the shipped models"):
        resolve_target(f"opencood:{tmp_path}").check(weights_file=str(tmp_path / "w.pt"))


#: the spellings that tell target kinds apart by name; only the target registry may hold them
KIND_BRANCHES = re.compile(r"is_opencood|[\"']opencood:[\"']|\bin FUSIONS\b(?!\.)|startswith\([\"']opencood:")


def test_no_module_outside_the_target_registry_branches_on_a_targets_kind():
    allowed = {ROOT / "asg" / "registry.py"} | set((ROOT / "asg" / "perception" / "targets").glob("*.py"))
    found = [f"{p.relative_to(ROOT)}:{n}" for p in sorted((ROOT / "asg").rglob("*.py")) if p not in allowed
             for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1) if KIND_BRANCHES.search(line)]
    assert not found, found


def test_the_detector_a_weights_check_built_is_handed_over_once(tmp_path, monkeypatch):
    """A shipped model's check of a weights file keeps its detector for the next caller with that
    file (the file read once a command); the caller after that, or after the file changed, reads it."""
    import os
    import shutil

    from asg.perception import weights_io

    target = resolve_target("early")
    mine = str(tmp_path / "mine.pt")
    shutil.copy(weights_io.weights_path(target.shipped_weights), mine)
    reads = []
    load_state = weights_io.load_state
    monkeypatch.setattr(weights_io, "load_state",
                        lambda model, path, *a, **k: reads.append(str(path)) or load_state(model, path, *a, **k))
    target.check(mine)
    first = resolve_target("early").detector(mine)
    assert reads.count(mine) == 1
    assert resolve_target("early").detector(mine) is not first and reads.count(mine) == 2
    target.check(mine)
    os.utime(mine, ns=(1, 1))  # the file changed since its check: read again
    assert target.detector(mine) is not first and reads.count(mine) == 4
    target.check(mine)
    resolve_target("early").detector()  # the shipped weights: another file
    resolve_target("early").detector(mine, cfg=first.cfg)  # other settings: its own detector
    assert reads.count(mine) == 6
    assert target.detector(mine) is not first and reads.count(mine) == 6  # the checked one, still there
