"""YAML written by PyYAML's full dumper from numpy values, read back as plain data without
constructing a Python object.

OpenCOOD's trainer saves its ``config.yaml`` by ``yaml.dump`` of the parsed settings, which writes
numpy arrays (``grid_size``) and scalars under Python tags; V2V4Real's frame yaml files hold numpy
arrays (``lidar_pose``, a 4 x 4 matrix) the same way. PyYAML's safe loader refuses those tags, its
full loader calls whatever function a tag names. :func:`add_numpy_data` teaches a safe loader the
exact shapes numpy's pickling protocol gives (``_reconstruct`` with an ndarray state, ``scalar``,
``dtype``) and decodes their bytes with ``numpy.frombuffer``: an array becomes nested lists, a
scalar a Python number. Only boolean, integer and float dtypes are read; any other Python tag, any
other function name and any other argument shape stays a ``ConstructorError``. Nothing named by a
tag is imported or called.

:func:`add_opencood_floats` teaches a loader the other rule OpenCOOD's ``load_yaml`` adds to PyYAML:
a float needs no dot (``1e-10`` is a number, where YAML 1.1 reads a string). OpenCOOD reads its
hypes and every frame yaml of a recording with it.
"""
from __future__ import annotations

import math
import re

import numpy as np
import yaml
from yaml.constructor import ConstructorError

#: the most elements one array may hold (the largest array either source writes has 16)
MAX_ARRAY_ELEMENTS = 100_000
#: numpy's module of ``_reconstruct`` and ``scalar``: ``numpy.core`` before NumPy 2, ``numpy._core`` after
_MODULES = ("numpy.core.multiarray", "numpy._core.multiarray")
_RECONSTRUCT = {f"{m}._reconstruct" for m in _MODULES}
_SCALAR = {f"{m}.scalar" for m in _MODULES}
_DTYPE_CODE = re.compile(r"[biuf][1248]")
_APPLY = "tag:yaml.org,2002:python/object/apply:"
_NAME = "tag:yaml.org,2002:python/name:"
_TUPLE = "tag:yaml.org,2002:python/tuple"


class _Ndarray:
    """What ``!!python/name:numpy.ndarray`` stands for: a marker, never the class itself."""


def _refuse(node, why: str) -> ConstructorError:
    return ConstructorError(None, None, f"{node.tag}: {why}; only numpy's boolean, integer and float data is read",
                            node.start_mark)


def _construct_name(loader, suffix: str, node):
    if suffix != "numpy.ndarray":
        raise _refuse(node, "a Python name other than numpy.ndarray")
    return _Ndarray


def _construct_tuple(loader, node):
    return tuple(loader.construct_sequence(node, deep=True))


def _apply_parts(loader, node) -> tuple[list, object]:
    """(args, state) of an ``object/apply`` node, in either of the two forms PyYAML writes."""
    if isinstance(node, yaml.SequenceNode):
        return list(loader.construct_sequence(node, deep=True)), None
    if not isinstance(node, yaml.MappingNode):
        raise _refuse(node, "not a call's arguments")
    value = loader.construct_mapping(node, deep=True)
    if set(value) - {"args", "state"}:
        raise _refuse(node, f"keys {sorted(map(str, value))}, where numpy's data has args and state")
    return list(value.get("args", ())), value.get("state")


def _dtype(node, args: list, state) -> np.dtype:
    """numpy's ``dtype(code, False, True)`` with its state ``(3, byte order, None, ...)``."""
    if (len(args) != 3 or not isinstance(args[0], str) or not _DTYPE_CODE.fullmatch(args[0])
            or args[1:] != [False, True]):
        raise _refuse(node, f"dtype arguments {args!r}")
    if not (isinstance(state, tuple) and len(state) == 8 and state[1] in ("<", ">", "|", "=")
            and state[2:5] == (None, None, None)):
        raise _refuse(node, "a dtype state other than a plain byte order (a structured or sub-array dtype)")
    return np.dtype(args[0]).newbyteorder(state[1])


