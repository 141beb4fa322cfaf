"""Write files so that a crash or Ctrl-C never leaves a half-written one behind.

Every writer writes to a temporary name in the same folder, then renames it into place
(``os.replace`` is atomic on POSIX within one file system).
"""
from __future__ import annotations

import contextlib
import errno
import os
import secrets
import shutil
from pathlib import Path
from typing import Iterator

from .errors import InputError


@contextlib.contextmanager
def atomic_path(final_path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``final_path``; on success rename it into place, else delete it.

    The temporary name keeps the final suffixes (``.xml.gz`` stays ``.xml.gz``) so that tools
    choosing a format by file name (SUMO, numpy) behave as for the final name.
    """
    final = Path(final_path)
    if final.is_dir():
        raise InputError(f"{final} is a folder where a file is to be written; give a file name")
    suffix = "".join(final.suffixes)
    tmp: Path | None = None
    try:
        try:
            final.parent.mkdir(parents=True, exist_ok=True)
            while tmp is None:  # named before it exists: whenever a signal's exception comes, the finally knows it
                tmp = final.parent / f".{final.stem}.{secrets.token_hex(6)}.tmp{suffix}"
                try:
                    os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))  # the umask applies
                except FileExistsError:  # another writer's: not ours to remove
                    tmp = None
        except _NO_PLACE as exc:
            tmp = None
            raise _no_place(final, "file", exc) from None
        yield tmp
        os.replace(tmp, final)
    except OSError as exc:
        raise _naming(exc, final) from None
    finally:
        if tmp is not None and tmp.exists():
            tmp.unlink()


#: what making a file or folder raises where the path itself is wrong (a file in its way, a place
#: that holds none): bad input, one line; a full disk or a refusal stays an OSError (the CLI names it)
_NO_PLACE = (FileExistsError, NotADirectoryError, IsADirectoryError, FileNotFoundError)


def _no_place(final: Path, what: str, exc: OSError) -> InputError:
    why = "a part of the path is a file" if isinstance(exc, (FileExistsError, NotADirectoryError)) else exc.strerror
    return InputError(f"{final}: no {what} can be made there ({why}); give a writable folder")


def write_text_atomic(final_path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``final_path`` atomically."""
    with atomic_path(final_path) as tmp:
        tmp.write_text(text, encoding="utf-8")


@contextlib.contextmanager
def atomic_dir(final_dir: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary folder beside ``final_dir``; on success move its files into ``final_dir``.

    Files already in ``final_dir`` with other names are kept; files of the same name are replaced
    one by one with ``os.replace``. On error the temporary folder is removed. A ``final_dir`` that
    is a file, or beside which no folder can be made, is an InputError before any work.
    """
    final = Path(final_dir)
    if final.exists() and not final.is_dir():
        raise InputError(f"{final} is a file where a folder is to be written; give a folder")
    tmp: Path | None = None
    try:
        try:
            final.parent.mkdir(parents=True, exist_ok=True)
            while tmp is None:  # named before it exists (see atomic_path)
                tmp = final.parent / f".{final.name}.{secrets.token_hex(6)}.tmp"
                try:
                    os.mkdir(tmp, 0o777)  # the umask applies
                except FileExistsError:
                    tmp = None
        except _NO_PLACE as exc:
            tmp = None
            raise _no_place(final, "folder", exc) from None
        yield tmp
        final.mkdir(parents=True, exist_ok=True)
        for item in sorted(tmp.iterdir()):
            target = final / item.name
            if target.is_dir() and not target.is_symlink():
                shutil.rmtree(target)
            os.replace(item, target)
    except OSError as exc:
        raise _naming(exc, final) from None
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


#: errno values of a write that a full disk or quota cut short, or that the file system refused
_FULL_OR_REFUSED = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG}


def _naming(exc: OSError, final: Path) -> OSError:
    """``exc`` naming the file it was writing: a short write (numpy's "N requested and M written",
    which carries no errno) as the full disk it is, a full disk or quota without a file name with
    ``final``'s; any other error as it was."""
    if exc.errno is None and "requested and" in str(exc) and "written" in str(exc):
        return OSError(errno.ENOSPC, f"No space left on device (the write was cut short: {exc})", str(final))
    if exc.errno in _FULL_OR_REFUSED and not exc.filename:
        return OSError(exc.errno, exc.strerror, str(final))
    return exc


def is_partial(name: str) -> bool:
    """Is ``name`` one of the temporary names above (``.NAME.XXXX.tmp...``)?"""
    return name.startswith(".") and ".tmp" in name


def remove_stale_partials(folder: str | os.PathLike) -> int:
    """Remove the temporary files and folders that an interrupted writer left in ``folder``
    (not below it); returns how many. Call it only where no other writer is at work."""
    folder = Path(folder)
    if not folder.is_dir():
        return 0
    stale = [p for p in folder.iterdir() if is_partial(p.name)]
    for p in stale:
        shutil.rmtree(p, ignore_errors=True) if p.is_dir() and not p.is_symlink() else p.unlink(missing_ok=True)
    return len(stale)


def remove_stale_partials_of(final: str | os.PathLike) -> None:
    """Remove what an interrupted :func:`atomic_dir` write of folder ``final`` left beside it
    (``.NAME.XXXX.tmp``); other names are kept."""
    final = Path(final)
    if final.parent.is_dir():
        for p in final.parent.glob(f".{final.name}.*.tmp"):
            shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
