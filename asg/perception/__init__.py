"""V2X detectors: the shipped PointPillars fusion models (fusion/), detector plugins, OpenCOOD model
folders (opencood/), each a kind of target (targets/), their networks and weights."""
from .allocator import keep_freed_memory
from .numerics import flush_subnormals_in_all_threads

flush_subnormals_in_all_threads()  # before any parallel torch operation starts the thread pool
keep_freed_memory()  # a frame's large tensors reuse the last frame's memory instead of fresh pages

from .fusion import V2XDetector  # noqa: E402
from .targets import build_detector, check_fusion, check_weights_file, detector_names, resolve_target  # noqa: E402

__all__ = ["V2XDetector", "build_detector", "check_fusion", "check_weights_file", "detector_names", "resolve_target"]
