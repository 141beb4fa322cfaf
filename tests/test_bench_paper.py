"""`asg bench paper --workers N`: the scenes run in parallel workers give the table a sequential
run gives (each scene is seeded on its own). Slow: it builds the normal set."""
import pytest

from asg.benchmarks.paper import bench_paper
from asg.executors import build_executor


@pytest.mark.exhaustive
def test_parallel_workers_give_the_sequential_table(tmp_path):
    one = bench_paper(tmp_path / "one", scenes=2, budget=3)
    with build_executor("local", 2) as two_workers:
        two = bench_paper(tmp_path / "two", scenes=2, budget=3, executor=two_workers)
    strip = lambda r: {k: {m: v[m] for m in ("normal", "after_acs", "challenging", "scenes")} for k, v in r["table"].items()}
    assert strip(one) == strip(two)
    assert set(one["table"]) == {"attention-bo", "attention-ga", "attention-rs", "random-bo", "off-bo", "off-ga", "off-rs"}


@pytest.mark.parametrize("table", ["", ",", "main,main", "main,nope", " "])
def test_a_bad_table_list_is_refused_before_anything_is_written(table, capsys, tmp_path):
    from test_cli import assert_one_line_error, run

    code, err = run(capsys, "bench", "paper", "--table", table, "--scenes", "1", "--out", str(tmp_path / "o"))
    assert code == 2
    assert_one_line_error(err, "--table: an empty value" if not table.strip() else "give distinct names of")
    assert not (tmp_path / "o").exists()


def test_bench_paper_under_proc_is_one_line(capsys):
    from test_cli import assert_one_line_error, run

    code, err = run(capsys, "bench", "paper", "--scenes", "1", "--out", "/proc/asg-bench")
    assert code == 2
    assert_one_line_error(err, "--out")
