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


VEHICLE = '<vehicle id="v1" x="1.0" y="2.0" angle="90.0" type="car" speed="3.0" lane="e_0"/>'
BAD_VEHICLES = {
    '<vehicle id="v1" x="nan" y="2.0"/>': "x nan is not a finite number",
    '<vehicle id="v1" x="1e300" y="2.0"/>': "x 1e+300 is out of range",
    '<vehicle id="v1" y="2.0"/>': "no x",
    '<vehicle id="v1" x="abc" y="2.0"/>': "x 'abc' is not a number",
    '<vehicle x="1.0" y="2.0"/>': "a vehicle without an id",
    '<vehicle id="../../evil" x="1.0" y="2.0"/>': "not a safe name",
    '<vehicle id="v1" x="1.0" y="2.0" speed="1e9"/>': "speed 1e+09 is out of range",
    '<vehicle id="v1" x="1.0" y="2.0" angle="-inf"/>': "angle -inf is not a finite number",
    '<vehicle id="v1" x="1.0" y="2.0" type="a b&lt;c"/>': "its type 'a b<c' is not a type name",
}


@pytest.mark.parametrize("bad", sorted(BAD_VEHICLES))
def test_a_vehicle_with_a_bad_attribute_is_refused_in_one_line_naming_it(bad, tmp_path):
    """A log is a file a user hands in: the reader refuses what a scene could not hold (an id that
    is no safe file name, a type SUMO could not take back, a number that is missing, not finite or
    out of range), naming the vehicle
    and the time, instead of a traceback or a scene that cannot be loaded again."""
    path = tmp_path / "fcd.xml"
    path.write_text(f'<fcd-export><timestep time="0.00">{VEHICLE}</timestep>'
                    f'<timestep time="0.50">{VEHICLE}{bad}</timestep></fcd-export>')
    frames = read_fcd(path)
    assert next(frames).vehicles[0].vehicle_id == "v1"  # the frames before it are read
    with pytest.raises(InputError, match="at time 0.5: ") as exc:
        next(frames)
    assert BAD_VEHICLES[bad] in str(exc.value) and str(path) in str(exc.value)


def test_a_timestep_without_a_time_is_refused(tmp_path):
    path = tmp_path / "fcd.xml"
    path.write_text(f'<fcd-export><timestep time="soon">{VEHICLE}</timestep></fcd-export>')
    with pytest.raises(InputError, match="time 'soon' is not a time in seconds"):
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
