"""The C allocator's freed memory kept for the next frame (glibc's malloc).

A detection allocates and frees the same large tensors frame after frame (a backbone map of one
agent at 96 x 96 x 64 floats is 2.4 MB). glibc's malloc serves large blocks by ``mmap`` and gives
them back to the system when they are freed (and trims the heap's free top), so the next frame's
tensors come in as fresh pages: every 4 KiB page is a page fault and a page the kernel zeroes,
1,000-3,400 faults a frame of AttFuse and 60,000-70,000 of an OpenCOOD model (docs/results/speed.md).
Served from the heap and kept there instead, a freed block is reused as it is. The numbers computed
do not change: only where a tensor's memory comes from (torch aligns it the same way). A process's
peak grew by about 7 % where it was measured (the blocks of the heap fit less tightly than
``mmap``'s), and after its peak it gives back only the heap's free top beyond TRIM_THRESHOLD_BYTES.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os

#: mallopt's parameters (glibc's malloc.h) and the values set: no block served by ``mmap`` (every
#: size from the heap: glibc's largest ``mmap`` threshold, 32 MiB, still left an OpenCOOD model's
#: larger maps 8,000-12,000 faults a frame), and up to 256 MiB of free memory at the heap's top kept
#: rather than given back
M_TRIM_THRESHOLD = -1
M_MMAP_MAX = -4
MMAP_BLOCKS = 0
TRIM_THRESHOLD_BYTES = 256 * 1024 * 1024
#: the environment through which a user tunes glibc's malloc: a setting there stands
_USER_SETTINGS = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_", "MALLOC_MMAP_MAX_")


def keep_freed_memory() -> bool:
    """Have glibc's malloc serve every block from its heap and keep freed ones for reuse (see the module's note);
    False, changing nothing, where the C library is not glibc or the user tuned its malloc
    (``GLIBC_TUNABLES`` with a ``glibc.malloc`` setting, or a ``MALLOC_*_`` variable)."""
    if any(name in os.environ for name in _USER_SETTINGS) or "glibc.malloc" in os.environ.get("GLIBC_TUNABLES", ""):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (macOS, musl): its allocator as it is
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(M_MMAP_MAX, MMAP_BLOCKS)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
