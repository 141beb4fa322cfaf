"""The C allocator keeps a frame's freed memory for the next (asg.perception.allocator)."""
from __future__ import annotations

import subprocess
import sys

import pytest

from asg.perception.allocator import keep_freed_memory

#: a subprocess that allocates, touches and frees a frame's large tensor, round after round, and
#: prints the page faults of the rounds after the first
_ROUNDS = """
import resource, sys, torch
if sys.argv[1] == "keep":
    from asg.perception.allocator import keep_freed_memory
    assert keep_freed_memory()
def frame():
    return float(torch.empty(2 ** 24).fill_(1.0)[-1])  # 64 MiB
frame()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    frame()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(mode: str) -> int:
    out = subprocess.run([sys.executable, "-c", _ROUNDS, mode], capture_output=True, text=True, check=True)
    return int(out.stdout.split()[-1])


def test_a_frames_large_tensors_reuse_the_last_frames_memory(monkeypatch):
    """A 64 MiB tensor allocated, written and freed 20 times: without the setting glibc serves it
    by ``mmap`` (above its largest threshold, 32 MiB) and gives it back, and every round faults its
    16,384 pages in again; with it the pages stay."""
    for name in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_", "MALLOC_MMAP_MAX_", "GLIBC_TUNABLES"):
        monkeypatch.delenv(name, raising=False)
    if not sys.platform.startswith("linux") or _mallopt_missing():
        pytest.skip("glibc's malloc only")
    assert _faults("keep") < 2 * 16_384  # glibc as it is: 20 x 16,384 (327,700 here); with it one round's (16,384)


def _mallopt_missing() -> bool:
    import ctypes

    try:
        ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        return True
    return False


@pytest.mark.parametrize("setting", [("MALLOC_TRIM_THRESHOLD_", "131072"),
                                     ("GLIBC_TUNABLES", "glibc.malloc.mmap_threshold=65536")])
def test_a_users_own_malloc_setting_stands(monkeypatch, setting):
    monkeypatch.setenv(*setting)
    assert keep_freed_memory() is False
