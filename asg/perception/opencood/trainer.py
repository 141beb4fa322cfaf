"""OpenCOOD's own trainer (``opencood/tools/train.py``, unmodified) on asg's exported scenes: a model
folder seeded from a trained one (its config with new data folders and more epochs, its latest
checkpoint), then trained in a child process (``python -m asg.perception.opencood.trainer DIR``:
asg's runtime preparation, runtime.py, which ``python -m opencood.tools.train`` lacks, then the
trainer). The trainer saves ``net_epochN.pth`` after each epoch and, run again on the folder,
resumes from the highest N (its optimizer restarts, as OpenCOOD's own resume does).

The child runs with ``OMP_WAIT_POLICY=ACTIVE`` (unless the user set the variable): threads that
sleep at once (``PASSIVE``; asg's own default, asg/__init__.py, spins only 10 us) made OpenCOOD's
trainer 5.1x slower (35.2 s a step against 6.8 s for its AttFuse, depths 1, 2, 2, batch 2, two
threads, 2-core AVX2 machine; docs/experiments/opencood_step_time.py): its many small parallel
regions each wake sleeping threads. A
training run owns the cores it runs on.

OpenCOOD's trainer writes each checkpoint in place: a Ctrl-C or a crash during its ``torch.save``
would leave a truncated ``net_epochN.pth`` that the resume then fails to load. In the child every
``torch.save`` to a path goes through a temporary file renamed into place (:func:`atomic_checkpoints`),
and the temporary files an interrupted run left are removed before the trainer starts.

opencoodx 0.1.19's datasets take a scenario's first agent folder in string order as its ego, so a
collaborating RSU (folder ``-1``) is read as the ego instead of ours (``0``); OpenCOOD's later
releases move one leading negative folder to the end, the rule asg's OPV2V export is numbered for.
The child trains with that rule (:func:`rsu_never_ego`), so that every scenario trains its own ego's
view. It reads OpenCOOD's yaml files by libyaml under a safe loader (:func:`libyaml_reading`):
OpenCOOD's pure-Python parse of each agent's yaml was most of its data loading's time. AttFuse's
fusion computes the ego's row of its attention alone (:func:`ego_row_attention`): the same function,
without the batched tiny matrix products that took most of a training step on CPU.
"""
from __future__ import annotations

import os
import runpy
import shutil
import subprocess
import sys
from pathlib import Path

import yaml

import asg
from sumo_scenarios.atomic import atomic_path, remove_stale_partials, write_text_atomic
from sumo_scenarios.errors import InputError

from .folder import LibyamlHypesLoader, checkpoint_of, plain_hypes, read_hypes
from .runtime import module, opencood

#: the trainer's log in a model folder (appended to: a resumed run adds to it)
TRAIN_LOG = "train.log"


def epoch_of(checkpoint: Path) -> int:
    """N of ``net_epochN.pth``; 1 for ``latest.pth`` (seeded as ``net_epoch1.pth``: OpenCOOD's trainer
    takes a ``latest.pth`` as epoch 100 and would train no further)."""
    digits = checkpoint.stem.removeprefix("net_epoch")
    return int(digits) if checkpoint.stem.startswith("net_epoch") and digits.isdigit() else 1


def seed_from(model_dir: Path, source: Path, train: Path, val: Path, more_epochs: int) -> None:
    """A new ``model_dir`` from the trained folder ``source``: its config (``root_dir`` and
    ``validate_dir`` replaced, ``more_epochs`` added to its epochs) and its checkpoint; nothing done
    if ``model_dir`` already has a config (a resumed fine-tuning)."""
    if (model_dir / "config.yaml").is_file():
        return
    read_hypes(source)  # one line for a folder OpenCOOD's adapter would refuse
    last = checkpoint_of(source)
    hypes = plain_hypes(source / "config.yaml")
    hypes.update(root_dir=str(Path(train).resolve()), validate_dir=str(Path(val).resolve()))
    epoch = epoch_of(last)
    hypes["train_params"]["epoches"] = epoch + more_epochs
    model_dir.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(last, model_dir / f"net_epoch{epoch}.pth")
    write_text_atomic(model_dir / "config.yaml", yaml.safe_dump(hypes, sort_keys=False))


def run_trainer(model_dir: Path) -> None:
    """OpenCOOD's ``tools/train.py --hypes_yaml model_dir/config.yaml --model_dir model_dir`` in a
    child process (module docstring), its output appended to ``model_dir/train.log``; InputError
    (one line, naming the log) if it fails."""
    env = dict(os.environ)
    asg.spin_waiting_threads(env)
    command = [sys.executable, "-m", __name__, str(model_dir)]
    with open(model_dir / TRAIN_LOG, "a", buffering=1) as log:
        code = subprocess.run(command, env=env, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL).returncode
    if code:
        raise InputError(f"OpenCOOD's trainer stopped with exit code {code}; its log: {model_dir / TRAIN_LOG}")


