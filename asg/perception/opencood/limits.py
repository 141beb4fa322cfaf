"""What OpenCOOD's post-processor never outputs, whatever its model detects.

``VoxelPostprocessor.post_process`` (the call ``tools/inference.py`` makes) drops, before its NMS,
every box whose corners span more than 6 m along x or y (``box_utils.remove_large_pred_bbx``) or
reach below -3 m or above 1 m in the ego frame (``box_utils.remove_bbx_abnormal_z``): OPV2V's
vehicles are cars. asg's traffic also has trucks and buses (sumo_scenarios/vehicles.py); those an
OpenCOOD model cannot report count as misses, under both yardsticks, as in OpenCOOD's own evaluation.
Which vehicle types that hits is asked of OpenCOOD's own two functions, not restated here.
"""
from __future__ import annotations

import numpy as np

from sumo_scenarios.vehicles import VEHICLE_TYPES

from ...sensors.ego_frame import STANDARD_SENSOR_HEIGHT_M
from .runtime import module

#: headings tried for each vehicle type (rad): along an axis and diagonal, where the span is largest
#: for a long box (its length) and for a square one
HEADINGS_RAD = (0.0, np.pi / 4)


def kept_by_post_processor(boxes: np.ndarray) -> np.ndarray:
    """(K,) bool: whether OpenCOOD's post-processor keeps each of ``boxes`` (K, 7) x, y, z (centre),
    l, w, h, yaw in OpenCOOD's ego frame (the exported one: its origin at the ego's sensor, lowered
    to 1.9 m above the ground when the sensor stands higher), by its own ``remove_large_pred_bbx``
    and ``remove_bbx_abnormal_z``."""
    import torch

    box_utils = module("utils.box_utils")
    corners = box_utils.boxes_to_corners_3d(torch.as_tensor(np.asarray(boxes, dtype=np.float32)), order="lwh")
    keep = torch.logical_and(box_utils.remove_large_pred_bbx(corners), box_utils.remove_bbx_abnormal_z(corners))
    return keep.numpy().astype(bool)


def dropped_vehicle_types() -> list[str]:
    """The ids of asg's vehicle types (sumo_scenarios.vehicles.VEHICLE_TYPES) that OpenCOOD's
    post-processor drops at some heading: a box of the type's size standing on the ground of the
    exported ego frame, at each of HEADINGS_RAD."""
    rows = [(t.type_id, [0.0, 0.0, t.height_m / 2 - STANDARD_SENSOR_HEIGHT_M, t.length_m, t.width_m, t.height_m, yaw])
            for t in VEHICLE_TYPES for yaw in HEADINGS_RAD]
    keep = kept_by_post_processor(np.array([box for _, box in rows]))
    return sorted({type_id for (type_id, _), kept in zip(rows, keep) if not kept},
                  key=[t.type_id for t in VEHICLE_TYPES].index)


def post_processor_note() -> str:
    """One line for a user scoring an OpenCOOD model on asg's scenes ('' if nothing is dropped)."""
    dropped = dropped_vehicle_types()
    if not dropped:
        return ""
    return (f"OpenCOOD's post-processor drops every box over 6 m long or reaching outside z -3..1 m "
            f"(remove_large_pred_bbx, remove_bbx_abnormal_z): vehicles of type {' and '.join(dropped)} are never "
            "detected and count as misses (docs/opencood.md#what-opencoods-post-processor-drops)")
