"""The C allocator keeps a frame's freed memory for the next (asg.perception.allocator)."""
from __future__ import annotations

import subprocess
import sys

import pytest

from asg.perception.allocator import keep_freed_memory

#: a subprocess that allocates, touches and frees a frame's worth of large tensors, round after
#: round, and prints the page faults of the rounds after the first
_ROUNDS = """
import resource, sys, torch
if sys.argv[1] == "keep":
    from asg.perception.allocator import keep_freed_memory
    assert keep_freed_memory()
def frame():
    maps = [torch.empty(3 * 2 ** 18).fill_(1.0) for _ in range(8)]  # 8 blocks of 3 MiB
    return sum(float(m[-1]) for m in maps)
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
    """24 MiB of tensors allocated and freed 20 times: without the setting glibc gives much of
    it back and the rounds fault pages in again (6,900-13,000 faults in the 20 rounds on the
    machine this was written on); with it the pages stay (768, the same in four runs)."""
    for name in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_", "MALLOC_MMAP_MAX_", "GLIBC_TUNABLES"):
        monkeypatch.delenv(name, raising=False)
    if not sys.platform.startswith("linux") or _mallopt_missing():
        pytest.skip("glibc's malloc only")
    assert _faults("keep") < 3000


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