def _array(node, args: list, state):
    """numpy's ``_reconstruct(ndarray, (0,), b'b')`` with state ``(1, shape, dtype, fortran, bytes)``,
    as nested lists (a 0-d array as its number)."""
    if len(args) != 3 or args[0] is not _Ndarray or args[1] != (0,) or args[2] not in (b"b", "b"):
        raise _refuse(node, "an array rebuilt from other arguments than numpy's own")
    if not (isinstance(state, tuple) and len(state) == 5 and isinstance(state[1], tuple)
            and isinstance(state[2], np.dtype) and isinstance(state[3], bool) and isinstance(state[4], bytes)):
        raise _refuse(node, "an array state other than (version, shape, dtype, fortran order, bytes)")
    shape = state[1]
    if not all(isinstance(n, int) and not isinstance(n, bool) and 0 <= n <= MAX_ARRAY_ELEMENTS for n in shape):
        raise _refuse(node, f"array shape {shape!r}")
    count = math.prod(shape)
    if count > MAX_ARRAY_ELEMENTS:
        raise _refuse(node, f"an array of {count} elements (at most {MAX_ARRAY_ELEMENTS})")
    if len(state[4]) != count * state[2].itemsize:
        raise _refuse(node, f"{len(state[4])} bytes for {count} elements of {state[2].itemsize} bytes")
    values = np.frombuffer(state[4], dtype=state[2]).reshape(shape, order="F" if state[3] else "C")
    return _finite(node, values.tolist())


def _scalar(node, args: list, state):
    """numpy's ``scalar(dtype, bytes)`` as a Python number."""
    if state is not None or len(args) != 2 or not isinstance(args[0], np.dtype) or not isinstance(args[1], bytes):
        raise _refuse(node, "a scalar rebuilt from other arguments than a dtype and its bytes")
    if len(args[1]) != args[0].itemsize:
        raise _refuse(node, f"{len(args[1])} bytes for one value of {args[0].itemsize}")
    return _finite(node, np.frombuffer(args[1], dtype=args[0])[0].item())


def _finite(node, value):
    flat = np.asarray(value, dtype=float).ravel() if not isinstance(value, (bool, int)) else ()
    if len(flat) and not np.isfinite(flat).all():
        raise _refuse(node, "a non-finite number")
    return value


def _construct_apply(loader, suffix: str, node):
    args, state = _apply_parts(loader, node)
    if suffix == "numpy.dtype":
        return _dtype(node, args, state)
    if suffix in _RECONSTRUCT:
        return _array(node, args, state)
    if suffix in _SCALAR:
        return _scalar(node, args, state)
    raise _refuse(node, "a call other than numpy's array, scalar or dtype")


#: OpenCOOD's float resolver (``opencood.hypes_yaml.yaml_utils.load_yaml``): YAML 1.1's floats and
#: those written without a dot (``1e-10``, ``-2E5``)
OPENCOOD_FLOAT = re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
    |\.[0-9_]+(?:[eE][-+][0-9]+)?
    |[-+]?[0-9][0-9_]*(?::[0-5]?[0-9])+\.[0-9_]*
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""", re.X)


def add_opencood_floats(loader: type) -> type:
    """Teach ``loader`` (a subclass of PyYAML's SafeLoader or CSafeLoader) OpenCOOD's float rule,
    in place, on a resolver table of its own (PyYAML's loaders keep theirs); returns it."""
    loader.yaml_implicit_resolvers = {k: list(v) for k, v in loader.yaml_implicit_resolvers.items()}
    loader.add_implicit_resolver("tag:yaml.org,2002:float", OPENCOOD_FLOAT, list("-+0123456789."))
    return loader


def add_numpy_data(loader: type) -> type:
    """Teach ``loader`` (a subclass of PyYAML's SafeLoader or CSafeLoader) numpy's data tags, in
    place; returns it. Its other tags are untouched, so every other Python tag is still refused."""
    loader.add_multi_constructor(_APPLY, _construct_apply)
    loader.add_multi_constructor(_NAME, _construct_name)
    loader.add_constructor(_TUPLE, _construct_tuple)
    return loader
