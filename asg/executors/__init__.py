"""Executors for batch commands: local worker processes or a Ray cluster (see base.py)."""
from ..registry import import_modules
from .base import EXECUTORS, Executor, Job, WorkerLost, apply_threads, build_executor, default_workers

import_modules(__name__, __path__)  # each module registers its executor: a new one adds no import line

__all__ = ["EXECUTORS", "Executor", "Job", "WorkerLost", "apply_threads", "build_executor", "default_workers"]
