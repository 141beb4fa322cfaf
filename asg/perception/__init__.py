"""V2X detectors: PointPillars with No / Late / Early / AttFuse fusion (the only torch user in asg)."""
from .numerics import flush_subnormals_in_all_threads

flush_subnormals_in_all_threads()  # before any parallel torch operation starts the thread pool

from .fusion import V2XDetector, build_detector, check_fusion, check_weights_file, detector_names  # noqa: E402

__all__ = ["V2XDetector", "build_detector", "check_fusion", "check_weights_file", "detector_names"]
