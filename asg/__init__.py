"""asg: adversarial scene generation for cooperative V2X LiDAR perception (V2XP-ASG on SUMO)."""
import os as _os

__version__ = "0.1.0"

# OpenMP threads (torch's) that wait for work sleep instead of spinning: on a shared machine (CI, a
# laptop, a cluster node, asg's own worker processes) spinning threads take the cores the others
# need, and inference beside a busy process ran 2.5-3.5x slower (docs/results/speed.md). Read by the
# OpenMP runtime when torch loads, so it is set before any asg module imports torch; a value the
# user set (even empty: the runtime's default) is kept.
#: the user's own OMP_WAIT_POLICY (None: unset), for a child process that trains (an OpenCOOD model's
#: trainer spins its waiting threads unless the user chose otherwise: asg/perception/opencood/trainer.py)
USER_OMP_WAIT_POLICY = _os.environ.get("OMP_WAIT_POLICY")
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def spinning_omp_policy() -> str:
    """The wait policy for work that owns its cores (OpenCOOD's models: their forward and trainer
    ran 5-7x slower under PASSIVE): ACTIVE, unless the user set one (even empty), which stands."""
    return "ACTIVE" if USER_OMP_WAIT_POLICY is None else USER_OMP_WAIT_POLICY
