"""Where the project's data folders are: ``nets/`` and ``configs/`` (and ``runs/`` for outputs).

In a checkout (or an editable install) they sit beside the packages. An installed wheel carries
them as data files under ``PREFIX/share/asg/`` (pyproject.toml's data-files), and its outputs go
to ``./runs`` of the working folder. The user's own towns (``asg towns import``) live in
``ASG_HOME/towns`` (``ASG_HOME`` when set, else the platform's user data folder), never inside the
package or the checkout.
"""
from __future__ import annotations

import os
import site
import sys
from pathlib import Path

#: the folder name of the installed data files under a prefix's ``share/``
SHARE_NAME = "asg"


def _checkout_root() -> Path | None:
    root = Path(__file__).resolve().parent.parent
    return root if (root / "configs").is_dir() and (root / "nets").is_dir() else None


def _installed_roots() -> list[Path]:
    """Where pip puts data files: the environment's prefix, then the user base (``--user``)."""
    return [Path(sys.prefix) / "share" / SHARE_NAME, Path(site.getuserbase()) / "share" / SHARE_NAME]


def project_root() -> Path:
    """The folder holding ``configs/`` and ``nets/``."""
    checkout = _checkout_root()
    if checkout is not None:
        return checkout
    for root in _installed_roots():
        if (root / "configs").is_dir():
            return root
    return Path(__file__).resolve().parent.parent  # nothing found: errors will name this path


def runs_dir() -> Path:
    """Default root of outputs (data sets, training runs): ``runs/`` of a checkout, else of the
    working folder."""
    checkout = _checkout_root()
    return (checkout if checkout is not None else Path.cwd()) / "runs"


def nets_dir() -> Path:
    return project_root() / "nets"


def user_home() -> Path:
    """The user's asg folder: ``ASG_HOME`` when set, else the platform's user data folder
    (``~/.local/share/asg`` on Linux)."""
    env = os.environ.get("ASG_HOME")
    if env:
        return Path(env)
    import platformdirs

    return Path(platformdirs.user_data_dir("asg", appauthor=False))


def user_towns_dir() -> Path:
    """Where ``asg towns import`` writes the user's towns (``NAME.net.xml`` + ``NAME.poly.xml``)."""
    return user_home() / "towns"


def configs_dir() -> Path:
    return project_root() / "configs"
