"""Executors: the same summary whichever way the scenes run, a killed worker recovered, bad
executor settings one line (exit 2). The fake detector keeps it fast."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from asg.cli import main
from asg.executors import Job, build_executor
from asg.generator.run import run_scenes
from asg.generator.pipeline import GenerateConfig
from asg.search import SpaceConfig

from test_cli import assert_one_line_error, run

ROOT = Path(__file__).resolve().parent.parent
from test_robustness import _scene_dict, _write

CFG = GenerateConfig(fusion="none", search="bo", acs="attention", budget=4, space=SpaceConfig(n_q=100))


def _scenes():
    from asg.scene import Scene

    return [Scene.from_dict(_scene_dict(f"s{i}")) for i in range(3)]


def _numbers(out: Path) -> dict:
    """summary.json without the timings."""
    summary = json.loads((out / "summary.json").read_text())
    for e in summary["scenes"]:
        e.pop("seconds")
    for k in ("seconds_per_scene_median", "scenes_per_hour", "wall_s"):
        summary["aggregate"].pop(k)
    return summary


def _run(out: Path, executor=None) -> dict:
    run_scenes(CFG, _scenes(), out, seed=3, detector_factory="fakes:oracle_factory", executor=executor)
    return _numbers(out)


def _fatal_handlers() -> dict:
    """{signal: the address of its C handler} of the fatal signals."""
    from asg.executors.fatal_signals import handler_address, saved_fatal_handlers

    return {sig: handler_address(buf) for sig, buf in saved_fatal_handlers().items()}


@pytest.mark.slow
def test_one_worker_two_workers_and_ray_give_the_same_summary(tmp_path):
    """... and a Ray batch leaves this process's fatal-signal handlers (pytest's faulthandler) as
    they were: ray.init puts its own on SIGSEGV and ray.shutdown left SIG_DFL, so that a later
    crash of the test process went unreported."""
    pytest.importorskip("ray")
    one = _run(tmp_path / "one")
    with build_executor("local", 2) as two:
        assert _run(tmp_path / "two", two) == one
    before = _fatal_handlers()
    assert before and all(before.values()), before  # pytest's faulthandler, not SIG_DFL
    with build_executor("ray", 2) as ray_two:
        assert _run(tmp_path / "ray", ray_two) == one
        assert _fatal_handlers() == before  # during the batch too
    assert _fatal_handlers() == before
    assert [e["scene_id"] for e in one["scenes"]] == ["s0", "s1", "s2"]  # input order, not finishing order


@pytest.mark.slow
def test_a_killed_worker_is_recovered(tmp_path, monkeypatch):
    monkeypatch.setenv("ASG_TEST_MARKER", str(tmp_path / "marker"))
    reference = _run(tmp_path / "reference")
    with build_executor("local", 2) as two:
        run_scenes(CFG, _scenes(), tmp_path / "killed", seed=3, detector_factory="fakes:dies_once_factory", executor=two)
    assert (tmp_path / "marker").exists()  # a worker was killed mid-scene
    assert _numbers(tmp_path / "killed") == reference  # every scene once, same numbers
    assert not [p for p in (tmp_path / "killed").rglob(".*")]


@pytest.mark.slow
def test_a_killed_ray_actor_is_recovered(tmp_path, monkeypatch):
    pytest.importorskip("ray")
    monkeypatch.setenv("ASG_TEST_MARKER", str(tmp_path / "marker"))
    reference = _run(tmp_path / "reference")
    with build_executor("ray", 2) as ray_two:
        run_scenes(CFG, _scenes(), tmp_path / "killed", seed=3, detector_factory="fakes:dies_once_factory",
                 executor=ray_two)
    assert (tmp_path / "marker").exists()
    assert _numbers(tmp_path / "killed") == reference


def _square(state, x):
    return x * x


@pytest.mark.slow
def test_local_executor_yields_every_item_once():
    with build_executor("local", 2) as ex:
        got = sorted(ex.map_unordered(Job(dict, _square), list(range(7))))
    assert got == [(i, i * i) for i in range(7)]


@pytest.mark.parametrize("argv,needle", [
    (["--workers", "0"], "--workers"),
    (["--executor", "dask"], "--executor"),
    (["--address", "10.0.0.1:6379"], "--address applies to --executor ray"),
])
def test_bad_executor_settings_are_one_line(capsys, tmp_path, argv, needle):
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict())
    code, err = run(capsys, "generate", "--scenes", str(scenes), "--out", str(tmp_path / "out"),
                    "--detector", "fakes:oracle_factory", *argv)
    assert code == 2
    assert_one_line_error(err, needle)


def test_ray_not_installed_is_one_line(capsys, tmp_path, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_ray(name, *a, **k):
        if name == "ray" or name.startswith("ray."):
            raise ImportError("No module named 'ray'")
        return real_import(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_ray)
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict())
    code, err = run(capsys, "generate", "--scenes", str(scenes), "--out", str(tmp_path / "out"),
                    "--detector", "fakes:oracle_factory", "--executor", "ray")
    assert code == 2
    assert_one_line_error(err, "pip install 'asg[ray]'")


@pytest.mark.parametrize("address, needle", [("127.0.0.1:1", "127.0.0.1:1"),
                                             ("10.0.0.5:99999", "a port of 1-65535"),
                                             ("10.0.0.5:0", "a port of 1-65535"),
                                             ("x" * 5000 + ":1", "x" * 80 + "...' is not host:port")])
def test_unreachable_or_malformed_ray_address_is_one_line(capsys, tmp_path, address, needle):
    pytest.importorskip("ray")
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict())
    code, err = run(capsys, "generate", "--scenes", str(scenes), "--out", str(tmp_path / "out"),
                    "--detector", "fakes:oracle_factory", "--executor", "ray", "--address", address)
    assert code == 2
    assert_one_line_error(err, needle)
    assert len(err) < 400


@pytest.mark.slow
def test_evaluate_on_workers_gives_the_same_ap(capsys, tmp_path):
    scenes = tmp_path / "scenes"
    for i in range(3):
        _write(scenes, _scene_dict(f"s{i}"))
    results = []
    for workers in ("1", "2"):
        assert main(["evaluate", "--fusion", "none", "--set", str(scenes), "--workers", workers, "--json"]) == 0
        results.append(json.loads(capsys.readouterr().out))
    assert results[0] == results[1] and results[0]["frames"] == 3
    assert set(results[0]["ap_per_frame"]) == set(results[0]["ap"])  # the paper's yardstick beside ours


@pytest.mark.slow
def test_progress_reaches_the_caller_in_process_and_a_pool_runs_without_it(tmp_path):
    """The evaluation callback travels with the job (no module state): called at every evaluation
    when the scenes run in this process; worker processes (which cannot call back) run the same."""
    from asg.generator.run import open_run

    steps: list[int] = []
    with build_executor("local", 1) as one:
        assert one.in_process
        open_run(CFG, tmp_path / "one", scenes=_scenes(), seed=3).run(
            detector_factory="fakes:oracle_factory", executor=one, on_step=steps.append)
    assert steps and max(steps) == CFG.budget and len(steps) >= 3 * CFG.budget
    with build_executor("local", 2) as two:
        assert not two.in_process
        open_run(CFG, tmp_path / "two", scenes=_scenes(), seed=3).run(
            detector_factory="fakes:oracle_factory", executor=two, on_step=lambda step: pytest.fail("called"))
    assert _numbers(tmp_path / "one") == _numbers(tmp_path / "two")


@pytest.mark.slow
def test_open_run_refuses_other_settings_and_removes_a_folder_it_made_for_bad_input(tmp_path):
    from dataclasses import replace

    from asg.generator.run import open_run
    from sumo_scenarios.errors import InputError

    open_run(CFG, tmp_path / "run", scenes=_scenes(), seed=3).run(detector_factory="fakes:oracle_factory")
    with pytest.raises(InputError, match="other settings"):
        open_run(replace(CFG, budget=5), tmp_path / "run", scenes=_scenes(), seed=3)
    twice = _scenes() + _scenes()[:1]
    with pytest.raises(InputError, match="appears twice"):
        open_run(CFG, tmp_path / "fresh", scenes=twice, seed=3)
    assert not (tmp_path / "fresh").exists()


@pytest.mark.slow
def test_a_hanging_detector_is_stopped_inside_a_ray_actor_too(capsys, tmp_path):
    """The time limit per detector call holds where Ray runs the scenes (an actor's task runs on its
    process's main thread, where the limit's alarm can be set): one line, exit 2."""
    pytest.importorskip("ray")
    scenes = tmp_path / "scenes"
    _write(scenes, _scene_dict("s0"))
    code, err = run(capsys, "generate", "--scenes", str(scenes), "--detector", "fakes:hang_with_short_limit_factory",
                    "--budget", "3", "--workers", "1", "--executor", "ray", "--out", str(tmp_path / "run"))
    assert code == 2
    assert_one_line_error(err, "ran over 1 s on one frame")


def test_third_party_notices_stay_off_a_runs_stderr():
    """torch's, shapely's ... notices are ignored (in the command and in its workers); asg's own
    warnings still show."""
    import warnings

    from asg.executors.base import quiet_third_party_warnings

    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        quiet_third_party_warnings()
        warnings.warn_explicit("a beta API", UserWarning, "torch/x.py", 1, module="torch.serialization")
        warnings.warn_explicit("overflow", RuntimeWarning, "shapely/x.py", 1, module="shapely.geometry")
        warnings.warn("index_reduce() is in beta (Triggered internally at TensorAdvancedIndexing.cpp:1523.)")
        warnings.warn_explicit("ours", UserWarning, "asg/x.py", 1, module="asg.generator.pipeline")
    assert [str(w.message) for w in seen] == ["ours"]



def _sigint_disposition(_=None) -> str:
    import signal

    return "ignored" if signal.getsignal(signal.SIGINT) == signal.SIG_IGN else "handled"


@pytest.mark.slow
def test_processes_spawned_inside_the_block_are_born_ignoring_ctrl_c():
    """The launcher makes a spawned interpreter ignore SIGINT before Python starts (so a Ctrl-C to
    the group while a worker imports prints nothing); outside the block, spawn is as it was, and
    this process's own Ctrl-C handling is untouched."""
    import multiprocessing
    import signal
    from multiprocessing import spawn

    from asg.executors.launcher import sigint_ignoring_launcher, spawned_ignoring_sigint

    if sigint_ignoring_launcher() is None:
        pytest.skip("no /bin/sh or an executable temporary folder here")
    ctx = multiprocessing.get_context("spawn")
    # this process as a terminal's foreground command has it (a shell's background job starts with
    # SIGINT ignored, and its children inherit that)
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        before = spawn.get_executable()
        with spawned_ignoring_sigint():
            with ctx.Pool(1) as pool:
                inside = pool.apply(_sigint_disposition)
            assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        assert spawn.get_executable() == before
        with ctx.Pool(1) as pool:
            outside = pool.apply(_sigint_disposition)
    finally:
        signal.signal(signal.SIGINT, inherited)
    assert (inside, outside) == ("ignored", "handled")