def ego_row_attention() -> None:
    """OpenCOOD's ``AttFusion`` class computes by the ego's row of its attention (asg/perception/
    opencood/attention.py: the same function and gradients, without the batched tiny products that
    took most of a training step on CPU). The checkpoints are OpenCOOD's as ever."""
    from .attention import attfusion_type, ego_row_forward

    attfusion_type().forward = ego_row_forward


def atomic_checkpoints() -> None:
    """``torch.save`` to a path writes a temporary file beside it and renames it into place
    (sumo_scenarios.atomic), so that the checkpoint OpenCOOD's trainer saves is whole or absent; a
    save to an open file object is left as it was. The temporary name starts with a dot, which
    OpenCOOD's resume (``glob('*epoch*.pth')``) never picks."""
    import torch

    save = torch.save

    def save_atomically(obj, f, *args, **kwargs):
        if not isinstance(f, (str, os.PathLike)):
            return save(obj, f, *args, **kwargs)
        with atomic_path(f) as tmp:
            save(obj, tmp, *args, **kwargs)

    torch.save = save_atomically


def rsu_never_ego() -> None:
    """OpenCOOD's ``BaseDataset`` with its later releases' ego rule: after its own ``__init__``, a
    scenario whose first agent id is negative (an RSU) has that agent moved to the end and the ego
    flag on the new first agent, as ``basedataset.py`` orders ``cav_list`` since (a leading RSU goes
    last). Scenarios without a leading RSU are left as they are."""
    base = module("data_utils.datasets.basedataset").BaseDataset
    if getattr(base.__init__, "rsu_never_ego", False):
        return
    init = base.__init__

    def __init__(self, *args, **kwargs):
        init(self, *args, **kwargs)
        for agents in self.scenario_database.values():
            order = list(agents)
            if len(order) > 1 and order[0].startswith("-") and order[0][1:].isdigit():
                agents[order[0]]["ego"], agents[order[1]]["ego"] = False, True
                agents.move_to_end(order[0])

    __init__.rsu_never_ego = True
    base.__init__ = __init__


def libyaml_reading() -> None:
    """OpenCOOD's ``load_yaml`` (every agent's yaml of every training example, and the config)
    parsed by libyaml under a safe loader with OpenCOOD's float resolver (``folder.HypesLoader``'s
    rules): the same dicts from asg's exports, 5.8x faster (21 ms against 123 ms a file of the
    exported detector-train set, docs/experiments/opencood-yaml-time.json), no Python object built
    from a tag (OpenCOOD's own uses PyYAML's full ``Loader``), and no float resolver added to
    PyYAML's ``Loader`` on every call (OpenCOOD's does, one more each file). Its ``yaml_parser`` is
    looked up by name in ``yaml_utils``, where OpenCOOD evaluates the string. PyYAML built without
    libyaml parses in Python under the same safe rules."""
    utils = module("hypes_yaml.yaml_utils")
    original = utils.load_yaml
    if getattr(original, "libyaml", False):
        return
    module("data_utils.datasets")  # its modules import load_yaml by name: loaded now, patched below

    def load_yaml(file, opt=None):
        if opt and opt.model_dir:
            file = os.path.join(opt.model_dir, "config.yaml")
        with open(file, "r") as stream:
            param = yaml.load(stream, Loader=LibyamlHypesLoader)
        if "yaml_parser" in param:
            param = getattr(utils, param["yaml_parser"])(param)
        return param

    load_yaml.libyaml = True
    for name, mod in list(sys.modules.items()):  # the modules that imported it by name
        if name.startswith("opencood") and getattr(mod, "load_yaml", None) is original:
            mod.load_yaml = load_yaml


def _train(model_dir: Path) -> None:
    """The child's work: asg's runtime preparation, then OpenCOOD's trainer on ``model_dir``."""
    opencood()  # box_overlaps compiled, get_cmap restored: the trainer imports as shipped
    remove_stale_partials(model_dir)  # what a killed save left; no other writer works in the folder
    atomic_checkpoints()
    rsu_never_ego()
    libyaml_reading()
    ego_row_attention()
    sys.argv = ["opencood.tools.train", "--hypes_yaml", str(model_dir / "config.yaml"), "--model_dir", str(model_dir)]
    runpy.run_module("opencood.tools.train", run_name="__main__")


if __name__ == "__main__":
    _train(Path(sys.argv[1]))
