"""A built wheel runs on its own: weights, configs and towns travel with it (not only with ``pip -e``)."""
import json
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _run(*args, cwd=None) -> str:
    proc = subprocess.run([str(a) for a in args], capture_output=True, text=True, cwd=cwd)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout


@pytest.mark.slow
def test_wheel_installs_into_a_fresh_venv_and_runs_from_any_folder(tmp_path):
    src = tmp_path / "src"  # a copy of what the wheel is built from: the build leaves nothing in the checkout
    for name in ("asg", "sumo_scenarios", "nets", "configs"):
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    _run(sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", src, "-w", tmp_path / "dist")
    (wheel,) = (tmp_path / "dist").glob("asg-*.whl")
    venv = tmp_path / "venv"
    _run(sys.executable, "-m", "venv", "--without-pip", venv)
    python = venv / "bin" / "python"
    _run(sys.executable, "-m", "pip", "--python", python, "install", "-q", "--no-deps", wheel)
    # the dependencies (torch, SUMO, ...) from this environment, but not its editable asg: a plain
    # path entry, whose .pth files (the editable finder) are not processed
    purelib = Path(_run(python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))").strip())
    (purelib / "deps.pth").write_text(sysconfig.get_path("purelib") + "\n")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    where = _run(python, "-c", "import asg, sumo_scenarios.paths as p; print(asg.__file__); print(p.configs_dir())",
                 cwd=elsewhere).split()
    assert where[0].startswith(str(venv)) and where[1].startswith(str(venv)), where
    towns = json.loads(_run(venv / "bin" / "asg", "towns", "list", "--json", cwd=elsewhere))
    assert {"fiveleg", "grid_small"} <= {t["name"] for t in towns}
    loaded = _run(python, "-c", "from asg.generator.config import load_generate_config; "
                  "from asg.perception import build_detector; "
                  "print(load_generate_config().fusion, type(build_detector('attfuse')).__name__, "
                  "load_generate_config(protocol='paper').space.dyaw_step_deg)", cwd=elsewhere)
    assert loaded.split() == ["attfuse", "AttFuseDetector", "15.0"]  # the named protocols travel too
