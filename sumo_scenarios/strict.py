"""Strict loading of frozen dataclasses from YAML mappings.

An unknown or misspelled key is an error that names the key and the keys that are allowed;
a value of the wrong type is an error that names the key and the expected type.
"""
from __future__ import annotations

import dataclasses
import enum
import math
import re
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

import yaml

from .errors import InputError

T = TypeVar("T")

_BaseLoader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class StrictLoader(_BaseLoader):  # type: ignore[misc, valid-type]
    """PyYAML's safe loader (its C parser where installed) that refuses what a hand-written file
    should not hold: an alias (``*name``: a few lines of nested aliases expand to gigabytes once
    the value is used) and a key written twice in one mapping (the later one silently won)."""

    def construct_object(self, node, deep=False):
        if node in self.constructed_objects or node in self.recursive_objects:
            raise InputError(f"line {node.start_mark.line + 1}: YAML aliases (*name) are not accepted; "
                             "write the value out")
        return super().construct_object(node, deep)

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for key_node, _ in node.value:
                key = (key_node.tag, key_node.value) if isinstance(key_node, yaml.ScalarNode) else None
                if key is not None and key in seen:
                    raise InputError(f"line {key_node.start_mark.line + 1}: key {key_node.value!r} is written twice; "
                                     "keep one")
                seen.add(key)
        return super().construct_mapping(node, deep)


class ConfigLoader(StrictLoader):
    """:class:`StrictLoader` that also reads YAML 1.2's floats without a dot (``1e30``, ``-2E-3``),
    which YAML 1.1 (PyYAML) takes for strings: a config's ``lr: 1e-3`` is a number."""


ConfigLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"))


def load_strict_yaml(text: str, loader: type = StrictLoader) -> Any:
    """``text`` parsed by ``loader`` (StrictLoader or ConfigLoader); InputError for what it refuses."""
    return yaml.load(text, Loader=loader)


#: the largest YAML file asg reads (bytes): a scene with its town's lanes is well under a megabyte
MAX_YAML_BYTES = 64 * 1024 * 1024


def check_yaml_size(path: Path) -> Path:
    """``path``, refused (InputError naming it) if the file is larger than MAX_YAML_BYTES: a file
    that size is none asg or a user wrote, and reading and parsing it would take the memory."""
    if path.stat().st_size > MAX_YAML_BYTES:
        raise InputError(f"{path}: larger than {MAX_YAML_BYTES >> 20} MB, which no settings or scene file is; "
                         "check the path")
    return path


def read_yaml(path: str | Path) -> Any:
    """Parse a YAML file; a missing, oversized or malformed file is an InputError naming it."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: file not found; check the path")
    check_yaml_size(p)
    try:
        return load_strict_yaml(p.read_text(encoding="utf-8"), ConfigLoader)
    except InputError as exc:
        raise InputError(f"{p}: {exc}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark is not None else ""
        raise InputError(f"{p}: not valid YAML{where}; fix the syntax") from None
    except UnicodeDecodeError:
        raise InputError(f"{p}: not UTF-8 text; save it as UTF-8") from None
    except OSError as exc:
        raise InputError(f"{p}: cannot be read ({exc.strerror}); check its permissions") from None
    except ValueError as exc:  # an integer of more digits than Python converts (its int_max_str_digits)
        raise InputError(f"{p}: a number is out of range ({str(exc).split(';')[0]}); fix the file") from None


def _check_value(value: Any, hint: Any, where: str) -> Any:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if hint is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        for option in args:
            try:
                return _check_value(value, option, where)
            except InputError:
                continue
        raise InputError(f"{where}: {value!r} is not one of {', '.join(_name(a) for a in args)}")
    if hint is type(None):
        if value is None:
            return None
        raise InputError(f"{where}: expected nothing (null), got {value!r}")
    if origin is typing.Literal:
        if value in args:
            return value
        raise InputError(f"{where}: {value!r} is not one of {', '.join(repr(a) for a in args)}")
    if dataclasses.is_dataclass(hint):
        return from_mapping(hint, value, where)
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise InputError(f"{where}: expected a list, got {value!r}")
        if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
            return tuple(_check_value(v, args[0], f"{where}[{i}]") for i, v in enumerate(value))
        if origin is tuple and args:
            if len(args) != len(value):
                raise InputError(f"{where}: expected {len(args)} values, got {len(value)}")
            return tuple(_check_value(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
        item = args[0] if args else Any
        return origin(_check_value(v, item, f"{where}[{i}]") for i, v in enumerate(value))
    if origin is dict:
        if not isinstance(value, dict):
            raise InputError(f"{where}: expected a mapping, got {value!r}")
        kt, vt = args if args else (Any, Any)
        return {_check_value(k, kt, where): _check_value(v, vt, _child(where, k)) for k, v in value.items()}
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(f"{where}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise InputError(f"{where}: {value} is not a finite number")
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise InputError(f"{where}: expected a whole number, got {value!r}")
        return value
    if hint in (str, bool):
        if not isinstance(value, hint):
            raise InputError(f"{where}: expected {_name(hint)}, got {value!r}")
        return value
    if isinstance(hint, type) and issubclass(hint, enum.Enum):
        try:
            return hint(value)
        except ValueError:
            raise InputError(f"{where}: {value!r} is not one of {', '.join(repr(m.value) for m in hint)}") from None
    return value


def _child(where: str, key: Any) -> str:
    """Where a key sits: ``file.yaml: key`` at a file's top, ``outer.key`` below."""
    return f"{where}: {key}" if where.endswith((".yaml", ".yml")) else f"{where}.{key}"


def _name(hint: Any) -> str:
    return getattr(hint, "__name__", str(hint))


def from_mapping(cls: type[T], data: Any, where: str = "config") -> T:
    """Build dataclass ``cls`` from ``data``; unknown keys and wrong types raise InputError."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise InputError(f"{where}: expected a mapping of keys to values, got {data!r}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise InputError(
            f"{where}: unknown key '{unknown[0]}'; allowed keys: {', '.join(sorted(fields))}"
        )
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for name, f in fields.items():
        if name in data:
            kwargs[name] = _check_value(data[name], hints[name], _child(where, name))
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise InputError(f"{where}: missing key '{name}'; add it")
    return cls(**kwargs)


def load_dataclass(cls: type[T], path: str | Path, section: str | None = None) -> T:
    """Read YAML file ``path`` (optionally one top-level ``section``) into dataclass ``cls``."""
    data = read_yaml(path)
    where = str(path)
    if section is not None:
        if not isinstance(data, dict) or section not in data:
            raise InputError(f"{path}: missing section '{section}'; add it")
        data = data[section]
        where = f"{path}:{section}"
    return from_mapping(cls, data, where)
