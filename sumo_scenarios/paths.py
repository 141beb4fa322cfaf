"""Where the project's data folders are: ``nets/`` and ``configs/`` beside the packages.

``ASG_HOME`` overrides the root (for an installed copy used outside the repository).
"""
from __future__ import annotations

import os
from pathlib import Path


def project_root() -> Path:
    env = os.environ.get("ASG_HOME")
    if env:
        return Path(env)
    return Path(__file__).resolve().parent.parent


def nets_dir() -> Path:
    return project_root() / "nets"


def configs_dir() -> Path:
    return project_root() / "configs"
