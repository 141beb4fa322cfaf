"""asg: adversarial scene generation for cooperative V2X LiDAR perception (V2XP-ASG on SUMO)."""
import os as _os
from typing import MutableMapping as _MutableMapping

__version__ = "0.1.0"

# How torch's OpenMP threads wait for work, read by the OpenMP runtime (GNU's, in torch's wheels)
# when torch loads, so set before any asg module imports torch; a value the user set (even empty:
# the runtime's default) is kept. Spinning threads take the cores a shared machine's other
# processes need (CI, a laptop, a cluster node, asg's own workers): under the runtime's default
# (3 ms of spinning) inference beside a busy process ran 8-20x slower. Threads that sleep at once
# (PASSIVE) wake too late for a frame's hundreds of small parallel steps: two threads then ran an
# AttFuse frame no faster than one. So they spin a short while (GOMP_SPINCOUNT, about 10 us),
# then sleep (docs/results/speed.md, "Beside a busy process").
#: the user's own OMP_WAIT_POLICY and GOMP_SPINCOUNT (None: unset)
USER_OMP_WAIT_POLICY = _os.environ.get("OMP_WAIT_POLICY")
USER_GOMP_SPINCOUNT = _os.environ.get("GOMP_SPINCOUNT")
#: asg's spin count before a waiting thread sleeps (GNU OpenMP counts about 100 spins a microsecond)
SHORT_SPIN_COUNT = "1000"
if USER_OMP_WAIT_POLICY is None:
    _os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
    if USER_GOMP_SPINCOUNT is None:
        _os.environ["GOMP_SPINCOUNT"] = SHORT_SPIN_COUNT


def spin_waiting_threads(env: _MutableMapping[str, str]) -> None:
    """Set ``env`` (``os.environ``, or a child's copy of it) for work that owns its cores
    (OpenCOOD's models: their forward and trainer ran 5-7x slower under PASSIVE): OpenMP's waiting
    threads spin (ACTIVE, without asg's short spin count), unless the user set the policy (even
    empty), which stands."""
    if USER_OMP_WAIT_POLICY is not None:
        env["OMP_WAIT_POLICY"] = USER_OMP_WAIT_POLICY
        return
    env["OMP_WAIT_POLICY"] = "ACTIVE"
    if USER_GOMP_SPINCOUNT is None:
        env.pop("GOMP_SPINCOUNT", None)
