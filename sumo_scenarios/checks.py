"""Checks for values read from files a user hands in: every number finite and in range, every id a
safe file name, every polyline long enough. Each failure is an InputError naming where it is.
"""
from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from .errors import InputError

#: coordinates further than this from a net's origin (m) are refused: SUMO nets are offset to the
#: origin, so anything larger is a corrupt or hostile file (and breaks collision checking)
MAX_COORD_M = 1.0e6
#: largest sizes accepted from a file (m): a long articulated truck, a tall RSU pole
SIZE_LIMITS_M = {"length_m": 30.0, "width_m": 5.0, "height_m": 20.0}
#: ground heights beyond this (m) are refused (SUMO nets with elevation stay far inside it)
MAX_ABS_Z_M = 10_000.0
#: a LiDAR's settings a file may give (a preset, a recording's protocol), (lowest, highest): the
#: largest any sensor sold has, with room; beyond them a sweep's rays would not fit in memory
LIDAR_LIMITS = {"channels": (1, 512), "points_per_s": (1_000.0, 1.0e8), "rotation_hz": (1.0, 100.0),
                "returns_per_ring": (16, 16_384), "range_m": (1.0, 1000.0), "elevation_deg": (-90.0, 90.0)}
#: 540 km/h either way: faster is not traffic (a negative speed is a vehicle backing up, as
#: highway-env's do when stopped close behind another)
MAX_SPEED_MPS = 150.0

#: ids that become file or folder names: letters, digits and ``_ - . # : +``, not starting with a dot
_SAFE_ID = re.compile(r"[A-Za-z0-9_\-#:+][A-Za-z0-9_.\-#:+]{0,127}")
#: a class label (a vehicle's type): no whitespace and none of the characters SUMO refuses in a
#: type id (``| \\ ' " ; , < > &``), at most 128 characters; empty: no type given
_LABEL = re.compile(r"[^\s|\\'\";,<>&]{0,128}")


def number(value: Any, where: str, lo: float = -math.inf, hi: float = math.inf, *, lo_open: bool = False) -> float:
    """``value`` as a float, refused unless it is a finite number with ``lo <= value <= hi``
    (``lo < value`` when ``lo_open``)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"{where}: expected a number, got {value!r}")
    try:
        v = float(value)
    except OverflowError:  # an integer too large for a float (hundreds of digits)
        raise InputError(f"{where}: {str(value)[:20]}... ({len(str(value))} digits) is out of range") from None
    if not math.isfinite(v):
        raise InputError(f"{where}: {v} is not a finite number")
    if v < lo or v > hi or (lo_open and v <= lo):
        low = f"above {lo:g}" if lo_open else f"at least {lo:g}"
        raise InputError(f"{where}: {v:g} is out of range (must be {low} and at most {hi:g})")
    return v


def coordinate(value: Any, where: str) -> float:
    return number(value, where, -MAX_COORD_M, MAX_COORD_M)


def points_xy(value: Any, where: str, min_points: int) -> np.ndarray:
    """A polyline or polygon ``[[x, y], ...]`` as an (N, 2) float array, with N >= ``min_points``
    and every coordinate finite and within MAX_COORD_M."""
    try:
        xy = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{where}: expected a list of [x, y] points, got {str(value)[:60]}") from None
    except OverflowError:
        raise InputError(f"{where}: a coordinate is an integer too large for a number; check the file") from None
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise InputError(f"{where}: expected a list of [x, y] points, got shape {xy.shape}")
    if len(xy) < min_points:
        raise InputError(f"{where}: needs at least {min_points} points, got {len(xy)}")
    if not np.all(np.isfinite(xy)) or np.abs(xy).max() > MAX_COORD_M:
        raise InputError(f"{where}: a coordinate is not finite or beyond {MAX_COORD_M:g} m")
    return xy


def is_safe_id(text: str) -> bool:
    """Could ``text`` be a file or folder name in a folder of ours (see :func:`safe_id`)?"""
    return bool(_SAFE_ID.fullmatch(text))


def safe_id(value: Any, where: str) -> str:
    """An id that may become a file or folder name: refused if it could leave its folder
    (``/``, ``..``, an absolute path), is hidden, empty, over 128 characters or has other characters."""
    if value is None or isinstance(value, bool):
        raise InputError(f"{where}: id {value!r} is not a name; give the id as text")
    text = str(value)
    if not is_safe_id(text):  # the whole text: "$" would accept a final newline
        raise InputError(f"{where}: id {text[:60]!r} is not a safe name (letters, digits and _ - . # : + "
                         f"only, at most 128, not starting with a dot); rename it")
    return text


def is_label(text: str) -> bool:
    """Could ``text`` be a vehicle type's name in SUMO and in the files asg writes (see :func:`label`)?"""
    return bool(_LABEL.fullmatch(text))


def label(value: Any, where: str) -> str:
    """A vehicle type's name as text, refused if SUMO could not take it as a type id (whitespace,
    ``| \\ ' " ; , < > &``) or it is over 128 characters; empty is no type (a car-like mesh)."""
    text = "" if value is None else str(value)
    if isinstance(value, bool) or not is_label(text):
        raise InputError(f"{where}: type {text[:60]!r} is not a type name (no spaces or | \\ ' \" ; , < > &, "
                         "at most 128 characters); rename it")
    return text


def inside(root: Path, path: Path, why: str = "would be written outside {root}; check the ids in the input") -> Path:
    """``path``, refused unless it resolves inside folder ``root`` (no write may leave it; no read
    of a source may leave it through a link): ``why`` (with ``{root}``) says so in the one line."""
    r, p = Path(root).resolve(), Path(path).resolve()
    if p != r and r not in p.parents:
        raise InputError(f"{path}: {why.format(root=root)}")
    return path


def output_dir(out: Path, flag: str = "--out") -> Path:
    """Create the output folder ``out`` (and its parents); one InputError for a file in the way, a
    symbolic link to nowhere, or a place that cannot hold a folder (read-only, /proc, no permission)."""
    out = Path(out)
    if out.is_symlink() and not out.exists():
        raise InputError(f"{flag} {out}: a symbolic link to a missing folder ({os.readlink(out)}); give a folder")
    if out.exists() and not out.is_dir():
        raise InputError(f"{flag} {out} is a file; give a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise InputError(f"{flag} {out}: a part of the path is a file; give a folder") from None
    except OSError as exc:
        raise InputError(f"{flag} {out}: cannot create it ({exc.strerror}); give a writable folder") from None
    return out
