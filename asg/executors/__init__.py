"""Executors for batch commands: local worker processes or a Ray cluster (see base.py)."""
from . import local, ray_executor  # noqa: F401  (their registration fills EXECUTORS)
from .base import EXECUTORS, Executor, Job, WorkerLost, apply_threads, build_executor, default_workers

__all__ = ["EXECUTORS", "Executor", "Job", "WorkerLost", "apply_threads", "build_executor", "default_workers"]
