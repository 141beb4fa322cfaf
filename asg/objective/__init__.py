"""The adversarial objective: rotated BEV IoU, AP, weighted AP loss."""
from .ap import AP_KEYS, REPORTED_THRESHOLDS, ap_at, ap_text, average_precision, both_yardsticks
from .iou import bev_iou_matrix
from .loss import ObjectiveConfig, adversarial_loss

__all__ = ["AP_KEYS", "ObjectiveConfig", "REPORTED_THRESHOLDS", "adversarial_loss", "ap_at", "ap_text", "both_yardsticks",
           "average_precision", "bev_iou_matrix"]
