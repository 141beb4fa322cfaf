"""Ctrl-C to the process group while a two-worker ``asg generate``'s workers start: how often a
worker prints a traceback beside the command's one line.

    ASG_DATA=... .venv/bin/python docs/experiments/ctrl_c_while_workers_start.py N

Each of N runs waits until the two workers exist, then 0-1.25 s (in 0.25 s steps, in turn) more,
sends SIGINT to the group and checks: exit 130, one line on stderr, no traceback.
"""
import os
import pathlib
import signal
import subprocess
import sys
import tempfile
import time

import psutil

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
from test_robustness import _write, _scene_dict
tmp = pathlib.Path(tempfile.mkdtemp())
scenes = tmp / "scenes"
for i in range(2):
    _write(scenes, _scene_dict(f"s{i}"))
bad = 0
n = int(sys.argv[1])
for k in range(n):
    out = tmp / f"out{k}"
    argv = [sys.executable, "-m", "asg", "generate", "--scenes", str(scenes), "--out", str(out), "--fusion", "none",
            "--search", "rs", "--acs", "random", "--budget", "150", "--workers", "2"]
    def fg():
        os.setpgrp(); signal.signal(signal.SIGINT, signal.SIG_DFL)
    p = subprocess.Popen(argv, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, cwd=ROOT, preexec_fn=fg)
    while len(psutil.Process(p.pid).children()) < 2 and p.poll() is None:
        time.sleep(0.01)
    time.sleep(0.25 * (k % 6))
    os.killpg(p.pid, signal.SIGINT)
    _, err = p.communicate(timeout=60)
    lines = [l for l in err.splitlines() if l.strip()]
    ok = p.returncode in (130, -2) and len(lines) == 1 and "Traceback" not in err
    bad += not ok
    print(k, 0.25 * (k % 6), p.returncode, len(lines), "ok" if ok else "BAD: " + err[-300:].replace("\n", " | "), flush=True)
print("bad", bad, "of", n)
