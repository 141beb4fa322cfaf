"""The frame an export writes the ego's view in, so that each stack's stock configuration keeps
every vehicle in range.

OpenCOOD's ground-truth range and OpenPCDet's point-cloud range are fixed boxes around the ego's
LiDAR that keep z in [-3, 1] m: they assume a sensor on a car's roof (OPV2V's LiDAR is 1.9 m above
the ground). Seen from an RSU's pole (4.5 m up) or a truck's roof, a car's centre lies near z = -3.8
m, and both stacks dropped every box. An ego sensor more than LOWER_ABOVE_M above the ground is
therefore written in a frame STANDARD_SENSOR_HEIGHT_M above the ground below it: its points and
boxes raised by the difference, its LiDAR pose lowered by it (OPV2V), the difference recorded
(docs/export.md). Every transform stays exact; only the origin's height is a convention.
"""
from __future__ import annotations

# the height above the ground of the frame the ego view is written in (m): OPV2V's vehicle LiDAR, one
# of the layout's conventions (asg.scene.recording), where an import reads a lowered view back
from ..scene.recording import STANDARD_SENSOR_HEIGHT_M
#: an ego sensor higher than this above the ground (an RSU, a truck's or bus's roof) is lowered
LOWER_ABOVE_M = 2.4


def ego_frame_drop_m(sensor_z_m: float, ground_z_m: float) -> float:
    """How far below the sensor (m, >= 0) the ego view's frame is put: its height above the
    ground minus STANDARD_SENSOR_HEIGHT_M if it stands higher than LOWER_ABOVE_M, else 0."""
    height_m = float(sensor_z_m) - float(ground_z_m)
    return round(height_m - STANDARD_SENSOR_HEIGHT_M, 6) if height_m > LOWER_ABOVE_M else 0.0
