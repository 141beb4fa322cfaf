"""`asg bench paper --jobs N`: the configurations run in parallel workers give the table a
sequential run gives (each configuration is seeded on its own). Slow: it builds the normal set."""
import pytest

from asg.benchmarks.paper import bench_paper


@pytest.mark.slow
def test_parallel_workers_give_the_sequential_table(tmp_path):
    one = bench_paper(tmp_path / "one", scenes=1, budget=3, jobs=1)
    two = bench_paper(tmp_path / "two", scenes=1, budget=3, jobs=2)
    strip = lambda r: {k: {m: v[m] for m in ("normal", "after_acs", "challenging", "scenes")} for k, v in r["table"].items()}
    assert strip(one) == strip(two)
    assert set(one["table"]) == {"attention-bo", "attention-ga", "attention-rs", "random-bo", "off-bo", "off-ga", "off-rs"}
