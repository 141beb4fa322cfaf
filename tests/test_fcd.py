import gzip
import math

import pytest

from sumo_scenarios.errors import InputError
from sumo_scenarios.fcd import (FcdFrame, FcdVehicle, center_from_front, read_fcd, sumo_angle_from_yaw_rad,
                                write_fcd, yaw_rad_from_sumo_angle)


def test_angle_conventions():
    assert math.isclose(yaw_rad_from_sumo_angle(90.0), 0.0, abs_tol=1e-12)  # east
    assert math.isclose(yaw_rad_from_sumo_angle(0.0), math.pi / 2)  # north
    assert math.isclose(yaw_rad_from_sumo_angle(180.0), -math.pi / 2)  # south
    for a in (0.0, 45.0, 135.0, 270.0, 359.0):
        assert math.isclose(sumo_angle_from_yaw_rad(yaw_rad_from_sumo_angle(a)), a, abs_tol=1e-9)
    assert center_from_front(10.0, 0.0, 0.0, 4.0) == (8.0, 0.0)


def test_fcd_round_trip(tmp_path):
    frames = [FcdFrame(0.5 * i, (FcdVehicle("a", 1.25, 2.5, 0.0, 90.0, "car", 3.5, "e_0"),)) for i in range(3)]
    path = tmp_path / "fcd.xml.gz"
    write_fcd(path, frames)
    assert list(read_fcd(path)) == frames
    assert list(tmp_path.iterdir()) == [path]  # no temporary left
    assert b' z="' not in gzip.decompress(path.read_bytes())  # a flat log leaves z and slope out, as SUMO does


def test_fcd_round_trip_with_elevation(tmp_path):
    frames = [FcdFrame(0.0, (FcdVehicle("a", 1.0, 2.0, 3.5, 90.0, "car", 3.0, "e_0", 1.25),
                             FcdVehicle("b", 4.0, 5.0, 0.0, 0.0, "car", 0.0, "e_1")))]
    path = tmp_path / "fcd.xml.gz"
    write_fcd(path, frames)
    assert list(read_fcd(path)) == frames


def test_truncated_log(tmp_path):
    frames = [FcdFrame(0.5 * i, (FcdVehicle("a", 1.0, 2.0, 0.0, 90.0, "car", 3.0, "e_0"),) * 50) for i in range(200)]
    path = tmp_path / "fcd.xml.gz"
    write_fcd(path, frames)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="truncated or corrupt"):
        list(read_fcd(path))


def test_not_fcd(tmp_path):
    path = tmp_path / "x.xml.gz"
    with gzip.open(path, "wt") as fh:
        fh.write("<routes/>")
    with pytest.raises(InputError, match="not an fcd-output"):
        list(read_fcd(path))


def test_angles_wrap_into_one_turn_alike_for_floats_and_arrays():
    import numpy as np

    from sumo_scenarios.geometry import heading_gap_rad, wrap_rad

    raw = np.array([0.0, math.pi, -math.pi, 3 * math.pi / 2, -3 * math.pi / 2, 7.0, -7.0, 1e3])
    wrapped = wrap_rad(raw)
    assert np.all((wrapped > -math.pi) & (wrapped <= math.pi))
    assert np.allclose(np.exp(1j * wrapped), np.exp(1j * raw))  # the same direction
    assert [wrap_rad(float(a)) for a in raw] == pytest.approx(list(wrapped))
    assert wrap_rad(math.pi) == pytest.approx(math.pi) and wrap_rad(-math.pi) == pytest.approx(math.pi)
    assert heading_gap_rad(math.radians(170), math.radians(-170)) == pytest.approx(math.radians(20))
    assert heading_gap_rad(0.3, 0.3 + 2 * math.pi) == pytest.approx(0.0, abs=1e-12)
