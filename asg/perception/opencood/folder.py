"""An OpenCOOD model folder read without running its code: ``config.yaml`` parsed by a safe YAML
loader (OpenCOOD's own ``load_yaml`` uses PyYAML's full loader, which builds arbitrary Python
objects, and ``eval``s its ``yaml_parser``), the parser looked up among OpenCOOD's own by name, and
the checkpoint loaded as tensors only (``weights_only``)."""
from __future__ import annotations

import math
import re
from pathlib import Path

import yaml

from sumo_scenarios.errors import InputError
from sumo_scenarios.numpy_yaml import add_numpy_data, add_opencood_floats

from .runtime import module
from .settings import check_settings

#: the dataset classes (OpenCOOD's ``fusion.core_method``) the adapter runs, and how each infers
FUSION_KINDS = {"LateFusionDataset": "late", "EarlyFusionDataset": "early",
                "IntermediateFusionDataset": "intermediate"}
#: OpenCOOD's models the adapter runs (the PointPillars family the paper attacked): model -> has the
#: attention ACS-A reads (AttFuse's self-attention)
MODELS = {"point_pillar": False, "point_pillar_intermediate": True, "point_pillar_fcooper": False,
          "point_pillar_v2vnet": False}
#: OpenCOOD's yaml parsers (``yaml_parser``), looked up by name instead of ``eval``
PARSERS = ("load_voxel_params", "load_point_pillar_params", "load_second_params", "load_bev_params")
#: a config expanding (aliases included) to more values than this is refused
MAX_CONFIG_VALUES = 100_000
#: a config.yaml larger than this is refused before it is parsed (OpenCOOD's stock configs, and the
#: ones its trainer writes with numpy's tags, are a few kB)
MAX_CONFIG_BYTES = 1 << 20
_EPOCH = re.compile(r"net_epoch([0-9]{1,6})\.pth")


class HypesLoader(yaml.SafeLoader):
    """PyYAML's safe loader with OpenCOOD's float resolver (``1e-10`` is a number) and numpy's data
    tags (the arrays and scalars OpenCOOD's trainer dumps into the config.yaml it saves) read as
    plain lists and numbers (:mod:`sumo_scenarios.numpy_yaml`); every other Python tag refused."""


add_numpy_data(add_opencood_floats(HypesLoader))


if getattr(yaml, "__with_libyaml__", False):
    class LibyamlHypesLoader(yaml.CSafeLoader):
        """:class:`HypesLoader`'s rules on libyaml's parser (the same dicts, several times faster)."""

    add_numpy_data(add_opencood_floats(LibyamlHypesLoader))
else:  # PyYAML built without libyaml
    LibyamlHypesLoader = HypesLoader


def plain_hypes(path: Path) -> dict:
    """A hypes yaml as plain dicts, to edit and write again: read by HypesLoader (OpenCOOD's float
    rule), each alias written out so that every value is its own, no ``yaml_parser`` applied.
    Unchecked: read a user's folder through :func:`read_hypes` first."""
    return yaml.safe_load(yaml.safe_dump(yaml.load(Path(path).read_text(encoding="utf-8"), Loader=HypesLoader)))


def stock_hypes(file_name: str) -> dict:
    """OpenCOOD's shipped hypes file ``file_name`` (its ``hypes_yaml`` folder) as :func:`plain_hypes`."""
    return plain_hypes(Path(module("hypes_yaml").__file__).parent / file_name)


