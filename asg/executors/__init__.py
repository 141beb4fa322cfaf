"""Executors for batch commands: local worker processes or a Ray cluster (see base.py)."""
from . import local, ray_executor  # noqa: F401  (fill the registry)
from .base import Executor, Job, WorkerLost, apply_threads, build_executor, default_workers

__all__ = ["Executor", "Job", "WorkerLost", "apply_threads", "build_executor", "default_workers"]
