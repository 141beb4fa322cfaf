"""Public metrics: ``average_precision(frames, iou_threshold)`` (see asg.objective.ap)."""
from .objective.ap import ap_at, average_precision
from .objective.iou import bev_iou_matrix

__all__ = ["ap_at", "average_precision", "bev_iou_matrix"]
