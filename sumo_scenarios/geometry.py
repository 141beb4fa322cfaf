"""Plane geometry every layer shares: angles wrapped to one turn and the gap between two headings.

Angles are radians, counter-clockwise from +x (SUMO's own angle convention is converted in
fcd.py). Functions take a float or a numpy array (any shape) and return the same kind.
"""
from __future__ import annotations

import math
from typing import TypeVar

import numpy as np

Angle = TypeVar("Angle", float, np.ndarray)


def wrap_rad(angle_rad: Angle) -> Angle:
    """``angle_rad`` turned by whole turns into (-pi, pi]."""
    if isinstance(angle_rad, np.ndarray):
        return np.pi - np.mod(np.pi - angle_rad, 2.0 * np.pi)
    return math.pi - (math.pi - angle_rad) % (2.0 * math.pi)


def heading_gap_rad(a_rad: Angle, b_rad: Angle) -> Angle:
    """The unsigned angle between two headings, in [0, pi]."""
    return abs(wrap_rad(a_rad - b_rad))
