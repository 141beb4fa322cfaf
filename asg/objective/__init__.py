"""The adversarial objective: rotated BEV IoU, AP, weighted AP loss."""
from .ap import ap_at, average_precision
from .iou import bev_iou_matrix
from .loss import ObjectiveConfig, adversarial_loss

__all__ = ["ObjectiveConfig", "adversarial_loss", "ap_at", "average_precision", "bev_iou_matrix"]
