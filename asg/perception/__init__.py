"""V2X detectors: PointPillars with No / Late / Early / AttFuse fusion (the only torch user in asg)."""
from .fusion import V2XDetector, build_detector, check_fusion, check_weights_file, detector_names

__all__ = ["V2XDetector", "build_detector", "check_fusion", "check_weights_file", "detector_names"]