def test_a_sigterm_taken_inside_a_finaliser_still_ends_the_busy_worker_silently():
    """A worker's SIGTERM handler raising inside a finaliser (the garbage collector's weakref
    callbacks, seen once in the suite) was swallowed: "Exception ignored in ..." and a traceback on
    stderr, and the item went on. The worker now exits at once with 143 and prints nothing."""
    code = textwrap.dedent("""
        import os, signal, sys
        from asg.executors import local
        sys.unraisablehook = local._unraisable_in_worker
        signal.signal(signal.SIGTERM, local._exit_on_sigterm)
        local._BUSY = True

        class Finalised:
            def __del__(self):
                os.kill(os.getpid(), signal.SIGTERM)
                sum(range(1000))  # the handler runs here, inside the finaliser

        obj = Finalised()
        del obj
        print("the item went on")
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert proc.returncode == 143, proc.stderr
    assert proc.stdout == "" and proc.stderr == ""


def test_a_rerun_after_the_search_settings_changed_is_refused(tmp_path, monkeypatch):
    """configs/search/NAME.yaml changes what a search finds (BO's batch): run.json records it."""
    from asg.generator import config
    from asg.generator.run import open_run
    from sumo_scenarios.errors import InputError

    open_run(CFG, tmp_path / "run", scenes=_scenes()[:1], seed=3).run(detector_factory="fakes:oracle_factory")
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    del record["search_settings"]  # a folder from before the settings were recorded resumes
    (tmp_path / "run" / "run.json").write_text(json.dumps(record))
    open_run(CFG, tmp_path / "run", scenes=_scenes()[:1], seed=3)
    real = config.search_params
    monkeypatch.setattr(config, "search_params", lambda name: real(name) | {"batch": 4})
    with pytest.raises(InputError, match="other settings \\(search_settings.batch: 1 -> 4\\)"):
        open_run(CFG, tmp_path / "run", scenes=_scenes()[:1], seed=3)


def test_local_workers_share_the_cores_for_their_candidates(monkeypatch):
    from asg.executors import base, local

    monkeypatch.setattr(local, "usable_cores", lambda: 8)
    assert local.LocalExecutor(workers=1).spare_threads(30) == 8
    assert local.LocalExecutor(workers=4).spare_threads(30) == 2
    assert local.LocalExecutor(workers=4).spare_threads(1) == 8  # one scene runs on one worker
    assert local.LocalExecutor(workers=2, threads=4).spare_threads(30) == 1
    assert local.LocalExecutor(workers=16).spare_threads(30) == 1
    assert base.Executor.spare_threads(local.LocalExecutor(), 3) == 1  # an executor that cannot tell: none
    assert local.LocalExecutor(workers=1, idle_cores=False).spare_threads(1) == 1
