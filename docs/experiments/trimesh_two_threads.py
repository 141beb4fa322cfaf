"""Threads casting through one TrimeshCaster at once, as World's static views do with backend trimesh.

    python docs/experiments/trimesh_two_threads.py CASTERS THREADS [--prebuilt]

Each of CASTERS casters (200 random boxes) is cast by THREADS threads at the same time (2,000
rays each), then dropped. Exit 0 and "done" when every cast ran; before TrimeshCaster cast one call
at a time, two threads corrupted the heap through trimesh's R-tree (libspatialindex) and the
process died (exit -11 / -6) when the garbage collector freed an index. ``--prebuilt`` builds
the R-tree before the threads start (shows the concurrent queries, not the build, are the fault).
"""
import sys
import threading

import numpy as np

from asg.sensors.raycast import TrimeshCaster


def main(casters: int, threads: int, prebuilt: bool) -> None:
    rng = np.random.default_rng(0)
    square = np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 0], [1, 1, 0], [0, 1, 0]]], dtype=float)
    for i in range(casters):
        caster = TrimeshCaster(np.concatenate([square + rng.normal(0, 6, 3) for _ in range(200)]))
        if prebuilt:
            caster._ray.mesh.triangles_tree  # noqa: B018 (builds and caches the R-tree)
        dirs = rng.normal(size=(2000, 3))
        dirs /= np.linalg.norm(dirs, axis=1)[:, None]
        origins = np.zeros((2000, 3))
        workers = [threading.Thread(target=caster.first_hits, args=(origins, dirs)) for _ in range(threads)]
        for w in workers:
            w.start()
        for w in workers:
            w.join()
        if i % 10 == 0:
            print(i, flush=True)
    print("done")


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]), "--prebuilt" in sys.argv[3:])