def read_hypes(folder: Path) -> dict:
    """``folder/config.yaml`` as OpenCOOD's ``load_yaml`` returns it (its parser applied); InputError
    (one line) for a missing, malformed, oversized or unsupported config."""
    path = folder / "config.yaml"
    if not path.is_file():
        raise InputError(f"{folder}: no config.yaml; an OpenCOOD model folder holds the config.yaml its trainer saved")
    if path.stat().st_size > MAX_CONFIG_BYTES:
        raise InputError(f"{path}: {path.stat().st_size} bytes, more than the {MAX_CONFIG_BYTES} an OpenCOOD "
                         "config can need; not an OpenCOOD config")
    try:
        hypes = yaml.load(path.read_text(encoding="utf-8"), Loader=LibyamlHypesLoader)
    except (yaml.YAMLError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        why = getattr(exc, "problem", None) if isinstance(exc, yaml.constructor.ConstructorError) else None
        raise InputError(f"{path}: not a readable OpenCOOD config ({type(exc).__name__}"
                         f"{': ' + why if why else ''}); fix or re-save it") from None
    if not isinstance(hypes, dict):
        raise InputError(f"{path}: expected a mapping of OpenCOOD's settings")
    _check_size(hypes, path)
    _check_supported(hypes, path)
    check_settings(hypes, path)
    parser = hypes.get("yaml_parser")
    if parser is not None:
        if parser not in PARSERS:
            raise InputError(f"{path}: yaml_parser {parser!r} is not one of OpenCOOD's ({', '.join(PARSERS)})")
        try:
            hypes = getattr(module("hypes_yaml.yaml_utils"), parser)(hypes)
        except (KeyError, TypeError, ValueError, ZeroDivisionError, IndexError) as exc:
            raise InputError(f"{path}: OpenCOOD's {parser} cannot read it ({type(exc).__name__}: {exc}); "
                             "compare it with OpenCOOD's hypes_yaml") from None
    return hypes


def _check_size(value, path: Path) -> None:
    """Refuse a config whose values (aliases expanded) exceed MAX_CONFIG_VALUES, or hold a
    non-finite number."""
    stack, seen = [value], 0
    while stack:
        item = stack.pop()
        seen += 1
        if seen > MAX_CONFIG_VALUES:
            raise InputError(f"{path}: more than {MAX_CONFIG_VALUES} values once its aliases are expanded; "
                             "not an OpenCOOD config")
        if isinstance(item, dict):
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item)
        elif isinstance(item, float) and not math.isfinite(item):
            raise InputError(f"{path}: holds a non-finite number ({item}); fix the config")


def _check_supported(hypes: dict, path: Path) -> None:
    try:
        fusion = hypes["fusion"]["core_method"]
        model = hypes["model"]["core_method"]
        hypes["preprocess"]["cav_lidar_range"], hypes["postprocess"]["anchor_args"]
    except (KeyError, TypeError):
        raise InputError(f"{path}: lacks fusion, model, preprocess or postprocess settings; not an OpenCOOD config") from None
    if not isinstance(fusion, str) or fusion not in FUSION_KINDS:
        raise InputError(f"{path}: fusion {str(fusion)[:60]!r} is not run here; the adapter runs {', '.join(FUSION_KINDS)}")
    if not isinstance(model, str) or model not in MODELS:
        raise InputError(f"{path}: model {str(model)[:60]!r} is not run here (the adapter runs OpenCOOD's PointPillars "
                         f"models: {', '.join(MODELS)})")


def checkpoint_of(folder: Path) -> Path:
    """The checkpoint OpenCOOD's ``load_saved_model`` takes: ``latest.pth``, else the highest
    ``net_epochN.pth``; InputError if there is none."""
    latest = folder / "latest.pth"
    if latest.is_file():
        return latest
    epochs = [(int(m.group(1)), p) for p in folder.iterdir() if (m := _EPOCH.fullmatch(p.name)) and p.is_file()]
    if not epochs:
        raise InputError(f"{folder}: no checkpoint (latest.pth or net_epochN.pth); train the model with OpenCOOD first")
    return max(epochs)[1]


def load_checkpoint(model, path: Path) -> None:
    """Load ``path``'s tensors into ``model`` without unpickling objects; InputError for a file that
    is not a state dict of tensors or does not fit the config's network."""
    import torch

    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types for a corrupt or code-carrying pickle
        raise InputError(f"{path}: not a checkpoint of tensors ({type(exc).__name__}); a checkpoint is loaded "
                         "only as tensors (weights_only), never as pickled objects") from None
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise InputError(f"{path}: not a state dict of tensors; save model.state_dict() as OpenCOOD's trainer does")
    odd = next((k for k, v in state.items() if v.layout is not torch.strided or v.device.type != "cpu"), None)
    if odd is not None:
        raise InputError(f"{path}: tensor {str(odd)[:60]} is {state[odd].layout} on {state[odd].device.type}; a "
                         "checkpoint holds dense tensors on the CPU (torch.save(model.state_dict()))")
    own = model.state_dict()
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    shape = next((k for k in own if k in state and own[k].shape != state[k].shape), None)
    if missing or unexpected or shape:
        what = (f"lacks {missing[0]}" if missing else f"has {unexpected[0]}, which the network has not" if unexpected
                else f"{shape} is {tuple(state[shape].shape)}, the network's {tuple(own[shape].shape)}")
        raise InputError(f"{path}: does not fit the network of its config.yaml ({what}); give the config it was trained with")
    if not all(torch.isfinite(v).all() for v in state.values() if v.is_floating_point()):
        raise InputError(f"{path}: holds non-finite weights; retrain or take an earlier checkpoint")
    model.load_state_dict(state)
