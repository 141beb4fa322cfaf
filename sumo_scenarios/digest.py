"""The sha256 of files a user gave (weights, a model folder's config and checkpoint), read in blocks."""
from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Iterable

from .errors import InputError


def files_digest(paths: Iterable[Path]) -> str:
    """sha256 (hex) of the files' bytes one after the other; InputError if one cannot be read."""
    h = hashlib.sha256()
    for path in paths:
        try:
            with open(path, "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    h.update(block)
        except OSError as exc:
            raise InputError(f"{path}: cannot be read ({exc.strerror}); check its permissions") from None
    return h.hexdigest()


def file_digest(path: Path) -> str:
    """sha256 (hex) of ``path``; InputError if it cannot be read."""
    return files_digest([path])
